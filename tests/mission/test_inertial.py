"""The odometry checked against the accelerometer: slips are dead-reckoned over, healthy
odometry passes through untouched."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Rigid3
from skyrecon.errors import InputError
from skyrecon.mission.inertial import InertialCheck, InertialCheckSettings
from skyrecon.sim.accelerometer import SimulatedAccelerometer

DT = 0.1


def _truth(n: int) -> np.ndarray:
    """(n, 3) a drone accelerating to 3 m/s along x, then turning left at a constant speed."""
    t = np.arange(n) * DT
    speed = np.minimum(3.0, 1.5 * t)
    heading = np.where(t > 4.0, 0.3 * (t - 4.0), 0.0)
    v = np.column_stack([speed * np.cos(heading), speed * np.sin(heading), np.zeros(n)])
    return np.cumsum(v * DT, axis=0)


def _fly(odometry: np.ndarray, truth: np.ndarray, settings=None):
    check, acc = InertialCheck(settings), SimulatedAccelerometer(seed=4)
    verdicts = []
    for k, (p_odo, p_true) in enumerate(zip(odometry, truth)):
        dv = acc.velocity_change(k * DT, Rigid3(np.eye(3), p_true))
        verdicts.append(check.update(k * DT, p_odo, dv))
    return check, verdicts


def test_healthy_odometry_passes_through_untouched():
    truth = _truth(150)
    rng = np.random.default_rng(0)
    odometry = truth + rng.normal(0.0, 0.01, truth.shape) + 0.002 * np.arange(150)[:, None]  # noise, drift
    check, verdicts = _fly(odometry, truth)
    assert check.slips == 0
    assert all(np.array_equal(v.position, p) for v, p in zip(verdicts, odometry))
    assert not any(v.dead_reckoning for v in verdicts)
    gaps = [v.disagreement_mps for v in verdicts if np.isfinite(v.disagreement_mps)]
    assert len(gaps) > 100 and max(gaps) < 0.6


def test_a_slip_is_dead_reckoned_over_and_the_odometry_trusted_again_once_it_agrees():
    truth = _truth(200)
    slip = np.zeros_like(truth)
    ramp = np.clip((np.arange(200) - 60) / 15.0, 0.0, 1.0)  # 6-7.5 s: the odometry slides 4 m away
    slip[:, 1] = 4.0 * ramp**2
    odometry = truth + slip
    check, verdicts = _fly(odometry, truth)
    assert check.slips == 1
    flagged = [k for k, v in enumerate(verdicts) if v.dead_reckoning]
    assert flagged and 60 < flagged[0] <= 70  # caught within 1 s of the slip's start
    assert all("accelerometer" in verdicts[k].reason for k in flagged)
    errors = np.array([np.linalg.norm(v.position - p) for v, p in zip(verdicts, truth)])
    # the slip (4 m) never reached the flown position: only the dead reckoning's own drift did
    # (this seed's accelerometer bias is 0.13 m/s^2 along x: 0.5 b t^2, 0.7 m over 3.4 s)
    assert errors.max() < 1.0
    # the slip over, the odometry agrees again: trusted, with the offset the dead reckoning left
    assert not verdicts[-1].dead_reckoning and not verdicts[-1].lost
    assert np.allclose(verdicts[-1].position - odometry[-1], verdicts[-2].position - odometry[-2])


def test_a_lasting_disagreement_reports_the_pose_lost():
    truth = _truth(120)
    odometry = truth.copy()
    odometry[50:, 2] += 2.0 * (np.arange(70) * DT) ** 2  # accelerating away upwards, for good
    _, verdicts = _fly(odometry, truth, InertialCheckSettings(max_dead_reckoning_s=2.0))
    lost = [k for k, v in enumerate(verdicts) if v.lost]
    assert lost and all(verdicts[k].dead_reckoning for k in lost)
    first_flag = next(k for k, v in enumerate(verdicts) if v.dead_reckoning)
    assert lost[0] * DT > first_flag * DT + 1.0 - 1e-9  # lost only after a while of dead reckoning


def test_bad_settings_and_time_going_back_are_refused():
    with pytest.raises(InputError):
        InertialCheckSettings(recover_mps=2.0, max_disagreement_mps=1.0)
    with pytest.raises(InputError):
        InertialCheckSettings(velocity_span=0)
    check = InertialCheck()
    check.update(0.0, np.zeros(3), np.zeros(3))
    with pytest.raises(InputError):
        check.update(0.0, np.zeros(3), np.zeros(3))
