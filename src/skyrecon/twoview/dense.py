"""Dense two-view model: rectify from the pose, compute disparity, triangulate; or the write-up's
direct NCC search along epipolar lines.

The disparity matcher is reached through :func:`compute_disparity`, a small adapter over the
stereo engine's ``skyrecon.stereo.create_matcher``, so the engine can be switched without touching
the pipeline.
"""

from __future__ import annotations

import cv2
import numpy as np

from skyrecon.core.depth import PointCloud
from skyrecon.core.intrinsics import Intrinsics
from skyrecon.errors import EstimationError, InputError
from skyrecon.features.detect import resize_longer_side, to_gray_uint8
from skyrecon.geometry.epipolar_search import match_along_epipolar_lines, search_segments_from_depth
from skyrecon.geometry.rectification import (
    epipole_in_image,
    rectify,
    triangulate_disparity,
    warp_images,
)
from skyrecon.geometry.triangulation import parallax_angles_deg, triangulate
from skyrecon.stereo import available_matchers, create_matcher
from skyrecon.twoview.result import DenseResult, TwoViewGeometry
from skyrecon.twoview.settings import TwoViewSettings

__all__ = ["compute_disparity", "dense_stereo", "dense_epipolar", "dense_model"]

MAX_DISPARITY_FRACTION = 0.5  # disparity ranges wider than this share of the image width are refused
EPIPOLAR_MAX_WINDOWS = 1.0e7  # window comparisons of one epipolar search (about a second on 2 cores)


_ALIASES = {"sgbm": "opencv-sgbm", "bm": "opencv-bm"}


def _engine_matcher(name: str, min_disparity: int, num_disparities: int):
    """The stereo engine's matcher (``skyrecon.stereo.create_matcher``).

    Raises:
        InputError: a name the engine does not know.
        EstimationError: the matcher refuses the disparity range.
    """
    names = available_matchers()
    engine_name = name if name in names else _ALIASES.get(name)
    if engine_name not in names:
        raise InputError(f"unknown stereo matcher {name!r}; choose one of {', '.join(sorted(names))}")
    try:
        return create_matcher(
            engine_name, max_disparity=int(min_disparity + num_disparities), min_disparity=int(min_disparity)
        )
    except InputError as exc:  # the name is known: the range does not suit this pair
        raise EstimationError(f"the disparity matcher refused this pair: {exc}") from None


