"""Sensing: stereo pair -> disparity -> depth image ready for the occupancy map.

The drone's rig is a rectified stereo pair looking forward (see
:class:`~skyrecon.mission.config.MissionConfig`). Every cycle the fast matcher turns the pair
into a disparity map; only *measured* pixels are kept (pixels the matcher filled by
interpolation carry no evidence and could carve free space through a textureless wall), and
the depth is subsampled by ``depth_stride`` (the fast matcher works at half resolution, so
nothing is lost) before integration. Sky matches at disparity 0, i.e. infinite depth: the map
carves free space along those rays up to its maximum range, which is right for open sky.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from skyrecon.core import Intrinsics, StereoRig
from skyrecon.mission.config import MissionConfig
from skyrecon.sim import default_rig
from skyrecon.stereo import DisparityResult, create_matcher


def mission_rig(cfg: MissionConfig) -> StereoRig:
    """The drone's rectified stereo rig (left camera at the drone's position)."""
    return default_rig(cfg.width, cfg.height, cfg.hfov_deg, cfg.baseline_m)


def strided_intrinsics(cam: Intrinsics, stride: int) -> Intrinsics:
    """The camera of ``image[::stride, ::stride]``: pixel (u, v) of the result is pixel
    ``(stride u, stride v)`` of the original (no averaging), so ``f / stride`` and ``c / stride``."""
    if stride == 1:
        return cam
    w = -(-cam.width // stride)
    h = -(-cam.height // stride)
    return Intrinsics(
        cam.fx / stride, cam.fy / stride, cam.cx / stride, cam.cy / stride, w, h, skew=cam.skew / stride
    )


@dataclass(eq=False)
class DepthFrame:
    """What perception gives the map for one cycle.

    Attributes:
        depth_m: (h, w) float32 depth along the left optical axis, metres, NaN where not measured,
            +inf for matches at disparity <= 0 (beyond any range: sky); (h, w) is the image size
            divided by the depth stride.
        intrinsics: the camera of ``depth_m``.
        disparity: (H, W) float32 full-resolution disparity of the matcher, pixels, NaN invalid.
        measured_fraction: share of pixels with a measured disparity.
        stereo_ms: wall-clock milliseconds of matching and conversion.
    """

    depth_m: np.ndarray
    intrinsics: Intrinsics
    disparity: np.ndarray
    measured_fraction: float
    stereo_ms: float


class StereoDepth:
    """A reusable stereo-to-depth stage for one rig.

    Args:
        cfg: the mission settings (matcher, disparity bound, depth stride).
        rig: the rectified rig the pairs come from.
    """

    def __init__(self, cfg: MissionConfig, rig: StereoRig):
        self.cfg = cfg
        self.rig = rig
        self.matcher = create_matcher(cfg.matcher, int(cfg.max_disparity))
        if hasattr(self.matcher, "warmup"):
            self.matcher.warmup()
        self.stride = int(cfg.depth_stride)
        self.intrinsics = strided_intrinsics(rig.left, self.stride)

    def compute(self, left: np.ndarray, right: np.ndarray) -> DepthFrame:
        """Depth of one rectified pair, each (H, W, 3) uint8 RGB."""
        t0 = time.perf_counter()
        result: DisparityResult = self.matcher.compute(left, right)
        s = self.stride
        disp = result.disparity[::s, ::s]
        measured = result.measured[::s, ::s]
        with np.errstate(invalid="ignore"):
            sky = measured & (disp + self.rig.doffs_px <= 0)
        # disparities stay in full-resolution pixels, so the full rig converts them
        depth = self.rig.disparity_to_depth(np.where(measured, disp, np.float32(np.nan)))
        depth[sky] = np.inf
        depth = np.ascontiguousarray(depth, dtype=np.float32)
        ms = 1e3 * (time.perf_counter() - t0)
        return DepthFrame(depth, self.intrinsics, result.disparity, float(result.measured.mean()), ms)
