"""Numba kernels of the PatchMatch multi-view stereo (ACMH/COLMAP-like, red-black sweeps).

Every kernel is compiled for exactly one set of argument types (``cache=True`` keeps the machine
code on disk, so a process pays the JIT once):

- reference image ``ref``: (H, W) float32 grey, any consistent scale (0..255 here);
- source images ``srcs``: (K, Hs, Ws) float32, each padded at the bottom/right to the largest
  source, ``src_wh``: (K, 2) int64 true (width, height) of each;
- ``A``: (K, 3, 3) float64 ``K_s R_sr K_r^-1``; ``b``: (K, 3) float64 ``K_s t_sr`` where
  ``(R_sr, t_sr) = src_from_ref``;
- ``intr``: (4,) float64 ``fx, fy, cx, cy`` of the reference camera;
- state: ``depth`` (H, W) float32 metres along the reference optical axis, ``normal`` (H, W, 3)
  float32 unit normals in the reference camera frame (facing the camera), ``cost`` (H, W)
  float32 aggregated matching cost in [0, 2] (1 - NCC; 2 = no estimate);
- ``mask``: (H, W) uint8, 1 where the pixel is estimated (inside the image by the window radius,
  textured, valid alpha);
- ``du``, ``dv``: (S,) float64 window sample offsets (whole pixels); ``params``: (P,) float64, see
  ``P_*`` indices below.

Hypotheses are slanted planes: at pixel ``p`` with depth ``d`` and normal ``n`` the plane is
``n . X = d n . K^-1 p``. A window sample ``q`` maps to source ``s`` through the homography
``H_s = A_s + b_s m^T`` with ``m = K^-T n / (n . X_p)``. The photo-consistency of one source is
``1 - NCC`` with bilateral weights (colour and space) over the window; the cost of a hypothesis
is the mean of the ``topk`` best source costs.

Red-black checkerboard: one sweep updates the pixels of one colour from hypotheses of the other
colour (neighbours at odd Manhattan distance), so rows can be split between threads. Random
numbers come from a counter-based hash of (seed, pixel, iteration, draw): results do not depend
on the thread split.

Numba's cache does not notice when a helper in another file changes, so helpers live here.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit

_JIT: dict[str, Any] = dict(
    cache=True,
    nogil=True,
    boundscheck=False,
    error_model="numpy",
    fastmath={"contract", "arcp", "nsz", "afn", "reassoc"},
)  # no nnan/ninf: NaN tests stay

# indices into ``params``
P_DMIN = 0  # smallest depth, metres
P_DMAX = 1  # largest depth, metres
P_SIGMA_COLOR = 2  # bilateral colour sigma (image units)
P_SIGMA_SPACE = 3  # bilateral spatial sigma (pixels)
P_TOPK = 4  # number of best sources averaged
P_PERTURB = 5  # relative depth perturbation of the refinement (fraction of the inverse-depth range)
P_NORMAL_PERTURB = 6  # normal perturbation (radians, roughly)
P_MIN_VAR = 7  # smallest source variance in the window (image units squared)
P_FAR = 8  # largest far-neighbour distance (pixels, odd)
P_MAX_INCIDENCE = 9  # cos of the largest angle between a normal and the reverse viewing ray
P_CANDIDATES = 10  # propagation candidates evaluated (the lowest-cost ones of up to 8)
P_REFINE = 11  # refinement trials per pixel and sweep (cycling random depth, random normal, perturbation)
P_MIN_REF_STD = 12  # smallest bilateral-weighted std of the reference window (image units)
P_MISSING = 13  # cost added per missing source (fewer than topk sources see the window)
N_PARAMS = 14

BAD_COST = 2.0
OUTSIDE = 1e9  # per-source cost of a window that falls outside that source image


@njit(**_JIT)
def _uniform(seed: np.uint64, a: np.int64, b: np.int64, c: np.int64) -> float:
    """Counter-based uniform in [0, 1): splitmix64 of (seed, a, b, c)."""
    z = (
        seed
        + np.uint64(a) * np.uint64(0x9E3779B97F4A7C15)
        + np.uint64(b) * np.uint64(0xD1B54A32D192ED03)
        + np.uint64(c) * np.uint64(0x8CB92BA72F3D8DD7)
    )
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(**_JIT)
def _window_stats(ref, u, v, du, dv, sigma_c, sigma_s, w_out, r_out):
    """Bilateral weights and reference values of the window at (u, v).

    ``w = exp(-(I(q) - I(p))^2 / (2 sigma_c^2) - |q - p|^2 / (2 sigma_s^2))``.

    Returns ``(sum_w, weighted mean, weighted std)``; fills ``w_out``, ``r_out`` (S,).
    """
    c0 = ref[v, u]
    ic = -0.5 / (sigma_c * sigma_c)
    is_ = -0.5 / (sigma_s * sigma_s)
    sw = 0.0
    swr = 0.0
    swrr = 0.0
    for i in range(du.shape[0]):
        r = ref[v + int(dv[i]), u + int(du[i])]
        dc = r - c0
        w = np.exp(dc * dc * ic + (du[i] * du[i] + dv[i] * dv[i]) * is_)
        w_out[i] = w
        r_out[i] = r
        sw += w
        swr += w * r
        swrr += w * r * r
    mr = swr / sw
    var = swrr / sw - mr * mr
    return sw, mr, np.sqrt(max(var, 0.0))


@njit(**_JIT)
def _hypothesis_cost(
    u,
    v,
    d,
    nx,
    ny,
    nz,
    w,
    rv,
    sw,
    mr,
    sr,
    du,
    dv,
    srcs,
    src_wh,
    A,
    b,
    intr,
    topk,
    min_var,
    missing_penalty,
    costs,
    xs,
    ys,
):
    """Aggregated cost of plane (d, n) at pixel (u, v).

    The mean of the ``topk`` best ``1 - NCC`` among the sources whose image contains the
    projected window, plus ``missing_penalty`` for each of the ``topk`` that no source could
    provide (so that a point seen by a single source can still be estimated, at a price);
    ``BAD_COST`` when no source sees it. ``xs``, ``ys`` are (S,) float64 scratch buffers.
    """
    fx = intr[0]
    fy = intr[1]
    cx = intr[2]
    cy = intr[3]
    rx = (u - cx) / fx
    ry = (v - cy) / fy
    h = d * (nx * rx + ny * ry + nz)  # n . X_p (negative: the plane faces the camera)
    if not (h < 0.0):
        return BAD_COST
    m0 = nx / fx / h
    m1 = ny / fy / h
    m2 = (nz - nx * cx / fx - ny * cy / fy) / h
    K = srcs.shape[0]
    S = du.shape[0]
    for k in range(K):
        H00 = A[k, 0, 0] + b[k, 0] * m0
        H01 = A[k, 0, 1] + b[k, 0] * m1
        H02 = A[k, 0, 2] + b[k, 0] * m2
        H10 = A[k, 1, 0] + b[k, 1] * m0
        H11 = A[k, 1, 1] + b[k, 1] * m1
        H12 = A[k, 1, 2] + b[k, 1] * m2
        H20 = A[k, 2, 0] + b[k, 2] * m0
        H21 = A[k, 2, 1] + b[k, 2] * m1
        H22 = A[k, 2, 2] + b[k, 2] * m2
        bx = H00 * u + H01 * v + H02
        by = H10 * u + H11 * v + H12
        bz = H20 * u + H21 * v + H22
        # pass 1 (vectorisable): sample positions and their bounds
        lo = 1e30
        hix = -1e30
        hiy = -1e30
        loz = 1e30
        for i in range(S):
            qz = bz + du[i] * H20 + dv[i] * H21
            iz = 1.0 / qz
            x = (bx + du[i] * H00 + dv[i] * H01) * iz
            y = (by + du[i] * H10 + dv[i] * H11) * iz
            xs[i] = x
            ys[i] = y
            lo = min(lo, min(x, y))
            hix = max(hix, x)
            hiy = max(hiy, y)
            loz = min(loz, qz)
        if not (loz > 1e-12 and lo >= 0.0 and hix < src_wh[k, 0] - 1.0 and hiy < src_wh[k, 1] - 1.0):
            costs[k] = OUTSIDE  # this source does not see the window: not counted
            continue
        # pass 2: bilinear samples and weighted sums
        sws = 0.0
        swss = 0.0
        swrs = 0.0
        for i in range(S):
            x = xs[i]
            y = ys[i]
            x0 = int(x)
            y0 = int(y)
            ax = x - x0
            ay = y - y0
            p00 = srcs[k, y0, x0]
            p01 = srcs[k, y0, x0 + 1]
            p10 = srcs[k, y0 + 1, x0]
            p11 = srcs[k, y0 + 1, x0 + 1]
            top = p00 + (p01 - p00) * ax
            bot = p10 + (p11 - p10) * ax
            s = top + (bot - top) * ay
            wi = w[i]
            sws += wi * s
            swss += wi * s * s
            swrs += wi * rv[i] * s
        ms = sws / sw
        vs = swss / sw - ms * ms
        if vs < min_var:
            costs[k] = BAD_COST
            continue
        cov = swrs / sw - mr * ms
        ncc = cov / (sr * np.sqrt(vs))
        if ncc > 1.0:
            ncc = 1.0
        elif ncc < -1.0:
            ncc = -1.0
        costs[k] = 1.0 - ncc
    # mean of the topk smallest among the sources that see the window (insertion sort, K is
    # small), plus a penalty for every missing one
    for i in range(1, K):
        x = costs[i]
        j = i - 1
        while j >= 0 and costs[j] > x:
            costs[j + 1] = costs[j]
            j -= 1
        costs[j + 1] = x
    want = topk if topk < K else K
    n = 0
    acc = 0.0
    for i in range(want):
        if costs[i] >= OUTSIDE:
            break
        acc += costs[i]
        n += 1
    if n == 0:
        return BAD_COST
    return acc / n + missing_penalty * (want - n)


@njit(**_JIT)
def _random_normal(seed, idx, it, draw, rx, ry, cos_max):
    """A random unit normal facing the camera along ray (rx, ry, 1), within acos(cos_max) of it."""
    rn = 1.0 / np.sqrt(rx * rx + ry * ry + 1.0)
    vx = -rx * rn
    vy = -ry * rn
    vz = -rn
    for t in range(8):
        a = _uniform(seed, idx, it, draw + 2 * t)
        bb = _uniform(seed, idx, it, draw + 2 * t + 1)
        z = 2.0 * a - 1.0
        r = np.sqrt(max(0.0, 1.0 - z * z))
        phi = 2.0 * np.pi * bb
        nx = r * np.cos(phi)
        ny = r * np.sin(phi)
        nz = z
        c = nx * vx + ny * vy + nz * vz
        if c < 0.0:
            nx = -nx
            ny = -ny
            nz = -nz
            c = -c
        if c >= cos_max:
            return nx, ny, nz
    return vx, vy, vz


@njit(**_JIT)
def _perturb_normal(seed, idx, it, draw, nx, ny, nz, amount, rx, ry, cos_max):
    """``n`` plus a random vector of size ``amount``, renormalised, kept facing the camera."""
    px = (2.0 * _uniform(seed, idx, it, draw) - 1.0) * amount
    py = (2.0 * _uniform(seed, idx, it, draw + 1) - 1.0) * amount
    pz = (2.0 * _uniform(seed, idx, it, draw + 2) - 1.0) * amount
    ax = nx + px
    ay = ny + py
    az = nz + pz
    nn = np.sqrt(ax * ax + ay * ay + az * az)
    if nn < 1e-9:
        return nx, ny, nz
    ax /= nn
    ay /= nn
    az /= nn
    rn = 1.0 / np.sqrt(rx * rx + ry * ry + 1.0)
    c = -(ax * rx + ay * ry + az) * rn
    if c < cos_max:
        return nx, ny, nz
    return ax, ay, az


@njit(**_JIT)
def _random_depth(seed, idx, it, draw, dmin, dmax):
    """Uniform in inverse depth on [dmin, dmax]."""
    a = _uniform(seed, idx, it, draw)
    inv = 1.0 / dmax + a * (1.0 / dmin - 1.0 / dmax)
    return 1.0 / inv


@njit(**_JIT)
def pm_init(row0, row1, seed, ref, mask, depth, normal, cost, srcs, src_wh, A, b, intr, du, dv, params):
    """Random initial hypotheses (unless ``depth`` is already finite there) and their costs.

    Pixels whose bilateral-weighted window is flat (std below ``P_MIN_REF_STD``) are removed
    from ``mask`` (they cannot be matched reliably).
    """
    H, W = ref.shape
    S = du.shape[0]
    K = srcs.shape[0]
    w = np.empty(S)
    rv = np.empty(S)
    costs = np.empty(K)
    xs = np.empty(S)
    ys = np.empty(S)
    dmin = params[P_DMIN]
    dmax = params[P_DMAX]
    topk = int(params[P_TOPK])
    cos_max = params[P_MAX_INCIDENCE]
    fx = intr[0]
    fy = intr[1]
    cx = intr[2]
    cy = intr[3]
    for v in range(row0, row1):
        for u in range(W):
            if mask[v, u] == 0:
                continue
            idx = v * W + u
            rx = (u - cx) / fx
            ry = (v - cy) / fy
            d = depth[v, u]
            if not (d >= dmin and d <= dmax):
                d = _random_depth(seed, idx, 0, 0, dmin, dmax)
                nx, ny, nz = _random_normal(seed, idx, 0, 1, rx, ry, cos_max)
            else:
                nx = normal[v, u, 0]
                ny = normal[v, u, 1]
                nz = normal[v, u, 2]
            sw, mr, sr = _window_stats(ref, u, v, du, dv, params[P_SIGMA_COLOR], params[P_SIGMA_SPACE], w, rv)
            if sr < params[P_MIN_REF_STD]:  # flat once weighted (e.g. dark background beside an edge)
                mask[v, u] = 0
                cost[v, u] = BAD_COST
                continue
            c = _hypothesis_cost(
                u,
                v,
                d,
                nx,
                ny,
                nz,
                w,
                rv,
                sw,
                mr,
                sr,
                du,
                dv,
                srcs,
                src_wh,
                A,
                b,
                intr,
                topk,
                params[P_MIN_VAR],
                params[P_MISSING],
                costs,
                xs,
                ys,
            )
            depth[v, u] = d
            normal[v, u, 0] = nx
            normal[v, u, 1] = ny
            normal[v, u, 2] = nz
            cost[v, u] = c


@njit(**_JIT)
def _propagated_depth(uq, vq, u, v, depth, normal, intr):
    """Depth at pixel (u, v) of the plane held by pixel (uq, vq); NaN if the ray misses it."""
    fx = intr[0]
    fy = intr[1]
    cx = intr[2]
    cy = intr[3]
    dq = depth[vq, uq]
    nx = normal[vq, uq, 0]
    ny = normal[vq, uq, 1]
    nz = normal[vq, uq, 2]
    hq = dq * (nx * (uq - cx) / fx + ny * (vq - cy) / fy + nz)
    den = nx * (u - cx) / fx + ny * (v - cy) / fy + nz
    if den > -1e-6:
        return np.nan
    return hq / den


@njit(**_JIT)
def pm_sweep(
    row0, row1, color, it, seed, ref, mask, depth, normal, cost, srcs, src_wh, A, b, intr, du, dv, params
):
    """One red-black half sweep over rows [row0, row1): propagation from the other colour + refinement.

    Candidates: the 4 direct neighbours (distance 1) and, in each of the 4 directions, the
    lowest-cost pixel among distances 3, 5, ..., ``P_FAR``; each is evaluated with its plane
    propagated to this pixel. Refinement then tries a random depth, a random normal and joint
    perturbations whose size halves every iteration.
    """
    H, W = ref.shape
    S = du.shape[0]
    K = srcs.shape[0]
    w = np.empty(S)
    rv = np.empty(S)
    costs = np.empty(K)
    xs = np.empty(S)
    ys = np.empty(S)
    dmin = params[P_DMIN]
    dmax = params[P_DMAX]
    topk = int(params[P_TOPK])
    min_var = params[P_MIN_VAR]
    missing = params[P_MISSING]
    far = int(params[P_FAR])
    cos_max = params[P_MAX_INCIDENCE]
    scale = 0.5**it
    pert = params[P_PERTURB] * scale
    npert = params[P_NORMAL_PERTURB] * scale
    fx = intr[0]
    fy = intr[1]
    cx = intr[2]
    cy = intr[3]
    inv_range = 1.0 / dmin - 1.0 / dmax
    cand_u = np.empty(8, np.int64)
    cand_v = np.empty(8, np.int64)
    cand_c = np.empty(8)
    n_cand = int(params[P_CANDIDATES])
    n_refine = int(params[P_REFINE])
    for v in range(row0, row1):
        u_start = (v + color) % 2
        for u in range(u_start, W, 2):
            if mask[v, u] == 0:
                continue
            idx = v * W + u
            sw, mr, sr = _window_stats(ref, u, v, du, dv, params[P_SIGMA_COLOR], params[P_SIGMA_SPACE], w, rv)
            bd = depth[v, u]
            bnx = normal[v, u, 0]
            bny = normal[v, u, 1]
            bnz = normal[v, u, 2]
            bc = cost[v, u]
            # --- candidates from the other colour: 4 near + best far per direction
            nc = 0
            for dirn in range(4):
                ddx = 1 if dirn == 0 else (-1 if dirn == 1 else 0)
                ddy = 1 if dirn == 2 else (-1 if dirn == 3 else 0)
                uq = u + ddx
                vq = v + ddy
                if 0 <= uq < W and 0 <= vq < H and mask[vq, uq] != 0:
                    cand_u[nc] = uq
                    cand_v[nc] = vq
                    cand_c[nc] = cost[vq, uq]
                    nc += 1
                best_far = 1e30
                bu = -1
                bv = -1
                dist = 3
                while dist <= far:
                    uq = u + ddx * dist
                    vq = v + ddy * dist
                    if not (0 <= uq < W and 0 <= vq < H):
                        break
                    if mask[vq, uq] != 0 and cost[vq, uq] < best_far:
                        best_far = cost[vq, uq]
                        bu = uq
                        bv = vq
                    dist += 2
                if bu >= 0:
                    cand_u[nc] = bu
                    cand_v[nc] = bv
                    cand_c[nc] = best_far
                    nc += 1
            # keep the n_cand lowest-cost candidates (insertion sort by stored cost)
            for i in range(1, nc):
                cc = cand_c[i]
                cu = cand_u[i]
                cv = cand_v[i]
                j = i - 1
                while j >= 0 and cand_c[j] > cc:
                    cand_c[j + 1] = cand_c[j]
                    cand_u[j + 1] = cand_u[j]
                    cand_v[j + 1] = cand_v[j]
                    j -= 1
                cand_c[j + 1] = cc
                cand_u[j + 1] = cu
                cand_v[j + 1] = cv
            if nc > n_cand:
                nc = n_cand
            for ci in range(nc):
                uq = cand_u[ci]
                vq = cand_v[ci]
                if cand_c[ci] >= BAD_COST:
                    break
                d = _propagated_depth(uq, vq, u, v, depth, normal, intr)
                if not (d >= dmin and d <= dmax):
                    continue
                nx = normal[vq, uq, 0]
                ny = normal[vq, uq, 1]
                nz = normal[vq, uq, 2]
                if nx == bnx and ny == bny and nz == bnz and abs(d - bd) < 1e-9 * bd:
                    continue
                c = _hypothesis_cost(
                    u,
                    v,
                    d,
                    nx,
                    ny,
                    nz,
                    w,
                    rv,
                    sw,
                    mr,
                    sr,
                    du,
                    dv,
                    srcs,
                    src_wh,
                    A,
                    b,
                    intr,
                    topk,
                    min_var,
                    missing,
                    costs,
                    xs,
                    ys,
                )
                if c < bc:
                    bc = c
                    bd = d
                    bnx = nx
                    bny = ny
                    bnz = nz
            # --- refinement
            rx = (u - cx) / fx
            ry = (v - cy) / fy
            for t in range(n_refine):
                trial = (t + it + color) % 3
                draw = 16 + 8 * t
                if trial == 0:  # random depth, current normal
                    d = _random_depth(seed, idx, it + 1, draw, dmin, dmax)
                    nx, ny, nz = bnx, bny, bnz
                elif trial == 1:  # current depth, random normal
                    d = bd
                    nx, ny, nz = _random_normal(seed, idx, it + 1, draw, rx, ry, cos_max)
                else:  # both perturbed
                    inv = 1.0 / bd + (2.0 * _uniform(seed, idx, it + 1, draw) - 1.0) * pert * inv_range
                    if not (inv > 0.0):
                        continue
                    d = 1.0 / inv
                    nx, ny, nz = _perturb_normal(
                        seed, idx, it + 1, draw + 1, bnx, bny, bnz, npert, rx, ry, cos_max
                    )
                if not (d >= dmin and d <= dmax):
                    continue
                c = _hypothesis_cost(
                    u,
                    v,
                    d,
                    nx,
                    ny,
                    nz,
                    w,
                    rv,
                    sw,
                    mr,
                    sr,
                    du,
                    dv,
                    srcs,
                    src_wh,
                    A,
                    b,
                    intr,
                    topk,
                    min_var,
                    missing,
                    costs,
                    xs,
                    ys,
                )
                if c < bc:
                    bc = c
                    bd = d
                    bnx = nx
                    bny = ny
                    bnz = nz
            depth[v, u] = bd
            normal[v, u, 0] = bnx
            normal[v, u, 1] = bny
            normal[v, u, 2] = bnz
            cost[v, u] = bc
