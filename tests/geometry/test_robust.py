"""Robust estimators against exact synthetic geometry and against OpenCV on the same data."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from skyrecon.core import rotvec_to_matrix
from skyrecon.errors import EstimationError, InputError
from skyrecon.eval.pose_metrics import rotation_error_deg, translation_direction_error_deg
from skyrecon.geometry.epipolar import essential_from_pose, sampson_sq
from skyrecon.geometry.essential import estimate_relative_pose
from skyrecon.geometry.fundamental import estimate_fundamental, fundamental_7point_batch
from skyrecon.geometry.homography import (
    decompose_homography,
    estimate_homography,
    homography_dlt,
    homography_transfer_sq,
)
from skyrecon.geometry.refine import refine_relative_pose
from skyrecon.geometry.sampling import RansacOptions, draw_samples, required_iterations
from tests.geometry.synthetic import make_pair


def _opencv_pose(p, threshold=1.0):
    K = p.intr1.K
    E, mask = cv2.findEssentialMat(p.x1, p.x2, K, method=cv2.RANSAC, prob=0.999, threshold=threshold)
    _, R, t, _ = cv2.recoverPose(E[:3], p.x1, p.x2, K, mask=mask)
    return R, t.ravel()


def _errors(R, t, p):
    return rotation_error_deg(R, p.R), translation_direction_error_deg(t, p.t)


def test_exact_data_gives_machine_precision():
    p = make_pair(seed=0, n=100)
    r = estimate_relative_pose(p.x1, p.x2, p.intr1, p.intr2, RansacOptions(threshold=1.0), seed=0)
    er, et = _errors(r.R, r.t, p)
    assert er < 1e-8 and et < 1e-8
    assert r.inliers.all()


def test_better_than_opencv_with_noise_and_outliers():
    ours, cv = [], []
    for seed in range(8):
        p = make_pair(seed=seed, n=400, noise_px=0.7, outlier_ratio=0.3, depth=(5, 30))
        r = estimate_relative_pose(p.x1, p.x2, p.intr1, p.intr2, RansacOptions(threshold=1.0), seed=seed)
        ours.append(_errors(r.R, r.t, p))
        cv.append(_errors(*_opencv_pose(p), p))
        # the outliers are found
        assert np.mean(r.inliers[p.outlier]) < 0.05
        assert np.mean(r.inliers[~p.outlier]) > 0.75  # Sampson sigma ~ 1 px at 0.7 px noise per image
    ours, cv = np.array(ours), np.array(cv)
    assert np.median(ours[:, 0]) <= np.median(cv[:, 0])
    assert np.median(ours[:, 1]) <= np.median(cv[:, 1])
    assert ours[:, 0].max() < 0.3 and ours[:, 1].max() < 2.0


def test_planar_scene():
    p = make_pair(seed=3, n=300, noise_px=0.5, outlier_ratio=0.2, planar=True)
    r = estimate_relative_pose(p.x1, p.x2, p.intr1, p.intr2, RansacOptions(threshold=1.0), seed=1)
    er, et = _errors(r.R, r.t, p)
    assert er < 0.2 and et < 2.0


def test_small_baseline_rotation_still_accurate():
    res = []
    for seed in range(4):
        p = make_pair(seed=seed, n=400, noise_px=0.5, outlier_ratio=0.2, baseline=0.05)
        r = estimate_relative_pose(p.x1, p.x2, p.intr1, p.intr2, RansacOptions(threshold=1.0), seed=seed)
        res.append((_errors(r.R, r.t, p), _errors(*_opencv_pose(p), p)))
    ours = np.array([a for a, _ in res])
    cv = np.array([b for _, b in res])
    assert np.median(ours[:, 0]) < 0.05
    assert np.median(ours[:, 0]) <= np.median(cv[:, 0]) * 1.1


def test_deterministic_for_a_seed():
    p = make_pair(seed=9, n=300, noise_px=1.0, outlier_ratio=0.4)
    a = estimate_relative_pose(p.x1, p.x2, p.intr1, p.intr2, seed=5)
    b = estimate_relative_pose(p.x1, p.x2, p.intr1, p.intr2, seed=5)
    assert np.array_equal(a.R, b.R) and np.array_equal(a.inliers, b.inliers)


def test_relative_pose_input_errors():
    p = make_pair(seed=0, n=4)
    with pytest.raises(EstimationError):
        estimate_relative_pose(p.x1, p.x2, p.intr1, p.intr2)
    with pytest.raises(InputError):
        estimate_relative_pose(p.x1, p.x2[:3], p.intr1, p.intr2)
    with pytest.raises(InputError):
        RansacOptions(threshold=-1)


@pytest.mark.parametrize("method", ["ransac", "lmeds", "magsac"])
def test_fundamental_robust_methods_vs_opencv(method):
    p = make_pair(seed=2, n=500, noise_px=0.5, outlier_ratio=0.3)
    est = estimate_fundamental(p.x1, p.x2, method, RansacOptions(threshold=1.0), seed=0)
    cv_flag = {"ransac": cv2.FM_RANSAC, "lmeds": cv2.FM_LMEDS, "magsac": cv2.USAC_MAGSAC}[method]
    F_cv, _ = cv2.findFundamentalMat(p.x1, p.x2, cv_flag, 1.0, 0.999)
    inl = ~p.outlier
    e_ours = np.sqrt(np.mean(sampson_sq(est.F, p.x1_true[inl], p.x2_true[inl])))
    e_cv = np.sqrt(np.mean(sampson_sq(F_cv[:3], p.x1_true[inl], p.x2_true[inl])))
    assert e_ours < 0.3  # pixels, against the exact projections
    assert e_ours <= 1.5 * e_cv + 0.02
    assert np.mean(est.inliers[p.outlier]) < 0.1


def test_fundamental_direct_methods():
    p = make_pair(seed=4, n=30)
    for method in ("8point", "7point"):
        est = estimate_fundamental(p.x1, p.x2, method)
        assert np.sqrt(np.mean(sampson_sq(est.F, p.x1[:7], p.x2[:7]))) < 1e-6
    est = estimate_fundamental(p.x1[:7], p.x2[:7], "7point")
    assert len(est.candidates) in (1, 3)
    with pytest.raises(InputError):
        estimate_fundamental(p.x1, p.x2, "9point")  # type: ignore[arg-type]
    with pytest.raises(EstimationError):
        estimate_fundamental(p.x1[:7], p.x2[:7], "ransac")


def test_seven_point_batch_finds_the_truth():
    p = make_pair(seed=7, n=7 * 6)
    Fs, idx = fundamental_7point_batch(p.x1.reshape(6, 7, 2), p.x2.reshape(6, 7, 2))
    Fgt = np.linalg.inv(p.intr2.K).T @ essential_from_pose(p.R, p.t) @ np.linalg.inv(p.intr1.K)
    Fgt /= np.linalg.norm(Fgt)
    for k in range(6):
        d = [min(np.abs(F - Fgt).max(), np.abs(F + Fgt).max()) for F in Fs[idx == k]]
        assert min(d) < 1e-8


def test_homography_exact_and_robust():
    p = make_pair(seed=5, n=200, planar=True)
    H = homography_dlt(p.x1, p.x2)
    assert np.sqrt(homography_transfer_sq(H, p.x1, p.x2)).max() < 1e-7
    q = make_pair(seed=5, n=300, planar=True, noise_px=0.5, outlier_ratio=0.3)
    est = estimate_homography(q.x1, q.x2, RansacOptions(threshold=2.0), seed=0)
    assert np.mean(est.inliers[~q.outlier]) > 0.9 and np.mean(est.inliers[q.outlier]) < 0.05
    Hcv, _ = cv2.findHomography(q.x1, q.x2, cv2.RANSAC, 2.0)
    inl = ~q.outlier
    e_ours = np.sqrt(np.mean(homography_transfer_sq(est.H, q.x1_true[inl], q.x2_true[inl])))
    e_cv = np.sqrt(np.mean(homography_transfer_sq(Hcv, q.x1_true[inl], q.x2_true[inl])))
    assert e_ours <= 1.2 * e_cv + 0.02


def test_refinement_converges_to_the_truth():
    p = make_pair(seed=8, n=80)
    x1n, x2n = p.intr1.normalized(p.x1), p.intr2.normalized(p.x2)
    R0 = rotvec_to_matrix([0.01, -0.02, 0.015]) @ p.R
    t0 = p.t + np.array([0.05, -0.03, 0.02])
    for loss in ("trivial", "cauchy", "huber"):
        r = refine_relative_pose(R0, t0, x1n, x2n, loss=loss, loss_scale=1e-3, max_iterations=100)
        assert rotation_error_deg(r.R, p.R) < 1e-7
        assert translation_direction_error_deg(r.t, p.t) < 1e-6
        assert r.final_cost < r.initial_cost


def test_sampling_helpers():
    rng = np.random.default_rng(0)
    s = draw_samples(rng, 1000, 5, 200)
    assert s.shape == (200, 5) and all(len(set(r)) == 5 for r in s.tolist())
    s = draw_samples(rng, 6, 5, 50)
    assert all(len(set(r)) == 5 for r in s.tolist())
    assert required_iterations(1.0, 5, 0.99, 100) == 1
    assert required_iterations(0.0, 5, 0.99, 100) == 100
    assert 10 < required_iterations(0.5, 5, 0.99, 10000) < 200


def test_homography_decomposition_contains_the_true_motion():
    p = make_pair(seed=6, n=100, planar=True)
    H = homography_dlt(p.x1, p.x2)
    sols = decompose_homography(H, p.intr1.K, p.intr2.K, p.intr1.normalized(p.x1), p.intr2.normalized(p.x2))
    assert 1 <= len(sols) <= 2
    best = min(rotation_error_deg(R, p.R) + translation_direction_error_deg(t, p.t) for R, t, _ in sols)
    assert best < 1e-6
    # a pure rotation decomposes into that rotation and no translation
    Hr = p.intr2.K @ p.R @ np.linalg.inv(p.intr1.K)
    sols = decompose_homography(Hr, p.intr1.K, p.intr2.K)
    assert len(sols) == 1 and rotation_error_deg(sols[0][0], p.R) < 1e-6 and np.linalg.norm(sols[0][1]) == 0


def test_planar_scene_twin_is_rejected_by_cheirality():
    # every seed must give the true pose on a plane, not its twin (MSAC counts points behind a camera as outliers)
    p = make_pair(seed=7, n=300, noise_px=0.5, planar=True)
    for seed in range(6):
        r = estimate_relative_pose(p.x1, p.x2, p.intr1, p.intr2, RansacOptions(threshold=1.0), seed=seed)
        assert rotation_error_deg(r.R, p.R) < 0.3
