"""Geographic frames of a survey: WGS84 latitude/longitude/height, a local ENU frame, UTM.

Everything a survey computes lives in a **local ENU frame** (x east, y north, z up, metres) around a
double-precision geographic origin (:class:`GeoOrigin`), so float32 clouds and maps keep
millimetre precision. Conversions to and from WGS84 are closed-form (ECEF, then a rotation) in NumPy
and need no extra package; the projected system of the GIS outputs (UTM by default) goes through
``pyproj`` (the optional ``geo`` extra), imported only when asked for.

Conventions: latitude and longitude in degrees (WGS84), heights in metres above the WGS84 ellipsoid
(GPS heights). EXIF altitudes are above mean sea level; the difference (the geoid, up to about
100 m) is a constant offset over a survey and is absorbed by the georeferencing fit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from skyrecon.errors import InputError

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
PYPROJ_HINT = "projected coordinates (UTM) need the 'geo' extra: pip install 'skyrecon[geo]'"


@dataclass(frozen=True)
class GeoOrigin:
    """The geographic point at the local ENU frame's origin (WGS84, ellipsoidal height in metres)."""

    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0

    def __post_init__(self) -> None:
        if not (-90.0 < self.lat_deg < 90.0) or not (-180.0 <= self.lon_deg <= 180.0):
            raise InputError(
                f"geographic origin ({self.lat_deg}, {self.lon_deg}) is not a latitude/longitude in degrees"
            )
        if not np.isfinite(self.alt_m):
            raise InputError(f"geographic origin height {self.alt_m} is not a number")

    def to_json(self) -> dict[str, Any]:
        return {
            "lat": float(self.lat_deg),
            "lon": float(self.lon_deg),
            "alt": float(self.alt_m),
            "datum": "WGS84",
        }

    @staticmethod
    def from_json(d: dict[str, Any]) -> GeoOrigin:
        try:
            return GeoOrigin(float(d["lat"]), float(d["lon"]), float(d.get("alt", 0.0)))
        except (KeyError, TypeError, ValueError):
            raise InputError(
                f"a geographic origin needs numeric 'lat', 'lon' (and 'alt'); got {d!r}"
            ) from None

    def ecef_m(self) -> np.ndarray:
        """The origin in ECEF, metres. Shape (3,)."""
        return ecef_from_lla(self.lat_deg, self.lon_deg, self.alt_m)[0]

    def ecef_from_enu_rotation(self) -> np.ndarray:
        """R (3, 3) with ``ecef - ecef_origin = R @ enu``: columns are east, north, up in ECEF."""
        lat, lon = np.radians(self.lat_deg), np.radians(self.lon_deg)
        sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
        east = [-so, co, 0.0]
        north = [-sl * co, -sl * so, cl]
        up = [cl * co, cl * so, sl]
        return np.array([east, north, up], dtype=np.float64).T


def _as_1d(*arrays: Any) -> list[np.ndarray]:
    out = [np.atleast_1d(np.asarray(a, dtype=np.float64)) for a in arrays]
    shape = np.broadcast_shapes(*(a.shape for a in out))
    return [np.broadcast_to(a, shape).ravel() for a in out]


def ecef_from_lla(lat_deg: Any, lon_deg: Any, alt_m: Any) -> np.ndarray:
    """WGS84 geodetic to Earth-centred Earth-fixed. Returns (N, 3) metres."""
    lat_d, lon_d, alt = _as_1d(lat_deg, lon_deg, alt_m)
    lat, lon = np.radians(lat_d), np.radians(lon_d)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    x = (n + alt) * np.cos(lat) * np.cos(lon)
    y = (n + alt) * np.cos(lat) * np.sin(lon)
    z = (n * (1.0 - WGS84_E2) + alt) * np.sin(lat)
    return np.stack([x, y, z], axis=1)


