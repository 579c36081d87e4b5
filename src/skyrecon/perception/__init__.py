"""Perception: what the drone's sensors tell the map.

Today stereo depth (:class:`StereoDepth` with the rules in :class:`PerceptionSettings`, presets
``mapping()`` for ``skyrecon map`` and ``flight()`` for the delivery loop); visual odometry
is meant to live here too; movers (:class:`MoverTracker`): what moves in the depth images,
kept out of the static map and tracked for the planner (with a full-resolution block matcher's
:class:`FineDepth` for small far ones).
"""

from skyrecon.perception.ground_plane import GroundPlane
from skyrecon.perception.movers import (
    MoverDetection,
    MoverFrame,
    MoverSettings,
    MoverTrack,
    MoverTracker,
    detect_movers,
)
from skyrecon.perception.settings import PerceptionSettings, stereo_hit_range_m
from skyrecon.perception.stereo_depth import (
    DepthFrame,
    FineDepth,
    StereoDepth,
    disparity_discontinuities,
    strided_intrinsics,
    texture_masks,
)

__all__ = [
    "DepthFrame",
    "FineDepth",
    "GroundPlane",
    "MoverDetection",
    "MoverFrame",
    "MoverSettings",
    "MoverTrack",
    "MoverTracker",
    "detect_movers",
    "PerceptionSettings",
    "StereoDepth",
    "disparity_discontinuities",
    "stereo_hit_range_m",
    "strided_intrinsics",
    "texture_masks",
]
