"""Sensing of the delivery loop: the drone's rig and its stereo-depth rules.

The stage itself is the shared perception layer (:class:`skyrecon.perception.StereoDepth`, also
used by ``skyrecon map``); the mission picks the :meth:`~skyrecon.perception.PerceptionSettings.flight`
preset with the matcher, disparity bound and depth stride of its :class:`MissionConfig`: the
fast matcher works at half resolution, only *measured* pixels are kept (pixels the matcher
filled by interpolation carry no evidence and could carve free space through a textureless
wall), the depth is subsampled by ``depth_stride`` (nothing is lost at half resolution), and sky
(disparity 0, infinite depth) carves free space up to the map's maximum range, which is right
for open sky; so does the unmeasured band between open sky and ground beyond that range across
the horizon (``horizon_far_m``, :func:`skyrecon.perception.stereo_depth.horizon_band`), where a
noisy camera measures nothing and the drone's own altitude projects. The map reaches as far as
the rig's trusted range (where a quarter pixel of disparity error at the matcher's half
resolution moves depth by at most 3 voxels: about 17 m for the default rig, below
``max_range_m``); farther depth carves free space up to it only. Marking
obstacles out to 20 m put phantom voxels metres from any surface where the matcher was off by a
pixel on far grass, and a hovering drone saw them again every cycle until they saturated (mission
seed 9 hovered by its goal); 2 voxels (14 m) saw obstacles so late that paths grew longer and
climbs steeper (median length ratio 1.03 -> 1.10 on the 20 missions, seed 19 lost its pose
looking up a climb). The 3 voxels were chosen on those two missions.
"""

from __future__ import annotations

from functools import lru_cache

from skyrecon.core import StereoRig
from skyrecon.mission.config import MissionConfig
from skyrecon.perception import PerceptionSettings
from skyrecon.sim import default_rig


def mission_rig(cfg: MissionConfig) -> StereoRig:
    """The drone's rectified stereo rig (left camera at the drone's position)."""
    return default_rig(cfg.width, cfg.height, cfg.hfov_deg, cfg.baseline_m)


#: disparities of the full-resolution block matcher that finds small movers for the tracker
#: (``PerceptionSettings.fine_max_disparity``): down to 6.4 m with the default rig
FINE_MAX_DISPARITY = 16


def flight_perception(cfg: MissionConfig) -> PerceptionSettings:
    """The stereo-depth rules of the delivery loop: :meth:`PerceptionSettings.flight` with the
    mission's matcher, disparity bound and depth stride; with ``mover_fine_depth`` (and movers
    tracked), also the full-resolution fine depth (a drone 15-20 m away is lost at half
    resolution). The horizon band and the ground prior's open air reach the mission's
    ``max_range_m`` (the map carves no farther than its own, shorter, range)."""
    return PerceptionSettings.flight(
        method=cfg.matcher,
        max_disparity=int(cfg.max_disparity),
        depth_stride=int(cfg.depth_stride),
        fine_max_disparity=FINE_MAX_DISPARITY if cfg.track_movers and cfg.mover_fine_depth else 0,
        horizon_far_m=float(cfg.max_range_m),
        ground_range_m=float(cfg.max_range_m),
    )


@lru_cache(maxsize=16)
def hit_range_m(cfg: MissionConfig) -> float:
    """Range up to which the drone's map marks obstacles, metres: the rig's trusted range for
    :func:`flight_perception`, at most ``cfg.max_range_m`` (farther depth carves free space only).
    Also how far ahead one look can verify space free (the stopping rule's cap,
    :mod:`skyrecon.mission.safety`); cached per config, as the stopping rule asks every cycle."""
    return flight_perception(cfg).hit_range_m(mission_rig(cfg), cfg.voxel_size_m, cfg.max_range_m)
