"""The generic LO-RANSAC loop on a toy problem (2D lines) and on homographies with outliers."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.errors import EstimationError
from skyrecon.geometry.homography import estimate_homography
from skyrecon.geometry.sampling import (
    LocalOptimization,
    RansacOptions,
    RansacProblem,
    lo_ransac,
    local_optimize,
)


class LineProblem:
    """Lines ``a x + b y + c = 0`` (unit normal) through 2D points: 2-point minimal solver, MSAC on
    the perpendicular distance, total-least-squares refit."""

    model_name = "line"
    sample_size = 2

    def __init__(self, points: np.ndarray, threshold: float) -> None:
        self.points = points
        self.thr2 = threshold**2
        self.num_data = len(points)
        self.refits = 0

    def best_minimal_model(self, samples: np.ndarray) -> tuple[np.ndarray, float] | None:
        p, q = self.points[samples[:, 0]], self.points[samples[:, 1]]
        d = q - p
        normal = np.stack([-d[:, 1], d[:, 0]], axis=1)
        length = np.linalg.norm(normal, axis=1)
        ok = length > 1e-12
        if not np.any(ok):
            return None
        normal = normal[ok] / length[ok, None]
        lines = np.concatenate([normal, -np.sum(normal * p[ok], axis=1, keepdims=True)], axis=1)
        err2 = (self.points @ lines[:, :2].T + lines[:, 2]).T ** 2
        costs = np.minimum(err2, self.thr2).sum(axis=1)
        k = int(np.argmin(costs))
        return lines[k], float(costs[k])

    def score(self, line: np.ndarray) -> tuple[float, np.ndarray]:
        err2 = (self.points @ line[:2] + line[2]) ** 2
        return float(np.minimum(err2, self.thr2).sum()), err2 < self.thr2

    def refit(self, line: np.ndarray, inliers: np.ndarray) -> np.ndarray:
        self.refits += 1
        pts = self.points[inliers]
        centre = pts.mean(axis=0)
        _, _, Vt = np.linalg.svd(pts - centre)
        normal = Vt[-1]
        return np.array([normal[0], normal[1], -normal @ centre])


def _line_points(seed: int, n: int = 300, outlier_ratio: float = 0.5, noise: float = 0.01):
    """Points near ``y = 0.5 x + 1`` on [-10, 10] with uniform outliers in a 20 x 20 box."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-10, 10, n)
    pts = np.stack([x, 0.5 * x + 1.0], axis=1) + rng.normal(scale=noise, size=(n, 2))
    outlier = rng.random(n) < outlier_ratio
    pts[outlier] = rng.uniform(-10, 10, (int(outlier.sum()), 2))
    return pts, outlier


def _true_line() -> np.ndarray:
    line = np.array([0.5, -1.0, 1.0])
    return line / np.linalg.norm(line[:2])


def test_problems_satisfy_the_protocol() -> None:
    problem: RansacProblem[np.ndarray] = LineProblem(np.zeros((3, 2)), 1.0)
    assert problem.sample_size == 2


def test_line_with_half_outliers() -> None:
    pts, outlier = _line_points(0)
    problem = LineProblem(pts, 0.05)
    found = lo_ransac(problem, RansacOptions(threshold=0.05), np.random.default_rng(1))
    line = found.model * np.sign(found.model[1] / _true_line()[1])
    assert np.allclose(line, _true_line(), atol=2e-3)
    # every true inlier found, almost no outlier accepted (a few lie near the line by chance)
    assert np.all(found.inliers[~outlier])
    assert np.count_nonzero(found.inliers & outlier) <= 0.02 * len(pts)
    assert found.local_optimizations >= 1 and problem.refits >= 1
    # adaptive stopping: with half inliers and m = 2 a few dozen samples suffice
    assert found.iterations < 200
    assert found.cost == pytest.approx(problem.score(found.model)[0])


def test_deterministic_for_a_seed() -> None:
    pts, _ = _line_points(3, outlier_ratio=0.7)
    opts = RansacOptions(threshold=0.05, local_optimization=False, min_iterations=0, batch_size=4)
    a = lo_ransac(LineProblem(pts, 0.05), opts, np.random.default_rng(7))
    b = lo_ransac(LineProblem(pts, 0.05), opts, np.random.default_rng(7))
    assert np.array_equal(a.model, b.model) and np.array_equal(a.inliers, b.inliers)
    assert a.iterations == b.iterations


