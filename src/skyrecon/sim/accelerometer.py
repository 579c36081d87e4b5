"""A simulated accelerometer: the camera's change of velocity between two frames, as a flight
controller integrates it.

Every multirotor's flight controller integrates a MEMS accelerometer at hundreds of hertz and,
knowing its attitude and gravity, has the change of the vehicle's velocity between two camera
frames to a few centimetres per second. It cannot give the velocity itself for long (the errors
integrate twice), but over a second it is a good check of what the visual odometry says
(:class:`skyrecon.mission.inertial.InertialCheck`).

Error model, per axis of the world frame (metres, seconds): a constant bias drawn once per seed
(``bias_mps2`` 1-sigma; a consumer MEMS accelerometer after its calibration, about 5 mg, with the
attitude's error folded in) plus white noise of density ``noise_density_mps2_rthz`` (300 ug per
root hertz) integrated over the frame interval ``dt``: the velocity-change error is ``bias dt +
N(0, density sqrt(dt))``. The true change is that of the finite-difference velocity of the poses
given (the same frames the odometry sees). Deterministic in ``seed``; feed the frames in time order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError

__all__ = ["AccelerometerSettings", "SimulatedAccelerometer"]


@dataclass(frozen=True)
class AccelerometerSettings:
    """Parameters of :class:`SimulatedAccelerometer` (metres per second squared; see the module)."""

    noise_density_mps2_rthz: float = 0.003
    bias_mps2: float = 0.05

    def __post_init__(self) -> None:
        if not (self.noise_density_mps2_rthz >= 0 and self.bias_mps2 >= 0):
            raise InputError("accelerometer noise density and bias must be at least 0")


class SimulatedAccelerometer:
    """The camera's measured change of velocity between consecutive frames.

    Args:
        settings: the error model (:class:`AccelerometerSettings`).
        seed: seeds the bias and the noise.
    """

    def __init__(self, settings: AccelerometerSettings | None = None, seed: int = 0) -> None:
        self.settings = settings or AccelerometerSettings()
        self._rng = np.random.default_rng([seed, 0xACC])
        self._bias = self._rng.normal(0.0, self.settings.bias_mps2, 3)
        self._last: tuple[float, np.ndarray] | None = None
        self._velocity: np.ndarray | None = None

    def velocity_change(self, time_s: float, true_world_from_cam: Rigid3) -> np.ndarray | None:
        """(3,) change of the camera's velocity since the previous frame, world frame, m/s, with
        the accelerometer's error; None for the first two frames (no velocity to change yet).

        Args:
            time_s: the frame's time, seconds, increasing.
            true_world_from_cam: the camera's true pose now (only its position is used).
        """
        p_now = np.asarray(true_world_from_cam.t, dtype=np.float64).copy()
        last, self._last = self._last, (float(time_s), p_now)
        if last is None:
            return None
        t_prev, p_prev = last
        dt = float(time_s) - t_prev
        if not dt > 0:
            raise InputError(f"accelerometer samples must move forward in time, got {time_s} after {t_prev}")
        v_now = (p_now - p_prev) / dt
        v_prev, self._velocity = self._velocity, v_now
        if v_prev is None:
            return None
        sigma = self.settings.noise_density_mps2_rthz * math.sqrt(dt)
        return v_now - v_prev + self._bias * dt + self._rng.normal(0.0, sigma, 3)
