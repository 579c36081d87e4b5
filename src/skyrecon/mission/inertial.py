"""The odometry checked against the flight controller's accelerometer.

Visual odometry can go wrong while it says all is well: with a noisy camera turned up to a plain
sky, the delivery demo's odometry read the noise's "corners" as features and its position went
9 m off in 2 s, every frame "ok" (fixed at its cause since, see
``OdometrySettings.corner_noise_factor``; smaller slips, 0.2-1.1 m in 0.3 s, remained on noisy
missions). A flight controller knows better over a second: its accelerometer gives the change of
velocity between frames to a few centimetres per second (:mod:`skyrecon.sim.accelerometer`).

:class:`InertialCheck` compares, each frame, how much the odometry's velocity changed over the
last ``window_s`` with how much the accelerometer says it changed (velocities are finite
differences over ``velocity_span`` frames, the accelerometer's changes averaged the same way).
When they differ by more than ``max_disagreement_mps`` the odometry is *slipping*: the pose
source reports its pose degraded (the loop slows down) until a whole window after the last
disagreement agrees again. The check only judges; the position stays the odometry's.

Replacing the position by dead reckoning from before the slip was built and flown, and left: the
accelerometer cannot see a velocity error that builds up over more than the window, so the dead
reckoning started from a velocity the slow slip had already spoiled; on one of ten noisy
odometry missions (seed 7) the drone, hovering with that velocity in its belief, drifted in its
own mind at 1.6 m/s, stayed lost, and later flew into the ground. Without it the mission
delivered.

On the ten noisy odometry missions of ``benchmarks/mission`` (1.5 grey levels, the corner floor
at a factor of 1) the disagreement stayed under 0.62 m/s except at two slips (1.2 and 3.1 m/s);
the demo's 9 m failure read 7-9 m/s. Noise-free flights: nothing flagged.

Frames: positions and velocity changes in the estimated world (the odometry's), metres, m/s,
seconds.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from skyrecon.errors import InputError

__all__ = ["InertialCheckSettings", "InertialVerdict", "InertialCheck"]


@dataclass(frozen=True)
class InertialCheckSettings:
    """How :class:`InertialCheck` judges the odometry (see the module docstring).

    Attributes:
        window_s: the span over which velocity changes are compared, seconds.
        velocity_span: frames over which a velocity is differenced (a single frame's odometry
            step carries a few centimetres of noise: 0.25 m/s at 10 Hz).
        max_disagreement_mps: the odometry's velocity change may differ from the accelerometer's
            by this much over a window, m/s.
    """

    window_s: float = 1.0
    velocity_span: int = 3
    max_disagreement_mps: float = 1.0

    def __post_init__(self) -> None:
        if not (self.window_s > 0 and self.velocity_span >= 1 and self.max_disagreement_mps > 0):
            raise InputError("window_s and max_disagreement_mps must be positive, velocity_span at least 1")


@dataclass
class InertialVerdict:
    """One frame's verdict.

    Attributes:
        disagreement_mps: how far the odometry's velocity change over the window ending at this
            frame differs from the accelerometer's, m/s; NaN before a window has been seen.
        slipping: the odometry disagreed within the last window.
        reason: why (empty when it is not slipping).
    """

    disagreement_mps: float
    slipping: bool = False
    reason: str = ""


class InertialCheck:
    """Checks the odometry's positions against the accelerometer's velocity changes, frame by
    frame (see the module docstring).

    Args:
        settings: :class:`InertialCheckSettings` (None: the defaults).
    """

    def __init__(self, settings: InertialCheckSettings | None = None) -> None:
        self.settings = settings or InertialCheckSettings()
        s = self.settings
        # per frame: time, odometry position, cumulative velocity change of the accelerometer
        n = 2 * (s.velocity_span + 1) + int(np.ceil(s.window_s * 100))
        self._t: deque[float] = deque(maxlen=n)
        self._odo: deque[np.ndarray] = deque(maxlen=n)
        self._cum: deque[np.ndarray] = deque(maxlen=n)
        self._last_disagreement: tuple[float, float] | None = None  # (time, m/s)
        self.slips = 0  # times a slip started

    def _velocity_at(self, i: int) -> np.ndarray:
        k = self.settings.velocity_span
        return (self._odo[i] - self._odo[i - k]) / (self._t[i] - self._t[i - k])

    def _mean_change_at(self, i: int) -> np.ndarray:
        """The cumulative velocity change averaged over the frames of the velocity at ``i``."""
        k = self.settings.velocity_span
        dt = np.array([self._t[m] - self._t[m - 1] for m in range(i - k + 1, i + 1)])
        cum = np.array([self._cum[m] for m in range(i - k + 1, i + 1)])
        return (cum * dt[:, None]).sum(axis=0) / dt.sum()

    def _window_start(self) -> int | None:
        """Index of the latest frame at least ``window_s`` before the newest with a velocity."""
        i = len(self._t) - 1
        k = self.settings.velocity_span
        for j in range(i - 1, k - 1, -1):
            if self._t[i] - self._t[j] >= self.settings.window_s - 1e-9:
                return j
        return None

    def update(
        self, time_s: float, odometry_position: np.ndarray, velocity_change: np.ndarray | None
    ) -> InertialVerdict:
        """Judge one frame.

        Args:
            time_s: the frame's time, seconds, increasing.
            odometry_position: (3,) the odometry's position of this frame, metres.
            velocity_change: (3,) the accelerometer's velocity change since the previous frame,
                m/s, in the odometry's world; None when it has none yet (the history restarts).
        Returns:
            :class:`InertialVerdict`.
        """
        s = self.settings
        if velocity_change is None:
            for history in (self._t, self._odo, self._cum):
                history.clear()
            return InertialVerdict(float("nan"))
        if self._t and not time_s > self._t[-1]:
            raise InputError(
                f"inertial check: frames must move forward in time, got {time_s} after {self._t[-1]}"
            )
        cum = (self._cum[-1] if self._cum else np.zeros(3)) + np.asarray(velocity_change, np.float64)
        self._t.append(float(time_s))
        self._odo.append(np.asarray(odometry_position, np.float64).reshape(3).copy())
        self._cum.append(cum)
        i = len(self._t) - 1
        j = self._window_start()
        gap = float("nan")
        if j is not None:
            dv_odo = self._velocity_at(i) - self._velocity_at(j)
            dv_acc = self._mean_change_at(i) - self._mean_change_at(j)
            gap = float(np.linalg.norm(dv_odo - dv_acc))
            if gap > s.max_disagreement_mps:
                last = self._last_disagreement
                self.slips += last is None or time_s - last[0] >= s.window_s - 1e-9
                self._last_disagreement = (float(time_s), gap)
        last = self._last_disagreement
        if last is None or time_s - last[0] >= s.window_s - 1e-9:
            return InertialVerdict(gap)
        reason = (
            f"the odometry disagrees with the accelerometer: its velocity changed {last[1]:.1f} m/s "
            f"more or less than the accelerometer's over {s.window_s:g} s"
        )
        return InertialVerdict(gap, True, reason)
