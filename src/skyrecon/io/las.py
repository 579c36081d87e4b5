"""Point clouds as PLY, LAS or LAZ: the one writer every command that writes a cloud uses.

LAS/LAZ (ASPRS LAS 1.2, via ``laspy``; LAZ compressed with the ``lazrs`` backend): coordinates in
metres in the cloud's frame (the world frame for maps and fused clouds), stored as integers with a
scale of 1 mm and offsets at the cloud's minimum; point format 2 with 16-bit RGB (``c * 257``)
when the cloud has colours, else format 0. No CRS is written by default: the coordinates are local
metres. With ``crs`` (georeferenced coordinates, e.g. UTM from ``skyrecon survey``) the file is LAS
1.4, point format 7 (RGB) or 6, with the coordinate system as an OGC WKT VLR, and ``points``
may be given in float64 so that large projected coordinates keep millimetres.
``laspy``/``lazrs`` are the optional ``geo`` extra, imported only when LAS/LAZ is written.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skyrecon.core.depth import PointCloud
from skyrecon.errors import InputError
from skyrecon.io.atomic import atomic_write
from skyrecon.io.ply import write_ply

__all__ = ["CLOUD_FORMATS", "GEO_HINT", "write_point_cloud", "write_las", "read_las"]

CLOUD_FORMATS = ("ply", "las", "laz")
GEO_HINT = "writing LAS/LAZ needs the 'geo' extra: pip install 'skyrecon[geo]'"
LAS_SCALE_M = 0.001
_WRITE_CHUNK = 1_000_000  # points per chunk written


def write_las(
    path: str | Path,
    cloud: PointCloud,
    compress: bool = False,
    crs: object | None = None,
    points: np.ndarray | None = None,
) -> None:
    """Write ``cloud`` (N points, metres) as LAS, or LAZ when ``compress``, atomically (see the module).

    Args:
        crs: the coordinate system of the points (anything ``pyproj.CRS.from_user_input`` reads,
            e.g. ``"EPSG:32632"``), written as a WKT VLR; None: no CRS (local metres).
        points: (N, 3) float64 coordinates to write instead of ``cloud.points`` (float32), same order.
    """
    try:
        import laspy
    except ImportError:
        raise InputError(GEO_HINT, path) from None
    pts = np.asarray(cloud.points if points is None else points, dtype=np.float64).reshape(-1, 3)
    if len(pts) != len(cloud.points):
        raise InputError(f"{len(pts)} coordinates for a cloud of {len(cloud.points)} points", path)
    if not np.all(np.isfinite(pts)):
        raise InputError("the cloud has NaN or infinite coordinates", path)
    colors = cloud.colors
    has_rgb = colors is not None
    if crs is None:
        header = laspy.LasHeader(point_format=2 if has_rgb else 0, version="1.2")
    else:
        try:
            import pyproj
        except ImportError:
            raise InputError(GEO_HINT, path) from None
        header = laspy.LasHeader(point_format=7 if has_rgb else 6, version="1.4")
        header.add_crs(pyproj.CRS.from_user_input(crs))
    header.scales = np.full(3, LAS_SCALE_M)
    header.offsets = pts.min(axis=0) if len(pts) else np.zeros(3)
    backend = None
    if compress:
        if not laspy.LazBackend.Lazrs.is_available():
            raise InputError("writing LAZ needs the 'lazrs' backend: pip install 'skyrecon[geo]'", path)
        # the parallel compressor (all cores) writes the same bytes as the serial one
        parallel = laspy.LazBackend.LazrsParallel
        backend = parallel if parallel.is_available() else laspy.LazBackend.Lazrs
    # written in chunks of points: a survey's tens of millions of points never exist a second time
    # as one whole point record (and its scaled copies) beside the cloud
    with atomic_write(path, "wb") as f:
        with laspy.open(
            f, mode="w", header=header, do_compress=compress, laz_backend=backend, closefd=False
        ) as writer:
            for a in range(0, len(pts), _WRITE_CHUNK):
                b = min(len(pts), a + _WRITE_CHUNK)
                rec = laspy.ScaleAwarePointRecord.zeros(b - a, header=header)
                rec.x, rec.y, rec.z = pts[a:b, 0], pts[a:b, 1], pts[a:b, 2]
                if colors is not None:
                    rgb = np.asarray(colors[a:b], dtype=np.uint16) * 257
                    rec.red, rec.green, rec.blue = rgb[:, 0], rgb[:, 1], rgb[:, 2]
                writer.write_points(rec)


def read_las(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a LAS or LAZ file.

    Returns:
        points (N, 3) float64 in the file's coordinates (scale and offset applied; metres for
        skyrecon's files; float64 so georeferenced coordinates keep their precision) and colours
        (N, 3) uint8 RGB (16-bit values scaled to 0..255) when the point format has them, else None.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("LAS/LAZ file not found; check the path", path)
    try:
        import laspy
    except ImportError:
        raise InputError("reading LAS/LAZ needs the 'geo' extra: pip install 'skyrecon[geo]'", path) from None
    try:
        las = laspy.read(path)
    except Exception as e:  # laspy raises its own errors and OSError/ValueError for bad files
        raise InputError(f"unreadable LAS/LAZ file ({e})", path) from None
    pts = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], axis=1)
    colors = None
    if {"red", "green", "blue"} <= set(las.point_format.dimension_names):
        rgb = np.stack([np.asarray(las.red), np.asarray(las.green), np.asarray(las.blue)], axis=1)
        colors = (rgb // 257 if rgb.max(initial=0) > 255 else rgb).astype(np.uint8)
    return pts.astype(np.float64), colors


def write_point_cloud(
    path: str | Path,
    cloud: PointCloud,
    fmt: str = "ply",
    crs: object | None = None,
    points: np.ndarray | None = None,
) -> Path:
    """Write ``cloud`` as ``fmt`` (``ply``, ``las`` or ``laz``) at ``path`` with its suffix set to the
    format (``points.ply`` -> ``points.las``); returns the path written. ``crs`` and float64
    ``points``: see :func:`write_las` (LAS/LAZ only; a PLY gets ``cloud`` as it is)."""
    if fmt not in CLOUD_FORMATS:
        raise InputError(f"unknown point cloud format {fmt!r}; choose one of {', '.join(CLOUD_FORMATS)}")
    out = Path(path).with_suffix("." + fmt)
    if fmt == "ply":
        write_ply(out, cloud)
    else:
        write_las(out, cloud, compress=fmt == "laz", crs=crs, points=points)
    return out
