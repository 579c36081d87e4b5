"""Occupancy mapping: a sparse probabilistic voxel map fed by depth images or point clouds,
and a bounded Euclidean distance field over it (world frame, z up, metres).

Main entry points:

* :func:`build_map_from_depth_frames` and :class:`OccupancyMap` (``integrate_depth``,
  ``integrate_points``, ``save`` / ``load``, ``pop_changed_blocks``);
* :class:`StereoMapper` / :func:`map_stereo_sequence`: a map from a rectified stereo sequence
  (what ``skyrecon map`` runs; stereo depth from :mod:`skyrecon.perception`);
* :func:`map_depth_sequence`: a map from posed depth images, streamed (``skyrecon map --depth``);
* :func:`write_map_preview` / :func:`map_preview_image`: a top view with paths;
* :func:`export_occupied_ply`, :func:`write_octomap_bt`;
* :class:`DistanceField` (``update``, ``query_distance``).
"""

from skyrecon.mapping.config import MapConfig
from skyrecon.mapping.depth_sequence import DepthSequenceMap, FrameTimings, MappedFrame, map_depth_sequence
from skyrecon.mapping.distance import DistanceField
from skyrecon.mapping.occupancy import (
    FREE,
    OCCUPIED,
    UNKNOWN,
    IntegrationStats,
    OccupancyMap,
    build_map_from_depth_frames,
    load_map,
    save_map,
)
from skyrecon.mapping.octomap_bt import write_octomap_bt
from skyrecon.mapping.preview import map_preview_image, write_map_preview
from skyrecon.mapping.stereo_sequence import (
    StereoMapper,
    StereoMapSettings,
    map_stereo_sequence,
)
from skyrecon.mapping.storage import export_occupied_ply, read_flown_path, write_flown_path
from skyrecon.perception import stereo_hit_range_m

__all__ = [
    "MapConfig",
    "OccupancyMap",
    "IntegrationStats",
    "build_map_from_depth_frames",
    "DistanceField",
    "export_occupied_ply",
    "read_flown_path",
    "write_flown_path",
    "write_octomap_bt",
    "save_map",
    "load_map",
    "FREE",
    "OCCUPIED",
    "UNKNOWN",
    "StereoMapper",
    "StereoMapSettings",
    "map_stereo_sequence",
    "stereo_hit_range_m",
    "DepthSequenceMap",
    "FrameTimings",
    "MappedFrame",
    "map_depth_sequence",
    "map_preview_image",
    "write_map_preview",
]
