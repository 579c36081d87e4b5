"""Plane-supported filling: disparity for unmeasured segments that measured edges bound as a plane.

A stereo matcher measures nothing inside a plain (textureless) wall or road: only the edges of
the region have texture to match. In a rectified pair the disparity of a plane is an affine
function of the pixel, ``d(u, v) = a u + b v + c``, so where the measured pixels all around an
unmeasured region lie on one such plane, the region is very likely that plane (a plain face
whose edges, corners and windows were measured). :func:`plane_supported_fill` accepts exactly
those regions:

1. the unmeasured pixels split into 4-connected segments (measured pixels separate them);
2. per segment, a plane is fitted by least squares to the *trusted* measured pixels bordering it
   (measured, and not at a depth edge: their measured 3x3 neighbours span at most
   ``max_step_px``), then refitted twice on the inliers of a narrowing band;
3. the segment takes the plane's disparity only when enough pixels support the plane, most of
   them are inliers, they are spread in two directions and they lie on all four sides of it.

An occluded strip beside a foreground object (its border is part foreground, part background:
not one plane), the sky above a roof line (bounded on one side only) or a region bounded by a
single edge (the plane is not fixed) are refused. The matcher's own fill (background-favouring,
along rows) is not used: on a slanted plane it is wrong, and the plane is right.

Frames and units: disparity (H, W) float32 pixels of the left image (``x_right = x_left - d``),
NaN invalid; masks (H, W) bool; pixel (u, v) = (column, row).
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from skyrecon.errors import InputError


def _trusted(disparity: np.ndarray, measured: np.ndarray, max_step: np.float32) -> np.ndarray:
    """(H, W) bool: measured pixels whose measured 3x3 neighbours span <= max_step pixels
    (``disparity`` float32, finite where ``measured``; a min and a max filter over the measured
    values, the image's outside neutral)."""
    kernel = np.ones((3, 3), np.uint8)
    lo = cv2.erode(np.where(measured, disparity, np.float32(np.inf)), kernel)
    hi = cv2.dilate(np.where(measured, disparity, np.float32(-np.inf)), kernel)
    with np.errstate(over="ignore", invalid="ignore"):  # unmeasured pixels alone: not read
        return measured & (hi - lo <= max_step)


def _keep_in_blobs_of(pixels: np.ndarray, mask: np.ndarray, min_area_px: int) -> None:
    """Clear, in place, the ``pixels`` ((H, W) bool, contiguous, within ``mask``) that lie in
    8-connected blobs of ``mask`` of fewer than ``min_area_px`` pixels."""
    _, labels, stats, _ = cv2.connectedComponentsWithStats(
        np.ascontiguousarray(mask).view(np.uint8), connectivity=8, ltype=cv2.CV_32S
    )
    small = stats[:, cv2.CC_STAT_AREA] < min_area_px
    flat = pixels.reshape(-1)
    idx = np.flatnonzero(flat)
    flat[idx[small[labels.reshape(-1)[idx]]]] = False


@njit(cache=True, nogil=True)
def _border_pairs(disparity, trusted, labels, radius):  # pragma: no cover - compiled
    """The (pixel, segment) pairs: each trusted pixel with the segments (at most 4) within
    ``radius`` pixels of it; returns (u, v, d, label) arrays of the pairs."""
    H, W = disparity.shape
    cap = 4 * int(trusted.sum()) + 1
    pu = np.empty(cap, np.float64)
    pv = np.empty(cap, np.float64)
    pd = np.empty(cap, np.float64)
    pl = np.empty(cap, np.int32)
    npair = 0
    seen = np.zeros(4, np.int32)
    for r in range(H):
        for c in range(W):
            if not trusted[r, c]:
                continue
            m = 0
            for i in range(max(r - radius, 0), min(r + radius + 1, H)):
                for j in range(max(c - radius, 0), min(c + radius + 1, W)):
                    lab = labels[i, j]
                    if lab <= 0 or m == 4:
                        continue
                    dup = False
                    for q in range(m):
                        if seen[q] == lab:
                            dup = True
                    if not dup:
                        seen[m] = lab
                        m += 1
            for q in range(m):
                pu[npair] = c
                pv[npair] = r
                pd[npair] = disparity[r, c]
                pl[npair] = seen[q]
                npair += 1
    return pu[:npair], pv[:npair], pd[:npair], pl[:npair]


@njit(cache=True, nogil=True)
def _solve_plane(S, Bv, lab, min_spread, span_u, span_v, max_slope, coef):  # pragma: no cover - compiled
    """Least-squares plane of segment ``lab`` from its sums into ``coef[lab]``; False when its
    support is not spread in two directions (smallest std of (u, v) along any direction below
    ``min_spread`` or below the smaller of ``span_u`` and ``span_v``: one edge, even a diagonal
    one, does not fix a plane) or
    does not span the segment (std of u below ``span_u``, of v below ``span_v``, pixels), or
    when the plane's disparity changes along rows by more than ``max_slope`` pixels per pixel."""
    k = S[lab, 5]
    mu = S[lab, 3] / k
    mv = S[lab, 4] / k
    cuu = S[lab, 0] / k - mu * mu
    cuv = S[lab, 1] / k - mu * mv
    cvv = S[lab, 2] / k - mv * mv
    half = 0.5 * (cuu + cvv)
    lam = half - np.sqrt(max(half * half - (cuu * cvv - cuv * cuv), 0.0))
    spread = max(min_spread, min(span_u, span_v))
    if lam < spread * spread or cuu < span_u * span_u or cvv < span_v * span_v:
        return False
    A = np.empty((3, 3))
    A[0, 0] = S[lab, 0]
    A[0, 1] = S[lab, 1]
    A[0, 2] = S[lab, 3]
    A[1, 0] = S[lab, 1]
    A[1, 1] = S[lab, 2]
    A[1, 2] = S[lab, 4]
    A[2, 0] = S[lab, 3]
    A[2, 1] = S[lab, 4]
    A[2, 2] = k
    coef[lab] = np.linalg.solve(A, Bv[lab])
    return abs(coef[lab, 0]) <= max_slope


@njit(cache=True, nogil=True)
def _ransac_planes(
    pu, pv, pd, pl, n, tolerance, tolerance_rel, min_support, trials, max_eval
):  # pragma: no cover
    """Per segment: the plane through 3 of its border pairs that most others agree with
    (``trials`` deterministic samples, each scored on at most ``max_eval`` pairs); (n, 3)
    coefficients and (n,) found."""
    order = np.argsort(pl, kind="mergesort")
    coef = np.zeros((n, 3))
    found = np.zeros(n, np.bool_)
    npair = pl.shape[0]
    start = 0
    state = np.uint64(88172645463325252)
    while start < npair:
        lab = pl[order[start]]
        stop = start
        while stop < npair and pl[order[stop]] == lab:
            stop += 1
        m = stop - start
        if m >= min_support:
            step = max(1, m // max_eval)
            best = -1
            for _ in range(trials):
                idx = np.empty(3, np.int64)
                for q in range(3):  # xorshift64: deterministic samples
                    state ^= state << np.uint64(13)
                    state ^= state >> np.uint64(7)
                    state ^= state << np.uint64(17)
                    idx[q] = order[start + int(state % np.uint64(m))]
                u0, v0, d0 = pu[idx[0]], pv[idx[0]], pd[idx[0]]
                u1, v1, d1 = pu[idx[1]] - u0, pv[idx[1]] - v0, pd[idx[1]] - d0
                u2, v2, d2 = pu[idx[2]] - u0, pv[idx[2]] - v0, pd[idx[2]] - d0
                det = u1 * v2 - u2 * v1
                if abs(det) < 25.0:  # (nearly) collinear, or too close together
                    continue
                a = (d1 * v2 - d2 * v1) / det
                b = (u1 * d2 - u2 * d1) / det
                c = d0 - a * u0 - b * v0
                score = 0
                for k in range(start, stop, step):
                    j = order[k]
                    if abs(a * pu[j] + b * pv[j] + c - pd[j]) <= tolerance + tolerance_rel * abs(pd[j]):
                        score += 1
                if score > best:
                    best = score
                    coef[lab, 0] = a
                    coef[lab, 1] = b
                    coef[lab, 2] = c
                    found[lab] = True
        start = stop
    return coef, found


@njit(cache=True, nogil=True)
def _segment_planes(
    pu,
    pv,
    pd,
    pl,
    n,
    cu,
    cv,
    open_sides,
    span_u,
    span_v,
    tolerance,
    tolerance_rel,
    min_support,
    min_inliers,
    min_side,
    min_spread,
    max_slope,
    n_iter,
    coef,
    ok,
):  # pragma: no cover - compiled
    """Per segment (label 1..n-1) with a first plane ``d = a u + b v + c`` in ``coef`` (``ok``):
    refit it by least squares on the border pairs within a band narrowing to ``tolerance +
    tolerance_rel * d`` (2^(n_iter - 1) times that, ..., once), and decide; returns (n, 3)
    coefficients and (n,) accepted. ``open_sides`` (n, 4) bool: the segment reaches the image
    border on that side (left, right, top, bottom), which then needs no support."""
    total = np.zeros(n)
    for k in range(pl.shape[0]):
        total[pl[k]] += 1.0
    last = n_iter - 1
    for it in range(n_iter):
        # the inlier band narrows from 2^(n_iter - 1 - it) tolerances to one, as the fit firms up
        scale = 2.0 ** (last - it)
        S = np.zeros((n, 6))  # sums of u u, u v, v v, u, v, 1
        Bv = np.zeros((n, 3))  # sums of u d, v d, d
        side = np.zeros((n, 4))  # inliers left / right / above / below the segment's centroid
        for k in range(pl.shape[0]):
            lab = pl[k]
            u = pu[k]
            v = pv[k]
            d = pd[k]
            band = scale * (tolerance + tolerance_rel * abs(d))
            if not ok[lab] or abs(coef[lab, 0] * u + coef[lab, 1] * v + coef[lab, 2] - d) > band:
                continue
            side[lab, 0 if u < cu[lab] else 1] += 1.0
            side[lab, 2 if v < cv[lab] else 3] += 1.0
            S[lab, 0] += u * u
            S[lab, 1] += u * v
            S[lab, 2] += v * v
            S[lab, 3] += u
            S[lab, 4] += v
            S[lab, 5] += 1.0
            Bv[lab, 0] += u * d
            Bv[lab, 1] += v * d
            Bv[lab, 2] += d
        for lab in range(1, n):
            if not ok[lab]:
                continue  # no fit to refine
            k = S[lab, 5]
            ok[lab] = k >= min_support and _solve_plane(
                S, Bv, lab, min_spread, span_u[lab], span_v[lab], max_slope, coef
            )
            if ok[lab] and it == last:
                bounded = True
                for q in range(4):
                    if side[lab, q] < min_side * k and not open_sides[lab, q]:
                        bounded = False
                ok[lab] = bounded and k >= min_inliers * total[lab]
    return coef, ok


@njit(cache=True, nogil=True)
def _prior_planes(
    pu,
    pv,
    pd,
    pl,
    n,
    x0,
    y0,
    w,
    h,
    cv,
    prior,
    floor,
    tolerance,
    tolerance_rel,
    min_support,
    min_inliers,
    min_below,
    coef,
    ok,
):  # pragma: no cover - compiled
    """Per segment not accepted on its own fit (``ok`` False): the ``prior`` plane ``d = a u + b v
    + c`` when at least ``min_support`` of its border pairs lie within ``tolerance +
    tolerance_rel * d`` of it, they are at least ``min_inliers`` of them all, at least
    ``min_below`` of them lie on or below the segment's centroid row ``cv`` or the middle row of
    its bounding box, whichever is higher (a ground segment is supported from below or beside:
    a plain wall whose only measured border is the far ground above its roof line is not; a
    street running out of the bottom of the image, its pavements joining it there, has its
    centroid low in the box and its kerbs beside it higher up), and the prior's
    disparity is above ``floor`` at the four corners of the segment's bounding box (``x0, y0, w,
    h``; the prior is affine, so it is above it everywhere inside): the whole segment lies on
    the side of the plane's horizon that the plane covers. Sets
    ``coef`` and ``ok`` of the segments it accepts; returns (n,) bool, those segments."""
    total = np.zeros(n)
    inl = np.zeros(n)
    low = np.zeros(n)
    a, b, c = prior[0], prior[1], prior[2]
    for k in range(pl.shape[0]):
        lab = pl[k]
        if ok[lab]:
            continue
        total[lab] += 1.0
        d = pd[k]
        if abs(a * pu[k] + b * pv[k] + c - d) <= tolerance + tolerance_rel * abs(d):
            inl[lab] += 1.0
            if pv[k] >= min(cv[lab], y0[lab] + 0.5 * (h[lab] - 1.0)):
                low[lab] += 1.0
    taken = np.zeros(n, np.bool_)
    for lab in range(1, n):
        if ok[lab] or inl[lab] < min_support or inl[lab] < min_inliers * total[lab]:
            continue
        if low[lab] < min_below * inl[lab]:
            continue
        below = True
        for cu in (x0[lab], x0[lab] + w[lab] - 1):
            for cv in (y0[lab], y0[lab] + h[lab] - 1):
                if a * cu + b * cv + c <= floor:
                    below = False
        if below:
            coef[lab, 0] = a
            coef[lab, 1] = b
            coef[lab, 2] = c
            ok[lab] = True
            taken[lab] = True
    return taken


@njit(cache=True, nogil=True)
def _photo_check(labels, ok, coef, left, right, max_diff, max_bad, min_count):  # pragma: no cover
    """Refuse (in ``ok``) the planes that do not map their segment onto the right image.

    Per row run of a segment, from each of its two ends walk outwards (at most 8 pixels) over
    pixels of the end's grey level (within 3): the plain surface reaches there, to about a
    pixel from its edge. The pixel one step back in from the farthest is looked up in the right
    image at ``u - d`` (the plane's disparity, linear interpolation): with the right plane it
    shows the same surface, with a plane off by more than about 2 pixels of disparity it shows
    what lies beyond the edge. A plane is refused when more than ``max_bad`` of its (at least
    ``min_count``) run ends differ by more than ``max_diff`` grey levels.
    """
    H, W = labels.shape
    n = ok.shape[0]
    bad = np.zeros(n)
    cnt = np.zeros(n)
    for r in range(H):
        for c in range(W):
            lab = labels[r, c]
            if lab <= 0 or not ok[lab]:
                continue
            for step in (-1, 1):
                nxt = c + step
                if 0 <= nxt < W and labels[r, nxt] == lab:
                    continue  # not an end of the run on this side
                g = left[r, c]
                far = c
                for k in range(1, 9):
                    x = c + step * k
                    if x < 0 or x >= W or abs(left[r, x] - g) > 3.0:
                        break
                    far = x
                test = far - step if far != c else c
                q = test - (coef[lab, 0] * test + coef[lab, 1] * r + coef[lab, 2])
                if q < 0.0 or q > W - 1:
                    continue
                q0 = int(q)
                t = q - q0
                q1 = min(q0 + 1, W - 1)
                val = (1.0 - t) * right[r, q0] + t * right[r, q1]
                cnt[lab] += 1.0
                if abs(val - left[r, test]) > max_diff:
                    bad[lab] += 1.0
    for lab in range(1, n):
        if ok[lab] and cnt[lab] >= min_count and bad[lab] > max_bad * cnt[lab]:
            ok[lab] = False


@njit(cache=True, nogil=True)
def _paint_planes(labels, coef, ok, taken, out, accepted, taken_px):  # pragma: no cover - compiled
    """Paint the plane of every ``ok`` segment into ``out`` and ``accepted`` (where its
    disparity is positive), and into ``taken_px`` too for the segments ``taken`` from the
    prior (``taken_px`` may be a dummy when no segment is)."""
    H, W = labels.shape
    for r in range(H):
        for c in range(W):
            lab = labels[r, c]
            if lab > 0 and ok[lab]:
                d = coef[lab, 0] * c + coef[lab, 1] * r + coef[lab, 2]
                if d > 0.0:
                    out[r, c] = d
                    accepted[r, c] = True
                    if taken[lab]:
                        taken_px[r, c] = True


def plane_supported_fill(
    disparity: np.ndarray,
    measured: np.ndarray,
    *,
    boundary: np.ndarray | None = None,
    left: np.ndarray | None = None,
    right: np.ndarray | None = None,
    tolerance_px: float = 0.3,
    tolerance_rel: float = 0.03,
    max_step_px: float = 1.0,
    radius_px: int = 2,
    seal_px: int = 1,
    min_support: int = 30,
    min_inlier_fraction: float = 0.7,
    min_side_fraction: float = 0.1,
    min_spread_px: float = 3.0,
    min_span_fraction: float = 0.15,
    max_slope: float = 0.5,
    open_borders: bool = True,
    max_guess_gap_px: float | None = None,
    prior_plane: tuple[float, float, float] | None = None,
    prior_min_support: int = 30,
    prior_min_inlier_fraction: float = 0.8,
    prior_min_disparity: float = 0.0,
    prior_tolerance_px: float | None = None,
    prior_tolerance_rel: float | None = None,
    min_support_area_px: int = 0,
    prior_guess_check: bool = True,
    prior_mask: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Disparity of unmeasured segments whose measured border is one plane.

    The unmeasured pixels split into 4-connected segments (measured pixels, including those at
    depth edges, separate them). Per segment, a plane ``d = a u + b v + c`` is fitted by least
    squares to the *trusted* measured pixels (measured, and their measured 3x3 neighbours span at
    most ``max_step_px``: not at a depth edge) within ``radius_px`` of it, then refitted on the
    inliers of a band narrowing to ``tolerance_px + tolerance_rel * d`` (4, 2, then 1 times
    that; a census window on a slanted surface measures with an error that grows with its
    disparity d). The
    segment takes the plane's disparity when: at least ``min_support`` pixels support it, at
    least ``min_inlier_fraction`` of them are inliers (a border that mixes a foreground and a
    background, as around an occluded strip, is not one plane), the inliers are spread in two
    directions (smallest standard deviation of their pixel coordinates at least
    ``min_spread_px`` and ``min_span_fraction`` of the segment's smaller side, along any
    direction: a single edge, even a diagonal one, does not fix a plane) and span the segment
    (standard deviation of their columns at least ``min_span_fraction`` of the segment's width,
    of their rows of its height: a plane is interpolated, not extrapolated far from its
    support), and
    the plane's disparity changes along rows by at most ``max_slope`` pixels per pixel (a
    surface seen by both cameras changes by less than 1; a "plane" joining a background to a
    foreground across the strip the right camera cannot see changes by about 1), and they lie
    on all four sides of the
    segment's centroid (each side at least ``min_side_fraction`` of them: a region the border
    bounds on one side only, like the sky above a roof line, is not bounded). With
    ``open_borders``, a side where the segment runs into the left, right or bottom image border
    needs no support (a near wall or the road cut by the frame); the top border never counts
    (a region open to the top of the image may be sky).

    Segments are separated by the measured pixels and the ``boundary`` pixels (image edges: a
    horizontal edge, such as the top of a wall against the sky, is textured but cannot be
    matched along rows), both thickened by ``seal_px`` on each side, so that a gap of up to
    ``2 seal_px`` pixels in an outline does not join the segments on either side of it; the
    pixels within ``seal_px`` of a separator stay unfilled.

    With ``max_guess_gap_px``, the matcher's own values inside the segment (the finite
    unmeasured values of ``disparity``: filled, or smoothed along its paths) must agree with the
    plane: a segment where more than half of them differ from it by more than
    ``max_guess_gap_px`` is refused. Two poles or a gantry at one depth "bound" the plain road
    behind them on a plane of their own, and the photometric check cannot tell a plain road
    from a plain sheet hung between them; the matcher's paths, which come in from the road
    around them, can. A plain wall's plane and the matcher's smoothed values over it differ by
    well under 1.5 px (the largest median seen on the synthetic plain cities: 1.3 px), the
    road behind a gantry by 2-7 px.

    With ``prior_plane`` ``(a, b, c)``, a plane known beforehand (the ground, from the drone's
    height and attitude: :class:`skyrecon.perception.GroundPlane`), a segment that its own border
    does not fix (bounded on one side, as a road or a field running out of the image and up to
    the horizon) takes the prior's disparity when at least ``prior_min_support`` of its trusted
    border pixels, and at least ``prior_min_inlier_fraction`` of them, agree with it (within
    ``prior_tolerance_px + prior_tolerance_rel * d``; None: the fit's band; a prior is not
    fitted to the border, so its band is the measurement's error plus the prior's own), at
    least ``min_side_fraction`` of those lie on or below the segment's centroid or the middle
    row of its bounding box, whichever is higher (support from below or beside: a plain wall
    whose only measured border is the far ground beyond its roof line is refused; a street
    running out of the bottom of the image is supported by its kerbs beside it) and the
    prior's disparity is above ``prior_min_disparity`` over the whole segment (it lies below
    the plane's horizon; for a rig with ``doffs``, ``-doffs``). The border's agreement is the
    evidence: a plain facade is bounded by its corners and roof line, which lie nearer than the
    ground behind them, and a segment with no measured border is never taken. The photometric check is applied to it as to a fitted plane, and so are the
    matcher's values (``max_guess_gap_px``) with ``prior_guess_check``. Off, a segment the prior
    takes is kept whatever the matcher's values inside: under a camera's noise they are not
    evidence on a plain street (the matcher's values there are the noise's, smoothed; on the
    noisy plain cities of ``benchmarks/mapping/stereo_map.py`` 12-55 % of the street pixels
    agreed with the ground within 1 px + 10 %), and a caller that takes such a segment only
    for hits on the ground, never for free space (:class:`skyrecon.mapping.StereoMapper`),
    risks a hit under something plain that stands on it at most.

    With ``min_support_area_px``, a measured blob (8-connected) of fewer pixels supports no plane
    (it still separates segments): a camera's noise passes the texture test here and there on a
    plain wall and matches at a random disparity, and a few such specks spread over the wall
    "span" it. Noisy plain delivery seed 19: a plain wall 5-8 m ahead filling the view, bounded
    only by a far building along one edge (the frame's left and bottom borders open), took the
    far building's plane through specks of 1-21 pixels (of the half-resolution grid) and read
    10-25 m; the map carved the wall free.

    Args:
        disparity: (H, W) float32 disparity, pixels; only the ``measured`` pixels are read
            (and, with ``max_guess_gap_px``, the others as the matcher's guesses).
        measured: (H, W) bool, True where the disparity is measured.
        boundary: optional (H, W) bool, more pixels that separate segments (e.g. textured
            pixels of the image, measured or not).
        left, right: optional (H, W) grey images of the rectified pair (0-255): then a plane
            must also map its segment onto the right image, edge to edge (a plain roof whose
            border took the disparity of the textured street beyond it is refused).
        prior_mask: optional (H, W) bool array, set in place to the accepted pixels that took
            ``prior_plane`` (False everywhere without one).
    Returns:
        ``(filled, accepted)``: (H, W) float32 disparity, pixels, equal to ``disparity`` on the
        measured pixels, the plane's disparity on the accepted ones and NaN elsewhere; (H, W)
        bool mask of the accepted (unmeasured) pixels.
    """
    d = np.ascontiguousarray(disparity, dtype=np.float32)
    m = np.ascontiguousarray(measured, dtype=np.bool_)
    if d.ndim != 2 or m.shape != d.shape or (boundary is not None and np.shape(boundary) != d.shape):
        raise InputError(f"disparity and masks must be (H, W) of one size, got {d.shape} and {m.shape}")
    m = m & np.isfinite(d)
    out = np.where(m, d, np.float32(np.nan)).astype(np.float32)
    accepted = np.zeros(d.shape, np.bool_)
    # measured (and boundary) pixels, thickened by ``seal_px`` on each side, separate the
    # segments: a gap of up to 2 seal_px pixels in an outline does not join a wall to the sky
    walls = m if boundary is None else m | np.asarray(boundary, dtype=np.bool_)
    sep: np.ndarray = np.ascontiguousarray(walls).view(np.uint8)
    if seal_px > 0:
        sep = cv2.dilate(sep, np.ones((2 * seal_px + 1, 2 * seal_px + 1), np.uint8))
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(1 - sep, connectivity=4, ltype=cv2.CV_32S)
    if n <= 1:
        return out, accepted
    trusted = _trusted(d, m, np.float32(max_step_px))
    if min_support_area_px > 1:
        _keep_in_blobs_of(trusted, m, int(min_support_area_px))
    reach = int(radius_px) + int(seal_px)
    # only trusted pixels with a segment within reach have pairs: the rest skip the window scan
    near = cv2.dilate((labels > 0).view(np.uint8), np.ones((2 * reach + 1, 2 * reach + 1), np.uint8))
    pu, pv, pd, pl = _border_pairs(d, trusted & near.view(np.bool_), labels, reach)
    H, W = d.shape
    x0, y0, w, h = (stats[:, i] for i in range(4))
    reach = int(seal_px) + 1  # the seal keeps segments a few pixels off a measured border pixel
    open_sides = np.zeros((n, 4), np.bool_)
    if open_borders:
        open_sides[:, 0] = x0 <= reach
        open_sides[:, 1] = x0 + w >= W - reach
        open_sides[:, 3] = y0 + h >= H - reach  # never the top: an open top is likely sky
    coef, ok = _ransac_planes(
        pu, pv, pd, pl, n, float(tolerance_px), float(tolerance_rel), float(min_support), 64, 256
    )
    coef, ok = _segment_planes(
        pu,
        pv,
        pd,
        pl,
        n,
        np.ascontiguousarray(centroids[:, 0]),
        np.ascontiguousarray(centroids[:, 1]),
        open_sides,
        min_span_fraction * w.astype(np.float64),
        min_span_fraction * h.astype(np.float64),
        float(tolerance_px),
        float(tolerance_rel),
        float(min_support),
        float(min_inlier_fraction),
        float(min_side_fraction),
        float(min_spread_px),
        float(max_slope),
        2,
        coef,
        ok,
    )
    from_prior = None
    if prior_plane is not None:
        from_prior = _prior_planes(
            pu,
            pv,
            pd,
            pl,
            n,
            x0.astype(np.float64),
            y0.astype(np.float64),
            w.astype(np.float64),
            h.astype(np.float64),
            np.ascontiguousarray(centroids[:, 1]),
            np.asarray(prior_plane, np.float64),
            float(prior_min_disparity),
            float(tolerance_px if prior_tolerance_px is None else prior_tolerance_px),
            float(tolerance_rel if prior_tolerance_rel is None else prior_tolerance_rel),
            float(prior_min_support),
            float(prior_min_inlier_fraction),
            float(min_side_fraction),
            coef,
            ok,
        )
    if left is not None and right is not None:
        gl = np.ascontiguousarray(left, dtype=np.float32)
        gr = np.ascontiguousarray(right, dtype=np.float32)
        if gl.shape != d.shape or gr.shape != d.shape:
            raise InputError(f"grey images must be {d.shape}, got {gl.shape} and {gr.shape}")
        _photo_check(labels, ok, coef, gl, gr, 8.0, 0.25, 10.0)
    if max_guess_gap_px is not None:
        exempt = ok & from_prior if from_prior is not None and not prior_guess_check else None
        held = ok if exempt is None else ok & ~exempt  # only these are counted and refused
        _refuse_against_guesses(d, labels, coef, held, float(max_guess_gap_px))
        ok = held if exempt is None else held | exempt
    taken = np.zeros(n, np.bool_)
    taken_px = np.zeros((1, 1), np.bool_)  # never written while nothing is taken
    if prior_mask is not None:
        if prior_mask.shape != d.shape or prior_mask.dtype != np.bool_:
            raise InputError(
                f"prior_mask must be a {d.shape} bool array, got {prior_mask.shape} {prior_mask.dtype}"
            )
        prior_mask[...] = False
        taken_px = prior_mask
        if from_prior is not None:
            taken = from_prior
    _paint_planes(labels, coef, ok, taken, out, accepted, taken_px)
    return out, accepted


def _refuse_against_guesses(
    guess: np.ndarray, labels: np.ndarray, coef: np.ndarray, ok: np.ndarray, max_gap_px: float
) -> None:
    """Refuse (in ``ok``, as :func:`_photo_check` does) the segments where more than half of the
    finite ``guess`` values (H, W) on the pixels their plane would paint (see
    :func:`_paint_planes`) differ from the plane by more than ``max_gap_px`` pixels."""
    n_all = np.zeros(len(ok), np.int64)
    n_far = np.zeros(len(ok), np.int64)
    _count_against_guesses(guess, labels, coef, ok, float(max_gap_px), n_all, n_far)
    ok &= ~(2 * n_far > n_all)


@njit(cache=True, nogil=True)
def _count_against_guesses(guess, labels, coef, ok, max_gap_px, n_all, n_far):
    """Per segment still ``ok``: its painted pixels with a finite guess (``n_all``) and those
    whose guess is more than ``max_gap_px`` from the plane (``n_far``); one pass."""
    H, W = labels.shape
    for r in range(H):
        for c in range(W):
            lab = labels[r, c]
            if lab <= 0 or not ok[lab]:
                continue
            g = guess[r, c]
            if not np.isfinite(g):
                continue
            plane = coef[lab, 0] * c + coef[lab, 1] * r + coef[lab, 2]
            if plane > 0.0:
                n_all[lab] += 1
                if abs(plane - g) > max_gap_px:
                    n_far[lab] += 1


def warm_kernels() -> None:
    """Load (or compile) every kernel :func:`plane_supported_fill` runs, on a tiny input: a
    measured ring around a plain square, with a prior plane, the grey images and the matcher's
    guesses. Loading them from Numba's cache takes about 50 ms, which a flight pays before it
    starts (:meth:`skyrecon.perception.StereoDepth.warm_up`), not in its first cycle."""
    size = 24
    disparity = np.full((size, size), 4.0, np.float32)
    measured = np.ones((size, size), np.bool_)
    measured[6:18, 6:18] = False  # the plain square, its border measured all round
    grey = np.tile(np.arange(size, dtype=np.float32) * 8.0, (size, 1))
    plane_supported_fill(
        disparity,
        measured,
        left=grey,
        right=grey,
        max_guess_gap_px=2.0,
        prior_plane=(0.0, 0.0, 4.0),
    )
