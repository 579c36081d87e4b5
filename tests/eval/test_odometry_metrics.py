"""Odometry metrics on trajectories with known perturbations."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core.rigid import Rigid3, rotvec_to_matrix
from skyrecon.errors import InputError
from skyrecon.eval.odometry_metrics import (
    ate_rmse,
    evaluate_odometry,
    kitti_drift,
    path_length,
    relative_pose_error,
)


def _curvy(n: int = 300, step: float = 1.0) -> list[Rigid3]:
    """A 3D flight: a wide turn with climbing, 1 m per frame, camera looking along the path."""
    poses = []
    for k in range(n):
        a = 0.01 * k
        p = np.array([60 * np.sin(a), 60 * (1 - np.cos(a)), 5 + 0.02 * k + np.sin(0.05 * k)]) * step
        poses.append(Rigid3(rotvec_to_matrix([0.0, 0.0, a]), p, "world", "left"))
    return poses


def _moved(poses: list[Rigid3], T: Rigid3) -> list[Rigid3]:
    return [T @ p for p in poses]


def test_ate_is_zero_for_a_rigidly_moved_copy():
    gt = _curvy()
    T = Rigid3(rotvec_to_matrix([0.1, -0.3, 1.2]), [10.0, -4.0, 2.0], "world", "world")
    est = _moved(gt, T)
    rmse, err, align = ate_rmse(est, gt)
    assert rmse < 1e-9 and err.max() < 1e-9
    assert np.allclose(align.R, T.R.T, atol=1e-9)


def test_ate_measures_known_noise_and_sim3_recovers_scale():
    gt = _curvy()
    rng = np.random.default_rng(0)
    noise = rng.normal(0, 0.5, (len(gt), 3))
    est = [Rigid3(p.R, p.t + e, "world", "left") for p, e in zip(gt, noise)]
    rmse, _, _ = ate_rmse(est, gt)
    # the alignment can absorb a little of the noise, never add to it
    assert (
        0.8 * np.sqrt(np.mean(np.sum(noise**2, axis=1))) < rmse <= np.sqrt(np.mean(np.sum(noise**2, axis=1)))
    )
    scaled = [Rigid3(p.R, 0.5 * p.t, "world", "left") for p in gt]
    assert ate_rmse(scaled, gt)[0] > 5.0
    rmse_s, _, T = ate_rmse(scaled, gt, with_scale=True)
    assert rmse_s < 1e-9 and T.scale == pytest.approx(2.0)


def test_straight_flight_aligns_without_failing():
    gt = [Rigid3(np.eye(3), [k * 1.0, 0, 0], "world", "left") for k in range(50)]
    est = [Rigid3(np.eye(3), [k * 1.0, 0.3, 0], "world", "left") for k in range(50)]
    rmse, _, _ = ate_rmse(est, gt)
    assert rmse < 1e-9  # a constant offset is absorbed by the alignment


def test_drift_of_a_scale_error_is_that_percentage():
    gt = _curvy(400)
    # 2 % too long everywhere: every relative motion's translation is 2 % too long
    est = [Rigid3(p.R, 1.02 * p.t, "world", "left") for p in gt]
    d = kitti_drift(est, gt)
    assert d["translation_pct"] == pytest.approx(2.0, rel=0.05)
    assert d["rotation_deg_per_100m"] == pytest.approx(0.0, abs=1e-6)
    assert set(d["per_length"]) == {"25", "50", "100"}
    rpe = relative_pose_error(est, gt, 100.0, "m")
    # 2 % of each 100 m sub-path's chord (shorter than its arc on this turning flight)
    assert 0.02 * 85 < rpe["trans_rmse_m"] < 0.02 * 100


def test_drift_from_a_heading_error_grows_with_distance():
    gt = [Rigid3(np.eye(3), [k * 1.0, 0, 0], "world", "left") for k in range(200)]
    yaw = np.radians(0.01)  # 0.01 degree of heading error per frame
    est, pose = [], Rigid3.identity("world", "left")
    step = Rigid3(rotvec_to_matrix([0, 0, yaw]), [1.0, 0, 0], "left", "left")
    for _ in range(200):
        est.append(pose)
        pose = pose @ step
    d = kitti_drift(est, gt)
    assert d["rotation_deg_per_100m"] == pytest.approx(1.0, rel=0.05)  # 0.01 deg/m
    assert d["translation_pct"] > 0.1
    assert d["per_length"]["100"]["translation_pct"] > d["per_length"]["25"]["translation_pct"]


def test_rpe_per_second_and_short_flights():
    gt = _curvy(60)
    t = np.arange(60) * 0.1
    est = [Rigid3(p.R, p.t + [0.0, 0.0, 0.01 * k], "world", "left") for k, p in enumerate(gt)]
    r = relative_pose_error(est, gt, 1.0, "s", t)
    assert r["pairs"] == 50 and r["trans_rmse_m"] == pytest.approx(0.1, rel=1e-6)
    short = relative_pose_error(est, gt, 100.0, "m")
    assert short["pairs"] == 0 and short["trans_rmse_m"] is None
    m = evaluate_odometry(est, gt, t)
    assert m.drift["per_length"]["100"]["segments"] == 0 and m.drift["segments"] > 0
    assert m.as_json()["rpe_1s"]["pairs"] == 50
    assert path_length(gt)[-1] == pytest.approx(m.path_length_m)


def test_mismatched_lengths_are_an_input_error():
    with pytest.raises(InputError):
        ate_rmse(_curvy(10), _curvy(11))
