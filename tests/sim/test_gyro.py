"""The simulated gyro: the true rotation between frames, with a bias and white noise of the stated size."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Rigid3
from skyrecon.core.rigid import rotation_angle_deg, rotvec_to_matrix
from skyrecon.errors import InputError
from skyrecon.sim.gyro import GyroSettings, SimulatedGyro


def _pose(yaw_rad: float) -> Rigid3:
    return Rigid3(rotvec_to_matrix(np.array([0.0, yaw_rad, 0.0])), np.zeros(3), "world", "cam")


def test_the_gyro_measures_the_turn_between_frames_within_its_noise():
    gyro = SimulatedGyro(seed=3)
    assert gyro.measure(0.0, _pose(0.0)) is None  # nothing to compare the first frame with
    errors = []
    for k in range(1, 200):
        measured = gyro.measure(0.1 * k, _pose(np.radians(9.0) * k))  # 90 deg/s
        true = _pose(np.radians(9.0) * (k - 1)).R.T @ _pose(np.radians(9.0) * k).R
        errors.append(rotation_angle_deg(measured.T @ true))
    s = GyroSettings()
    per_frame = np.hypot(s.bias_dps * 0.1, s.noise_density_dps_rthz * np.sqrt(0.1))
    assert 0 < np.median(errors) < 5 * per_frame  # a few thousandths of a degree per frame


def test_same_seed_same_measurements_and_time_must_move_on():
    a, b, c = SimulatedGyro(seed=1), SimulatedGyro(seed=1), SimulatedGyro(seed=2)
    for g in (a, b, c):
        g.measure(0.0, _pose(0.0))
    first = a.measure(0.1, _pose(0.2))
    assert np.array_equal(first, b.measure(0.1, _pose(0.2)))
    assert not np.array_equal(first, c.measure(0.1, _pose(0.2)))
    with pytest.raises(InputError):
        a.measure(0.1, _pose(0.3))  # not later than the last sample
    perfect = SimulatedGyro(GyroSettings(noise_density_dps_rthz=0.0, bias_dps=0.0))
    perfect.measure(0.0, _pose(0.0))
    assert rotation_angle_deg(perfect.measure(0.1, _pose(0.5)).T @ _pose(0.5).R) < 1e-9
