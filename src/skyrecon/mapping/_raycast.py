"""Numba kernels for ray-casting integration of point clouds with a known sensor origin.

Each ray is walked voxel by voxel (Amanatides & Woo) from the sensor to its end point; the
voxels it crosses are free, the voxel holding the end point is occupied (unless the point lies
beyond the maximum range: then the ray is cut at the range and gives no hit). Within one scan
every voxel is updated once, and occupied wins over free (as OctoMap does).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from skyrecon.mapping._projective import _change, _hit, _miss
from skyrecon.mapping.blocks import EMPTY, table_find


@njit(cache=True, nogil=True)
def _traverse(o, e, buf):
    """Voxels (in ``buf`` (L, 3) int64) crossed by the segment o -> e, both in voxel units. Returns count."""
    ix = int(np.floor(o[0]))
    iy = int(np.floor(o[1]))
    iz = int(np.floor(o[2]))
    jx = int(np.floor(e[0]))
    jy = int(np.floor(e[1]))
    jz = int(np.floor(e[2]))
    dx = e[0] - o[0]
    dy = e[1] - o[1]
    dz = e[2] - o[2]
    sx = 1 if dx > 0 else (-1 if dx < 0 else 0)
    sy = 1 if dy > 0 else (-1 if dy < 0 else 0)
    sz = 1 if dz > 0 else (-1 if dz < 0 else 0)
    inf = np.inf
    tdx = abs(1.0 / dx) if dx != 0 else inf
    tdy = abs(1.0 / dy) if dy != 0 else inf
    tdz = abs(1.0 / dz) if dz != 0 else inf
    tmx = ((ix + 1 - o[0]) / dx if dx > 0 else (o[0] - ix) / -dx) if dx != 0 else inf
    tmy = ((iy + 1 - o[1]) / dy if dy > 0 else (o[1] - iy) / -dy) if dy != 0 else inf
    tmz = ((iz + 1 - o[2]) / dz if dz > 0 else (o[2] - iz) / -dz) if dz != 0 else inf
    n = 0
    L = buf.shape[0]
    while n < L:
        buf[n, 0] = ix
        buf[n, 1] = iy
        buf[n, 2] = iz
        n += 1
        if ix == jx and iy == jy and iz == jz:
            break
        if tmx <= tmy and tmx <= tmz:
            if tmx > 1.0:
                break
            ix += sx
            tmx += tdx
        elif tmy <= tmz:
            if tmy > 1.0:
                break
            iy += sy
            tmy += tdy
        else:
            if tmz > 1.0:
                break
            iz += sz
            tmz += tdz
    return n


@njit(cache=True, nogil=True)
def collect_ray_blocks(origin, ends, B, max_steps):
    """Block coordinates (K, 3) int32 crossed by the rays origin -> ends[i] (voxel units), consecutive duplicates removed."""
    cap = 1024
    out = np.empty((cap, 3), np.int32)
    n = 0
    buf = np.empty((max_steps, 3), np.int64)
    lx = EMPTY
    ly = EMPTY
    lz = EMPTY
    for r in range(ends.shape[0]):
        m = _traverse(origin, ends[r], buf)
        for s in range(m):
            bx = buf[s, 0] // B
            by = buf[s, 1] // B
            bz = buf[s, 2] // B
            if bx == lx and by == ly and bz == lz:
                continue
            if n >= cap:
                cap *= 2
                nxt = np.empty((cap, 3), np.int32)
                nxt[:n] = out[:n]
                out = nxt
            out[n, 0] = bx
            out[n, 1] = by
            out[n, 2] = bz
            n += 1
            lx = bx
            ly = by
            lz = bz
    return out[:n]


@njit(cache=True, nogil=True)
def mark_rays(tkeys, tvals, local_of_pool, n_local, origin, ends, is_hit, B, max_steps):
    """Free / hit flags (n_local, B^3) uint8 for one scan. ``is_hit`` (N,) uint8: the end voxel is a hit."""
    free = np.zeros((n_local, B * B * B), np.uint8)
    hits = np.zeros((n_local, B * B * B), np.uint8)
    N = ends.shape[0]
    buf = np.empty((max_steps, 3), np.int64)
    lbx = EMPTY
    lby = EMPTY
    lbz = EMPTY
    loc = -1
    for r in range(N):
        m = _traverse(origin, ends[r], buf)
        for s in range(m):
            vx = buf[s, 0]
            vy = buf[s, 1]
            vz = buf[s, 2]
            bx = vx // B
            by = vy // B
            bz = vz // B
            if bx != lbx or by != lby or bz != lbz:
                k = table_find(tkeys, tvals, bx, by, bz)
                loc = local_of_pool[k] if k >= 0 else -1
                lbx = bx
                lby = by
                lbz = bz
            if loc < 0:
                continue
            q = ((vx - bx * B) * B + (vy - by * B)) * B + (vz - bz * B)
            if s == m - 1 and is_hit[r]:
                hits[loc, q] = 1
            else:
                free[loc, q] = 1
    return free, hits


@njit(cache=True, nogil=True)
def apply_flags(data, sat, pool_ids, free, hits, lodds):
    """Apply hit (wins) / miss flags to blocks ``pool_ids``; returns changed (M,) uint8 (change
    codes, see :func:`skyrecon.mapping._projective.update_blocks`) and counts (M, 2).

    ``sat`` (N,) uint8 (see :func:`skyrecon.mapping._projective.update_blocks`) is cleared for blocks with hits.
    """
    M = pool_ids.shape[0]
    changed = np.zeros(M, np.uint8)
    counts = np.zeros((M, 2), np.int64)
    l_hit, l_miss, c_lo, c_hi, thr = lodds[0], lodds[1], lodds[2], lodds[3], lodds[4]
    stale = lodds[5]
    for j in range(M):
        blk = data[pool_ids[j]]
        ch = 0
        for q in range(blk.shape[0]):
            if not (hits[j, q] or free[j, q]):
                continue
            old = blk[q]
            if hits[j, q]:
                new = _hit(old, l_hit, c_hi, stale)
                counts[j, 1] += 1
                sat[pool_ids[j]] = 0
            else:
                new = _miss(old, l_miss, c_lo, stale)
                counts[j, 0] += 1
            blk[q] = new
            ch |= _change(old, new, thr)
        changed[j] = ch
    return changed, counts