def _run_engine(matcher, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Disparity from the engine; interpolated (filled) pixels are dropped: the cloud keeps
    measurements only."""
    out = matcher.compute(left, right)
    d = np.array(getattr(out, "disparity", out), dtype=np.float32)
    filled = getattr(out, "filled", None)
    if filled is not None and np.shape(filled) == d.shape:
        d[np.asarray(filled, bool)] = np.nan
    return d


def compute_disparity(
    left: np.ndarray, right: np.ndarray, min_disparity: int, num_disparities: int, matcher: str = "sgbm"
) -> tuple[np.ndarray, str]:
    """Disparity of a rectified pair.

    Args:
        left, right: (H, W[, 3]) uint8 rectified images.
        min_disparity, num_disparities: search range ``[min, min + num)``, pixels.
        matcher: stereo-engine matcher name (``skyrecon.stereo.available_matchers()``:
            ``"skyrecon"``, ``"skyrecon-fast"``, ``"opencv-sgbm"``, ``"opencv-bm"``; ``"sgbm"`` and
            ``"bm"`` are aliases).
    Returns:
        ``(disparity, used)``: (H, W) float32 pixels with NaN where invalid
        (``x_right = x_left - d``), and the name of the matcher that ran.
    Raises:
        InputError: unknown matcher name.
        EstimationError: the matcher refused this pair (e.g. its disparity range).
    """
    m = _engine_matcher(matcher, int(min_disparity), int(num_disparities))
    try:
        d = _run_engine(m, left, right).copy()
    except InputError as exc:  # e.g. a disparity range as wide as the image
        raise EstimationError(f"the disparity matcher refused this pair: {exc}") from None
    d[~np.isfinite(d)] = np.nan
    return d, f"skyrecon.stereo:{getattr(m, 'name', None) or _ALIASES.get(matcher, matcher)}"


def _valid_mask(
    shape: tuple[int, int], intr: Intrinsics, rect_size: tuple[int, int], M: np.ndarray
) -> np.ndarray:
    """(H, W) bool: rectified pixels whose source lies inside the source image."""
    mx, my = cv2.initUndistortRectifyMap(intr.K, intr.dist, M, np.eye(3), rect_size, cv2.CV_32FC1)
    return (mx >= 0) & (my >= 0) & (mx <= intr.width - 1) & (my <= intr.height - 1)


def dense_stereo(
    image1: np.ndarray,
    image2: np.ndarray,
    intr1: Intrinsics,
    intr2: Intrinsics,
    geo: TwoViewGeometry,
    x1: np.ndarray,
    x2: np.ndarray,
    settings: TwoViewSettings,
) -> DenseResult:
    """Rectify, match, triangulate (see module doc). x1, x2: (K, 2) inlier pixels (full resolution).

    Raises:
        EstimationError: the motion is along the optical axis (epipole inside the image) or
            rectification failed.
    """
    assert geo.R is not None and geo.t is not None
    if settings.rectification != "uncalibrated" and epipole_in_image(geo.R, geo.t, intr1, intr2, margin=0.25):
        raise EstimationError(
            "the camera moved mostly along its viewing direction (the epipole is in or near the image), "
            "so planar rectification is impossible"
        )
    scale = min(1.0, settings.dense_max_image_size / max(intr1.width, intr1.height))
    rect = rectify(settings.rectification, intr1, intr2, geo.R, geo.t, geo.F, x1, x2, scale)  # type: ignore[arg-type]
    left, right = warp_images(image1, image2, intr1, intr2, rect)
    lo = rect.min_disparity if rect.min_disparity is not None else 0
    num = rect.num_disparities if rect.num_disparities is not None else 128
    if num > MAX_DISPARITY_FRACTION * rect.size[0]:
        raise EstimationError(
            f"the disparity range of the rectified pair ({num} px for a {rect.size[0]} px wide image) is too "
            "wide for dense matching (strong depth variation or a nearly forward motion)"
        )
    disp, used = compute_disparity(left, right, lo, num, settings.stereo_matcher)
    il, ir = (intr2, intr1) if rect.swapped else (intr1, intr2)
    valid = _valid_mask(disp.shape, il, rect.size, rect.M_left)
    disp[~valid] = np.nan
    # the matched right pixel must come from inside the right image too
    vr = _valid_mask(disp.shape, ir, rect.size, rect.M_right)
    H, W = disp.shape
    xs = np.arange(W)[None, :] - np.nan_to_num(disp, nan=0.0)
    xi = np.clip(np.round(xs).astype(np.int64), 0, W - 1)
    ok_r = vr[np.arange(H)[:, None], xi] & (xs >= 0) & (xs <= W - 1)
    disp[~ok_r] = np.nan
    s = 1.0 if settings.baseline_m is None else settings.baseline_m
    X, pix = triangulate_disparity(disp, rect, geo.R, geo.t * s, settings.dense_step)
    cols = (
        left[pix[:, 1], pix[:, 0]]
        if left.ndim == 3
        else np.repeat(left[pix[:, 1], pix[:, 0], None], 3, axis=1)
    )
    keep = np.all(np.isfinite(X), axis=1) & (X[:, 2] > 0)
    with np.errstate(invalid="ignore"):
        keep &= parallax_angles_deg(X, geo.R, geo.t * s) > 0.05
    cloud = PointCloud(X[keep].astype(np.float32), cols[keep])
    return DenseResult("stereo", cloud, rect, left, right, disp, used)


def _working_to_full(q: np.ndarray, s: float) -> np.ndarray:
    """Working-resolution pixels (N, 2) -> full-resolution pixels for resize factor s."""
    return (q + 0.5) / s - 0.5


def dense_epipolar(
    image1: np.ndarray,
    image2: np.ndarray,
    intr1: Intrinsics,
    intr2: Intrinsics,
    geo: TwoViewGeometry,
    x1: np.ndarray,
    x2: np.ndarray,
    settings: TwoViewSettings,
) -> DenseResult:
    """The write-up's dense method: NCC windows searched along epipolar segments.

    A grid of pixels of image 1 (``epipolar_step`` working pixels apart, coarser when the total
    search would exceed ``EPIPOLAR_MAX_WINDOWS`` window comparisons) is searched in image 2
    along the segment of its epipolar line between the near and far depths of the sparse
    inliers (x1, x2: (K, 2) full-resolution pixels); unambiguous matches with NCC above
    ``epipolar_min_ncc`` are triangulated optimally.
    """
    R, t = geo.R, geo.t
    assert R is not None and t is not None
    g1, s1x, _ = resize_longer_side(to_gray_uint8(image1), settings.features.max_image_size)
    g2, s2x, _ = resize_longer_side(to_gray_uint8(image2), settings.features.max_image_size)
    w1 = intr1.scaled(s1x) if s1x != 1.0 else intr1
    w2 = intr2.scaled(s2x) if s2x != 1.0 else intr2
    X = triangulate(R, t, intr1.normalized(x1), intr2.normalized(x2), "midpoint")
    z = X[:, 2][np.isfinite(X[:, 2]) & (X[:, 2] > 0)]
    if len(z) < 5:
        raise EstimationError("too few triangulated inliers to bound the depth of the epipolar search")
    near, far = np.percentile(z, 2) * 0.8, np.percentile(z, 98) * 1.25
    half = settings.epipolar_window // 2 + 1
    st = settings.epipolar_step

    def grid(step: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        vv, uu = np.mgrid[half : g1.shape[0] - half : step, half : g1.shape[1] - half : step]
        q = np.stack([uu.ravel(), vv.ravel()], 1).astype(np.float64)
        sg = search_segments_from_depth(q, w1, w2, R, t, (near, far))
        return q, sg, np.all(np.isfinite(sg), axis=1)

    p1, seg, ok = grid(st)
    # bound the work (window evaluations along all segments): coarsen the grid if needed
    work = float(np.sum(np.hypot(seg[ok, 2] - seg[ok, 0], seg[ok, 3] - seg[ok, 1]) + 1.0))
    if work > EPIPOLAR_MAX_WINDOWS:
        st = int(np.ceil(st * np.sqrt(work / EPIPOLAR_MAX_WINDOWS)))
        p1, seg, ok = grid(st)
    res = match_along_epipolar_lines(g1, g2, p1[ok], seg[ok], settings.epipolar_window, "ncc")
    good = np.isfinite(res.scores) & (res.scores >= settings.epipolar_min_ncc)
    good &= ~(np.nan_to_num(res.second_scores, nan=-1.0) > res.scores - 0.05)
    q1 = p1[ok][good]
    q2 = res.points2[good]
    s = 1.0 if settings.baseline_m is None else settings.baseline_m
    P = triangulate(R, t * s, w1.normalized(q1), w2.normalized(q2), "optimal")
    keep = np.all(np.isfinite(P), axis=1) & (P[:, 2] > 0)
    img = np.asarray(image1)
    ij = np.clip(
        np.round(_working_to_full(q1[keep], s1x)).astype(np.int64), 0, [intr1.width - 1, intr1.height - 1]
    )
    cols = img[ij[:, 1], ij[:, 0]] if img.ndim == 3 else np.repeat(img[ij[:, 1], ij[:, 0], None], 3, axis=1)
    return DenseResult(
        "epipolar", PointCloud(P[keep].astype(np.float32), cols[..., :3]), matcher="ncc-epipolar"
    )


def dense_model(
    image1: np.ndarray,
    image2: np.ndarray,
    intr1: Intrinsics,
    intr2: Intrinsics,
    geo: TwoViewGeometry,
    x1: np.ndarray,
    x2: np.ndarray,
    settings: TwoViewSettings,
) -> DenseResult:
    """Dense model of a pair with a full pose (dispatch on ``settings.dense_method``).

    Args:
        image1, image2: full-resolution images matching intr1, intr2.
        geo: geometry with a pose.
        x1, x2: (K, 2) full-resolution pixels of the pose inliers (depth range, disparity range).
    Returns:
        DenseResult; with ``settings.dense_fallback`` a stereo failure (forward motion, too wide
        a disparity range) falls back to the epipolar search and says so in ``warnings``.
    Raises:
        InputError: the geometry has no pose.
        EstimationError: the dense method cannot run on this geometry (see messages).
    """
    if not geo.has_pose:
        raise InputError("a dense model needs a relative pose (R and t)")
    if settings.dense_method == "epipolar":
        return dense_epipolar(image1, image2, intr1, intr2, geo, x1, x2, settings)
    try:
        return dense_stereo(image1, image2, intr1, intr2, geo, x1, x2, settings)
    except EstimationError as exc:
        if not settings.dense_fallback:
            raise
        # rectification impossible (forward motion, huge disparity range): search along the
        # epipolar lines directly instead
        try:
            out = dense_epipolar(image1, image2, intr1, intr2, geo, x1, x2, settings)
        except EstimationError as exc2:
            raise EstimationError(f"{exc}; the epipolar search failed too: {exc2}") from None
        out.warnings.append(f"dense model from the epipolar window search instead of stereo: {exc}")
        return out
