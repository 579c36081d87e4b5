"""The loop flies on its believed pose: frames of the pose sources and missions with a wrong belief."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyrecon.core import Rigid3
from skyrecon.mission import make_scenario, run_mission
from skyrecon.mission.pose_source import (
    PoseReading,
    TruthPose,
    believed_state,
    est_from_true,
    true_step,
    yaw_of,
)
from skyrecon.mission.vehicle import DroneState
from skyrecon.odometry.types import TrackingState


def _yaw_shift(yaw_rad: float, t) -> Rigid3:
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return Rigid3(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), np.asarray(t, float), "est", "world")


def test_believed_state_and_true_step_agree():
    E = _yaw_shift(0.1, [2.0, -1.0, 0.5])
    true = DroneState(np.array([10.0, 5.0, 15.0]), np.array([3.0, 0.0, 0.0]), 0.3, 0.1, 2.0)
    wfl = true.cam_from_world().inverse().with_frames("world", "left")
    est_wfl = (E @ wfl.with_frames("world", "left")).with_frames("world", "left")
    E2 = est_from_true(est_wfl, wfl)
    assert E2.allclose(E, atol=1e-9)
    b = believed_state(true, E2)
    assert np.allclose(b.position, E.apply(true.position[None])[0])
    assert math.isclose(b.yaw, 0.4, abs_tol=1e-9) and math.isclose(yaw_of(E.R), 0.1, abs_tol=1e-12)
    # the believed camera is the estimated camera
    assert b.cam_from_world().inverse().allclose(est_wfl.with_frames("world", "cam"), atol=1e-9)
    nb = DroneState(
        b.position + np.array([0.5, 0.2, 0.0]), np.array([2.0, 1.0, 0.0]), b.yaw + 0.05, 0.12, 2.1
    )
    t2 = true_step(true, b, nb, E2)
    # the step seen from the estimated world is the commanded one
    assert np.allclose(E.apply(t2.position[None])[0], nb.position)
    assert np.allclose(E.R @ t2.velocity, nb.velocity)
    assert math.isclose(t2.yaw, 0.35, abs_tol=1e-9) and t2.pitch_down == 0.12 and t2.time_s == 2.1


class _OffsetPose:
    """Believes the drone is ``offset`` metres away from where it is (a biased estimate)."""

    name = "biased"

    def __init__(self, offset, state=TrackingState.OK):
        self.offset = np.asarray(offset, float)
        self.state = state

    def read(self, left, right, time_s, disparity_px, true_world_from_left):
        est = Rigid3(true_world_from_left.R, true_world_from_left.t + self.offset, "world", "left")
        return PoseReading(est, self.state, "" if self.state == TrackingState.OK else "test")


def test_truth_source_flies_as_before(tiny_config):
    sc = make_scenario(1, tiny_config)
    a = run_mission(sc, tiny_config)
    b = run_mission(sc, tiny_config, pose_source=TruthPose())
    assert a.success and np.array_equal(a.flown_path(), b.flown_path())
    assert all(r.est_position is None and r.pose_state == "ok" for r in a.records)


def test_a_biased_belief_misses_the_goal_and_collisions_are_judged_on_truth(tiny_config):
    sc = make_scenario(1, tiny_config)
    r = run_mission(sc, tiny_config, pose_source=_OffsetPose([0.0, 0.0, 3.0]))
    # it believes it arrived: the true end lies 3 m below the goal, beyond the delivery tolerance
    assert not r.success and r.reason in ("missed_goal", "collision")
    if r.reason == "missed_goal":
        assert np.linalg.norm(r.final_est_position - sc.goal) <= tiny_config.arrival_tolerance_m
        assert np.linalg.norm(r.final_position - sc.goal) == pytest.approx(3.0, abs=1.1)
    assert all(rec.pose_error_m == pytest.approx(3.0, abs=1e-6) for rec in r.records)
    small = run_mission(sc, tiny_config, pose_source=_OffsetPose([0.0, 0.6, 0.0]))
    assert small.success and small.collisions == 0


def test_a_lost_pose_hovers_without_mapping(tiny_config):
    cfg = tiny_config.with_overrides(time_limit_s=3.0)
    r = run_mission(make_scenario(1, cfg), cfg, pose_source=_OffsetPose([0, 0, 0], TrackingState.LOST))
    assert not r.success and r.reason == "timeout"
    assert max(rec.speed_mps for rec in r.records) == 0.0
    assert r.occ_map.counts()["occupied"] == 0 and all(rec.pose_state == "lost" for rec in r.records)


def test_a_degraded_pose_caps_the_speed(tiny_config):
    cfg = tiny_config.with_overrides(degraded_speed_mps=1.5)
    r = run_mission(make_scenario(1, cfg), cfg, pose_source=_OffsetPose([0, 0, 0], TrackingState.DEGRADED))
    assert max(rec.speed_mps for rec in r.records) <= 1.5 + 1e-6


class _LostAtFirst(_OffsetPose):
    """Lost for the first ``n`` frames, then exact."""

    def __init__(self, n):
        super().__init__([0.0, 0.0, 0.0])
        self.n, self.calls = n, 0

    def read(self, left, right, time_s, disparity_px, true_world_from_left):
        self.calls += 1
        self.state = TrackingState.LOST if self.calls <= self.n else TrackingState.OK
        return super().read(left, right, time_s, disparity_px, true_world_from_left)


def test_a_lasting_loss_looks_around_then_flies_on(tiny_config):
    sc = make_scenario(1, tiny_config)
    r = run_mission(sc, tiny_config, pose_source=_LostAtFirst(25))
    lost = r.records[:25]
    assert all(rec.speed_mps == 0.0 for rec in lost)
    # after a second lost it turns to find texture (45 degrees a second), not staring at one view
    turned = abs(math.remainder(lost[-1].yaw - lost[0].yaw, 2 * math.pi))
    assert turned > math.radians(40)
    assert r.success and r.collisions == 0


def test_an_odometry_slip_is_caught_by_the_accelerometer_and_reported_degraded():
    """The odometry pose source with its engine slipping sideways while it says "ok": the reading
    says degraded, why, and keeps the odometry's pose; without the check it says ok."""
    from types import SimpleNamespace

    from skyrecon.mission.pose_source import OdometryPose
    from skyrecon.sim import default_rig

    rig = default_rig(64, 48, baseline_m=0.3)
    frame = np.zeros((48, 64, 3), np.uint8)

    def fly(inertial: bool) -> list[tuple[PoseReading, np.ndarray]]:
        source = OdometryPose(rig, Rigid3(), seed=1, inertial=inertial)
        out = []
        for k in range(60):
            t = 0.1 * k
            true = Rigid3(np.eye(3), np.array([2.0 * t, 0.0, 10.0]), "world", "left")  # 2 m/s along x
            slip = np.array([0.0, 3.0 * max(0.0, t - 3.0) ** 2, 0.0])  # from 3 s: sliding off along y
            est = SimpleNamespace(
                world_from_left=Rigid3(np.eye(3), true.t + slip), state=TrackingState.OK, reason=""
            )
            source.odometry = SimpleNamespace(track=lambda *a, est=est: est)
            out.append((source.read(frame, frame, t, None, true), true.t + slip))
        return out

    checked = fly(True)
    assert all(r.state is TrackingState.OK for r, _ in checked[:30])  # before the slip: as given
    assert all(r.state is TrackingState.DEGRADED and "accelerometer" in r.reason for r, _ in checked[38:])
    assert all(np.array_equal(r.world_from_left.t, odo) for r, odo in checked)  # the odometry's pose
    assert all(r.state is TrackingState.OK for r, _ in fly(False))
