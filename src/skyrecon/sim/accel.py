"""A uniform 2-D grid over the ground plane listing the obstacles above each cell.

Ray casting walks the grid cells a ray crosses (2-D DDA in x, y) and tests only the
obstacles listed there; distance queries search rings of cells outward from a point.
Items are numbered boxes first (``0 .. N-1``) then cylinders (``N .. N+M-1``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class UniformGrid:
    """Cells of side ``cell_m`` covering the obstacles' footprint, world frame.

    Attributes:
        x0, y0: world position of the grid's lower-left corner, metres.
        cell_m: cell side, metres.
        ncx, ncy: number of cells along x and y.
        z_lo, z_hi: vertical range of all obstacles, metres.
        cell_start: (ncx * ncy + 1,) int64 CSR offsets into ``cell_items``; cell ``c = iy * ncx + ix``.
        cell_items: (K,) int32 item numbers (boxes first, then cylinders).
        cell_zmax: (ncx * ncy,) float64 top of the highest item in each cell (-inf if empty).
    """

    x0: float
    y0: float
    cell_m: float
    ncx: int
    ncy: int
    z_lo: float
    z_hi: float
    cell_start: np.ndarray
    cell_items: np.ndarray
    cell_zmax: np.ndarray


def item_bounds(boxes: np.ndarray, cylinders: np.ndarray) -> np.ndarray:
    """(N + M, 6) axis-aligned bounds ``[xmin, ymin, zmin, xmax, ymax, zmax]`` of every item."""
    c = cylinders
    cyl_b = np.stack(
        [c[:, 0] - c[:, 2], c[:, 1] - c[:, 2], c[:, 3], c[:, 0] + c[:, 2], c[:, 1] + c[:, 2], c[:, 4]], axis=1
    )
    return np.concatenate([boxes.reshape(-1, 6), cyl_b.reshape(-1, 6)], axis=0)


def build_grid(boxes: np.ndarray, cylinders: np.ndarray, cell_m: float | None = None) -> UniformGrid:
    """Bin boxes (N, 6) and cylinders (M, 5) into a uniform grid.

    Args:
        boxes: (N, 6) ``[xmin, ymin, zmin, xmax, ymax, zmax]``, metres.
        cylinders: (M, 5) ``[x, y, radius, zmin, zmax]``, metres.
        cell_m: cell side in metres; by default about four cells per item over the footprint.
    """
    bounds = item_bounds(boxes, cylinders)
    n = len(bounds)
    if n == 0:
        return UniformGrid(
            0.0, 0.0, 1.0, 1, 1, 0.0, 0.0, np.zeros(2, np.int64), np.zeros(0, np.int32), np.full(1, -np.inf)
        )
    lo = bounds[:, :3].min(axis=0)
    hi = bounds[:, 3:].max(axis=0)
    span = np.maximum(hi[:2] - lo[:2], 1e-3)
    if cell_m is None:
        cell_m = float(np.clip(np.sqrt(span[0] * span[1] / (4.0 * n)), 0.25, 16.0))
    pad = 1e-6 * max(1.0, float(span.max()))
    x0, y0 = float(lo[0] - pad), float(lo[1] - pad)
    ncx = max(1, int(np.ceil((hi[0] + pad - x0) / cell_m)))
    ncy = max(1, int(np.ceil((hi[1] + pad - y0) / cell_m)))
    i0 = np.clip(np.floor((bounds[:, 0] - x0) / cell_m).astype(np.int64), 0, ncx - 1)
    i1 = np.clip(np.floor((bounds[:, 3] - x0) / cell_m).astype(np.int64), 0, ncx - 1)
    j0 = np.clip(np.floor((bounds[:, 1] - y0) / cell_m).astype(np.int64), 0, ncy - 1)
    j1 = np.clip(np.floor((bounds[:, 4] - y0) / cell_m).astype(np.int64), 0, ncy - 1)
    cells, items = [], []
    for k in range(n):
        jj, ii = np.meshgrid(np.arange(j0[k], j1[k] + 1), np.arange(i0[k], i1[k] + 1), indexing="ij")
        c = (jj * ncx + ii).ravel()
        cells.append(c)
        items.append(np.full(c.size, k, np.int32))
    cells_a = np.concatenate(cells)
    items_a = np.concatenate(items)
    order = np.lexsort((items_a, cells_a))
    cells_a, items_a = cells_a[order], items_a[order]
    counts = np.bincount(cells_a, minlength=ncx * ncy)
    start = np.zeros(ncx * ncy + 1, np.int64)
    np.cumsum(counts, out=start[1:])
    zmax = np.full(ncx * ncy, -np.inf)
    np.maximum.at(zmax, cells_a, bounds[items_a, 5])
    return UniformGrid(
        x0,
        y0,
        float(cell_m),
        ncx,
        ncy,
        float(lo[2]),
        float(hi[2]),
        start,
        np.ascontiguousarray(items_a),
        zmax,
    )
