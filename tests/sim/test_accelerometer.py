"""The simulated accelerometer: the true change of velocity between frames, with a bias and white
noise of the stated size."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Rigid3
from skyrecon.errors import InputError
from skyrecon.sim.accelerometer import AccelerometerSettings, SimulatedAccelerometer


def _at(p) -> Rigid3:
    return Rigid3(np.eye(3), np.asarray(p, np.float64), "world", "cam")


def test_the_accelerometer_measures_the_change_of_velocity_within_its_noise():
    acc = SimulatedAccelerometer(seed=3)
    dt, a = 0.1, np.array([2.0, -1.0, 0.5])  # constant acceleration, m/s^2
    pos = [0.5 * a * (k * dt) ** 2 for k in range(100)]
    assert acc.velocity_change(0.0, _at(pos[0])) is None  # no velocity yet
    assert acc.velocity_change(dt, _at(pos[1])) is None  # one velocity, no change yet
    errors = [np.linalg.norm(acc.velocity_change(k * dt, _at(pos[k])) - a * dt) for k in range(2, 100)]
    s = AccelerometerSettings()
    per_frame = np.sqrt(3) * np.hypot(s.bias_mps2 * dt, s.noise_density_mps2_rthz * np.sqrt(dt))
    assert 0 < np.median(errors) < 5 * per_frame  # a centimetre per second or less per frame


def test_same_seed_same_measurements_and_time_must_move_on():
    a, b, c = SimulatedAccelerometer(seed=1), SimulatedAccelerometer(seed=1), SimulatedAccelerometer(seed=2)
    for acc in (a, b, c):
        acc.velocity_change(0.0, _at([0, 0, 0]))
        acc.velocity_change(0.1, _at([0.1, 0, 0]))
    first = a.velocity_change(0.2, _at([0.3, 0, 0]))
    assert np.array_equal(first, b.velocity_change(0.2, _at([0.3, 0, 0])))
    assert not np.array_equal(first, c.velocity_change(0.2, _at([0.3, 0, 0])))
    with pytest.raises(InputError):
        a.velocity_change(0.2, _at([0.4, 0, 0]))  # not later than the last sample
    perfect = SimulatedAccelerometer(AccelerometerSettings(noise_density_mps2_rthz=0.0, bias_mps2=0.0))
    for k, x in enumerate([0.0, 0.1, 0.3]):
        dv = perfect.velocity_change(0.1 * k, _at([x, 0, 0]))
    assert np.allclose(dv, [1.0, 0.0, 0.0])
