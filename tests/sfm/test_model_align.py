"""skyrecon.sfm.model_align: camera-centre fits and ICP with scale against known similarities."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from skyrecon.core import PointCloud
from skyrecon.core.rigid import rotvec_to_matrix
from skyrecon.errors import InputError
from skyrecon.sfm.align import Sim3, estimate_normals
from skyrecon.sfm.model_align import (
    centroid_init,
    check_spread,
    fit_camera_centres,
    icp_plane_with_scale,
    icp_refine,
)


def _box_surface(n: int, seed: int) -> np.ndarray:
    """Points on the faces of a 4 x 3 x 2 m box plus a ground patch (a shape that fixes all 7 unknowns)."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-2, -1.5, 0], [2, 1.5, 2], (n, 3))
    face = rng.integers(0, 5, n)
    pts[face == 0, 0] = -2
    pts[face == 1, 0] = 2
    pts[face == 2, 1] = -1.5
    pts[face == 3, 1] = 1.5
    pts[face == 4, 2] = 2
    ground = np.column_stack([rng.uniform(-5, 5, n // 2), rng.uniform(-5, 5, n // 2), np.zeros(n // 2)])
    return np.vstack([pts, ground])


TRUE = Sim3(rotvec_to_matrix(np.array([0.03, -0.02, 0.05])), np.array([0.2, -0.1, 0.15]), 1.04)


def test_point_to_plane_icp_recovers_scale():
    target = _box_surface(6000, 0)
    source = TRUE.inverse().apply(_box_surface(4000, 1))  # other samples of the same surfaces
    tree = cKDTree(target)
    normals = estimate_normals(target, 12, tree)
    T, iterations, converged, rmse, fitness, n = icp_plane_with_scale(
        source, Sim3(np.eye(3), np.zeros(3), 1.0), target, normals, tree, 1.0, 100, 10.0
    )
    assert converged and fitness > 0.9
    assert abs(T.scale - TRUE.scale) < 2e-3
    assert np.degrees(np.arccos(np.clip((np.trace(T.R @ TRUE.R.T) - 1) / 2, -1, 1))) < 0.1
    assert np.linalg.norm(T.t - TRUE.t) < 0.01


def test_icp_refine_from_centroid_start():
    target = _box_surface(6000, 2)
    source = TRUE.inverse().apply(_box_surface(4000, 3))
    T0 = centroid_init(source, target, with_scale=True)
    T, stats = icp_refine(source, PointCloud(target.astype(np.float32)), T0, True, None, 60, seed=0)
    assert stats["converged"]
    assert abs(T.scale - TRUE.scale) < 5e-3
    assert np.linalg.norm(T.apply(source) - TRUE.apply(source), axis=1).max() < 0.03


def test_camera_centre_fit_and_degenerate_layouts():
    rng = np.random.default_rng(4)
    src = rng.uniform(-10, 10, (12, 3))
    dst = TRUE.apply(src)
    dst[3] += 5.0  # one GPS glitch
    fit, thr = fit_camera_centres(src, dst, [f"im{k}" for k in range(12)], True, None, 0, "positions")
    assert abs(fit.transform.scale - TRUE.scale) < 1e-6
    assert not fit.inliers[3] and fit.inliers.sum() == 11  # the glitch is set aside
    line = np.outer(np.arange(5.0), [1.0, 2.0, 0.5])
    with pytest.raises(InputError, match="line"):
        check_spread(line, "positions", ["a", "b", "c", "d", "e"])
