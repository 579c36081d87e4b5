"""The odometry checked against the accelerometer: a slip is flagged within the window, healthy
odometry never is."""

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


def test_healthy_odometry_is_never_flagged():
    truth = _truth(150)
    rng = np.random.default_rng(0)
    odometry = truth + rng.normal(0.0, 0.01, truth.shape) + 0.002 * np.arange(150)[:, None]  # noise, drift
    check, verdicts = _fly(odometry, truth)
    assert check.slips == 0 and not any(v.slipping for v in verdicts)
    gaps = [v.disagreement_mps for v in verdicts if np.isfinite(v.disagreement_mps)]
    assert len(gaps) > 100 and max(gaps) < 0.6


def test_a_slip_is_flagged_within_the_window_until_a_window_agrees_again():
    truth = _truth(200)
    ramp = np.clip((np.arange(200) - 60) / 15.0, 0.0, 1.0)  # 6-7.5 s: the odometry slides 4 m away
    odometry = truth.copy()
    odometry[:, 1] += 4.0 * ramp**2
    check, verdicts = _fly(odometry, truth)
    assert check.slips == 1
    flagged = [k for k, v in enumerate(verdicts) if v.slipping]
    assert 60 < flagged[0] <= 68  # within 0.8 s of the slip's start
    assert flagged == list(range(flagged[0], flagged[-1] + 1))  # one stretch
    # the slip ends at 75; windows that hold it (span 3 + 10 frames), then a window of agreement
    assert flagged[-1] <= 75 + 3 + 10 + 10
    assert all("accelerometer" in verdicts[k].reason for k in flagged)
    assert not verdicts[-1].slipping and verdicts[-1].reason == ""


def test_bad_settings_and_time_going_back_are_refused():
    with pytest.raises(InputError):
        InertialCheckSettings(max_disagreement_mps=0.0)
    with pytest.raises(InputError):
        InertialCheckSettings(velocity_span=0)
    check = InertialCheck()
    check.update(0.0, np.zeros(3), np.zeros(3))
    with pytest.raises(InputError):
        check.update(0.0, np.zeros(3), np.zeros(3))
