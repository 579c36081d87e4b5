"""Triangulation methods on exact data, the optimal correction, and the point filters."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from skyrecon.geometry.epipolar import essential_from_pose
from skyrecon.geometry.triangulation import (
    TriangulationFilter,
    correct_matches_optimal,
    filter_points,
    parallax_angles_deg,
    reprojection_errors,
    triangulate,
    triangulate_dlt,
    triangulate_pinv,
)
from tests.geometry.synthetic import make_pair


@pytest.mark.parametrize("method", ["dlt", "pinv", "midpoint", "optimal"])
def test_exact_triangulation(method):
    p = make_pair(seed=1, n=100)
    X = triangulate(p.R, p.t, p.intr1.normalized(p.x1), p.intr2.normalized(p.x2), method)
    np.testing.assert_allclose(X, p.X, atol=1e-9 * np.abs(p.X).max())


def test_pixel_projection_matrices():
    p = make_pair(seed=2, n=50)
    P1 = p.intr1.K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = p.intr2.K @ np.hstack([p.R, p.t[:, None]])
    for fn in (triangulate_dlt, triangulate_pinv):
        np.testing.assert_allclose(fn(P1, P2, p.x1, p.x2), p.X, atol=1e-8 * np.abs(p.X).max())


def test_optimal_correction_satisfies_the_constraint_and_is_minimal():
    p = make_pair(seed=3, n=40, noise_px=2.0)
    x1n, x2n = p.intr1.normalized(p.x1), p.intr2.normalized(p.x2)
    E = essential_from_pose(p.R, p.t)
    c1, c2 = correct_matches_optimal(E, x1n, x2n)
    h1 = np.concatenate([c1, np.ones((40, 1))], 1)
    h2 = np.concatenate([c2, np.ones((40, 1))], 1)
    assert np.abs(np.sum(h2 * (h1 @ E.T), 1)).max() < 1e-14
    # the correction is the minimum over all 3D points of the summed squared reprojection error
    for i in range(5):

        def residuals(X, i=i):
            Y = p.R @ X + p.t
            return np.concatenate([X[:2] / X[2] - x1n[i], Y[:2] / Y[2] - x2n[i]])

        best = least_squares(residuals, p.X[i], method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
        ours = np.sum((c1[i] - x1n[i]) ** 2) + np.sum((c2[i] - x2n[i]) ** 2)
        assert ours <= np.sum(best.fun**2) * (1 + 1e-6) + 1e-20


def test_optimal_is_more_accurate_than_linear_with_noise():
    p = make_pair(seed=4, n=400, noise_px=1.0, baseline=0.3)
    x1n, x2n = p.intr1.normalized(p.x1), p.intr2.normalized(p.x2)
    e = {
        m: np.median(np.linalg.norm(triangulate(p.R, p.t, x1n, x2n, m) - p.X, axis=1))
        for m in ("dlt", "optimal")
    }
    assert e["optimal"] <= e["dlt"] * 1.05


def test_filters():
    p = make_pair(seed=5, n=60)
    X = p.X.copy()
    X[0] = -X[0]  # behind both cameras
    X[1] = X[1] + np.array([0.2, 0.0, 0.0])  # reprojects far from its pixels
    X[2] = np.nan
    e1, e2 = reprojection_errors(p.X, p.R, p.t, p.intr1.K, p.intr2.K, p.x1, p.x2)
    assert max(e1.max(), e2.max()) < 1e-8
    ok = filter_points(X, p.R, p.t, p.intr1.K, p.intr2.K, p.x1, p.x2, TriangulationFilter(1.0, 0.1))
    assert not ok[:3].any() and ok[3:].all()
    ang = parallax_angles_deg(p.X, p.R, p.t)
    assert np.all((ang > 0) & (ang < 90))
    far = filter_points(p.X * 1e4, p.R, p.t, p.intr1.K, p.intr2.K, p.x1, p.x2, TriangulationFilter(1e9, 0.5))
    assert not far.any()  # tiny parallax
