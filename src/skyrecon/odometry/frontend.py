"""The odometry front end: corners spread over a grid, KLT tracking with a forward-backward
check, and sparse stereo (a KLT search from the left to the right image along the same row, with
a right-to-left check) or a lookup in a given dense disparity.

Images are (H, W) uint8 grey; points are (N, 2) float32 pixels ``(u, v)`` (column, row; the
centre of the top-left pixel is (0, 0)). Disparity follows the rig: ``x_right = x_left - d``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = [
    "Pyramid",
    "build_pyramid",
    "detect_corners",
    "track_points",
    "refine_to_anchor",
    "global_shift",
    "stereo_match",
    "disparity_lookup",
    "grid_coverage",
]


@dataclass
class Pyramid:
    """An image with its KLT search parameters.

    (OpenCV's Python binding cannot take a pre-built pyramid back into ``calcOpticalFlowPyrLK``,
    so each call builds its own from ``image``.)

    Attributes:
        image: (H, W) uint8 grey image.
        max_level: pyramid levels above the base.
        win: the KLT window side, pixels.
    """

    image: np.ndarray
    max_level: int
    win: int


def build_pyramid(grey: np.ndarray, win: int, max_level: int) -> Pyramid:
    """A (H, W) uint8 grey image set up for KLT with ``win``-pixel windows and ``max_level`` levels."""
    return Pyramid(np.ascontiguousarray(grey), int(max_level), int(win))


_KLT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.01)


def detect_corners(
    grey: np.ndarray,
    existing_px: np.ndarray,
    max_features: int,
    grid: tuple[int, int] = (8, 6),
    min_distance_px: float = 8.0,
    quality: float = 0.005,
    min_strength: float = 0.0,
) -> np.ndarray:
    """New Shi-Tomasi corners spread over a grid, away from the existing features.

    Each of the ``grid`` = (columns, rows) cells gets up to ``max_features / cells`` features in
    all, counting the existing ones in it, so features stay spread when the scene is uneven.

    Args:
        grey: (H, W) uint8 image.
        existing_px: (M, 2) pixels of the features already tracked.
        max_features: the number of features wanted in all (existing + new).
        grid: cells across and down.
        min_distance_px: minimum distance between corners (and to the existing ones), pixels.
        quality: Shi-Tomasi quality level relative to the best corner in each cell.
        min_strength: corners weaker than this (OpenCV's ``cornerMinEigenVal`` over a 5-pixel
            block) are left out, whatever the best corner in their cell: the noise floor of a
            noisy camera (see :func:`skyrecon.core.image_noise.corner_noise_quantile`), where a
            plain cell's best "corner" is noise; 0 keeps every one.
    Returns:
        (K, 2) float32 pixels of the new corners (K may be 0).
    """
    H, W = grey.shape
    gx, gy = grid
    per_cell = max(1, int(np.ceil(max_features / (gx * gy))))
    counts = np.zeros((gy, gx), np.int64)
    if len(existing_px):
        cx = np.clip((existing_px[:, 0] * gx / W).astype(np.int64), 0, gx - 1)
        cy = np.clip((existing_px[:, 1] * gy / H).astype(np.int64), 0, gy - 1)
        np.add.at(counts, (cy, cx), 1)
    mask = np.full((H, W), 255, np.uint8)
    r = max(1, int(round(min_distance_px)))
    for u, v in np.asarray(existing_px, np.float64):
        cv2.circle(mask, (int(round(u)), int(round(v))), r, 0, -1)
    out = []
    border = 4
    for j in range(gy):
        y0, y1 = j * H // gy, (j + 1) * H // gy
        for i in range(gx):
            want = per_cell - counts[j, i]
            if want <= 0:
                continue
            x0, x1 = i * W // gx, (i + 1) * W // gx
            ya, yb = max(y0, border), min(y1, H - border)
            xa, xb = max(x0, border), min(x1, W - border)
            if yb - ya < 3 or xb - xa < 3:
                continue
            cell_mask = np.ascontiguousarray(mask[ya:yb, xa:xb])
            if min_strength > 0:
                pts, strength = cv2.goodFeaturesToTrackWithQuality(
                    grey[ya:yb, xa:xb], int(want), quality, min_distance_px, cell_mask, blockSize=5
                )
                if pts is not None:
                    pts = pts[strength.reshape(-1) >= min_strength]
            else:
                pts = cv2.goodFeaturesToTrack(
                    grey[ya:yb, xa:xb], int(want), quality, min_distance_px, mask=cell_mask, blockSize=5
                )
            if pts is not None and len(pts):
                out.append(pts.reshape(-1, 2) + np.array([xa, ya], np.float32))
    if not out:
        return np.zeros((0, 2), np.float32)
    return np.concatenate(out).astype(np.float32)


def track_points(
    prev: Pyramid,
    cur: Pyramid,
    points_px: np.ndarray,
    guess_px: np.ndarray | None = None,
    fb_threshold_px: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """KLT optical flow from ``prev`` to ``cur`` with a forward-backward check.

    Args:
        prev, cur: pyramids of the two images (same window and levels).
        points_px: (N, 2) float32 pixels in ``prev``.
        guess_px: optional (N, 2) predicted pixels in ``cur`` (e.g. from a motion prior).
        fb_threshold_px: a track is kept when tracking it back lands within this many pixels
            of where it started.
    Returns:
        ``(points (N, 2) float32 in cur, ok (N,) bool)``.
    """
    n = len(points_px)
    if n == 0:
        return np.zeros((0, 2), np.float32), np.zeros(0, bool)
    p0 = np.ascontiguousarray(points_px, np.float32).reshape(-1, 1, 2)
    win = (cur.win, cur.win)
    level = min(prev.max_level, cur.max_level)
    guess = p0 if guess_px is None else np.ascontiguousarray(guess_px, np.float32).reshape(-1, 1, 2)
    p1, st, _ = cv2.calcOpticalFlowPyrLK(
        prev.image,
        cur.image,
        p0,
        guess.copy(),
        winSize=win,
        maxLevel=level,
        criteria=_KLT_CRITERIA,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    p0b, st_b, _ = cv2.calcOpticalFlowPyrLK(
        cur.image,
        prev.image,
        p1,
        p0.copy(),
        winSize=win,
        maxLevel=level,
        criteria=_KLT_CRITERIA,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    p1 = p1.reshape(-1, 2)
    fb = np.linalg.norm(p0b.reshape(-1, 2) - p0.reshape(-1, 2), axis=1)
    H, W = cur.image.shape
    inside = (p1[:, 0] >= 0) & (p1[:, 0] <= W - 1) & (p1[:, 1] >= 0) & (p1[:, 1] <= H - 1)
    ok = (st.reshape(-1) == 1) & (st_b.reshape(-1) == 1) & (fb < fb_threshold_px) & inside
    return p1.astype(np.float32), ok


def refine_to_anchor(
    anchor: np.ndarray,
    cur: np.ndarray,
    anchor_px: np.ndarray,
    guess_px: np.ndarray,
    win: int,
    max_move_px: float = 1.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Re-align tracked points on their keyframe (anchor) patch, so a track does not drift.

    Chained frame-to-frame KLT accumulates a sub-pixel error at every step; one KLT from the
    anchor image (where the feature was last anchored, e.g. its keyframe) straight to the current
    image, started at the chained position on the finest level, removes what accumulated since
    the anchor.

    Args:
        anchor, cur: (H, W) uint8 grey anchor and current images.
        anchor_px: (N, 2) pixels of the features in ``anchor``.
        guess_px: (N, 2) chained positions in ``cur``.
        win: KLT window side, pixels.
        max_move_px: a refinement moving a point farther than this from ``guess_px`` is refused.
    Returns:
        ``(points (N, 2) float32, refined (N,) bool)``: the refined position where ``refined``,
        else ``guess_px``.
    """
    n = len(anchor_px)
    g = np.ascontiguousarray(guess_px, np.float32).reshape(-1, 2)
    if n == 0:
        return g.copy(), np.zeros(0, bool)
    p1, st, _ = cv2.calcOpticalFlowPyrLK(
        anchor,
        cur,
        np.ascontiguousarray(anchor_px, np.float32).reshape(-1, 1, 2),
        g.reshape(-1, 1, 2).copy(),
        winSize=(win, win),
        maxLevel=0,
        criteria=_KLT_CRITERIA,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    p1 = p1.reshape(-1, 2)
    good = (
        (st.reshape(-1) == 1) & (np.linalg.norm(p1 - g, axis=1) < max_move_px) & np.isfinite(p1).all(axis=1)
    )
    out = g.copy()
    out[good] = p1[good]
    return out, good


def global_shift(prev: np.ndarray, cur: np.ndarray, levels: int = 2) -> tuple[float, float, float]:
    """The dominant image translation from ``prev`` to ``cur`` by phase correlation on a
    ``2**levels`` times smaller copy: a coarse guess for a sudden camera rotation.

    Returns:
        ``(dx, dy, response)``: the shift in full-resolution pixels and the correlation peak's
        strength (0 to 1; low when there is no single dominant shift).
    """
    a, b = prev, cur
    for _ in range(levels):
        a, b = cv2.pyrDown(a), cv2.pyrDown(b)
    a32, b32 = a.astype(np.float32), b.astype(np.float32)
    win = cv2.createHanningWindow((a32.shape[1], a32.shape[0]), cv2.CV_32F)
    (dx, dy), response = cv2.phaseCorrelate(a32 - a32.mean(), b32 - b32.mean(), win)
    k = float(2**levels)
    return float(dx) * k, float(dy) * k, float(response)


def stereo_match(
    left: Pyramid,
    right: Pyramid,
    points_px: np.ndarray,
    guess_disparity_px: np.ndarray | None = None,
    max_row_error_px: float = 0.7,
    lr_threshold_px: float = 0.5,
    min_disparity_px: float = 0.0,
    max_disparity_px: float = 256.0,
) -> np.ndarray:
    """Sparse stereo for a rectified pair: the disparity of each left feature, NaN where unmatched.

    The right-image position is found by KLT starting on the same row at ``x - guess``; a match
    must stay on its row (``max_row_error_px``), track back to the left feature within
    ``lr_threshold_px`` (left-right check) and fall in ``[min_disparity_px, max_disparity_px]``.

    Args:
        left, right: pyramids of the rectified left and right images.
        points_px: (N, 2) float32 left pixels.
        guess_disparity_px: optional (N,) initial disparities (NaN: none), pixels.
    Returns:
        (N,) float64 disparities ``x_left - x_right``, pixels; NaN where no reliable match.
    """
    n = len(points_px)
    if n == 0:
        return np.zeros(0)
    p0 = np.ascontiguousarray(points_px, np.float32).reshape(-1, 2)
    g = np.full(n, 2.0) if guess_disparity_px is None else np.asarray(guess_disparity_px, np.float64).copy()
    g[~np.isfinite(g)] = 2.0
    guess = p0.copy()
    guess[:, 0] -= g.astype(np.float32)
    ok_r = np.zeros(n, bool)
    p1, st, _ = cv2.calcOpticalFlowPyrLK(
        left.image,
        right.image,
        p0.reshape(-1, 1, 2),
        guess.reshape(-1, 1, 2),
        winSize=(left.win, left.win),
        maxLevel=min(left.max_level, right.max_level, 2),
        criteria=_KLT_CRITERIA,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    p1 = p1.reshape(-1, 2)
    ok_r = (st.reshape(-1) == 1) & (np.abs(p1[:, 1] - p0[:, 1]) < max_row_error_px)
    pb, st_b, _ = cv2.calcOpticalFlowPyrLK(
        right.image,
        left.image,
        p1.reshape(-1, 1, 2),
        p0.reshape(-1, 1, 2).copy(),
        winSize=(left.win, left.win),
        maxLevel=min(left.max_level, right.max_level, 2),
        criteria=_KLT_CRITERIA,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    back = np.linalg.norm(pb.reshape(-1, 2) - p0, axis=1)
    d = (p0[:, 0] - p1[:, 0]).astype(np.float64)
    ok = (
        ok_r
        & (st_b.reshape(-1) == 1)
        & (back < lr_threshold_px)
        & (d >= min_disparity_px)
        & (d <= max_disparity_px)
    )
    d[~ok] = np.nan
    return d


def disparity_lookup(
    disparity_px: np.ndarray, points_px: np.ndarray, max_spread_px: float = 0.5
) -> np.ndarray:
    """Disparity at sub-pixel feature positions from a dense (H, W) left disparity map.

    Bilinear interpolation over the 2x2 neighbourhood; NaN where any of the four is NaN or where
    they disagree by more than ``max_spread_px`` plus 10 % (a depth edge, where corners often sit
    and where interpolating would invent a depth between the two surfaces).

    Args:
        disparity_px: (H, W) float32 disparity, NaN invalid.
        points_px: (N, 2) pixels.
    Returns:
        (N,) float64 disparities, NaN where unusable.
    """
    H, W = disparity_px.shape
    p = np.asarray(points_px, np.float64).reshape(-1, 2)
    if len(p) == 0:
        return np.zeros(0)
    x0 = np.clip(np.floor(p[:, 0]).astype(np.int64), 0, W - 2)
    y0 = np.clip(np.floor(p[:, 1]).astype(np.int64), 0, H - 2)
    fx = np.clip(p[:, 0] - x0, 0.0, 1.0)
    fy = np.clip(p[:, 1] - y0, 0.0, 1.0)
    d00 = disparity_px[y0, x0].astype(np.float64)
    d01 = disparity_px[y0, x0 + 1].astype(np.float64)
    d10 = disparity_px[y0 + 1, x0].astype(np.float64)
    d11 = disparity_px[y0 + 1, x0 + 1].astype(np.float64)
    stack = np.stack([d00, d01, d10, d11])
    with np.errstate(invalid="ignore"):
        spread = stack.max(axis=0) - stack.min(axis=0)
        d = (d00 * (1 - fx) + d01 * fx) * (1 - fy) + (d10 * (1 - fx) + d11 * fx) * fy
        bad = ~np.isfinite(d) | (spread > max_spread_px + 0.1 * np.abs(d))
    d[bad] = np.nan
    return d


def grid_coverage(points_px: np.ndarray, width: int, height: int, grid: tuple[int, int] = (4, 4)) -> float:
    """Fraction of the ``grid`` = (columns, rows) cells of the image holding at least one point."""
    gx, gy = grid
    if len(points_px) == 0:
        return 0.0
    p = np.asarray(points_px, np.float64)
    cx = np.clip((p[:, 0] * gx / width).astype(np.int64), 0, gx - 1)
    cy = np.clip((p[:, 1] * gy / height).astype(np.int64), 0, gy - 1)
    return len(np.unique(cy * gx + cx)) / (gx * gy)
