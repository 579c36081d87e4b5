"""Numba helpers on a dense distance grid: interpolation, segment checks, path shortening.

The grid ``dist`` (NX, NY, NZ) float32 holds distances (metres) at voxel centres
``origin + (i + 0.5) * voxel`` (world frame). :func:`trilinear` interpolates them; points
outside the grid, or outside the altitude band ``[zmin, zmax]``, read -1 (never clear). A point
is *clear* when the interpolated distance is at least ``thr`` (clearance plus margin).

Segments are checked exactly with :func:`skyrecon.planning._los.los` on the safe dual cells
``safe``; a segment that touches the start or the goal (which may lie in a dual cell that is not
safe as a whole) may instead pass a sampled check, every ``step`` metres.

The shortening functions take the context ``(safe, dist, origin, inv_v, zmin, zmax, thr, step)``
first and keep every segment of the polyline clear; the first and last points never move.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from skyrecon.planning._los import los


@njit(cache=True)
def trilinear(dist, origin, inv_v, zmin, zmax, px, py, pz):
    """Interpolated distance at world point (px, py, pz); -1 outside the grid or altitude band."""
    if pz < zmin or pz > zmax:
        return -1.0
    NX, NY, NZ = dist.shape
    gx = (px - origin[0]) * inv_v - 0.5
    gy = (py - origin[1]) * inv_v - 0.5
    gz = (pz - origin[2]) * inv_v - 0.5
    if gx < 0.0 or gy < 0.0 or gz < 0.0 or gx > NX - 1 or gy > NY - 1 or gz > NZ - 1:
        return -1.0
    ix = min(int(gx), NX - 2) if NX > 1 else 0
    iy = min(int(gy), NY - 2) if NY > 1 else 0
    iz = min(int(gz), NZ - 2) if NZ > 1 else 0
    fx = gx - ix
    fy = gy - iy
    fz = gz - iz
    jx = min(ix + 1, NX - 1)
    jy = min(iy + 1, NY - 1)
    jz = min(iz + 1, NZ - 1)
    c00 = dist[ix, iy, iz] * (1 - fz) + dist[ix, iy, jz] * fz
    c01 = dist[ix, jy, iz] * (1 - fz) + dist[ix, jy, jz] * fz
    c10 = dist[jx, iy, iz] * (1 - fz) + dist[jx, iy, jz] * fz
    c11 = dist[jx, jy, iz] * (1 - fz) + dist[jx, jy, jz] * fz
    c0 = c00 * (1 - fy) + c01 * fy
    c1 = c10 * (1 - fy) + c11 * fy
    return c0 * (1 - fx) + c1 * fx


@njit(cache=True)
def sample_many(dist, origin, inv_v, zmin, zmax, pts):
    """(N,) interpolated distances at world points (N, 3)."""
    out = np.empty(pts.shape[0])
    for i in range(pts.shape[0]):
        out[i] = trilinear(dist, origin, inv_v, zmin, zmax, pts[i, 0], pts[i, 1], pts[i, 2])
    return out


@njit(cache=True)
def sampled_clear(dist, origin, inv_v, zmin, zmax, thr, step, a, b):
    """Whether samples every <= step metres along a -> b (ends included) are all clear."""
    dx = b[0] - a[0]
    dy = b[1] - a[1]
    dz = b[2] - a[2]
    L = np.sqrt(dx * dx + dy * dy + dz * dz)
    n = max(1, int(np.ceil(L / step)))
    for i in range(n + 1):
        t = i / n
        if trilinear(dist, origin, inv_v, zmin, zmax, a[0] + t * dx, a[1] + t * dy, a[2] + t * dz) < thr:
            return False
    return True


@njit(cache=True)
def clear(safe, dist, origin, inv_v, zmin, zmax, thr, step, a, b, sampled_ok):
    """Segment a -> b (world (3,) each) is clear: exact dual-cell test, else (if ``sampled_ok``)
    the sampled test."""
    if los(
        safe,
        (a[0] - origin[0]) * inv_v - 0.5,
        (a[1] - origin[1]) * inv_v - 0.5,
        (a[2] - origin[2]) * inv_v - 0.5,
        (b[0] - origin[0]) * inv_v - 0.5,
        (b[1] - origin[1]) * inv_v - 0.5,
        (b[2] - origin[2]) * inv_v - 0.5,
    ):
        return True
    if sampled_ok:
        return sampled_clear(dist, origin, inv_v, zmin, zmax, thr, step, a, b)
    return False


@njit(cache=True)
def path_min_distance(dist, origin, inv_v, zmin, zmax, step, pts):
    """Minimum interpolated distance along the polyline pts (K, 3), sampled every ``step`` metres."""
    best = np.inf
    for s in range(pts.shape[0] - 1):
        a = pts[s]
        b = pts[s + 1]
        L = np.sqrt(((b - a) ** 2).sum())
        n = max(1, int(np.ceil(L / step)))
        for i in range(n + 1):
            t = i / n
            d = trilinear(
                dist,
                origin,
                inv_v,
                zmin,
                zmax,
                a[0] + t * (b[0] - a[0]),
                a[1] + t * (b[1] - a[1]),
                a[2] + t * (b[2] - a[2]),
            )
            best = min(best, d)
    if pts.shape[0] == 1:
        best = trilinear(dist, origin, inv_v, zmin, zmax, pts[0, 0], pts[0, 1], pts[0, 2])
    return best


@njit(cache=True)
def first_blocked(dist, origin, inv_v, zmin, zmax, thr, step, pts):
    """Index of the first segment of pts (K, 3) failing the sampled check, or -1."""
    for s in range(pts.shape[0] - 1):
        if not sampled_clear(dist, origin, inv_v, zmin, zmax, thr, step, pts[s], pts[s + 1]):
            return s
    return -1


@njit(cache=True)
def shortcut(safe, dist, origin, inv_v, zmin, zmax, thr, step, pts):
    """Greedy string pulling: from each kept point jump to the farthest point in sequence
    reachable in a straight clear line (scanning forward until the first blocked one)."""
    K = pts.shape[0]
    keep = np.zeros(K, np.bool_)
    keep[0] = True
    i = 0
    while i < K - 1:
        j = i + 1
        while j + 1 < K and clear(
            safe, dist, origin, inv_v, zmin, zmax, thr, step, pts[i], pts[j + 1], i == 0 or j + 1 == K - 1
        ):
            j += 1
        keep[j] = True
        i = j
    return pts[keep].copy()


@njit(cache=True)
def densify(pts, max_len):
    """Insert evenly spaced points so that no segment of pts (K, 3) is longer than max_len metres."""
    K = pts.shape[0]
    counts = np.empty(K - 1, np.int64)
    total = 1
    for s in range(K - 1):
        L = np.sqrt(((pts[s + 1] - pts[s]) ** 2).sum())
        counts[s] = max(1, int(np.ceil(L / max_len)))
        total += counts[s]
    out = np.empty((total, 3))
    m = 0
    for s in range(K - 1):
        for i in range(counts[s]):
            t = i / counts[s]
            out[m] = pts[s] + t * (pts[s + 1] - pts[s])
            m += 1
    out[m] = pts[K - 1]
    return out


@njit(cache=True)
def polyline_length(pts):
    L = 0.0
    for s in range(pts.shape[0] - 1):
        L += np.sqrt(((pts[s + 1] - pts[s]) ** 2).sum())
    return L


@njit(cache=True)
def relax(safe, dist, origin, inv_v, zmin, zmax, thr, step, pts, passes, tol):
    """Shorten a clear polyline by pulling each inner vertex towards the chord of its neighbours.

    Each vertex tries four moves: towards the nearest point of the segment joining its
    neighbours, towards that segment's middle, and towards either neighbour (sliding along an
    edge of the path), each as far as both adjacent segments stay clear (bisection); the move
    that shortens the path most is kept. Vertices whose neighbours see each other are dropped. Passes repeat until the length improves by less than ``tol`` metres.
    """
    cur = pts.copy()
    prev_len = polyline_length(cur)
    for _ in range(passes):
        K = cur.shape[0]
        if K <= 2:
            break
        keep = np.ones(K, np.bool_)
        last = 0  # index of the previous kept vertex
        for i in range(1, K - 1):
            a = cur[last]
            b = cur[i]
            c = cur[i + 1]
            end_a = last == 0
            end_c = i + 1 == K - 1
            if clear(safe, dist, origin, inv_v, zmin, zmax, thr, step, a, c, end_a or end_c):
                keep[i] = False
                continue
            ac = c - a
            L2 = (ac * ac).sum()
            t = 0.0 if L2 == 0 else min(1.0, max(0.0, ((b - a) * ac).sum() / L2))
            q = b.copy()
            best = np.sqrt(((a - b) ** 2).sum()) + np.sqrt(((c - b) ** 2).sum())
            # towards the chord, its middle, or sliding along either edge (lets vertices slide
            # along obstacle edges where the chord direction is blocked)
            for m in range(4):
                if m == 0:
                    target = a + t * ac
                elif m == 1:
                    target = a + 0.5 * ac
                elif m == 2:
                    target = a.copy()
                else:
                    target = c.copy()
                lo = 0.0
                hi = 1.0
                for _it in range(8):
                    mid = 0.5 * (lo + hi)
                    cand = b + mid * (target - b)
                    if clear(safe, dist, origin, inv_v, zmin, zmax, thr, step, a, cand, end_a) and clear(
                        safe, dist, origin, inv_v, zmin, zmax, thr, step, cand, c, end_c
                    ):
                        lo = mid
                    else:
                        hi = mid
                if lo > 0.0:
                    cand = b + lo * (target - b)
                    Lc = np.sqrt(((a - cand) ** 2).sum()) + np.sqrt(((c - cand) ** 2).sum())
                    if Lc < best - 1e-9:
                        best = Lc
                        q = cand
            cur[i] = q
            last = i
        cur = cur[keep].copy()
        L = polyline_length(cur)
        if prev_len - L < tol:
            prev_len = L
            break
        prev_len = L
    return cur


@njit(cache=True)
def smooth_corners(safe, dist, origin, inv_v, zmin, zmax, thr, step, pts, iterations, radius):
    """Chaikin-style corner cutting with collision checks.

    Each corner b (between a and c) is replaced by the two points at distance
    ``r = min(radius, |ab| / 4, |bc| / 4)`` from b along its edges when the new short segment is
    clear (else r is halved once, else the corner stays). Cutting a corner always shortens the path.
    """
    cur = pts.copy()
    for _ in range(iterations):
        K = cur.shape[0]
        if K <= 2:
            break
        out = np.empty((2 * K, 3))
        out[0] = cur[0]
        m = 1
        for i in range(1, K - 1):
            a = cur[i - 1]
            b = cur[i]
            c = cur[i + 1]
            la = np.sqrt(((a - b) ** 2).sum())
            lc = np.sqrt(((c - b) ** 2).sum())
            r = min(radius, 0.25 * la, 0.25 * lc)
            done = False
            if r > 1e-6:
                for _try in range(2):
                    u = b + (a - b) * (r / la)
                    w = b + (c - b) * (r / lc)
                    if clear(safe, dist, origin, inv_v, zmin, zmax, thr, step, u, w, False):
                        out[m] = u
                        out[m + 1] = w
                        m += 2
                        done = True
                        break
                    r *= 0.5
            if not done:
                out[m] = b
                m += 1
        out[m] = cur[K - 1]
        m += 1
        cur = out[:m].copy()
    return cur


@njit(cache=True)
def drop_collinear(safe, dist, origin, inv_v, zmin, zmax, thr, step, pts, tol):
    """Remove inner vertices within ``tol`` metres of the segment joining their neighbours, when
    that segment is clear."""
    K = pts.shape[0]
    if K <= 2:
        return pts.copy()
    keep = np.ones(K, np.bool_)
    last = 0
    for i in range(1, K - 1):
        a = pts[last]
        b = pts[i]
        c = pts[i + 1]
        ac = c - a
        L2 = (ac * ac).sum()
        t = 0.0 if L2 == 0 else min(1.0, max(0.0, ((b - a) * ac).sum() / L2))
        d = np.sqrt(((a + t * ac - b) ** 2).sum())
        if d < tol and clear(
            safe, dist, origin, inv_v, zmin, zmax, thr, step, a, c, last == 0 or i + 1 == K - 1
        ):
            keep[i] = False
        else:
            last = i
    return pts[keep].copy()
