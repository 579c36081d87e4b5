"""Dense multi-view stereo: view selection, per-view depth (PatchMatch or pairwise), fusion.

Quick use::

    from skyrecon.mvs import MVSSettings, load_views_and_images, run_mvs
    views, _ = load_views_and_images("images/", "cameras/")      # cameras matched to files by name
    result = run_mvs(views, settings=MVSSettings())               # PatchMatch + consistency fusion
    result.cloud            # PointCloud, world frame, colours and normals
    result.depth_maps       # {image stem: DepthMap} at the working resolution
    baseline = run_mvs(views, settings=MVSSettings.writeup_baseline())  # pairwise SGBM, concatenated

Conventions: metres, OpenCV camera axes, pixel (0, 0) = centre of the top-left pixel, poses
``cam_from_world``; depth (H, W) float32 along the optical axis, NaN invalid.
"""

from skyrecon.mvs.export import save_mvs_result
from skyrecon.mvs.frames import WorkingView, make_working_view
from skyrecon.mvs.fusion import FusedCloud, FusionSettings, fuse_concat, fuse_consistent
from skyrecon.mvs.inputs import load_views_and_images, load_working_views
from skyrecon.mvs.pairwise import PairwiseResult, pairwise_depth
from skyrecon.mvs.patchmatch import PatchMatchResult, PatchMatchSettings, patchmatch_depth
from skyrecon.mvs.pipeline import MVSResult, run_mvs
from skyrecon.mvs.planar_prior import PlanarPriorSettings
from skyrecon.mvs.settings import DEPTH_METHODS, FUSION_METHODS, MVSSettings
from skyrecon.mvs.topology import TOPOLOGIES, neighbors_from_pairs, select_neighbors, topology_pairs

__all__ = [
    "MVSSettings",
    "MVSResult",
    "run_mvs",
    "load_views_and_images",
    "load_working_views",
    "save_mvs_result",
    "WorkingView",
    "make_working_view",
    "FusionSettings",
    "FusedCloud",
    "fuse_consistent",
    "fuse_concat",
    "PairwiseResult",
    "pairwise_depth",
    "PatchMatchSettings",
    "PatchMatchResult",
    "patchmatch_depth",
    "PlanarPriorSettings",
    "TOPOLOGIES",
    "DEPTH_METHODS",
    "FUSION_METHODS",
    "topology_pairs",
    "neighbors_from_pairs",
    "select_neighbors",
]