def test_local_optimisation_lowers_the_cost() -> None:
    pts, _ = _line_points(4, noise=0.05)
    base = RansacOptions(threshold=0.15, min_iterations=0, max_iterations=8, batch_size=8)
    plain = lo_ransac(
        LineProblem(pts, 0.15),
        RansacOptions(
            threshold=0.15, min_iterations=0, max_iterations=8, batch_size=8, local_optimization=False
        ),
        np.random.default_rng(0),
    )
    polished = lo_ransac(LineProblem(pts, 0.15), base, np.random.default_rng(0))
    assert polished.cost < plain.cost and plain.local_optimizations == 0


def test_local_optimize_respects_its_settings() -> None:
    pts, _ = _line_points(5)
    problem = LineProblem(pts, 0.05)
    start = _true_line() + np.array([0.0, 0.0, 0.03])  # shifted by 0.03: a rough start
    cost, inl = problem.score(start)
    _, _, inl_none = local_optimize(problem, start, cost, inl, LocalOptimization(max_steps=0))
    assert problem.refits == 0 and np.array_equal(inl_none, inl)
    local_optimize(problem, start, cost, inl, LocalOptimization(max_steps=3, min_inliers=len(pts) + 1))
    assert problem.refits == 0  # too few inliers to refit
    _, new_cost, _ = local_optimize(problem, start, cost, inl, LocalOptimization(max_steps=3, min_inliers=2))
    assert 1 <= problem.refits <= 3 and new_cost <= cost


def test_iteration_limits() -> None:
    pts, _ = _line_points(6, outlier_ratio=0.9)
    opts = RansacOptions(threshold=0.05, min_iterations=40, max_iterations=50, batch_size=16)
    found = lo_ransac(LineProblem(pts, 0.05), opts, np.random.default_rng(0))
    assert 40 <= found.iterations <= 50


def test_polish_every_best_sample_polishes_at_least_as_often() -> None:
    pts, _ = _line_points(8, noise=0.05)
    opts = RansacOptions(threshold=0.15, min_iterations=200, max_iterations=200, batch_size=4)
    colmap = lo_ransac(LineProblem(pts, 0.15), opts, np.random.default_rng(2))
    every = lo_ransac(LineProblem(pts, 0.15), opts, np.random.default_rng(2), polish_every_best_sample=True)
    assert every.local_optimizations >= colmap.local_optimizations
    assert every.cost <= colmap.cost * (1 + 1e-9)


def test_no_valid_model_raises() -> None:
    same = np.ones((10, 2))  # every sample degenerate
    with pytest.raises(EstimationError, match="no line found in"):
        lo_ransac(LineProblem(same, 0.1), RansacOptions(max_iterations=64), np.random.default_rng(0))


def test_homography_with_outliers_through_the_generic_loop() -> None:
    rng = np.random.default_rng(0)
    H = np.array([[1.05, 0.02, 12.0], [-0.03, 0.98, -7.0], [1e-5, -2e-5, 1.0]])
    x1 = rng.uniform(0, 1000, (400, 2))
    h = np.concatenate([x1, np.ones((400, 1))], axis=1) @ H.T
    x2 = h[:, :2] / h[:, 2:] + rng.normal(scale=0.3, size=(400, 2))
    outlier = rng.random(400) < 0.4
    x2[outlier] = rng.uniform(0, 1000, (int(outlier.sum()), 2))
    est = estimate_homography(x1, x2, RansacOptions(threshold=2.0), seed=3)
    grid = np.stack(np.meshgrid(np.linspace(0, 1000, 11), np.linspace(0, 1000, 11)), -1).reshape(-1, 2)
    g = np.concatenate([grid, np.ones((len(grid), 1))], axis=1)
    mapped_est, mapped_true = g @ est.H.T, g @ H.T
    shift = mapped_est[:, :2] / mapped_est[:, 2:] - mapped_true[:, :2] / mapped_true[:, 2:]
    assert np.abs(shift).max() < 0.5  # pixels, over the whole image
    assert np.count_nonzero(est.inliers[~outlier]) >= 0.97 * np.count_nonzero(~outlier)
    again = estimate_homography(x1, x2, RansacOptions(threshold=2.0), seed=3)
    assert np.array_equal(est.H, again.H) and est.iterations == again.iterations
