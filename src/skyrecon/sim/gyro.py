"""A simulated gyro for the camera: its rotation between two frames, as a flight controller has it.

Every multirotor's flight controller integrates a MEMS gyro at hundreds of hertz, and a gimbal
reports its angles; together they give the camera's rotation between two frames. The stereo
odometry uses it as its rotation prior (:meth:`skyrecon.odometry.engine.StereoOdometry.track`).

Error model, per axis of the camera frame (degrees, seconds): a constant bias drawn once per seed
(``bias_dps`` 1-sigma; what remains after the flight controller's at-rest calibration) plus white
rate noise of density ``noise_density_dps_rthz`` (a consumer MEMS gyro: 0.014 deg/s/sqrt(Hz)),
integrated over the frame interval ``dt``: the rotation vector error is ``bias dt + N(0,
density sqrt(dt))``. Deterministic in ``seed``; feed the frames in time order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyrecon.core.rigid import Rigid3, rotvec_to_matrix
from skyrecon.errors import InputError

__all__ = ["GyroSettings", "SimulatedGyro"]


@dataclass(frozen=True)
class GyroSettings:
    """Parameters of :class:`SimulatedGyro` (degrees per second; see the module docstring)."""

    noise_density_dps_rthz: float = 0.014
    bias_dps: float = 0.05

    def __post_init__(self) -> None:
        if not (self.noise_density_dps_rthz >= 0 and self.bias_dps >= 0):
            raise InputError("gyro noise density and bias must be at least 0")


class SimulatedGyro:
    """The camera's measured rotation between consecutive frames.

    Args:
        settings: the error model (:class:`GyroSettings`).
        seed: seeds the bias and the noise.
    """

    def __init__(self, settings: GyroSettings | None = None, seed: int = 0) -> None:
        self.settings = settings or GyroSettings()
        self._rng = np.random.default_rng([seed, 0x6790])
        self._bias = np.radians(self._rng.normal(0.0, self.settings.bias_dps, 3))
        self._last: tuple[float, np.ndarray] | None = None

    def measure(self, time_s: float, true_world_from_cam: Rigid3) -> np.ndarray | None:
        """``cam_prev_from_cam_now`` (3, 3) with the gyro's error since the previous call, or None
        at the first call (nothing to compare with).

        Args:
            time_s: the frame's time, seconds, increasing.
            true_world_from_cam: the camera's true pose now (only its rotation is used).
        """
        R_now = np.asarray(true_world_from_cam.R, dtype=np.float64)
        last, self._last = self._last, (float(time_s), R_now.copy())
        if last is None:
            return None
        t_prev, R_prev = last
        dt = float(time_s) - t_prev
        if not dt > 0:
            raise InputError(f"gyro samples must move forward in time, got {time_s} after {t_prev}")
        sigma = math.radians(self.settings.noise_density_dps_rthz) * math.sqrt(dt)
        err = self._bias * dt + self._rng.normal(0.0, sigma, 3)
        return (R_prev.T @ R_now) @ rotvec_to_matrix(err)
