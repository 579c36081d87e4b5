"""Two-view geometry: epipolar solvers (7/8/5-point), robust estimation (RANSAC, LMedS,
MAGSAC++, LO-RANSAC), non-linear pose refinement, homographies and degeneracy, triangulation,
rectification and direct epipolar window search.

Conventions: pixels with the top-left pixel centre at (0, 0); ``x2^T F x1 = 0``;
``(R, t) = cam2_from_cam1`` with ``p_cam2 = R p_cam1 + t`` and ``E = [t]x R``.
"""

from skyrecon.geometry.epipolar import (
    decompose_essential,
    epipolar_lines,
    essential_8point,
    essential_from_fundamental,
    essential_from_pose,
    fundamental_7point,
    fundamental_8point,
    fundamental_from_essential,
    pose_candidates,
    project_to_essential,
    sampson_distance,
    sampson_sq,
    select_pose,
    skew,
)
from skyrecon.geometry.epipolar_search import (
    EpipolarSearchResult,
    match_along_epipolar_lines,
    search_segments_from_depth,
)
from skyrecon.geometry.essential import (
    RelativePose,
    estimate_essential,
    estimate_relative_pose,
    finalize_pose,
    polish_pose,
)
from skyrecon.geometry.five_point import essential_5point, essential_5point_batch
from skyrecon.geometry.fundamental import FundamentalEstimate, estimate_fundamental
from skyrecon.geometry.homography import (
    HomographyEstimate,
    decompose_homography,
    estimate_homography,
    homography_dlt,
)
from skyrecon.geometry.rectification import (
    Rectification,
    rectify,
    rectify_calibrated,
    rectify_opencv,
    rectify_uncalibrated,
    triangulate_disparity,
    warp_images,
)
from skyrecon.geometry.refine import RefineResult, refine_relative_pose
from skyrecon.geometry.sampling import RansacOptions
from skyrecon.geometry.triangulation import (
    TriangulationFilter,
    filter_points,
    parallax_angles_deg,
    reprojection_errors,
    triangulate,
    triangulate_dlt,
    triangulate_midpoint,
    triangulate_optimal,
    triangulate_pinv,
)

__all__ = [
    "skew",
    "fundamental_8point",
    "fundamental_7point",
    "essential_8point",
    "essential_from_fundamental",
    "fundamental_from_essential",
    "essential_from_pose",
    "project_to_essential",
    "sampson_sq",
    "sampson_distance",
    "epipolar_lines",
    "decompose_essential",
    "pose_candidates",
    "select_pose",
    "essential_5point",
    "essential_5point_batch",
    "RansacOptions",
    "RelativePose",
    "estimate_essential",
    "estimate_relative_pose",
    "polish_pose",
    "finalize_pose",
    "FundamentalEstimate",
    "estimate_fundamental",
    "HomographyEstimate",
    "estimate_homography",
    "homography_dlt",
    "decompose_homography",
    "EpipolarSearchResult",
    "match_along_epipolar_lines",
    "search_segments_from_depth",
    "RefineResult",
    "refine_relative_pose",
    "triangulate",
    "triangulate_dlt",
    "triangulate_pinv",
    "triangulate_midpoint",
    "triangulate_optimal",
    "reprojection_errors",
    "parallax_angles_deg",
    "TriangulationFilter",
    "filter_points",
    "Rectification",
    "rectify",
    "rectify_calibrated",
    "rectify_opencv",
    "rectify_uncalibrated",
    "warp_images",
    "triangulate_disparity",
]