def lla_from_ecef(ecef_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF (N, 3) metres to WGS84 (lat_deg, lon_deg, alt_m), each (N,).

    Iterative (converges to below a micrometre in a few steps anywhere off the poles' axis).
    """
    p = np.asarray(ecef_m, dtype=np.float64).reshape(-1, 3)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    lon = np.arctan2(y, x)
    r = np.hypot(x, y)
    lat = np.arctan2(z, r * (1.0 - WGS84_E2))
    alt = np.zeros_like(lat)
    for _ in range(6):
        n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
        alt = r / np.maximum(np.cos(lat), 1e-12) - n
        lat = np.arctan2(z, r * (1.0 - WGS84_E2 * n / (n + alt)))
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    alt = r / np.maximum(np.cos(lat), 1e-12) - n
    return np.degrees(lat), np.degrees(lon), alt


def enu_from_lla(origin: GeoOrigin, lat_deg: Any, lon_deg: Any, alt_m: Any) -> np.ndarray:
    """WGS84 positions to the local ENU frame of ``origin``. Returns (N, 3) float64 metres."""
    d = ecef_from_lla(lat_deg, lon_deg, alt_m) - origin.ecef_m()
    return d @ origin.ecef_from_enu_rotation()


def lla_from_enu(origin: GeoOrigin, enu_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local ENU (N, 3) metres to WGS84 (lat_deg, lon_deg, alt_m), each (N,)."""
    enu = np.asarray(enu_m, dtype=np.float64).reshape(-1, 3)
    ecef = enu @ origin.ecef_from_enu_rotation().T + origin.ecef_m()
    return lla_from_ecef(ecef)


def utm_epsg(lat_deg: float, lon_deg: float) -> int:
    """The EPSG code of the WGS84 UTM zone holding a point (326zz north, 327zz south).

    Norway's and Svalbard's zone exceptions are applied as in the UTM standard.
    """
    lon = ((float(lon_deg) + 180.0) % 360.0) - 180.0
    zone = int((lon + 180.0) // 6.0) + 1
    if 56.0 <= lat_deg < 64.0 and 3.0 <= lon < 12.0:
        zone = 32
    if 72.0 <= lat_deg < 84.0:
        for lo, hi, z in ((0.0, 9.0, 31), (9.0, 21.0, 33), (21.0, 33.0, 35), (33.0, 42.0, 37)):
            if lo <= lon < hi:
                zone = z
    zone = min(max(zone, 1), 60)
    return (32600 if lat_deg >= 0.0 else 32700) + zone


def _transformer(epsg: int) -> Any:
    try:
        from pyproj import Transformer
    except ImportError:
        raise InputError(PYPROJ_HINT) from None
    try:
        return Transformer.from_crs("EPSG:4326", f"EPSG:{int(epsg)}", always_xy=True)
    except Exception as exc:  # pyproj's CRSError and friends
        raise InputError(f"unknown coordinate system EPSG:{epsg} ({exc})") from None


def projected_from_enu(
    origin: GeoOrigin, enu_m: np.ndarray, epsg: int | None = None
) -> tuple[np.ndarray, int]:
    """Local ENU (N, 3) to a projected system: (easting, northing, height) (N, 3) metres and its EPSG.

    ``epsg`` defaults to the UTM zone of the origin. Heights stay ellipsoidal (metres).
    """
    code = int(epsg) if epsg is not None else utm_epsg(origin.lat_deg, origin.lon_deg)
    lat, lon, alt = lla_from_enu(origin, enu_m)
    east, north = _transformer(code).transform(lon, lat)
    return np.stack([np.asarray(east), np.asarray(north), alt], axis=1), code


def lla_from_projected(easting: Any, northing: Any, epsg: int) -> tuple[np.ndarray, np.ndarray]:
    """Projected coordinates (metres) back to WGS84 (lat_deg, lon_deg), each (N,)."""
    e, n = _as_1d(easting, northing)
    lon, lat = _transformer(epsg).transform(e, n, direction="INVERSE")
    return np.asarray(lat), np.asarray(lon)
