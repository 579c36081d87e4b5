"""Direct window matching along epipolar lines (the write-up's dense method), in Numba.

For a pixel of image 1, its match in image 2 lies on the epipolar line ``F x1``; with a known
pose and a depth interval it lies on a segment of that line. We slide an axis-aligned window
along the segment (bilinear sampling, unit steps), score it against the window around the pixel
of image 1 by NCC (or negated SSD), keep the best, and refine it to sub-pixel with a parabola.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numba
import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.errors import InputError
from skyrecon.geometry.epipolar import homogeneous

__all__ = [
    "EpipolarSearchResult",
    "search_segments_from_depth",
    "clip_segments",
    "match_along_epipolar_lines",
]


@dataclass
class EpipolarSearchResult:
    """Matches found along epipolar segments.

    Attributes:
        points2: (N, 2) float64 best pixel in image 2 (NaN where none).
        scores: (N,) float64 best score (NCC in [-1, 1], or -SSD per pixel); NaN where none.
        second_scores: (N,) best score at least ``window`` pixels away from the best (for a
            uniqueness test), NaN where none.
    """

    points2: np.ndarray
    scores: np.ndarray
    second_scores: np.ndarray


@numba.njit(cache=True, inline="always")
def _bilinear(img: np.ndarray, x: float, y: float) -> float:
    h, w = img.shape
    x0 = int(np.floor(x))
    y0 = int(np.floor(y))
    if x0 < 0 or y0 < 0 or x0 + 1 >= w or y0 + 1 >= h:
        return np.nan
    ax = x - x0
    ay = y - y0
    return (
        (1 - ax) * (1 - ay) * img[y0, x0]
        + ax * (1 - ay) * img[y0, x0 + 1]
        + (1 - ax) * ay * img[y0 + 1, x0]
        + ax * ay * img[y0 + 1, x0 + 1]
    )


@numba.njit(cache=True, parallel=True)
def _search(  # noqa: C901  (Numba kernel: one flat loop nest)
    img1: np.ndarray,
    img2: np.ndarray,
    p1: np.ndarray,
    seg: np.ndarray,
    half: int,
    use_ncc: bool,
    min_std: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = p1.shape[0]
    k = (2 * half + 1) * (2 * half + 1)
    out = np.full((n, 2), np.nan)
    best_s = np.full(n, np.nan)
    second_s = np.full(n, np.nan)
    for i in numba.prange(n):
        a = np.empty(k)
        b = np.empty(k)
        # reference window
        m = 0
        ok = True
        for dy in range(-half, half + 1):
            for dx in range(-half, half + 1):
                v = _bilinear(img1, p1[i, 0] + dx, p1[i, 1] + dy)
                if np.isnan(v):
                    ok = False
                a[m] = v
                m += 1
        if not ok:
            continue
        ma = a.mean()
        sa = np.sqrt(((a - ma) ** 2).mean())
        if use_ncc and sa < min_std:
            continue
        x0, y0, x1, y1 = seg[i, 0], seg[i, 1], seg[i, 2], seg[i, 3]
        length = np.hypot(x1 - x0, y1 - y0)
        steps = int(np.ceil(length)) + 1
        if steps < 2 or not np.isfinite(length):
            continue
        ux = (x1 - x0) / (steps - 1)
        uy = (y1 - y0) / (steps - 1)
        scores = np.full(steps, -np.inf)
        for s in range(steps):
            qx = x0 + s * ux
            qy = y0 + s * uy
            m = 0
            good = True
            for dy in range(-half, half + 1):
                for dx in range(-half, half + 1):
                    v = _bilinear(img2, qx + dx, qy + dy)
                    if np.isnan(v):
                        good = False
                        break
                    b[m] = v
                    m += 1
                if not good:
                    break
            if not good:
                continue
            if use_ncc:
                mb = b.mean()
                sb = np.sqrt(((b - mb) ** 2).mean())
                if sb < 1e-6:
                    continue
                scores[s] = ((a - ma) * (b - mb)).mean() / (sa * sb)
            else:
                scores[s] = -((a - b) ** 2).mean()
        j = int(np.argmax(scores))
        if not np.isfinite(scores[j]):
            continue
        # second best outside the window around the best
        sec = -np.inf
        for s in range(steps):
            if abs(s - j) > 2 * half and scores[s] > sec:
                sec = scores[s]
        off = 0.0
        if 0 < j < steps - 1 and np.isfinite(scores[j - 1]) and np.isfinite(scores[j + 1]):
            den = scores[j - 1] - 2 * scores[j] + scores[j + 1]
            if den < 0:
                off = 0.5 * (scores[j - 1] - scores[j + 1]) / den
                off = min(0.5, max(-0.5, off))
        out[i, 0] = x0 + (j + off) * ux
        out[i, 1] = y0 + (j + off) * uy
        best_s[i] = scores[j]
        second_s[i] = sec if np.isfinite(sec) else np.nan
    return out, best_s, second_s


def search_segments_from_depth(
    x1: np.ndarray,
    intr1: Intrinsics,
    intr2: Intrinsics,
    R: np.ndarray,
    t: np.ndarray,
    depth_range: tuple[float, float],
) -> np.ndarray:
    """Epipolar segments in image 2 for pixels of image 1 and a depth interval.

    Args:
        x1: (N, 2) pixels of image 1.
        intr1, intr2: cameras (distortion ignored along the segment).
        R, t: cam2_from_cam1; depths are in the units of t.
        depth_range: (near, far) depths along camera 1's optical axis, near > 0.
    Returns:
        (N, 4) float64 segment end points ``(u_near, v_near, u_far, v_far)`` in image 2.
    """
    near, far = depth_range
    if not (0 < near < far):
        raise InputError(f"the depth range must satisfy 0 < near < far, got {depth_range}")
    rays = homogeneous(intr1.normalized(x1))
    ends = []
    for z in (near, far):
        P = rays * z @ np.asarray(R).T + np.asarray(t).reshape(3)
        P[:, 2] = np.maximum(P[:, 2], 1e-6)
        ends.append(intr2.project(P))
    return clip_segments(np.concatenate(ends, axis=1), intr2.width, intr2.height)


def clip_segments(seg: np.ndarray, width: int, height: int) -> np.ndarray:
    """Clip (N, 4) segments ``(u0, v0, u1, v1)`` to the image rectangle (Liang-Barsky).

    Segments entirely outside become NaN.
    """
    seg = np.asarray(seg, np.float64).copy()
    x0, y0, x1, y1 = seg.T
    dx, dy = x1 - x0, y1 - y0
    t0 = np.zeros(len(seg))
    t1 = np.ones(len(seg))
    for p, q in ((-dx, x0), (dx, width - 1 - x0), (-dy, y0), (dy, height - 1 - y0)):
        with np.errstate(divide="ignore", invalid="ignore"):
            r = q / p
        par = p == 0
        out = par & (q < 0)
        t0 = np.where(~par & (p < 0), np.maximum(t0, r), t0)
        t1 = np.where(~par & (p > 0), np.minimum(t1, r), t1)
        t0 = np.where(out, np.inf, t0)
    bad = ~(t0 <= t1) | ~np.isfinite(seg).all(axis=1)
    res = np.stack([x0 + t0 * dx, y0 + t0 * dy, x0 + t1 * dx, y0 + t1 * dy], axis=1)
    res[bad] = np.nan
    return res


def match_along_epipolar_lines(
    image1: np.ndarray,
    image2: np.ndarray,
    x1: np.ndarray,
    segments: np.ndarray,
    window: int = 7,
    metric: Literal["ncc", "ssd"] = "ncc",
    min_std: float = 2.0,
) -> EpipolarSearchResult:
    """Best window match of each pixel of image 1 along its segment in image 2.

    Args:
        image1, image2: (H, W) grey or (H, W, 3) RGB images (converted to float grey).
        x1: (N, 2) pixels of image 1.
        segments: (N, 4) segments ``(u0, v0, u1, v1)`` in image 2 (see
            :func:`search_segments_from_depth`; a whole epipolar line clipped to the image works too).
        window: odd window side, pixels.
        metric: ``"ncc"`` (normalised cross-correlation) or ``"ssd"`` (scores are -SSD per pixel).
        min_std: skip reference windows whose grey-level standard deviation is below this (NCC).
    Returns:
        EpipolarSearchResult.
    """
    if window < 3 or window % 2 == 0:
        raise InputError(f"the matching window must be odd and >= 3, got {window}")
    if metric not in ("ncc", "ssd"):
        raise InputError(f"unknown window metric {metric!r}; use ncc or ssd")

    def grey(img: np.ndarray) -> np.ndarray:
        img = np.asarray(img)
        if img.ndim == 3:
            img = img[..., :3] @ np.array([0.299, 0.587, 0.114])
        return np.ascontiguousarray(img, dtype=np.float64)

    p1 = np.ascontiguousarray(np.asarray(x1, np.float64).reshape(-1, 2))
    seg = np.ascontiguousarray(np.asarray(segments, np.float64).reshape(-1, 4))
    if len(seg) != len(p1):
        raise InputError(f"{len(p1)} pixels but {len(seg)} search segments")
    pts, s, s2 = _search(grey(image1), grey(image2), p1, seg, window // 2, metric == "ncc", float(min_std))
    return EpipolarSearchResult(pts, s, s2)
