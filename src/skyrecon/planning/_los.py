"""Exact line-of-sight on the grid of *safe dual cells* (Numba).

The distance grid holds values at voxel centres ``c_i = origin + (i + 0.5) v``. Its dual cells
are the boxes between 2 x 2 x 2 neighbouring centres: dual cell ``i`` spans ``[c_i, c_{i+1}]``.
Trilinear interpolation inside a dual cell is a weighted average of its 8 corner values, so
when all 8 corners are at least the threshold (the cell is *safe*) every point of the cell is
clear. A segment is therefore clear if every dual cell it passes through is safe, which a 3-D
DDA (Amanatides & Woo) decides in one array read per cell: exact (never accepts a segment that
dips below the threshold) and fast.

Positions here are in dual units ``u = (p - origin) / v - 0.5``: dual cell ``i`` is ``[i, i + 1)``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def los(safe, ax, ay, az, bx, by, bz):
    """Whether the segment a -> b (dual units) crosses only safe dual cells of ``safe`` (uint8 3-D).

    Symmetric: the walk always starts from the lexicographically smaller end, so that ties
    (the segment passing exactly through a cell edge or corner) are broken the same way for
    a -> b and b -> a.
    """
    if (bx, by, bz) < (ax, ay, az):
        ax, ay, az, bx, by, bz = bx, by, bz, ax, ay, az
    NX, NY, NZ = safe.shape
    ix = int(np.floor(ax))
    iy = int(np.floor(ay))
    iz = int(np.floor(az))
    jx = int(np.floor(bx))
    jy = int(np.floor(by))
    jz = int(np.floor(bz))
    if (
        min(ix, iy, iz, jx, jy, jz) < 0
        or ix >= NX
        or jx >= NX
        or iy >= NY
        or jy >= NY
        or iz >= NZ
        or jz >= NZ
    ):
        return False
    dx = bx - ax
    dy = by - ay
    dz = bz - az
    sx = 1 if dx > 0 else -1
    sy = 1 if dy > 0 else -1
    sz = 1 if dz > 0 else -1
    inf = np.inf
    tdx = abs(1.0 / dx) if dx != 0 else inf
    tdy = abs(1.0 / dy) if dy != 0 else inf
    tdz = abs(1.0 / dz) if dz != 0 else inf
    tmx = ((ix + 1 - ax) / dx if dx > 0 else (ax - ix) / -dx) if dx != 0 else inf
    tmy = ((iy + 1 - ay) / dy if dy > 0 else (ay - iy) / -dy) if dy != 0 else inf
    tmz = ((iz + 1 - az) / dz if dz > 0 else (az - iz) / -dz) if dz != 0 else inf
    while True:
        if safe[ix, iy, iz] == 0:
            return False
        if ix == jx and iy == jy and iz == jz:
            return True
        if tmx <= tmy and tmx <= tmz:
            if tmx > 1.0:
                return True
            ix += sx
            tmx += tdx
            if ix < 0 or ix >= NX:
                return False
        elif tmy <= tmz:
            if tmy > 1.0:
                return True
            iy += sy
            tmy += tdy
            if iy < 0 or iy >= NY:
                return False
        else:
            if tmz > 1.0:
                return True
            iz += sz
            tmz += tdz
            if iz < 0 or iz >= NZ:
                return False


@njit(cache=True)
def safe_cells(flyable):
    """(NX-1, NY-1, NZ-1) uint8: dual cells whose 8 corner voxel centres are all flyable."""
    NX, NY, NZ = flyable.shape
    out = np.zeros((max(NX - 1, 0), max(NY - 1, 0), max(NZ - 1, 0)), np.uint8)
    for i in range(NX - 1):
        for j in range(NY - 1):
            for k in range(NZ - 1):
                ok = 1
                for a in range(2):
                    for b in range(2):
                        for c in range(2):
                            if flyable[i + a, j + b, k + c] == 0:
                                ok = 0
                out[i, j, k] = ok
    return out


def lattice(safe, f):
    """Level-f nodes: every f-th safe dual cell along each axis, (ceil(NX/f), ceil(NY/f), ceil(NZ/f)) uint8."""
    return np.ascontiguousarray(safe[::f, ::f, ::f])
