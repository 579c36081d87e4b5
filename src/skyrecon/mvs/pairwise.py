"""Two-view depth for a reference view: rectify with a neighbour, match, map back to the reference.

The pair is rectified with the stereo engine (:func:`skyrecon.stereo.rectify_rig`, principal
points free so that convergent ring cameras keep the object in view), matched by a registered
stereo matcher, and the rectified depth is carried back to the *original* reference camera:
the rectified camera shares the optical centre but is rotated (``left_rect_from_left``), so a
reference pixel ``p`` looks along ``r = R_rect K^-1 p`` in the rectified frame, meets the
rectified image at ``K_rect r / r_z`` and has reference depth ``Z_rect / r_z``.

When the neighbour is on the reference camera's left, the pair is rectified the other way
round (neighbour = left) and both rectified images are mirrored, so the matcher still returns
the reference view's disparity. When the baseline is mostly vertical in the reference image
(e.g. a camera mounted sideways), both images and cameras are turned by 90 degrees first and
the depth is turned back.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from skyrecon.core import Intrinsics, Rigid3, StereoRig
from skyrecon.errors import InputError
from skyrecon.mvs.frames import WorkingView
from skyrecon.stereo import create_matcher, rectify_rig

__all__ = ["PairwiseResult", "pairwise_depth"]


@dataclass
class PairwiseResult:
    """Depth of a reference view from one neighbour.

    Attributes:
        depth: (H, W) float32 metres along the reference optical axis (reference working
            resolution), NaN where there is no measured disparity.
        swapped: True when the neighbour was on the left (rectified as the left camera).
        disparity_range: (min, max) disparity searched in the rectified pair, pixels.
        timings_ms: per stage.
        rotated: True when the baseline was mostly vertical in the reference image and the
            pair was matched on images turned by 90 degrees.
    """

    depth: np.ndarray
    swapped: bool
    disparity_range: tuple[int, int]
    timings_ms: dict[str, float] = field(default_factory=dict)
    rotated: bool = False


_ROT_CW = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # rotated cam <- cam


def _rotated_clockwise(view: WorkingView) -> WorkingView:
    """The view with its image turned 90 degrees clockwise (and its camera with it).

    Pixel ``(u, v)`` moves to ``(H - 1 - v, u)``; camera axes ``x' = -y, y' = x, z' = z``.
    """
    k = view.intrinsics
    intr = Intrinsics(k.fy, k.fx, k.height - 1 - k.cy, k.cx, k.height, k.width)
    pose = Rigid3(_ROT_CW @ view.cam_from_world.R, _ROT_CW @ view.cam_from_world.t, "cam", "world")
    rot = lambda a: np.ascontiguousarray(np.rot90(a, -1))  # noqa: E731
    return replace(
        view,
        intrinsics=intr,
        cam_from_world=pose,
        rgb=rot(view.rgb) if view.rgb.size else view.rgb,
        grey=rot(view.grey),
        valid=rot(view.valid),
    )


def _grey8(view: WorkingView) -> np.ndarray:
    return np.clip(view.grey + 0.5, 0, 255).astype(np.uint8)


@dataclass
class _RectifiedPair:
    """A (left, right) pair rectified for matching; the reference is the right camera when swapped.

    Attributes:
        left, right: rectified images (H, W) uint8 grey or (H, W, 3) uint8 RGB.
        rig: the rectified rig (metres, pixels).
        ref_rect: the reference's rectified camera (``rig.right`` when swapped, else ``rig.left``).
        ref_rect_from_ref: (3, 3) rotation from the reference camera to its rectified frame.
        disparity_range: (min, max) disparity to search, pixels, within the image width.
    """

    left: np.ndarray
    right: np.ndarray
    rig: StereoRig
    ref_rect: Intrinsics
    ref_rect_from_ref: np.ndarray
    disparity_range: tuple[int, int]


def _disparity_bounds(
    rig: StereoRig,
    left_from_world: Rigid3,
    left_rect_from_left: np.ndarray,
    depth_range: tuple[float, float],
    points_world: np.ndarray | None,
) -> tuple[int, int]:
    """(min, max) rectified disparity, pixels: from the sparse points both views see (1st-99th
    percentile plus a margin) when at least 20 lie in front, else from ``depth_range`` widened
    by 25 % (the rectified frames are rotated by up to half the convergence)."""
    near, far = depth_range
    f, B, doffs = rig.left.fx, rig.baseline_m, rig.doffs_px
    z_rect = None
    if points_world is not None and len(points_world) >= 20:
        Xl = left_from_world.apply(np.asarray(points_world, np.float64))
        z_rect = (Xl @ left_rect_from_left.T)[:, 2]
        z_rect = z_rect[z_rect > 0]
    if z_rect is not None and len(z_rect) >= 20:
        # disparities of the sparse points both views see, with a margin
        dd = f * B / z_rect - doffs
        lo, hi = np.percentile(dd, [1.0, 99.0])
        pad = 0.15 * (hi - lo) + 8.0
        d_lo, d_hi = lo - pad, hi + pad
    else:
        d_lo = f * B / (far * 1.25) - doffs
        d_hi = f * B / (near / 1.25) - doffs
    W = rig.left.width
    dmin = int(np.floor(d_lo))
    dmax = int(np.ceil(d_hi)) + 1
    if dmax - dmin >= W - 16:
        dmin = max(dmin, dmax - (W - 32))
    return dmin, dmax


def _rectify_pair(
    ref: WorkingView,
    src: WorkingView,
    swapped: bool,
    depth_range: tuple[float, float],
    alpha: float,
    points_world: np.ndarray | None,
    use_colour: bool,
) -> _RectifiedPair:
    """Rectify (ref, src), or (src, ref) when swapped, so that the searched disparities fit the width.

    Raises:
        InputError: the disparity range does not fit the rectified image width.
    """
    left, right = (src, ref) if swapped else (ref, src)
    right_from_left = right.cam_from_world @ left.cam_from_world.inverse()
    rig_in = StereoRig(left.intrinsics, right.intrinsics, right_from_left)
    for zero_disparity in (False, True):
        # free principal points keep convergent views centred; OpenCV sometimes moves them far
        # apart (large roll differences): then the common principal point is tried
        rect = rectify_rig(rig_in, alpha=alpha, zero_disparity=zero_disparity)
        R_left = rect.left_rect_from_left.R
        dmin, dmax = _disparity_bounds(rect.rig, left.cam_from_world, R_left, depth_range, points_world)
        W = rect.rig.left.width
        if dmax > -(W - 16) and dmin < W - 16:
            break
    else:
        raise InputError(
            f"views {ref.name} and {src.name}: their rectified disparity range {dmin}..{dmax} does not fit "
            f"{W}-pixel-wide images; the pair cannot be matched by two-view stereo"
        )
    img = (lambda v: v.rgb) if use_colour else _grey8
    L, R = rect.apply(img(left), img(right))
    rig = rect.rig
    return _RectifiedPair(
        L,
        R,
        rig,
        rig.right if swapped else rig.left,
        (rect.right_rect_from_right if swapped else rect.left_rect_from_left).R,
        (max(dmin, -(W - 17)), min(dmax, W - 17)),
    )


def _match(
    pair: _RectifiedPair, swapped: bool, matcher: str, matcher_settings: dict[str, Any] | None
) -> np.ndarray:
    """(H, W) float32 disparity of the reference view in the rectified pair, pixels, NaN unmeasured.

    When swapped, both images are mirrored so that the matcher returns the reference's disparity.
    """
    dmin, dmax = pair.disparity_range
    m = create_matcher(matcher, dmax, min_disparity=dmin, **(matcher_settings or {}))
    if swapped:
        matched = m.compute(
            np.ascontiguousarray(pair.right[:, ::-1]), np.ascontiguousarray(pair.left[:, ::-1])
        )
        disp = matched.disparity[:, ::-1]
        measured = matched.measured[:, ::-1]
    else:
        matched = m.compute(pair.left, pair.right)
        disp, measured = matched.disparity, matched.measured
    return np.where(measured, disp, np.float32(np.nan))


def _depth_in_reference(ref: WorkingView, pair: _RectifiedPair, disp: np.ndarray) -> np.ndarray:
    """(H, W) float32 depth along the reference optical axis, metres, NaN invalid, from the
    reference's rectified disparity ``disp`` (see the module docstring)."""
    z_rect = pair.rig.disparity_to_depth(disp)  # same Z in both rectified frames
    # reference pixel -> rectified pixel (a homography: pure rotation about the centre)
    rays = ref.intrinsics.ray_directions().reshape(-1, 3) @ pair.ref_rect_from_ref.T  # rectified-frame rays
    rz = rays[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        q = rays @ pair.ref_rect.K.T
        mx = (q[:, 0] / q[:, 2]).astype(np.float32)
        my = (q[:, 1] / q[:, 2]).astype(np.float32)
    H, Wr = ref.shape
    mx = mx.reshape(H, Wr)
    my = my.reshape(H, Wr)
    z = cv2.remap(z_rect, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = (z / rz.reshape(H, Wr)).astype(np.float32)
    depth[~(rz.reshape(H, Wr) > 0) | ~(depth > 0) | ~ref.valid] = np.nan
    return depth


def pairwise_depth(
    ref: WorkingView,
    src: WorkingView,
    depth_range: tuple[float, float],
    matcher: str = "opencv-sgbm",
    matcher_settings: dict[str, Any] | None = None,
    alpha: float = 1.0,
    use_colour: bool = False,
    points_world: np.ndarray | None = None,
) -> PairwiseResult:
    """Depth of ``ref`` from the rectified pair (``ref``, ``src``).

    Args:
        ref, src: working views (same world frame); their images must have equal sizes.
        depth_range: (near, far) metres: sets the searched disparity range (widened by 25 %)
            when ``points_world`` is not given.
        points_world: optional (N, 3) sparse world points seen by both views: the searched
            disparity range is their 1st-99th percentile plus a margin (OpenCV's SGBM marks the
            leftmost ``max_disparity`` columns invalid, so a tight range matters).
        matcher: a registered stereo matcher name (``skyrecon.stereo.available_matchers``).
        matcher_settings: keyword settings for the matcher.
        alpha: rectification free scaling (0: crop to valid pixels, 1: keep all source pixels).
        use_colour: match RGB instead of grey.
    Returns:
        PairwiseResult with the reference depth.
    Raises:
        InputError: different image sizes, a mostly vertical baseline, a bad depth range.
    """
    t0 = time.perf_counter()
    near, far = depth_range
    if not (0 < near < far):
        raise InputError(f"views {ref.name}/{src.name}: bad depth range {depth_range}")
    if ref.shape != src.shape:
        raise InputError(
            f"views {ref.name} and {src.name} have different working sizes {ref.shape} and {src.shape}; "
            "pairwise stereo needs equal image sizes"
        )
    src_in_ref = ref.cam_from_world.apply(src.center_world[None])[0]
    if abs(src_in_ref[1]) > abs(src_in_ref[0]):  # mostly vertical baseline: work on turned images
        res = pairwise_depth(
            _rotated_clockwise(ref),
            _rotated_clockwise(src),
            depth_range,
            matcher,
            matcher_settings,
            alpha,
            use_colour,
            points_world,
        )
        res.depth = np.ascontiguousarray(np.rot90(res.depth, 1))
        res.rotated = True
        return res
    swapped = bool(src_in_ref[0] < 0)
    pair = _rectify_pair(ref, src, swapped, depth_range, alpha, points_world, use_colour)
    t1 = time.perf_counter()
    disp = _match(pair, swapped, matcher, matcher_settings)
    t2 = time.perf_counter()
    depth = _depth_in_reference(ref, pair, disp)
    t3 = time.perf_counter()
    dmin, dmax = pair.disparity_range
    return PairwiseResult(
        depth,
        swapped,
        (dmin, dmax),
        {
            "rectify": (t1 - t0) * 1e3,
            "match": (t2 - t1) * 1e3,
            "to_reference": (t3 - t2) * 1e3,
            "total": (t3 - t0) * 1e3,
        },
    )
