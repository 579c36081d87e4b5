"""From disparity to metric depth and coloured point clouds (rectified rigs).

Depth along the left optical axis: ``Z = f * B / (d + doffs)`` with f the focal length in
pixels, B the baseline in metres and ``doffs = cx_right - cx_left`` (pixels). Points are in
the (rectified) left camera frame: x right, y down, z forward, metres.
"""

from __future__ import annotations

import numpy as np

from skyrecon.core.depth import DepthMap, PointCloud
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError

__all__ = ["disparity_to_depth", "disparity_to_points", "depth_error_bound", "max_disparity_for"]


def _check(disparity: np.ndarray, rig: StereoRig) -> np.ndarray:
    disparity = np.asarray(disparity, dtype=np.float32)
    if disparity.ndim != 2:
        raise InputError(f"a disparity map must be 2-D (H, W), got shape {disparity.shape}")
    rig.left.check_image(disparity, "the disparity map")
    if not rig.is_rectified:
        raise InputError("the stereo rig is not rectified; rectify it (skyrecon.stereo.rectify_rig) first")
    return disparity


def disparity_to_depth(disparity: np.ndarray, rig: StereoRig) -> np.ndarray:
    """(H, W) float32 disparity (pixels, NaN invalid) -> (H, W) float32 depth in metres.

    NaN where the disparity is invalid or ``d + doffs <= 0`` (at or beyond infinity).
    """
    return rig.disparity_to_depth(_check(disparity, rig))


def disparity_to_points(
    disparity: np.ndarray,
    rig: StereoRig,
    image: np.ndarray | None = None,
    min_depth_m: float = 0.0,
    max_depth_m: float = np.inf,
    mask: np.ndarray | None = None,
) -> PointCloud:
    """Reproject a disparity map to a (coloured) point cloud in the left camera frame.

    Args:
        disparity: (H, W) float32 left disparity, pixels, ``x_right = x_left - d``, NaN invalid.
        rig: the rectified rig the disparity was computed on (``rig.left`` has size W x H).
        image: optional (H, W, 3) uint8 RGB or (H, W) grey left image for the colours.
        min_depth_m, max_depth_m: keep points with depth in this range, metres.
        mask: optional (H, W) bool of pixels to keep (e.g. ``result.measured`` to drop
            filled pixels).
    Returns:
        PointCloud: (N, 3) float32 points in metres in the left camera frame, in row-major
        pixel order, with (N, 3) uint8 colours when ``image`` is given.
    Raises:
        InputError: sizes differ, the rig is not rectified, or the depth range is empty.
    """
    disparity = _check(disparity, rig)
    if not (min_depth_m >= 0 and max_depth_m > min_depth_m):
        raise InputError(f"need 0 <= min_depth_m < max_depth_m, got {min_depth_m} and {max_depth_m}")
    depth = rig.disparity_to_depth(disparity)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != depth.shape:
            raise InputError(f"mask has shape {mask.shape}, expected {depth.shape}")
        depth = np.where(mask, depth, np.float32(np.nan))
    if image is not None:
        rig.left.check_image(image, "the colour image")
    return DepthMap(depth, rig.left).to_points_cam(image, min_depth_m, max_depth_m)


def depth_error_bound(
    disparity: np.ndarray, rig: StereoRig, disparity_error_px: float | np.ndarray = 1.0
) -> np.ndarray:
    """First-order depth uncertainty ``f * B / (d + doffs)**2 * disparity_error``, metres.

    A disparity error of ``e`` pixels moves the depth by about ``Z**2 / (f B) * e``: depth
    accuracy falls with the square of the distance. NaN where the disparity is invalid.
    """
    disparity = _check(disparity, rig)
    d = disparity.astype(np.float64) + rig.doffs_px
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = rig.left.fx * rig.baseline_m / (d * d) * np.asarray(disparity_error_px, dtype=np.float64)
    bound[~(d > 0)] = np.nan
    return bound.astype(np.float32)


def max_disparity_for(rig: StereoRig, min_depth_m: float, multiple: int = 16) -> int:
    """The disparity search bound needed to see down to ``min_depth_m`` metres.

    ``ceil(f * B / min_depth_m - doffs) + 1`` rounded up to ``multiple`` (16 suits every
    matcher; OpenCV needs it), for ``create_matcher(name, max_disparity=...)``.
    """
    if not (np.isfinite(min_depth_m) and min_depth_m > 0):
        raise InputError(f"min_depth_m must be positive, got {min_depth_m}")
    if multiple < 1:
        raise InputError(f"multiple must be >= 1, got {multiple}")
    d = int(np.ceil(rig.left.fx * rig.baseline_m / min_depth_m - rig.doffs_px)) + 1
    return max(multiple, -(-d // multiple) * multiple)


def trusted_range_m(rig: StereoRig, max_depth_error_m: float, disparity_error_px: float = 0.25) -> float:
    """Depth up to which a disparity error of ``disparity_error_px`` moves depth by at most
    ``max_depth_error_m``: ``sqrt(max_depth_error * f * B / disparity_error)``, metres.

    Beyond it stereo depth is too uncertain to place obstacles (mapping uses it as the range
    up to which measurements mark hits; farther ones only carve free space up to it).
    """
    if not (max_depth_error_m > 0 and disparity_error_px > 0):
        raise InputError("max_depth_error_m and disparity_error_px must be positive")
    return float(np.sqrt(max_depth_error_m * rig.left.fx * rig.baseline_m / disparity_error_px))
