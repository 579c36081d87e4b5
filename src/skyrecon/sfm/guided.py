"""Guided matching: descriptor matching restricted to a band around epipolar segments.

Once a pair's relative pose is known from a coarse match of its strongest features, every
feature of image 1 is compared only with the features of image 2 that lie within ``band`` of the
part of its epipolar line where points in front of both cameras, within the depth range of the
coarse matches, project (and the other way round), with the ratio test and the mutual check
applied among those candidates. This finds (nearly) all the matches of an exhaustive comparison at a few
percent of its cost, and more of them: the ratio test competes only against geometrically
possible candidates.

Coordinates are undistorted normalised camera coordinates; ``E`` maps image-1 points to
image-2 lines (``x2^T E x1 = 0``).
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["guided_match"]


@nb.njit(cache=True)
def _grid(xy: np.ndarray, cell: float):
    n = xy.shape[0]
    x0 = xy[:, 0].min() - 1e-9
    y0 = xy[:, 1].min() - 1e-9
    ncx = int((xy[:, 0].max() - x0) / cell) + 1
    ncy = int((xy[:, 1].max() - y0) / cell) + 1
    cid = np.empty(n, np.int64)
    for k in range(n):
        cx = min(int((xy[k, 0] - x0) / cell), ncx - 1)
        cy = min(int((xy[k, 1] - y0) / cell), ncy - 1)
        cid[k] = cy * ncx + cx
    order = np.argsort(cid, kind="mergesort")
    start = np.zeros(ncx * ncy + 1, np.int64)
    for k in range(n):
        start[cid[k] + 1] += 1
    for c in range(ncx * ncy):
        start[c + 1] += start[c]
    return order, start, x0, y0, ncx, ncy


@nb.njit(cache=True, fastmath=True)
def _dot(q: np.ndarray, t: np.ndarray) -> np.float32:
    s = np.float32(0.0)
    for d in range(q.shape[0]):
        s += q[d] * t[d]
    return s


@nb.njit(cache=True)
def _best2_in_band(q_xy, q_desc, R, t, d_lo, d_hi, t_xy, t_desc, band, cell, best, d1, d2):
    """For each query: best and second-best descriptor similarity among the targets within
    ``band`` of the segment of its epipolar line that holds the points at depths
    ``[d_lo, d_hi]`` in front of both cameras (``(R, t)`` = target_from_query camera)."""
    order, start, x0, y0, ncx, ncy = _grid(t_xy, cell)
    nq = q_xy.shape[0]
    eps = 1e-9
    for i in range(nq):
        best[i] = -1
        d1[i] = np.inf
        d2[i] = np.inf
        x = q_xy[i, 0]
        y = q_xy[i, 1]
        f0 = R[0, 0] * x + R[0, 1] * y + R[0, 2]
        f1 = R[1, 0] * x + R[1, 1] * y + R[1, 2]
        f2 = R[2, 0] * x + R[2, 1] * y + R[2, 2]
        # depths in front of the target camera: f2 d + t2 > 0
        lo = d_lo
        hi = d_hi
        if f2 > 0:
            lo = max(lo, (eps - t[2]) / f2)
        elif f2 < 0:
            hi = min(hi, (eps - t[2]) / f2)
        elif t[2] <= 0:
            continue
        if not lo < hi:
            continue
        p0 = f0 * lo + t[0]
        p1 = f1 * lo + t[1]
        p2 = f2 * lo + t[2]
        ax = p0 / p2
        ay = p1 / p2
        if np.isfinite(hi):
            p0 = f0 * hi + t[0]
            p1 = f1 * hi + t[1]
            p2 = f2 * hi + t[2]
            bx = p0 / p2
            by = p1 / p2
        else:  # the vanishing point of the ray
            bx = f0 / f2
            by = f1 / f2
        dx = bx - ax
        dy = by - ay
        L = np.sqrt(dx * dx + dy * dy)
        if L < 1e-12:
            dx, dy, L = 1.0, 0.0, 1.0
        # unit direction and normal of the segment's line
        ux = dx / L
        uy = dy / L
        a = -uy
        b = ux
        c = -(a * ax + b * ay)
        s_lo = -band
        s_hi = L + band
        s1 = -np.inf
        s2 = -np.inf
        arg = -1
        xmin = min(ax, bx) - band
        xmax = max(ax, bx) + band
        ymin = min(ay, by) - band
        ymax = max(ay, by) + band
        gx0 = max(int(np.floor((xmin - x0) / cell)), 0)
        gx1 = min(int(np.floor((xmax - x0) / cell)), ncx - 1)
        gy0 = max(int(np.floor((ymin - y0) / cell)), 0)
        gy1 = min(int(np.floor((ymax - y0) / cell)), ncy - 1)
        if gx1 < gx0 or gy1 < gy0:
            continue
        horizontal = abs(b) >= abs(a)
        if horizontal:
            o_lo, o_hi = gx0, gx1
        else:
            o_lo, o_hi = gy0, gy1
        for go in range(o_lo, o_hi + 1):
            if horizontal:
                u0 = x0 + go * cell
                u1 = u0 + cell
                va = -(a * u0 + c) / b
                vb = -(a * u1 + c) / b
                w = band / abs(b)
                lo_i = max(int(np.floor((min(va, vb) - w - y0) / cell)), gy0)
                hi_i = min(int(np.floor((max(va, vb) + w - y0) / cell)), gy1)
            else:
                u0 = y0 + go * cell
                u1 = u0 + cell
                va = -(b * u0 + c) / a
                vb = -(b * u1 + c) / a
                w = band / abs(a)
                lo_i = max(int(np.floor((min(va, vb) - w - x0) / cell)), gx0)
                hi_i = min(int(np.floor((max(va, vb) + w - x0) / cell)), gx1)
            for gi in range(lo_i, hi_i + 1):
                g = gi * ncx + go if horizontal else go * ncx + gi
                for kk in range(start[g], start[g + 1]):
                    k = order[kk]
                    qx = t_xy[k, 0] - ax
                    qy = t_xy[k, 1] - ay
                    if abs(a * qx + b * qy) > band:
                        continue
                    sp = ux * qx + uy * qy
                    if sp < s_lo or sp > s_hi:
                        continue
                    s = _dot(q_desc[i], t_desc[k])
                    if s > s1:
                        s2 = s1
                        s1 = s
                        arg = k
                    elif s > s2:
                        s2 = s
        if arg >= 0:
            best[i] = arg
            d1[i] = np.sqrt(max(2.0 - 2.0 * s1, 0.0))
            d2[i] = np.sqrt(max(2.0 - 2.0 * s2, 0.0)) if s2 > -np.inf else np.inf


def guided_match(
    x1n: np.ndarray,
    desc1: np.ndarray,
    x2n: np.ndarray,
    desc2: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    band: float,
    depth_range1: tuple[float, float] = (1e-6, np.inf),
    depth_range2: tuple[float, float] = (1e-6, np.inf),
    ratio: float = 0.8,
    mutual: bool = True,
) -> np.ndarray:
    """Match two feature sets along epipolar segments.

    Args:
        x1n, x2n: (N1, 2), (N2, 2) undistorted normalised coordinates of all features.
        desc1, desc2: (N1, D), (N2, D) float32 unit-norm descriptors.
        R, t: ``cam2_from_cam1`` (the scale of t sets the units of the depth ranges).
        band: largest distance of a candidate from the epipolar line, normalised units.
        depth_range1, depth_range2: depths along camera 1's / camera 2's optical axis a match
            may have (restricts each epipolar line to a segment; ``inf`` allowed).
        ratio: Lowe's ratio among the candidates of the band.
        mutual: keep only mutual best matches.
    Returns:
        (M, 2) int64 ``[index in 1, index in 2]``.
    """
    x1n = np.ascontiguousarray(x1n, np.float64)
    x2n = np.ascontiguousarray(x2n, np.float64)
    d1 = np.ascontiguousarray(desc1, np.float32)
    d2 = np.ascontiguousarray(desc2, np.float32)
    R = np.ascontiguousarray(R, np.float64)
    t = np.ascontiguousarray(t, np.float64).reshape(3)
    if len(x1n) == 0 or len(x2n) == 0:
        return np.zeros((0, 2), np.int64)
    span = max(np.ptp(x2n[:, 0]), np.ptp(x2n[:, 1]), np.ptp(x1n[:, 0]), np.ptp(x1n[:, 1]), 1e-9)
    cell = max(2.0 * band, span / 64.0)
    b12 = np.empty(len(x1n), np.int64)
    a1 = np.empty(len(x1n))
    a2 = np.empty(len(x1n))
    _best2_in_band(
        x1n,
        d1,
        R,
        t,
        float(depth_range1[0]),
        float(depth_range1[1]),
        x2n,
        d2,
        float(band),
        float(cell),
        b12,
        a1,
        a2,
    )
    i1 = np.nonzero(b12 >= 0)[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        keep = ~(a1[i1] >= ratio * a2[i1])
    i1 = i1[keep]
    j = b12[i1]
    if mutual and len(i1):
        # the reverse search only for the image-2 features that were chosen
        uj, inv = np.unique(j, return_inverse=True)
        b21 = np.empty(len(uj), np.int64)
        c1 = np.empty(len(uj))
        c2 = np.empty(len(uj))
        Rt = np.ascontiguousarray(R.T)
        _best2_in_band(
            np.ascontiguousarray(x2n[uj]),
            np.ascontiguousarray(d2[uj]),
            Rt,
            -Rt @ t,
            float(depth_range2[0]),
            float(depth_range2[1]),
            x1n,
            d1,
            float(band),
            float(cell),
            b21,
            c1,
            c2,
        )
        ok = b21[inv] == i1
        i1, j = i1[ok], j[ok]
    else:
        # one feature of image 2 claimed twice: keep none of the claims
        u, cnt = np.unique(j, return_counts=True)
        ok = ~np.isin(j, u[cnt > 1])
        i1, j = i1[ok], j[ok]
    return np.stack([i1, j], axis=1).astype(np.int64)
