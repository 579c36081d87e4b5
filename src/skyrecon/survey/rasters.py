"""Surface rasters of a survey: a DSM and an orthophoto on a projected grid, written as GeoTIFFs.

:func:`surface_rasters` bins a georeferenced cloud (local ENU around a :class:`GeoOrigin`) into a
north-up grid of the projected system (UTM by default). Per cell the **DSM** holds the highest
surface: a high quantile (default the 90th percentile) of the heights that fall in the cell, which is
the top surface without single-point spikes. The **orthophoto** holds the colour of the point that
gave the DSM value: the colour seen from straight above. Cells with no point stay empty (NaN height,
alpha 0), except isolated one-cell gaps inside covered ground, which take their neighbours' median.

Heights are WGS84 ellipsoidal heights in metres (what GPS measures). The grid's affine transform is
stored GDAL/rasterio style: ``(a, b, c, d, e, f)`` with ``x = a * col + b * row + c`` and
``y = d * col + e * row + f`` for the top-left corner of a cell (north-up: ``b = d = 0``, ``e < 0``).
GeoTIFFs are written with ``rasterio`` (the optional ``geo`` extra), atomically.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy import ndimage

from skyrecon.errors import InputError
from skyrecon.io.atomic import write_bytes_atomic
from skyrecon.survey.geo import GeoOrigin, lla_from_projected, projected_from_enu

RASTERIO_HINT = "writing GeoTIFFs needs the 'geo' extra: pip install 'skyrecon[geo]'"
MAX_CELLS = 400_000_000


@dataclass
class SurfaceRasters:
    """A DSM and an orthophoto on one north-up grid of a projected coordinate system.

    Attributes:
        dsm_m: (H, W) float32 ellipsoidal heights, metres; NaN where no surface was seen.
        ortho_rgb: (H, W, 3) uint8 colour seen from above (0 where ``valid`` is False).
        valid: (H, W) bool, cells with a surface.
        transform: ``(a, b, c, d, e, f)`` affine of the grid (top-left corners, metres).
        epsg: EPSG code of the projected system.
        cell_m: cell size, metres.
        points_per_cell: (H, W) int32 how many cloud points fell in each cell.
    """

    dsm_m: np.ndarray
    ortho_rgb: np.ndarray
    valid: np.ndarray
    transform: tuple[float, float, float, float, float, float]
    epsg: int
    cell_m: float
    points_per_cell: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.dsm_m.shape[0]), int(self.dsm_m.shape[1]))

    def cell_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Projected (easting, northing) of every cell centre, each (H, W) metres."""
        a, _, c, _, e, f = self.transform
        h, w = self.shape
        cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        return c + a * cols, f + e * rows

    def cell_of(self, easting: np.ndarray, northing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(row, col) int arrays of projected points; outside the grid gives -1."""
        a, _, c, _, e, f = self.transform
        col = np.floor((np.asarray(easting) - c) / a).astype(np.int64)
        row = np.floor((np.asarray(northing) - f) / e).astype(np.int64)
        h, w = self.shape
        inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
        return np.where(inside, row, -1), np.where(inside, col, -1)


def default_cell_m(points_enu: np.ndarray) -> float:
    """A cell size from the cloud's ground density: about two mean point spacings, rounded to
    1, 2 or 5 times a power of ten (a cloud of 1 point per 0.04 m^2 gives 0.5 m)."""
    p = np.asarray(points_enu, dtype=np.float64)
    if len(p) < 4:
        return 1.0
    lo, hi = np.percentile(p[:, :2], [1, 99], axis=0)
    area = float(np.prod(np.maximum(hi - lo, 1e-3)))
    spacing = np.sqrt(area / len(p))
    raw = max(2.0 * spacing, 0.01)
    power = 10.0 ** np.floor(np.log10(raw))
    for step in (1.0, 2.0, 5.0, 10.0):
        if raw <= step * power * 1.2:
            return float(step * power)
    return float(10.0 * power)


def surface_rasters(
    points_enu: np.ndarray,
    colors: np.ndarray | None,
    origin: GeoOrigin,
    cell_m: float | None = None,
    epsg: int | None = None,
    quantile: float = 0.9,
    fill_gaps: bool = True,
) -> SurfaceRasters:
    """Bin a cloud into a DSM and an orthophoto.

    Args:
        points_enu: (N, 3) points in the local ENU frame of ``origin``, metres.
        colors: (N, 3) uint8 RGB, or None (grey orthophoto).
        origin: the ENU frame's geographic origin.
        cell_m: cell size in metres (default :func:`default_cell_m`).
        epsg: projected system (default the origin's UTM zone).
        quantile: which height quantile of a cell is its surface (1.0 = the highest point).
        fill_gaps: give one-cell holes inside covered ground their neighbours' values.
    """
    pts = np.asarray(points_enu, dtype=np.float64).reshape(-1, 3)
    rgb = None if colors is None else np.asarray(colors, dtype=np.uint8).reshape(-1, 3)
    finite = np.all(np.isfinite(pts), axis=1)
    if not finite.all():  # (no copy of a survey's tens of millions of points when all are finite)
        pts = pts[finite]
        rgb = None if rgb is None else rgb[finite]
    if len(pts) == 0:
        raise InputError("the cloud has no points to make a DSM or an orthophoto from")
    if rgb is None:
        rgb = np.full((len(pts), 3), 160, np.uint8)
    if not 0.0 <= quantile <= 1.0:
        raise InputError(f"the DSM quantile must lie in [0, 1], got {quantile}")
    cell = float(cell_m) if cell_m is not None else default_cell_m(pts)
    if not np.isfinite(cell) or cell <= 0:
        raise InputError(f"the raster cell size must be a positive number of metres, got {cell_m}")
    proj, code = projected_from_enu(origin, pts, epsg)
    west = np.floor(proj[:, 0].min() / cell) * cell
    north = np.ceil(proj[:, 1].max() / cell) * cell
    if north == proj[:, 1].max():
        north += cell
    width = int(np.floor((proj[:, 0].max() - west) / cell)) + 1
    height = int(np.floor((north - proj[:, 1].min()) / cell)) + 1
    if width * height > MAX_CELLS:
        raise InputError(
            f"a {width} x {height} raster at {cell:g} m is too large; choose a larger cell size (--cell)"
        )
    del pts  # only the projected coordinates from here
    flat = np.clip(((north - proj[:, 1]) / cell).astype(np.int64), 0, height - 1)  # row
    flat *= width
    flat += np.clip(((proj[:, 0] - west) / cell).astype(np.int64), 0, width - 1)  # + column
    order = np.lexsort((proj[:, 2], flat))  # by cell, then height
    flat_sorted = flat[order]
    starts = np.flatnonzero(np.r_[True, flat_sorted[1:] != flat_sorted[:-1]])
    counts = np.diff(np.r_[starts, len(flat_sorted)])
    pick = order[starts + np.floor(quantile * (counts - 1)).astype(np.int64)]
    cells = flat_sorted[starts]

    dsm: np.ndarray = np.full((height, width), np.nan, np.float32)
    ortho: np.ndarray = np.zeros((height, width, 3), np.uint8)
    per_cell: np.ndarray = np.zeros((height, width), np.int32)
    cell_rows, cell_cols = np.divmod(cells, width)
    dsm[cell_rows, cell_cols] = proj[pick, 2].astype(np.float32)
    ortho[cell_rows, cell_cols] = rgb[pick]
    per_cell[cell_rows, cell_cols] = counts
    valid = np.isfinite(dsm)
    if fill_gaps:
        _fill_single_gaps(dsm, ortho, valid)
    return SurfaceRasters(
        dsm_m=dsm,
        ortho_rgb=ortho,
        valid=valid,
        transform=(cell, 0.0, float(west), 0.0, -cell, float(north)),
        epsg=code,
        cell_m=cell,
        points_per_cell=per_cell,
    )


def _fill_single_gaps(dsm: np.ndarray, ortho: np.ndarray, valid: np.ndarray) -> None:
    """In place: an empty cell with at least 6 of its 8 neighbours covered takes their median
    height and colour (a one-cell hole in a surface, not the edge of the covered area)."""
    kernel = np.ones((3, 3), np.int32)
    kernel[1, 1] = 0
    neighbours = ndimage.convolve(valid.astype(np.int32), kernel, mode="constant")
    holes = np.argwhere(~valid & (neighbours >= 6))
    if len(holes) == 0:
        return
    h, w = valid.shape
    offsets = np.array([(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc])
    rr = np.clip(holes[:, :1] + offsets[None, :, 0], 0, h - 1)
    cc = np.clip(holes[:, 1:] + offsets[None, :, 1], 0, w - 1)
    heights = dsm[rr, cc]  # (K, 8), NaN where a neighbour is empty
    colours = ortho[rr, cc].astype(np.float64)  # (K, 8, 3)
    colours[~np.isfinite(heights)] = np.nan
    dsm[holes[:, 0], holes[:, 1]] = np.nanmedian(heights, axis=1)
    ortho[holes[:, 0], holes[:, 1]] = np.nanmedian(colours, axis=1).round().astype(np.uint8)
    valid[holes[:, 0], holes[:, 1]] = True


def geotiff_bytes(rasters: SurfaceRasters, which: Literal["dsm", "ortho"]) -> bytes:
    """The GeoTIFF file of the DSM (1 band float32, NaN no-data) or the orthophoto (RGBA uint8,
    alpha 0 where empty), tiled and deflate-compressed."""
    try:
        import rasterio
        from rasterio.io import MemoryFile
        from rasterio.transform import Affine
    except ImportError:
        raise InputError(RASTERIO_HINT) from None
    h, w = rasters.shape
    profile: dict[str, Any] = {
        "driver": "GTiff",
        "width": w,
        "height": h,
        "crs": rasterio.crs.CRS.from_epsg(rasters.epsg),
        "transform": Affine(*rasters.transform),
        "compress": "deflate",
    }
    if w >= 256 and h >= 256:
        profile.update(tiled=True, blockxsize=256, blockysize=256)
    if which == "dsm":
        profile.update(count=1, dtype="float32", nodata=float("nan"))
        bands = rasters.dsm_m[None].astype(np.float32)
    elif which == "ortho":
        profile.update(count=4, dtype="uint8", photometric="RGB")
        alpha = np.where(rasters.valid, 255, 0).astype(np.uint8)
        bands = np.concatenate([np.moveaxis(rasters.ortho_rgb, 2, 0), alpha[None]], axis=0)
    else:
        raise ValueError(f"which must be 'dsm' or 'ortho', got {which!r}")
    with MemoryFile() as mem:
        with mem.open(**profile) as dst:
            dst.write(bands)
            if which == "ortho":
                from rasterio.enums import ColorInterp

                dst.colorinterp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue, ColorInterp.alpha]
            else:
                dst.update_tags(1, units="metre", height="WGS84 ellipsoidal")
        return bytes(mem.read())


def write_geotiff(path: str | Path, rasters: SurfaceRasters, which: Literal["dsm", "ortho"]) -> Path:
    """Write the DSM or the orthophoto to ``path`` as a GeoTIFF, atomically. Returns the path."""
    path = Path(path)
    write_bytes_atomic(path, geotiff_bytes(rasters, which))
    return path


def footprint_geojson(rasters: SurfaceRasters, name: str = "survey footprint") -> dict[str, Any]:
    """A GeoJSON FeatureCollection with the covered area as (multi)polygons in WGS84 lon/lat.

    The outline follows the covered cells (after closing gaps of up to 2 cells); holes smaller than
    20 cells are dropped. Coordinates are ``[lon, lat]`` in degrees (RFC 7946).
    """
    covered = ndimage.binary_closing(rasters.valid, structure=np.ones((5, 5), bool), border_value=0)
    covered = ndimage.binary_fill_holes(covered) | rasters.valid
    labels, n = ndimage.label(covered)
    a, _, c, _, e, f = rasters.transform
    polygons: list[list[list[list[float]]]] = []
    for k in range(1, n + 1):
        mask = labels == k
        if mask.sum() < 4:
            continue
        ring = _outline(mask)
        if len(ring) < 4:
            continue
        east = c + a * ring[:, 1]
        north = f + e * ring[:, 0]
        lat, lon = lla_from_projected(east, north, rasters.epsg)
        coords = [[round(float(x), 9), round(float(y), 9)] for x, y in zip(lon, lat, strict=True)]
        polygons.append([coords])
    geometry: dict[str, Any]
    if len(polygons) == 1:
        geometry = {"type": "Polygon", "coordinates": polygons[0]}
    else:
        geometry = {"type": "MultiPolygon", "coordinates": polygons}
    area_m2 = float(rasters.valid.sum()) * rasters.cell_m**2
    return {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "properties": {"name": name, "covered_area_m2": round(area_m2, 1), "epsg": rasters.epsg},
                "geometry": geometry,
            }
        ],
    }


def _outline(mask: np.ndarray) -> np.ndarray:
    """The outer boundary of one connected region as a closed ring of cell-corner (row, col)
    vertices, counter-clockwise in east/north (the GeoJSON right-hand rule), collinear points removed."""
    padded = np.pad(mask, 1)
    # directed boundary edges between cell corners, with the region on the left (east/north frame)
    edges: dict[tuple[int, int], tuple[int, int]] = {}
    rows, cols = np.nonzero(padded)
    for r, cc in zip(rows.tolist(), cols.tolist(), strict=True):
        rr, c0 = r - 1, cc - 1  # corner coordinates in the unpadded grid
        if not padded[r + 1, cc]:  # south side: west -> east
            edges[(rr + 1, c0)] = (rr + 1, c0 + 1)
        if not padded[r, cc + 1]:  # east side: south -> north
            edges[(rr + 1, c0 + 1)] = (rr, c0 + 1)
        if not padded[r - 1, cc]:  # north side: east -> west
            edges[(rr, c0 + 1)] = (rr, c0)
        if not padded[r, cc - 1]:  # west side: north -> south
            edges[(rr, c0)] = (rr + 1, c0)
    if not edges:
        return np.zeros((0, 2))
    # the outer ring holds the lowest-left corner; walk it
    start = min(edges, key=lambda p: (-p[0], p[1]))
    ring = [start]
    node = edges[start]
    guard = len(edges) + 1
    while node != start and guard > 0:
        ring.append(node)
        node = edges.get(node, start)
        guard -= 1
    ring.append(start)
    pts = np.array(ring, dtype=np.float64)
    d1 = pts[1:-1] - pts[:-2]
    d2 = pts[2:] - pts[1:-1]
    keep = np.r_[True, np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) > 0, True]
    return pts[keep]
