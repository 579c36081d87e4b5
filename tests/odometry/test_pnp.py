import numpy as np
import pytest

from skyrecon.core.rigid import rotvec_to_matrix
from skyrecon.errors import EstimationError
from skyrecon.odometry.pnp import fast_absolute_pose


def test_fast_absolute_pose_recovers_the_pose_despite_outliers():
    rng = np.random.default_rng(1)
    X = np.column_stack([rng.uniform(-8, 8, 200), rng.uniform(-4, 4, 200), rng.uniform(5, 40, 200)])
    R = rotvec_to_matrix(np.array([0.02, -0.1, 0.03]))
    t = np.array([0.3, -0.1, -0.8])
    P = X @ R.T + t
    xn = P[:, :2] / P[:, 2:3] + rng.normal(0, 0.2 / 500.0, (200, 2))
    xn[:40] += rng.uniform(-0.05, 0.05, (40, 2))  # 20 % gross outliers
    pose = fast_absolute_pose(xn, X, 500.0, threshold_px=2.0, seed=3, min_inliers=30)
    assert np.abs(pose.R - R).max() < 1e-3
    assert np.linalg.norm(pose.t - t) < 0.02
    assert pose.inliers[40:].mean() > 0.95 and pose.inliers[:40].mean() < 0.2
    again = fast_absolute_pose(xn, X, 500.0, threshold_px=2.0, seed=3, min_inliers=30)
    assert np.array_equal(again.R, pose.R)


def test_fast_absolute_pose_raises_on_too_few_matches():
    X = np.ones((5, 3))
    with pytest.raises(EstimationError):
        fast_absolute_pose(np.zeros((5, 2)), X, 500.0, min_inliers=15)
