"""Sensing of the delivery loop: the drone's rig and its stereo-depth rules.

The stage itself is the shared perception layer (:class:`skyrecon.perception.StereoDepth`, also
used by ``skyrecon map``); the mission picks the :meth:`~skyrecon.perception.PerceptionSettings.flight`
preset with the matcher, disparity bound and depth stride of its :class:`MissionConfig`: the
fast matcher works at half resolution, only *measured* pixels are kept (pixels the matcher
filled by interpolation carry no evidence and could carve free space through a textureless
wall), the depth is subsampled by ``depth_stride`` (nothing is lost at half resolution), and sky
(disparity 0, infinite depth) carves free space up to the map's maximum range, which is right
for open sky.
"""

from __future__ import annotations

from skyrecon.core import StereoRig
from skyrecon.mission.config import MissionConfig
from skyrecon.perception import PerceptionSettings
from skyrecon.sim import default_rig


def mission_rig(cfg: MissionConfig) -> StereoRig:
    """The drone's rectified stereo rig (left camera at the drone's position)."""
    return default_rig(cfg.width, cfg.height, cfg.hfov_deg, cfg.baseline_m)


def flight_perception(cfg: MissionConfig) -> PerceptionSettings:
    """The stereo-depth rules of the delivery loop: :meth:`PerceptionSettings.flight` with the
    mission's matcher, disparity bound and depth stride."""
    return PerceptionSettings.flight(
        method=cfg.matcher, max_disparity=int(cfg.max_disparity), depth_stride=int(cfg.depth_stride)
    )
