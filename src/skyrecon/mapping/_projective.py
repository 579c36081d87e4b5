"""Numba kernels for projective integration of one depth image into the block map.

Each voxel in the camera frustum (up to the maximum range) is updated at most once per frame:
its centre is projected into the depth image and compared with the depth at that pixel:

* wholly in front of the local surface plane through the measured point -> free (miss),
* overlapping that plane                                                -> occupied (hit),
* otherwise (behind the surface, or no valid depth)                     -> untouched.

The plane's orientation is estimated from the neighbouring depths, so that a voxel counts as
occupied when it overlaps the surface, not only when its centre lies behind it; this matches
ground truth that marks every voxel overlapping an obstacle (see :func:`prepare_depth`). A pixel whose
depth lies beyond the maximum range carves free space up to the range and gives no hit. Blocks are culled in two levels (superblocks of 4^3
blocks, then blocks) with a min/max depth pyramid: a block entirely in front of the measured
surfaces is carved in one tight loop, a block entirely behind them is skipped, and only blocks
that straddle a surface are tested voxel by voxel.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from skyrecon.mapping.blocks import table_find

SUPER = 4  # blocks per superblock edge
SKIP, FREE, PARTIAL = 0, 1, 2
# bits of the per-block change codes returned by update_blocks (and _raycast.apply_flags)
CHANGED_STATE, CHANGED_OCCUPIED = 1, 2
_NEG_INF = np.float32(-np.inf)


@njit(cache=True, nogil=True)
def _slope(depth, r, c, dr, dc, d, jump):
    """One-sided depth difference towards the smoother valid neighbour along (dr, dc); NaN if none."""
    H, W = depth.shape
    best = np.nan
    for sgn in (1, -1):
        rr = r + sgn * dr
        cc = c + sgn * dc
        if rr < 0 or cc < 0 or rr >= H or cc >= W:
            continue
        e = depth[rr, cc]
        if not (e > 0 and e < np.inf):
            continue
        g = sgn * (e - d)
        if abs(g) <= jump * d and (best != best or abs(g) < abs(best)):
            best = g
    return best


@njit(cache=True, nogil=True)
def _range_plane(plane, lo, hi, r, c, zmax):
    """Free up to depth ``zmax`` (the maximum range along this pixel's ray), no hits."""
    plane[r, c, 0] = 0.0
    plane[r, c, 1] = 0.0
    plane[r, c, 2] = 1.0
    plane[r, c, 3] = zmax
    plane[r, c, 4] = 0.0
    plane[r, c, 5] = -1.0
    lo[r, c] = zmax
    hi[r, c] = zmax


@njit(cache=True, nogil=True)
def _prepare_row(
    r, depth, dirs, ray_norm, R_wc, fx, fy, min_range, max_range, half, worst, eps, cap, plane, lo, hi
):
    """One image row of :func:`prepare_depth`."""
    H, W = depth.shape
    for c in range(W):
        d = depth[r, c]
        n = ray_norm[r, c]
        x = dirs[r, c, 0]
        y = dirs[r, c, 1]
        if not (d > 0 and d == d and d * n >= min_range):
            for q in range(6):
                plane[r, c, q] = np.nan
            lo[r, c] = _NEG_INF
            hi[r, c] = _NEG_INF
            continue
        zmax = max_range / n
        if d == np.inf:
            _range_plane(plane, lo, hi, r, c, zmax)
            continue
        du = _slope(depth, r, c, 0, 1, d, 0.05)
        dv = _slope(depth, r, c, 1, 0, d, 0.05)
        if du == du and dv == dv:
            nx = -fx * du
            ny = -fy * dv
            nz = d - nx * x - ny * y
            g = 0.5 * (abs(du) + abs(dv))
            wx = abs(R_wc[0, 0] * nx + R_wc[0, 1] * ny + R_wc[0, 2] * nz)
            wy = abs(R_wc[1, 0] * nx + R_wc[1, 1] * ny + R_wc[1, 2] * nz)
            wz = abs(R_wc[2, 0] * nx + R_wc[2, 1] * ny + R_wc[2, 2] * nz)
            nn = np.sqrt(nx * nx + ny * ny + nz * nz)
            Hf = half * (wx + wy + wz)
        else:  # no usable neighbours: a plane facing the camera, worst-case cube width
            k = d / (n * n)
            nx = k * x
            ny = k * y
            nz = k
            g = 0.5 * k * (abs(x) / fx + abs(y) / fy)
            nn = np.sqrt(nx * nx + ny * ny + nz * nz)
            Hf = worst * nn
        o = d * d + eps * nn
        zfree = (o - Hf) / (d + g)
        if d * n > max_range:
            if zfree >= zmax:  # the range, not the surface, ends the free space
                _range_plane(plane, lo, hi, r, c, zmax)
                continue
            Hh = -1.0  # beyond range: no hits
        else:
            Hh = min(Hf, cap * d / n)  # |s| / |n| = along-ray distance * cos, cos = d / (|n| |r|)
        plane[r, c, 0] = nx
        plane[r, c, 1] = ny
        plane[r, c, 2] = nz
        plane[r, c, 3] = o
        plane[r, c, 4] = Hf
        plane[r, c, 5] = Hh
        # a voxel centre projecting here lies on z * (r + dr), |n . dr| <= g
        lo[r, c] = zfree
        if Hh < 0:
            hi[r, c] = zfree
        else:
            hi[r, c] = (o + Hh) / (d - g) if d > g else np.inf


@njit(cache=True, nogil=True, parallel=True)
def prepare_depth(depth, dirs, ray_norm, R_wc, fx, fy, min_range, max_range, voxel, eps, cap, carve_only):
    """Per-pixel surface planes that decide the fate of the voxels projecting onto each pixel.

    For a pixel with depth ``d`` within range, the local surface is the plane through the
    measured point ``d * r`` (``r = (x, y, 1)`` the pixel's ray) with normal, from the depth
    slopes ``d_u, d_v`` towards the smoother neighbours, ``n = (-fx d_u, -fy d_v, d + fx x d_u +
    fy y d_v)`` (not normalised; ``n . r = d``, so n points away from the camera). For a voxel
    centre ``C`` (camera frame) projecting onto the pixel, ``s = n . C - o`` with
    ``o = d^2 + eps |n|`` is ``|n|`` times its signed distance to the plane pushed ``eps`` metres
    into the surface (which settles voxel faces lying exactly on a surface). The voxel overlaps
    the plane when ``|s| <= H = v/2 |R_wc n|_1`` (``v/2 |n_world|_1`` is the half-width of a cube
    along the normal), lies wholly in front of it when ``s < -H``. So the voxel is

    * free if ``s < -F`` (``F = H``),
    * hit if ``|s| <= Hh``, where ``Hh`` is ``H`` cut so that the band spans at most ``cap``
      metres along the ray either side (grazing views),
    * untouched otherwise.

    A pixel whose depth is beyond ``max_range`` gives no hits (``Hh = -1``) and carves free space
    up to the surface plane or the range, whichever is nearer (+inf depth, or a range nearer than
    the plane: ``n = (0, 0, 1)``, ``o`` the depth at the range, ``F = 0``). Without a
    usable neighbour the plane faces the camera and the cube's worst-case width is used.
    Invalid pixels (NaN, <= 0, nearer than ``min_range``) get ``F = NaN``: no update. A
    ``carve_only`` pixel (a depth not trusted to mark a surface) carves free space up to a
    voxel's half diagonal in front of its point (or the range) and gives no hit, as one beyond
    the range does.

    Args:
        depth: (H, W) float32 metres; dirs: (H, W, 3) float32 ray directions with z = 1 (camera
        frame); ray_norm: (H, W) float32 their lengths; R_wc: (3, 3) rotation world_from_cam;
        carve_only: (H, W) bool or uint8, the pixels that carve only.
    Returns:
        plane (H, W, 6) float32 ``nx, ny, nz, o, F, Hh``; lo, hi (H, W) float32: bounds on the
        depth z of a voxel centre projecting onto the pixel below which it is surely free and
        above which it is surely untouched (-inf where invalid), for the min/max pyramid.
    """
    H, W = depth.shape
    plane = np.empty((H, W, 6), np.float32)
    lo = np.empty((H, W), np.float32)
    hi = np.empty((H, W), np.float32)
    half = 0.5 * voxel
    worst = half * np.sqrt(3.0)
    for r in prange(H):
        _prepare_row(
            r, depth, dirs, ray_norm, R_wc, fx, fy, min_range, max_range, half, worst, eps, cap, plane, lo, hi
        )
        _carve_only_row(r, depth, ray_norm, min_range, max_range, worst, carve_only, plane, lo, hi)
    return plane, lo, hi


@njit(cache=True, nogil=True)
def _carve_only_row(r, depth, ray_norm, min_range, max_range, worst, carve_only, plane, lo, hi):
    """The ``carve_only`` pixels of one row of :func:`prepare_depth` with a finite, valid depth:
    free up to a voxel's half diagonal (``worst``) in front of the point, or the range, no hit."""
    for c in range(depth.shape[1]):
        d = depth[r, c]
        n = ray_norm[r, c]
        if carve_only[r, c] and d > 0 and d < np.inf and d * n >= min_range:
            _range_plane(plane, lo, hi, r, c, min(max_range / n, d - worst / n))


@njit(cache=True, nogil=True)
def _endpoints_row(
    r,
    depth,
    dirs,
    ray_norm,
    R_wc,
    t_wc,
    voxel,
    B,
    min_range,
    max_range,
    eps,
    tkeys,
    tvals,
    local_of_pool,
    hitmask,
    octflag,
):
    """One image row of :func:`mark_endpoints`."""
    H, W = depth.shape
    h = B // 2
    inv_v = 1.0 / voxel
    lbx = np.int64(-(1 << 40))
    lby = np.int64(0)
    lbz = np.int64(0)
    loc = -1
    for c in range(W):
        d = depth[r, c]
        n = ray_norm[r, c]
        if not (d > 0 and d < np.inf and d * n >= min_range and d * n <= max_range):
            continue
        s = d + eps / n
        cx = s * dirs[r, c, 0]
        cy = s * dirs[r, c, 1]
        cz = s
        wx = R_wc[0, 0] * cx + R_wc[0, 1] * cy + R_wc[0, 2] * cz + t_wc[0]
        wy = R_wc[1, 0] * cx + R_wc[1, 1] * cy + R_wc[1, 2] * cz + t_wc[1]
        wz = R_wc[2, 0] * cx + R_wc[2, 1] * cy + R_wc[2, 2] * cz + t_wc[2]
        vx = np.int64(np.floor(wx * inv_v))
        vy = np.int64(np.floor(wy * inv_v))
        vz = np.int64(np.floor(wz * inv_v))
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
        lx = vx - bx * B
        ly = vy - by * B
        lz = vz - bz * B
        hitmask[loc, (lx * B + ly) * B + lz] = 1
        octflag[loc, ((lx // h) << 2) | ((ly // h) << 1) | (lz // h)] = 1


@njit(cache=True, nogil=True, parallel=True)
def mark_endpoints(
    depth,
    dirs,
    ray_norm,
    R_wc,
    t_wc,
    voxel,
    B,
    min_range,
    max_range,
    eps,
    tkeys,
    tvals,
    local_of_pool,
    hitmask,
    octflag,
):
    """Flag the voxels that hold a measured surface point (within range) for this frame.

    Every valid pixel's point ``d * r``, pushed ``eps`` metres further along its ray, is mapped
    to the world; its voxel gets ``hitmask[local, q] = 1`` and its block octant
    ``octflag[local, o] = 1``, where ``local = local_of_pool[pool index]`` (blocks with -1,
    or absent, are ignored). As in OctoMap, such voxels count as hit in this frame even when
    the projective test would carve them (thin structures, silhouette edges). Every pixel is
    used (thin structures may cover a single one); a pixel mapping to the same block as its
    left neighbour skips the block lookup.
    """
    for r in prange(depth.shape[0]):
        _endpoints_row(
            r,
            depth,
            dirs,
            ray_norm,
            R_wc,
            t_wc,
            voxel,
            B,
            min_range,
            max_range,
            eps,
            tkeys,
            tvals,
            local_of_pool,
            hitmask,
            octflag,
        )


@njit(cache=True, nogil=True)
def build_pyramid(lo0, hi0):
    """Min/max pyramid: level k pools 2^k x 2^k pixels. Returns flat (mins, maxs, offsets, heights, widths)."""
    H, W = lo0.shape
    hs = [H]
    ws = [W]
    while hs[-1] > 1 or ws[-1] > 1:
        hs.append((hs[-1] + 1) // 2)
        ws.append((ws[-1] + 1) // 2)
    L = len(hs)
    offs = np.zeros(L, np.int64)
    total = 0
    for k in range(L):
        offs[k] = total
        total += hs[k] * ws[k]
    mn = np.empty(total, np.float32)
    mx = np.empty(total, np.float32)
    for r in range(H):
        for c in range(W):
            mn[r * W + c] = lo0[r, c]
            mx[r * W + c] = hi0[r, c]
    for k in range(1, L):
        ph, pw, po = hs[k - 1], ws[k - 1], offs[k - 1]
        h, w, o = hs[k], ws[k], offs[k]
        for r in range(h):
            for c in range(w):
                a = np.float32(np.inf)
                b = _NEG_INF
                for dr in range(2):
                    rr = 2 * r + dr
                    if rr >= ph:
                        continue
                    for dc in range(2):
                        cc = 2 * c + dc
                        if cc >= pw:
                            continue
                        a = min(a, mn[po + rr * pw + cc])
                        b = max(b, mx[po + rr * pw + cc])
                mn[o + r * w + c] = a
                mx[o + r * w + c] = b
    hs_a = np.empty(L, np.int64)
    ws_a = np.empty(L, np.int64)
    for k in range(L):
        hs_a[k] = hs[k]
        ws_a[k] = ws[k]
    return mn, mx, offs, hs_a, ws_a


@njit(cache=True, nogil=True)
def _pyr_query(mn, mx, offs, ws, u0, u1, v0, v1):
    s = max(u1 - u0 + 1, v1 - v0 + 1)
    k = 0
    while (4 << k) < s and k < offs.shape[0] - 1:  # the box spans at most 5 cells of level k
        k += 1
    a = np.float32(np.inf)
    b = _NEG_INF
    w = ws[k]
    o = offs[k]
    for r in range(v0 >> k, (v1 >> k) + 1):
        for c in range(u0 >> k, (u1 >> k) + 1):
            a = min(a, mn[o + r * w + c])
            b = max(b, mx[o + r * w + c])
    return a, b


@njit(cache=True, nogil=True)
def _classify(px, py, pz, corners, cam, planes, pyr_mn, pyr_mx, offs, ws, simple):
    """Class (SKIP, FREE or PARTIAL) of a world-axis-aligned cube centred at (px, py, pz)
    (camera frame) whose corners are ``(px, py, pz) + corners[i]`` ((8, 3) camera frame)."""
    min_z = cam[6]
    max_range = cam[7]
    r2 = corners[0, 0] ** 2 + corners[0, 1] ** 2 + corners[0, 2] ** 2
    if np.sqrt(px * px + py * py + pz * pz) - np.sqrt(r2) > max_range:
        return SKIP
    zn = np.inf
    zf = -np.inf
    for i in range(8):
        z = pz + corners[i, 2]
        zn = min(zn, z)
        zf = max(zf, z)
    if zf <= min_z:
        return SKIP
    for i in range(4):
        a = planes[i, 0]
        b = planes[i, 1]
        c = planes[i, 2]
        outside = True
        for q in range(8):
            if a * (px + corners[q, 0]) + b * (py + corners[q, 1]) + c * (pz + corners[q, 2]) >= 0:
                outside = False
                break
        if outside:
            return SKIP
    W = cam[4]
    H = cam[5]
    if simple or zn <= min_z:
        u0, u1, v0, v1 = 0, int(W) - 1, 0, int(H) - 1
        inside = False
    else:
        fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
        umin = np.inf
        umax = -np.inf
        vmin = np.inf
        vmax = -np.inf
        for q in range(8):
            iz = 1.0 / (pz + corners[q, 2])
            u = (px + corners[q, 0]) * iz
            v = (py + corners[q, 1]) * iz
            umin = min(umin, u)
            umax = max(umax, u)
            vmin = min(vmin, v)
            vmax = max(vmax, v)
        umin = cx + fx * umin
        umax = cx + fx * umax
        vmin = cy + fy * vmin
        vmax = cy + fy * vmax
        if umax < -0.5 or vmax < -0.5 or umin >= W - 0.5 or vmin >= H - 0.5:
            return SKIP
        inside = umin >= -0.5 and vmin >= -0.5 and umax < W - 0.5 and vmax < H - 0.5
        u0 = max(0, int(np.floor(umin + 0.5)))
        v0 = max(0, int(np.floor(vmin + 0.5)))
        u1 = min(int(W) - 1, int(np.floor(umax + 0.5)))
        v1 = min(int(H) - 1, int(np.floor(vmax + 0.5)))
    lo, hi = _pyr_query(pyr_mn, pyr_mx, offs, ws, u0, u1, v0, v1)
    if zn > hi:
        return SKIP
    if inside and zf < lo:
        return FREE
    return PARTIAL


@njit(cache=True, nogil=True)
def cube_corners(R, half):
    """(8, 3) camera-frame offsets of the corners of a world-axis-aligned cube of half edge ``half``."""
    out = np.empty((8, 3), np.float64)
    for q in range(8):
        a = half if q & 4 else -half
        b = half if q & 2 else -half
        c = half if q & 1 else -half
        for i in range(3):
            out[q, i] = R[i, 0] * a + R[i, 1] * b + R[i, 2] * c
    return out


@njit(cache=True, nogil=True)
def _classify_super(s, out, s_lo, s_n, bedge, R, t, cam, planes, pyr_mn, pyr_mx, offs, ws, simple, cb, cs):
    """Row ``s`` of :func:`classify_blocks`."""
    sedge = SUPER * bedge
    sx = s_lo[0] + s // (s_n[1] * s_n[2])
    sy = s_lo[1] + (s // s_n[2]) % s_n[1]
    sz = s_lo[2] + s % s_n[2]
    wx = (sx + 0.5) * sedge
    wy = (sy + 0.5) * sedge
    wz = (sz + 0.5) * sedge
    px = R[0, 0] * wx + R[0, 1] * wy + R[0, 2] * wz + t[0]
    py = R[1, 0] * wx + R[1, 1] * wy + R[1, 2] * wz + t[1]
    pz = R[2, 0] * wx + R[2, 1] * wy + R[2, 2] * wz + t[2]
    c = _classify(px, py, pz, cs, cam, planes, pyr_mn, pyr_mx, offs, ws, simple)
    if c == SKIP:
        return
    if c == FREE:
        out[s, :] = FREE
        return
    for i in range(SUPER):
        for j in range(SUPER):
            for k in range(SUPER):
                bx = (sx * SUPER + i + 0.5) * bedge
                by = (sy * SUPER + j + 0.5) * bedge
                bz = (sz * SUPER + k + 0.5) * bedge
                qx = R[0, 0] * bx + R[0, 1] * by + R[0, 2] * bz + t[0]
                qy = R[1, 0] * bx + R[1, 1] * by + R[1, 2] * bz + t[1]
                qz = R[2, 0] * bx + R[2, 1] * by + R[2, 2] * bz + t[2]
                out[s, (i * SUPER + j) * SUPER + k] = _classify(
                    qx, qy, qz, cb, cam, planes, pyr_mn, pyr_mx, offs, ws, simple
                )


@njit(cache=True, nogil=True, parallel=True)
def classify_blocks(s_lo, s_n, B, voxel, R, t, cam, planes, pyr_mn, pyr_mx, offs, ws, simple):
    """Classify every block of the superblock box ``[s_lo, s_lo + s_n)`` against the frame.

    Args:
        s_lo: (3,) int64 first superblock coordinate; s_n: (3,) int64 box size in superblocks.
        R, t: (3, 3), (3,) float64 ``cam_from_world``.
        cam: (9,) float64 fx, fy, cx, cy, W, H, min_z, max_range, skew.
        planes: (4, 3) float64 inward unit normals of the frustum side planes (camera frame).
    Returns:
        (S, SUPER^3) int8 classes, S = prod(s_n), block (i, j, k) of superblock s at
        ``[s, (i * SUPER + j) * SUPER + k]``.
    """
    nS = s_n[0] * s_n[1] * s_n[2]
    out = np.zeros((nS, SUPER * SUPER * SUPER), np.int8)
    bedge = B * voxel
    cb = cube_corners(R, 0.5 * bedge)
    cs = cube_corners(R, 0.5 * SUPER * bedge)
    for s in prange(nS):
        _classify_super(s, out, s_lo, s_n, bedge, R, t, cam, planes, pyr_mn, pyr_mx, offs, ws, simple, cb, cs)
    return out


@njit(cache=True, nogil=True)
def collect_blocks(cls, s_lo, s_n):
    """Block coordinates (M, 3) int32 and classes (M,) int8 of the non-skipped blocks."""
    n = 0
    for s in range(cls.shape[0]):
        for q in range(cls.shape[1]):
            if cls[s, q] != SKIP:
                n += 1
    coords = np.empty((n, 3), np.int32)
    kinds = np.empty(n, np.int8)
    m = 0
    for s in range(cls.shape[0]):
        sx = s_lo[0] + s // (s_n[1] * s_n[2])
        sy = s_lo[1] + (s // s_n[2]) % s_n[1]
        sz = s_lo[2] + s % s_n[2]
        for q in range(cls.shape[1]):
            if cls[s, q] != SKIP:
                coords[m, 0] = sx * SUPER + q // (SUPER * SUPER)
                coords[m, 1] = sy * SUPER + (q // SUPER) % SUPER
                coords[m, 2] = sz * SUPER + q % SUPER
                kinds[m] = cls[s, q]
                m += 1
    return coords, kinds


@njit(cache=True, nogil=True)
def _change(old, new, thr):
    """Change code of one voxel update: ``CHANGED_STATE`` (unknown / free / occupied) plus
    ``CHANGED_OCCUPIED`` when the voxel entered or left the occupied state; 0 for none."""
    ob = old >= thr  # False for NaN (unknown)
    nb = new >= thr
    if ob != nb:
        return CHANGED_STATE | CHANGED_OCCUPIED
    if old != old:
        return CHANGED_STATE
    return 0


@njit(cache=True, nogil=True)
def _miss(old, l_miss, c_lo, stale):
    """A voxel's log-odds after a miss: ``old + l_miss`` clamped at ``c_lo``; an unknown voxel
    (NaN), or one still at the ``stale`` prior value (NaN: none, see
    :attr:`skyrecon.mapping.MapConfig.stale_log_odds`), starts from 0 as if never measured."""
    if old != old or old == stale:
        return max(l_miss, c_lo)
    return max(old + l_miss, c_lo)


@njit(cache=True, nogil=True)
def _hit(old, l_hit, c_hi, stale):
    """A voxel's log-odds after a hit: ``old + l_hit`` clamped at ``c_hi``; an unknown voxel
    (NaN), or one still at the ``stale`` prior value, starts from 0 as if never measured: this
    flight's first measurement of a voxel replaces an earlier flight's belief, hit or miss."""
    if old != old or old == stale:
        return min(l_hit, c_hi)
    return min(old + l_hit, c_hi)


@njit(cache=True, nogil=True)
def _carve_range(blk, B, x0, x1, y0, y1, z0, z1, l_miss, c_lo, c_hi, thr, stale):
    """Miss every voxel of the local box [x0, x1) x [y0, y1) x [z0, z1) (see :func:`_miss`).

    Returns (change code, see :func:`_change`; every voxel of the box now sits at ``c_lo``).
    """
    ch = 0
    sat = True
    for lx in range(x0, x1):
        for ly in range(y0, y1):
            base = (lx * B + ly) * B
            for lz in range(z0, z1):
                old = blk[base + lz]
                new = _miss(old, l_miss, c_lo, stale)
                blk[base + lz] = new
                ch |= _change(old, new, thr)
                if new != c_lo:
                    sat = False
    return ch, sat


@njit(cache=True, nogil=True)
def _voxels(
    blk, hm, B, x0, x1, y0, y1, z0, z1, px, py, pz, R, voxel, cam, dist, plane, lodds, counts, j, order
):
    """Test every voxel of a local box against the depth image; ``(px, py, pz)`` is voxel (0, 0, 0)'s centre (camera frame).

    ``hm`` (B^3,) uint8 flags the voxels holding a measured point (hit regardless), or is empty.
    ``order`` (3,) int64: world axes from the outer to the inner loop; the inner one should move
    along image rows (camera x), so that consecutive voxels read neighbouring pixels.
    Returns (change code, see :func:`_change`; some voxel was hit).
    """
    use_hm = hm.shape[0] > 0
    l_hit, l_miss, c_lo, c_hi, thr = lodds[0], lodds[1], lodds[2], lodds[3], lodds[4]
    stale = lodds[5]
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    W = cam[4]
    H = cam[5]
    min_z = cam[6]
    skew = cam[8]
    has_dist = dist[0] != 0.0
    k1, k2, p1, p2, k3 = dist[1], dist[2], dist[3], dist[4], dist[5]
    lo0 = (x0, y0, z0)
    hi0 = (x1, y1, z1)
    stride = (B * B, B, 1)
    a, b, c = order[0], order[1], order[2]
    ea0, ea1, ea2 = R[0, a] * voxel, R[1, a] * voxel, R[2, a] * voxel
    eb0, eb1, eb2 = R[0, b] * voxel, R[1, b] * voxel, R[2, b] * voxel
    ec0, ec1, ec2 = R[0, c] * voxel, R[1, c] * voxel, R[2, c] * voxel
    sa, sb, sc = stride[a], stride[b], stride[c]
    ch = 0
    nf = 0
    nh = 0
    umax = W - 0.5
    vmax = H - 0.5
    for ia in range(lo0[a], hi0[a]):
        for ib in range(lo0[b], hi0[b]):
            qx = px + ia * ea0 + ib * eb0
            qy = py + ia * ea1 + ib * eb1
            qz = pz + ia * ea2 + ib * eb2
            base = ia * sa + ib * sb
            for ic in range(lo0[c], hi0[c]):
                q = base + ic * sc
                if use_hm and hm[q]:
                    old = blk[q]
                    nh += 1
                    new = _hit(old, l_hit, c_hi, stale)
                    ch |= _change(old, new, thr)
                    blk[q] = new
                    continue
                z = qz + ic * ec2
                if z <= min_z:
                    continue
                iz = 1.0 / z
                cxv = qx + ic * ec0
                cyv = qy + ic * ec1
                x = cxv * iz
                y = cyv * iz
                if has_dist:
                    r2 = x * x + y * y
                    rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
                    xd = x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
                    yd = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
                    x = xd
                    y = yd
                u = fx * x + skew * y + cx
                v = fy * y + cy
                if not (u >= -0.5 and u < umax and v >= -0.5 and v < vmax):
                    continue
                iu = int(u + 0.5)
                iv = int(v + 0.5)
                sd = plane[iv, iu, 0] * cxv + plane[iv, iu, 1] * cyv + plane[iv, iu, 2] * z - plane[iv, iu, 3]
                old = blk[q]
                if sd < -plane[iv, iu, 4]:
                    nf += 1
                    new = _miss(old, l_miss, c_lo, stale)
                elif abs(sd) <= plane[iv, iu, 5]:
                    nh += 1
                    new = _hit(old, l_hit, c_hi, stale)
                else:
                    continue  # behind the surface, or no valid depth (NaN compares False)
                ch |= _change(old, new, thr)
                blk[q] = new
    counts[j, 0] += nf
    counts[j, 1] += nh
    return ch, nh > 0


@njit(cache=True, nogil=True)
def _all_at(blk, B, x0, y0, z0, h, value):
    """Whether every voxel of the local box [x0, x0 + h) x ... holds ``value``."""
    for lx in range(x0, x0 + h):
        for ly in range(y0, y0 + h):
            base = (lx * B + ly) * B
            for lz in range(z0, z0 + h):
                if blk[base + lz] != value:
                    return False
    return True


@njit(cache=True, nogil=True)
def _update_block(
    j,
    data,
    sat,
    coords,
    ids,
    kinds,
    B,
    voxel,
    R,
    t,
    cam,
    dist,
    plane,
    lodds,
    planes,
    pyr_mn,
    pyr_mx,
    offs,
    ws,
    simple,
    loc,
    hitmask,
    octflag,
    co,
    counts,
    order,
):
    """Update block ``ids[j]``; returns its change code (see :func:`update_blocks`)."""
    l_miss, c_lo, c_hi, thr = lodds[1], lodds[2], lodds[3], lodds[4]
    stale = lodds[5]
    h = B // 2
    k = ids[j]
    blk = data[k]
    if kinds[j] == FREE:
        counts[j, 0] = B * B * B
        ch = 0
        for o in range(8):
            if sat[k] & (1 << o):
                continue
            x0 = h * (o >> 2)
            y0 = h * ((o >> 1) & 1)
            z0 = h * (o & 1)
            c1, full = _carve_range(
                blk, B, x0, x0 + h, y0, y0 + h, z0, z0 + h, l_miss, c_lo, c_hi, thr, stale
            )
            ch |= c1
            if full:
                sat[k] |= 1 << o
        return ch
    wx0 = (coords[k, 0] * B + 0.5) * voxel
    wy0 = (coords[k, 1] * B + 0.5) * voxel
    wz0 = (coords[k, 2] * B + 0.5) * voxel
    px = R[0, 0] * wx0 + R[0, 1] * wy0 + R[0, 2] * wz0 + t[0]
    py = R[1, 0] * wx0 + R[1, 1] * wy0 + R[1, 2] * wz0 + t[1]
    pz = R[2, 0] * wx0 + R[2, 1] * wy0 + R[2, 2] * wz0 + t[2]
    ch = 0
    lj = loc[j]
    for o in range(8):
        forced = lj >= 0 and octflag[lj, o] != 0
        bit = 1 << o
        if (sat[k] & bit) and not forced:
            # every voxel sits at the lower clamp: misses change nothing, and without a
            # measured point inside, nothing here can be hit
            continue
        x0 = h * (o >> 2)
        y0 = h * ((o >> 1) & 1)
        z0 = h * (o & 1)
        # octant centre, camera frame
        ox = (x0 + 0.5 * (h - 1)) * voxel
        oy = (y0 + 0.5 * (h - 1)) * voxel
        oz = (z0 + 0.5 * (h - 1)) * voxel
        cxo = px + R[0, 0] * ox + R[0, 1] * oy + R[0, 2] * oz
        cyo = py + R[1, 0] * ox + R[1, 1] * oy + R[1, 2] * oz
        czo = pz + R[2, 0] * ox + R[2, 1] * oy + R[2, 2] * oz
        c = PARTIAL if forced else _classify(cxo, cyo, czo, co, cam, planes, pyr_mn, pyr_mx, offs, ws, simple)
        if c == SKIP:
            continue
        if c == FREE:
            counts[j, 0] += h * h * h
            c1, full = _carve_range(
                blk, B, x0, x0 + h, y0, y0 + h, z0, z0 + h, l_miss, c_lo, c_hi, thr, stale
            )
            ch |= c1
            if full:
                sat[k] |= bit
            continue
        hm = hitmask[lj] if lj >= 0 else hitmask[0, :0]
        c1, hit = _voxels(
            blk,
            hm,
            B,
            x0,
            x0 + h,
            y0,
            y0 + h,
            z0,
            z0 + h,
            px,
            py,
            pz,
            R,
            voxel,
            cam,
            dist,
            plane,
            lodds,
            counts,
            j,
            order,
        )
        ch |= c1
        if hit:
            sat[k] &= ~bit
        elif _all_at(blk, B, x0, y0, z0, h, c_lo):
            sat[k] |= bit
    return ch


@njit(cache=True, nogil=True)
def _loop_order(R):
    """World axes ordered so that the last one moves most along the camera's x axis (image rows)
    and the middle one most along its y axis: consecutive voxels then read nearby pixels."""
    inner = 0
    for a in range(3):
        if abs(R[0, a]) > abs(R[0, inner]):
            inner = a
    mid = -1
    for a in range(3):
        if a != inner and (mid < 0 or abs(R[1, a]) > abs(R[1, mid])):
            mid = a
    outer = 3 - inner - mid
    out = np.empty(3, np.int64)
    out[0] = outer
    out[1] = mid
    out[2] = inner
    return out


@njit(cache=True, nogil=True, parallel=True)
def update_blocks(
    data,
    sat,
    coords,
    ids,
    kinds,
    B,
    voxel,
    R,
    t,
    cam,
    dist,
    plane,
    lodds,
    planes,
    pyr_mn,
    pyr_mx,
    offs,
    ws,
    simple,
    loc,
    hitmask,
    octflag,
):
    """Apply one frame's hits and misses to blocks ``ids`` (pool indices) of classes ``kinds``.

    A PARTIAL block is split into 8 octants, each classified again against the depth pyramid
    (skipped, carved in one loop, or tested voxel by voxel).

    Args:
        data: (N, B^3) float32 log-odds pool (NaN unknown), updated in place.
        sat: (N,) uint8 bit mask per block: bit o set when every voxel of octant o is known to
            sit at ``clamp_min``. Misses cannot change such an octant, so it is skipped unless a
            measured point falls inside it this frame (then it is tested voxel by voxel; a hit
            clears the bit). Maintained in place; 0 is always safe.
        coords: (N, 3) int32 block coordinates of the pool.
        R, t: ``cam_from_world``. cam: (9,) fx, fy, cx, cy, W, H, min_z, max_range, skew.
        dist: (6,) float64 ``has_distortion, k1, k2, p1, p2, k3``.
        plane: (H, W, 6) float32 from :func:`prepare_depth`.
        loc: (M,) int32 row of each block in ``hitmask`` / ``octflag`` (from
            :func:`mark_endpoints`), -1 for none.
        lodds: (6,) float32, :attr:`skyrecon.mapping.MapConfig.log_odds`.
    Returns:
        changed (M,) uint8 change code per block: bit ``CHANGED_STATE`` (1) when some voxel
        changed state (unknown / free / occupied), bit ``CHANGED_OCCUPIED`` (2) when some voxel
        entered or left the occupied state;
        counts (M, 2) int64: voxels updated as free and as occupied.
    """
    M = ids.shape[0]
    changed = np.zeros(M, np.uint8)
    counts = np.zeros((M, 2), np.int64)
    co = cube_corners(R, 0.5 * (B // 2) * voxel)
    order = _loop_order(R)
    for j in prange(M):
        changed[j] = _update_block(
            j,
            data,
            sat,
            coords,
            ids,
            kinds,
            B,
            voxel,
            R,
            t,
            cam,
            dist,
            plane,
            lodds,
            planes,
            pyr_mn,
            pyr_mx,
            offs,
            ws,
            simple,
            loc,
            hitmask,
            octflag,
            co,
            counts,
            order,
        )
    return changed, counts
