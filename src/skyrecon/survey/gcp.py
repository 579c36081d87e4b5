"""Ground control points in OpenDroneMap's ``gcp_list.txt`` format.

The first line names the coordinate system of the points: ``EPSG:32632``, ``WGS84 UTM 32N``
(``S`` for the south), or a PROJ string ``+proj=utm +zone=32 +datum=WGS84 +units=m +no_defs``.
Every other non-empty, non-comment line is one observation of a point in one photo::

    geo_x geo_y geo_z im_x im_y image_name [gcp_name ...]

``geo_x geo_y`` are easting and northing in the system (longitude, latitude for ``EPSG:4326``),
``geo_z`` the height in metres, ``im_x im_y`` the pixel (OpenDroneMap's convention: the top-left
pixel's corner at (0, 0); converted here to skyrecon's, the top-left pixel's centre at (0, 0)).
Observations of the same point (same name, else same coordinates) are grouped.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skyrecon.errors import InputError

__all__ = ["GroundControlPoint", "GcpList", "read_gcp_list", "GEO_HINT"]

GEO_HINT = "the survey's geodesy needs the 'geo' extra: pip install 'skyrecon[geo]'"


@dataclass
class GroundControlPoint:
    """One control point.

    Attributes:
        name: its name (the 7th column, else ``gcpN``).
        xyz: (3,) float64 coordinates in the file's system (easting, northing, height; or lon, lat, height).
        lat_deg, lon_deg, alt_m: the same point in WGS84 (filled by :func:`read_gcp_list`).
        observations: image name -> (2,) pixel (u, v), skyrecon convention.
    """

    name: str
    xyz: np.ndarray
    lat_deg: float = float("nan")
    lon_deg: float = float("nan")
    alt_m: float = float("nan")
    observations: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass
class GcpList:
    """A parsed ``gcp_list.txt``: the coordinate system line, its CRS, and the points."""

    path: Path
    crs_text: str
    points: list[GroundControlPoint]


_UTM = re.compile(r"^\s*WGS\s*-?84\s+UTM\s+(\d{1,2})\s*([NS])\s*$", re.IGNORECASE)


def _crs(text: str, path: Path):
    """A ``pyproj.CRS`` of the coordinate-system line."""
    try:
        from pyproj import CRS
        from pyproj.exceptions import CRSError
    except ImportError:
        raise InputError(GEO_HINT, path) from None
    m = _UTM.match(text)
    try:
        if m:
            zone = int(m.group(1))
            if not 1 <= zone <= 60:
                raise InputError(f"UTM zone {zone} does not exist (1..60)", path)
            return CRS.from_epsg((32600 if m.group(2).upper() == "N" else 32700) + zone)
        return CRS.from_user_input(text.strip())
    except CRSError as exc:
        raise InputError(
            f"the first line {text.strip()!r} is not a coordinate system ({exc}); write e.g. 'EPSG:32632', "
            "'WGS84 UTM 32N' or a '+proj=...' string",
            path,
        ) from None


def read_gcp_list(path: str | Path) -> GcpList:
    """Read an OpenDroneMap GCP file (see the module) and convert the points to WGS84.

    Raises:
        InputError: missing file, a bad coordinate system line or observation line (the message
            names the line), or no observation.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError("GCP file not found; check the path", p)
    lines = [ln.strip() for ln in p.read_text(errors="replace").splitlines()]
    lines = [ln for ln in lines if ln and not ln.startswith("#")]
    if not lines:
        raise InputError("the GCP file is empty; the first line names the coordinate system", p)
    crs = _crs(lines[0], p)
    by_key: dict[str, GroundControlPoint] = {}
    for no, ln in enumerate(lines[1:], start=2):
        parts = ln.split()
        if len(parts) < 6:
            raise InputError(
                f"line {no} has {len(parts)} fields; expected 'X Y Z px py image [name]': {ln[:80]!r}", p
            )
        try:
            x, y, z, u, v = (float(t) for t in parts[:5])
        except ValueError:
            raise InputError(f"line {no}: the first five fields must be numbers: {ln[:80]!r}", p) from None
        if not all(np.isfinite([x, y, z, u, v])):
            raise InputError(f"line {no}: NaN or infinite value", p)
        image = parts[5]
        name = parts[6] if len(parts) > 6 else f"{x:.3f},{y:.3f},{z:.3f}"
        g = by_key.get(name)
        if g is None:
            g = by_key[name] = GroundControlPoint(
                parts[6] if len(parts) > 6 else f"gcp{len(by_key) + 1}", np.array([x, y, z])
            )
        g.observations[image] = np.array([u - 0.5, v - 0.5])
    if not by_key:
        raise InputError("the GCP file has a coordinate system line but no observation", p)
    points = list(by_key.values())
    from pyproj import Transformer

    to_wgs = Transformer.from_crs(
        crs, "EPSG:4979" if crs.is_geographic and len(crs.axis_info) == 3 else "EPSG:4326", always_xy=True
    )
    xyz = np.stack([g.xyz for g in points])
    lon, lat = to_wgs.transform(xyz[:, 0], xyz[:, 1])[:2]
    for g, la, lo in zip(points, np.atleast_1d(lat), np.atleast_1d(lon)):
        g.lat_deg, g.lon_deg, g.alt_m = float(la), float(lo), float(g.xyz[2])
    return GcpList(p, lines[0], points)
