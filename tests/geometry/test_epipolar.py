"""Linear epipolar solvers, E <-> F, Sampson error and the decomposition of E, on exact data."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from skyrecon.core import rotvec_to_matrix
from skyrecon.errors import EstimationError, InputError
from skyrecon.geometry.epipolar import (
    as_points2,
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
    sampson_sq_batch,
    select_pose,
)
from tests.geometry.synthetic import make_pair


def _gt_F(p) -> np.ndarray:
    return fundamental_from_essential(essential_from_pose(p.R, p.t), p.intr1.K, p.intr2.K)


def _same_up_to_sign(A: np.ndarray, B: np.ndarray) -> float:
    A = A / np.linalg.norm(A)
    B = B / np.linalg.norm(B)
    return float(min(np.abs(A - B).max(), np.abs(A + B).max()))


@pytest.mark.parametrize("seed", range(5))
def test_eight_point_is_exact_without_noise(seed):
    p = make_pair(seed=seed, n=60)
    F = fundamental_8point(p.x1, p.x2)
    assert _same_up_to_sign(F, _gt_F(p)) < 1e-9
    assert abs(np.linalg.det(F / np.linalg.norm(F))) < 1e-12
    assert sampson_distance(F, p.x1, p.x2).max() < 1e-8  # pixels


def test_eight_point_rank_two_on_noisy_data():
    p = make_pair(seed=3, n=100, noise_px=1.0)
    F = fundamental_8point(p.x1, p.x2)
    s = np.linalg.svd(F, compute_uv=False)
    assert s[2] < 1e-12 * s[0]


@pytest.mark.parametrize("seed", range(5))
def test_seven_point_one_root_is_exact(seed):
    p = make_pair(seed=seed, n=7)
    Fs = fundamental_7point(p.x1, p.x2)
    assert len(Fs) in (1, 3)
    for F in Fs:  # every root is a rank-2 matrix through the 7 matches
        assert sampson_distance(F, p.x1, p.x2).max() < 1e-6
        assert abs(np.linalg.det(F)) < 1e-10
    assert min(_same_up_to_sign(F, _gt_F(p)) for F in Fs) < 1e-8


def test_too_few_points_raise():
    p = make_pair(seed=0, n=7)
    with pytest.raises(EstimationError):
        fundamental_8point(p.x1, p.x2)
    with pytest.raises(EstimationError):
        fundamental_7point(p.x1[:6], p.x2[:6])


def test_essential_fundamental_round_trip():
    p = make_pair(seed=1)
    E = essential_from_pose(p.R, p.t)
    F = fundamental_from_essential(E, p.intr1.K, p.intr2.K)
    E2 = essential_from_fundamental(F, p.intr1.K, p.intr2.K)
    assert _same_up_to_sign(E2, E) < 1e-12
    s = np.linalg.svd(project_to_essential(E2 * 7.0), compute_uv=False)
    np.testing.assert_allclose(s, [1, 1, 0], atol=1e-12)


def test_essential_8point_exact():
    p = make_pair(seed=2, n=40)
    E = essential_8point(p.intr1.normalized(p.x1), p.intr2.normalized(p.x2))
    assert _same_up_to_sign(E, essential_from_pose(p.R, p.t)) < 1e-9


@pytest.mark.parametrize("seed", range(8))
def test_decomposition_contains_the_true_pose(seed):
    rng = np.random.default_rng(seed)
    R = rotvec_to_matrix(rng.normal(size=3))
    t = rng.normal(size=3)
    t /= np.linalg.norm(t)
    E = essential_from_pose(R, t) * rng.uniform(0.1, 10) * rng.choice([-1, 1])
    R1, R2, u = decompose_essential(E)
    for Rc in (R1, R2):
        np.testing.assert_allclose(Rc @ Rc.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(Rc) == pytest.approx(1.0, abs=1e-12)
    errs = [max(np.abs(Rc - R).max(), np.abs(tc - t).max()) for Rc, tc in pose_candidates(E)]
    assert min(errs) < 1e-12


@pytest.mark.parametrize("seed", range(4))
def test_cheirality_selects_the_true_pose(seed):
    p = make_pair(seed=seed, n=50)
    R, t, front = select_pose(
        essential_from_pose(p.R, p.t), p.intr1.normalized(p.x1), p.intr2.normalized(p.x2)
    )
    assert np.abs(R - p.R).max() < 1e-12 and np.abs(t - p.t).max() < 1e-12
    assert front.all()


def test_sampson_matches_opencv():
    p = make_pair(seed=4, n=50, noise_px=2.0)
    F = _gt_F(p)
    ours = sampson_sq(F, p.x1, p.x2)
    h1 = np.concatenate([p.x1, np.ones((50, 1))], 1)
    h2 = np.concatenate([p.x2, np.ones((50, 1))], 1)
    ref = np.array([cv2.sampsonDistance(a[:, None], b[:, None], F) for a, b in zip(h1, h2)])
    np.testing.assert_allclose(ours, ref, rtol=1e-9)
    np.testing.assert_allclose(
        sampson_sq_batch(np.stack([F, 2 * F]), p.x1, p.x2), np.stack([ours, ours]), rtol=1e-9
    )


def test_sampson_close_to_geometric_error_for_small_noise():
    # a single point moved off its epipolar line in image 2 only: Sampson ~ distance to the line
    p = make_pair(seed=5, n=30)
    F = _gt_F(p)
    lines = epipolar_lines(F, p.x1, which=2)
    x2 = p.x2 + 0.7 * lines[:, :2]
    assert np.allclose(np.hypot(lines[:, 0], lines[:, 1]), 1.0)
    d = sampson_distance(F, p.x1, x2)
    ratio = d / 0.7
    assert np.all(ratio < 1.0 + 1e-6) and np.all(ratio > 0.3)


def test_bad_point_arrays():
    with pytest.raises(InputError):
        as_points2(np.zeros((4, 3)))
    with pytest.raises(InputError):
        as_points2(np.array([[np.nan, 1.0]]))


def test_eight_point_agrees_with_opencv_on_noisy_data():
    p = make_pair(seed=6, n=300, noise_px=0.5)
    ours = fundamental_8point(p.x1, p.x2)
    cv, _ = cv2.findFundamentalMat(p.x1, p.x2, cv2.FM_8POINT)
    e_ours = np.sqrt(np.mean(sampson_sq(ours, p.x1_true, p.x2_true)))
    e_cv = np.sqrt(np.mean(sampson_sq(cv, p.x1_true, p.x2_true)))
    assert e_ours <= 1.05 * e_cv + 1e-6
