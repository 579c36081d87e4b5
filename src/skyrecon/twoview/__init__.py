"""Two arbitrary views with known intrinsics -> relative pose, sparse and dense coloured model.

from skyrecon.twoview import reconstruct_two_view, TwoViewSettings
result = reconstruct_two_view(image1, image2, intrinsics1, intrinsics2, TwoViewSettings(), seed=0)
"""

from skyrecon.twoview.dense import compute_disparity, dense_model
from skyrecon.twoview.draw import draw_epipolar_lines, draw_matches, draw_rectified_pair
from skyrecon.twoview.estimate import estimate_two_view_geometry, fit_rotation
from skyrecon.twoview.pipeline import reconstruct_two_view, sparse_cloud
from skyrecon.twoview.result import DenseResult, Status, TwoViewGeometry, TwoViewResult
from skyrecon.twoview.settings import TwoViewSettings

__all__ = [
    "reconstruct_two_view",
    "TwoViewSettings",
    "TwoViewResult",
    "TwoViewGeometry",
    "DenseResult",
    "Status",
    "estimate_two_view_geometry",
    "fit_rotation",
    "sparse_cloud",
    "dense_model",
    "compute_disparity",
    "draw_matches",
    "draw_epipolar_lines",
    "draw_rectified_pair",
]
