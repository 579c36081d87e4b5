"""Photo metadata of a survey: EXIF GPS, focal length and sensor size, DJI-style XMP altitudes.

* :func:`read_photo_meta`: what a geotagged photo says about where it was taken and with what lens
  (Pillow; the JPEG is not decoded).
* :func:`write_geotagged_jpeg`: an RGB image as a JPEG carrying EXIF GPS and camera tags (what
  ``skyrecon render survey`` writes), optionally with a DJI-style XMP packet.

Positions: latitude and longitude in degrees (WGS84, north and east positive), altitude in metres.
EXIF's ``GPSAltitude`` is nominally above sea level; drones (DJI) also put
``drone-dji:AbsoluteAltitude`` and ``drone-dji:RelativeAltitude`` (above take-off) in an XMP packet.
The absolute XMP altitude is preferred when present (it is what the flight controller used); a
survey treats every altitude of one set as one datum, so a constant offset only shifts the model.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.errors import InputError
from skyrecon.io.atomic import atomic_write

__all__ = ["PhotoMeta", "read_photo_meta", "write_geotagged_jpeg", "intrinsics_from_meta"]

_IFD_EXIF = 0x8769
_IFD_GPS = 0x8825
_MAKE, _MODEL = 271, 272
_FOCAL_LENGTH = 37386
_FOCAL_PLANE_X_RES, _FOCAL_PLANE_Y_RES, _FOCAL_PLANE_UNIT = 41486, 41487, 41488
_FOCAL_35MM = 41989
_GPS_LAT_REF, _GPS_LAT, _GPS_LON_REF, _GPS_LON, _GPS_ALT_REF, _GPS_ALT = 1, 2, 3, 4, 5, 6
#: EXIF FocalPlaneResolutionUnit -> millimetres per unit.
_UNIT_MM = {1: 25.4, 2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}


@dataclass(frozen=True)
class PhotoMeta:
    """What a photo's tags say.

    Attributes:
        path: the file.
        width, height: pixels.
        lat_deg, lon_deg, alt_m: the GPS position (None when the photo has no GPS tags);
            ``alt_m`` from the XMP absolute altitude when present (see ``alt_source``), else EXIF.
        alt_source: ``"xmp"``, ``"exif"`` or None.
        relative_alt_m: XMP ``RelativeAltitude`` (above take-off), metres, or None.
        focal_mm: EXIF ``FocalLength``, millimetres, or None.
        sensor_width_mm: sensor width from ``FocalPlaneXResolution`` (or known from the camera), or None.
        focal_35mm: EXIF ``FocalLengthIn35mmFilm``, millimetres, or None.
        make, model: camera maker and model ("" when absent).
    """

    path: Path
    width: int
    height: int
    lat_deg: float | None
    lon_deg: float | None
    alt_m: float | None
    alt_source: str | None
    relative_alt_m: float | None
    focal_mm: float | None
    sensor_width_mm: float | None
    focal_35mm: float | None
    make: str = ""
    model: str = ""

    @property
    def has_gps(self) -> bool:
        return self.lat_deg is not None and self.lon_deg is not None and self.alt_m is not None


def _float(v) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return f if np.isfinite(f) else None


def _dms(v) -> float | None:
    try:
        d, m, s = (float(x) for x in v)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return d + m / 60.0 + s / 3600.0


def _ref(v) -> str:
    if isinstance(v, bytes):
        v = v.decode("ascii", "ignore")
    return str(v or "").strip("\x00 ").upper()


_XMP_NUM = r"\s*[=:>]\s*\"?\s*([+-]?[0-9.]+(?:[eE][+-]?\d+)?)"


def _xmp_value(xmp: str, name: str) -> float | None:
    """A number of the XMP packet: attribute ``drone-dji:Name="+1.0"`` or element ``<drone-dji:Name>1.0<``."""
    m = re.search(r"(?:drone-dji|drone|Camera|dji):" + name + _XMP_NUM, xmp)
    return _float(m.group(1)) if m else None


def read_photo_meta(path: str | Path) -> PhotoMeta:
    """The GPS position, focal length and sensor size a photo's EXIF/XMP tags give.

    Raises:
        InputError: the file cannot be read as an image.
    """
    from PIL import Image as PILImage

    p = Path(path)
    try:
        with PILImage.open(p) as img:
            width, height = img.size
            exif = img.getexif()
            xmp_raw = img.info.get("xmp") or b""
    except Exception as exc:  # noqa: BLE001 - Pillow raises many types for a bad file
        raise InputError(f"unreadable image ({exc})", p) from None
    gps = exif.get_ifd(_IFD_GPS)
    ex = exif.get_ifd(_IFD_EXIF)
    xmp = xmp_raw.decode("utf-8", "ignore") if isinstance(xmp_raw, bytes) else str(xmp_raw)
    lat = _dms(gps.get(_GPS_LAT))
    lon = _dms(gps.get(_GPS_LON))
    if lat is not None and _ref(gps.get(_GPS_LAT_REF)) == "S":
        lat = -lat
    if lon is not None and _ref(gps.get(_GPS_LON_REF)) == "W":
        lon = -lon
    alt = _float(gps.get(_GPS_ALT))
    if alt is not None:
        ref = gps.get(_GPS_ALT_REF, 0)
        below = ref[0] if isinstance(ref, bytes) and ref else ref
        if below == 1:
            alt = -alt
    alt_source = "exif" if alt is not None else None
    if xmp:
        if lat is None:
            lat = _xmp_value(xmp, "GpsLatitude")
        if lon is None:
            lon = _xmp_value(xmp, "GpsLongitude") or _xmp_value(xmp, "GpsLongtitude")
        x_alt = _xmp_value(xmp, "AbsoluteAltitude")
        if x_alt is not None:
            alt, alt_source = x_alt, "xmp"
    rel = _xmp_value(xmp, "RelativeAltitude") if xmp else None
    focal = _float(ex.get(_FOCAL_LENGTH))
    f35 = _float(ex.get(_FOCAL_35MM))
    sensor_w = None
    xres = _float(ex.get(_FOCAL_PLANE_X_RES))
    unit = ex.get(_FOCAL_PLANE_UNIT, 2)
    if xres and xres > 0 and unit in _UNIT_MM:
        sensor_w = width / xres * _UNIT_MM[unit]
    return PhotoMeta(
        p,
        int(width),
        int(height),
        lat,
        lon,
        alt,
        alt_source if lat is not None and lon is not None else None,
        rel,
        focal if focal and focal > 0 else None,
        sensor_w,
        f35 if f35 and f35 > 0 else None,
        str(exif.get(_MAKE, "") or "").strip("\x00 "),
        str(exif.get(_MODEL, "") or "").strip("\x00 "),
    )


def intrinsics_from_meta(meta: PhotoMeta) -> Intrinsics:
    """A pinhole camera from the EXIF focal length and sensor width (principal point at the centre).

    ``fx = fy = focal_mm / sensor_width_mm * width``; without a sensor width, the 35 mm equivalent
    focal length (``f35 / 36 mm * width``, the diagonal rule for the image's aspect).

    Raises:
        InputError: neither is in the tags (give ``--camera K.txt``).
    """
    W, H = meta.width, meta.height
    if meta.focal_mm and meta.sensor_width_mm:
        f = meta.focal_mm / meta.sensor_width_mm * W
    elif meta.focal_35mm:
        # 35 mm equivalence is defined on the diagonal (43.27 mm for 36 x 24 mm)
        f = meta.focal_35mm / 43.2666 * float(np.hypot(W, H))
    else:
        raise InputError(
            "the photo has no EXIF focal length with a sensor size (FocalLength + FocalPlaneXResolution, "
            "or FocalLengthIn35mmFilm); give the camera matrix with --camera K.txt",
            meta.path,
        )
    return Intrinsics(f, f, (W - 1) / 2.0, (H - 1) / 2.0, W, H)


def _rational(x: float, denominator: int = 10000):
    from PIL.TiffImagePlugin import IFDRational

    return IFDRational(round(float(x) * denominator), denominator)


def _to_dms(value_deg: float) -> tuple:
    """(degrees, minutes, seconds) rationals; seconds to 1e-5 (0.3 mm of latitude)."""
    v = abs(float(value_deg))
    d = int(v)
    m = int((v - d) * 60)
    s = (v - d - m / 60.0) * 3600.0
    return _rational(d, 1), _rational(m, 1), _rational(s, 100000)


def dji_xmp(absolute_alt_m: float, relative_alt_m: float | None = None) -> bytes:
    """A minimal DJI-style XMP packet with ``drone-dji:AbsoluteAltitude`` (and ``RelativeAltitude``)."""
    rel = f' drone-dji:RelativeAltitude="{relative_alt_m:+.3f}"' if relative_alt_m is not None else ""
    return (
        '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
        '<rdf:Description rdf:about="" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" '
        f'drone-dji:AbsoluteAltitude="{absolute_alt_m:+.3f}"{rel}/></rdf:RDF></x:xmpmeta>'
    ).encode()


def write_geotagged_jpeg(
    path: str | Path,
    rgb: np.ndarray,
    lat_deg: float,
    lon_deg: float,
    alt_m: float,
    focal_mm: float,
    sensor_width_mm: float,
    *,
    quality: int = 92,
    make: str = "skyrecon",
    model: str = "synthetic survey camera",
    xmp: bytes | None = None,
) -> None:
    """Write ``rgb`` (H, W, 3) uint8 as a JPEG with EXIF GPS (degrees, metres) and the focal length
    and sensor width (millimetres) that give its camera matrix, atomically."""
    from PIL import Image as PILImage

    img = PILImage.fromarray(np.ascontiguousarray(rgb, dtype=np.uint8), "RGB")
    exif = PILImage.Exif()
    exif[_MAKE] = make
    exif[_MODEL] = model
    ex = exif.get_ifd(_IFD_EXIF)
    ex[_FOCAL_LENGTH] = _rational(focal_mm)
    ex[_FOCAL_PLANE_X_RES] = _rational(img.width / sensor_width_mm, 100000)
    ex[_FOCAL_PLANE_Y_RES] = _rational(img.width / sensor_width_mm, 100000)
    ex[_FOCAL_PLANE_UNIT] = 4  # millimetres
    gps = exif.get_ifd(_IFD_GPS)
    gps[0] = b"\x02\x03\x00\x00"  # GPSVersionID 2.3
    gps[_GPS_LAT_REF] = "N" if lat_deg >= 0 else "S"
    gps[_GPS_LAT] = _to_dms(lat_deg)
    gps[_GPS_LON_REF] = "E" if lon_deg >= 0 else "W"
    gps[_GPS_LON] = _to_dms(lon_deg)
    gps[_GPS_ALT_REF] = b"\x00" if alt_m >= 0 else b"\x01"
    gps[_GPS_ALT] = _rational(abs(alt_m), 1000)
    kwargs: dict = {"exif": exif, "quality": quality}
    if xmp is not None:
        kwargs["xmp"] = xmp
    with atomic_write(path, "wb") as f:
        img.save(f, "JPEG", **kwargs)
