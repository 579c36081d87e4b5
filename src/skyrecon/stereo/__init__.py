"""Dense stereo: rectification, disparity matchers, depth and point clouds.

Quick use::

    from skyrecon.stereo import create_matcher, disparity_to_points
    matcher = create_matcher("skyrecon", max_disparity=128)   # reusable across frames
    result = matcher.compute(left_rgb, right_rgb)              # DisparityResult
    cloud = disparity_to_points(result.disparity, rig, left_rgb, 0.5, 80.0)

Conventions: images (H, W, 3) uint8 RGB or (H, W) grey; disparity (H, W) float32 pixels with
``x_right = x_left - d``, NaN invalid; depth (H, W) float32 metres along the optical axis;
points in the left camera frame (x right, y down, z forward), metres.
"""

from skyrecon.stereo.base import (
    DisparityResult,
    Matcher,
    PreparedPair,
    available_matchers,
    create_matcher,
    prepare_pair,
    to_grey,
)
from skyrecon.stereo.opencv_matchers import (
    OpenCVBMMatcher,
    OpenCVBMSettings,
    OpenCVSGBMMatcher,
    OpenCVSGBMSettings,
)
from skyrecon.stereo.plane_fill import plane_supported_fill
from skyrecon.stereo.rectify import RigRectification, rectify_rig
from skyrecon.stereo.reproject import (
    depth_error_bound,
    disparity_to_depth,
    disparity_to_points,
    max_disparity_for,
    trusted_range_m,
)
from skyrecon.stereo.sgm import (
    FAST_SETTINGS,
    SkyreconMatcher,
    SkyreconSettings,
    fill_invalid,
    remove_speckles,
)

__all__ = [
    "DisparityResult",
    "Matcher",
    "PreparedPair",
    "available_matchers",
    "create_matcher",
    "prepare_pair",
    "to_grey",
    "OpenCVBMMatcher",
    "OpenCVBMSettings",
    "OpenCVSGBMMatcher",
    "OpenCVSGBMSettings",
    "FAST_SETTINGS",
    "SkyreconMatcher",
    "SkyreconSettings",
    "fill_invalid",
    "plane_supported_fill",
    "remove_speckles",
    "RigRectification",
    "rectify_rig",
    "depth_error_bound",
    "disparity_to_depth",
    "disparity_to_points",
    "trusted_range_m",
    "max_disparity_for",
]
