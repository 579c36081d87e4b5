"""Exact Euclidean distance transform (Felzenszwalb & Huttenlocher), separable, in Numba.

``squared_edt(obstacle)`` gives, for every voxel of a dense (X, Y, Z) grid, the squared distance
in voxel units from its centre to the nearest obstacle voxel centre (inf when the grid has none).
The same numbers as ``scipy.ndimage.distance_transform_edt(~obstacle) ** 2``, faster on two cores.

``bounded_distance(obstacle, voxel, max_distance)`` needs only the distances up to a few voxels
(the occupancy map's distance field is clipped at its clearance radius): it runs the same
separable decomposition ``d2 = min_dx [dx^2 + min_dy [dy^2 + g_z^2]]`` with the inner minima over
windows of ``|d| <= w`` voxels, ``w = floor(max_distance / voxel)`` (any source farther than ``w``
voxels along one axis is farther than ``max_distance``), in float32 and without divisions. Exact
for every distance below ``max_distance``; about ten times faster than the full transform on the
distance field's boxes (15 ms down to 1-2 ms for 300 000 voxels on two cores).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

INF = np.inf


@njit(cache=True)
def _dt1d(f, n, out, v, z):
    """1-D squared distance transform of the sampled function ``f[:n]`` (inf = no source) into ``out``."""
    k = -1
    for q in range(n):
        fq = f[q]
        if fq == INF:
            continue
        if k < 0:
            k = 0
            v[0] = q
            z[0] = -INF
            z[1] = INF
            continue
        while True:
            vk = v[k]
            s = ((fq + q * q) - (f[vk] + vk * vk)) / (2.0 * (q - vk))
            if s <= z[k]:
                k -= 1
            else:
                break
        k += 1
        v[k] = q
        z[k] = s
        z[k + 1] = INF
    if k < 0:
        for q in range(n):
            out[q] = INF
        return
    j = 0
    for q in range(n):
        while z[j + 1] < q:
            j += 1
        dq = q - v[j]
        out[q] = dq * dq + f[v[j]]


@njit(cache=True)
def _pass_z(obstacle, d, i, f, o, v, z):
    Y, Z = d.shape[1], d.shape[2]
    for j in range(Y):
        for k in range(Z):
            f[k] = 0.0 if obstacle[i, j, k] else INF
        _dt1d(f, Z, o, v, z)
        for k in range(Z):
            d[i, j, k] = o[k]


@njit(cache=True)
def _pass_y(d, i, f, o, v, z):
    Y, Z = d.shape[1], d.shape[2]
    for k in range(Z):
        for j in range(Y):
            f[j] = d[i, j, k]
        _dt1d(f, Y, o, v, z)
        for j in range(Y):
            d[i, j, k] = o[j]


@njit(cache=True)
def _pass_x(d, j, f, o, v, z):
    X, Z = d.shape[0], d.shape[2]
    for k in range(Z):
        for i in range(X):
            f[i] = d[i, j, k]
        _dt1d(f, X, o, v, z)
        for i in range(X):
            d[i, j, k] = o[i]


@njit(cache=True, parallel=True)
def squared_edt(obstacle):
    """(X, Y, Z) float64 squared distance (voxel units) to the nearest True voxel of ``obstacle`` (X, Y, Z) bool."""
    X, Y, Z = obstacle.shape
    d = np.empty((X, Y, Z), np.float64)
    n = max(X, max(Y, Z))
    for i in prange(X):  # along z, then y, slab by slab
        f = np.empty(n, np.float64)
        o = np.empty(n, np.float64)
        v = np.empty(n, np.int64)
        z = np.empty(n + 1, np.float64)
        _pass_z(obstacle, d, i, f, o, v, z)
        _pass_y(d, i, f, o, v, z)
    for j in prange(Y):  # along x
        f = np.empty(n, np.float64)
        o = np.empty(n, np.float64)
        v = np.empty(n, np.int64)
        z = np.empty(n + 1, np.float64)
        _pass_x(d, j, f, o, v, z)
    return d


@njit(cache=True, parallel=True)
def _bounded_squared_edt(obstacle, w):
    """(X, Y, Z) float32 squared distance (voxel units) to the nearest True voxel of ``obstacle``,
    exact where it is at most ``w * w``; elsewhere at least ``(w + 1) ** 2``."""
    X, Y, Z = obstacle.shape
    far = np.float32((w + 1) * (w + 1))
    g = np.empty((X, Y, Z), np.float32)
    for i in prange(X):  # along z: two sweeps, squared, capped
        for j in range(Y):
            last = -(1 << 30)
            for k in range(Z):
                if obstacle[i, j, k]:
                    last = k
                g[i, j, k] = np.float32(k - last)
            last = 1 << 30
            for k in range(Z - 1, -1, -1):
                if obstacle[i, j, k]:
                    last = k
                dk = min(g[i, j, k], np.float32(last - k))
                g[i, j, k] = dk * dk if dk <= w else far
    # the y and x passes are written out: one helper over 2-D views runs 1.8 ms against 1.2 ms
    # on an 80x72x64 box (Numba does not vectorise the x pass's strided views)
    h = np.empty((X, Y, Z), np.float32)
    for i in prange(X):  # along y: minimum over the window
        for j in range(Y):
            for k in range(Z):
                h[i, j, k] = g[i, j, k]
            for dj in range(1, w + 1):
                c = np.float32(dj * dj)
                if j - dj >= 0:
                    for k in range(Z):
                        h[i, j, k] = min(h[i, j, k], g[i, j - dj, k] + c)
                if j + dj < Y:
                    for k in range(Z):
                        h[i, j, k] = min(h[i, j, k], g[i, j + dj, k] + c)
    for i in prange(X):  # along x, into g
        for j in range(Y):
            for k in range(Z):
                g[i, j, k] = h[i, j, k]
            for di in range(1, w + 1):
                c = np.float32(di * di)
                if i - di >= 0:
                    for k in range(Z):
                        g[i, j, k] = min(g[i, j, k], h[i - di, j, k] + c)
                if i + di < X:
                    for k in range(Z):
                        g[i, j, k] = min(g[i, j, k], h[i + di, j, k] + c)
    return g


def bounded_distance(obstacle: np.ndarray, voxel: float, max_distance: float) -> np.ndarray:
    """(X, Y, Z) float32 Euclidean distance, metres, to the nearest obstacle voxel centre, clipped at ``max_distance``."""
    w = int(np.floor(max_distance / voxel))
    d = np.sqrt(_bounded_squared_edt(np.ascontiguousarray(obstacle, dtype=np.bool_), w))
    d *= np.float32(voxel)
    np.minimum(d, np.float32(max_distance), out=d)
    return d
