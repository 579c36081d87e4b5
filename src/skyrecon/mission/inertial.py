"""The odometry checked against the flight controller's accelerometer.

Visual odometry can go wrong while it says all is well: with a noisy camera turned up to a plain
sky, the delivery demo's odometry read the noise's "corners" as features and its position went
9 m off in 2 s, every frame "ok" (fixed at its cause since, see
``OdometrySettings.corner_noise_factor``; smaller slips of 0.2-1.1 m in 0.3 s remained on noisy
missions). A flight controller knows better over a second: its accelerometer gives the change of
velocity between frames to a few centimetres per second (:mod:`skyrecon.sim.accelerometer`).

:class:`InertialCheck` compares, each frame, how much the odometry's velocity changed over the
last ``window_s`` with how much the accelerometer says it changed (velocities are finite
differences over ``velocity_span`` frames, the accelerometer's changes averaged the same way). When
they differ by more than ``max_disagreement_mps`` the odometry is not flown on: the position is
dead-reckoned from the last trusted one (the start of the window, before the slip) with the
velocity trusted there plus the accelerometer's changes since, and the pose is reported degraded
(the loop slows down). The odometry is trusted again once its velocity has agreed with the
dead-reckoned one within ``recover_mps`` for a whole window; its position then carries the offset
the dead reckoning left (a jump never reaches the map or the planner). Dead reckoning longer than
``max_dead_reckoning_s`` reports the pose lost (the loop hovers: the accelerometer's errors grow
with the square of the time).

On healthy flights nothing changes: the odometry's own numbers are passed through untouched. Over
the ten noisy odometry missions of ``benchmarks/mission`` (1.5 grey levels, with the corner floor)
the disagreement stayed under 0.62 m/s except at two slips (1.2 and 3.1 m/s); the demo's 9 m
failure read 7-9 m/s.

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
        recover_mps: the odometry is trusted again once its velocity change over a whole window
            after the slip agrees with the accelerometer's this well, m/s.
        max_dead_reckoning_s: dead reckoning longer than this reports the pose lost, seconds.
    """

    window_s: float = 1.0
    velocity_span: int = 3
    max_disagreement_mps: float = 1.0
    recover_mps: float = 0.5
    max_dead_reckoning_s: float = 3.0

    def __post_init__(self) -> None:
        if not (self.window_s > 0 and self.velocity_span >= 1 and self.max_dead_reckoning_s > 0):
            raise InputError("window_s and max_dead_reckoning_s must be positive, velocity_span at least 1")
        if not (0 < self.recover_mps <= self.max_disagreement_mps):
            raise InputError("recover_mps must be positive and at most max_disagreement_mps")


@dataclass
class InertialVerdict:
    """One frame's verdict.

    Attributes:
        position: (3,) the position to fly on, metres (the odometry's, plus any offset a dead
            reckoning left; the dead-reckoned one while the odometry is not trusted).
        disagreement_mps: how far the odometry's velocity change over the window differs from the
            accelerometer's (while dead reckoning: its velocity from the dead-reckoned one), m/s;
            NaN before a window has been seen.
        dead_reckoning: the odometry is not flown on this frame.
        lost: dead reckoning has lasted longer than ``max_dead_reckoning_s``.
        reason: why (empty when the odometry is trusted).
    """

    position: np.ndarray
    disagreement_mps: float
    dead_reckoning: bool = False
    lost: bool = False
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
        self._offset = np.zeros(3)
        # per frame: time, odometry position, flown position, cumulative velocity change
        n = 2 * (s.velocity_span + 1) + int(np.ceil(s.window_s * 100))
        self._t: deque[float] = deque(maxlen=n)
        self._odo: deque[np.ndarray] = deque(maxlen=n)
        self._out: deque[np.ndarray] = deque(maxlen=n)
        self._cum: deque[np.ndarray] = deque(maxlen=n)
        self._since: float | None = None  # dead reckoning since (time), None when trusting
        self._velocity = np.zeros(3)  # the dead-reckoned velocity
        self._detected_t = 0.0  # when the current dead reckoning was started
        self.slips = 0  # times dead reckoning started

    @property
    def dead_reckoning(self) -> bool:
        return self._since is not None

    def _velocity_at(self, series: deque, i: int) -> np.ndarray:
        k = self.settings.velocity_span
        return (series[i] - series[i - k]) / (self._t[i] - self._t[i - k])

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
        p_odo = np.asarray(odometry_position, np.float64).reshape(3)
        if velocity_change is None:
            for history in (self._t, self._odo, self._out, self._cum):
                history.clear()
            out = p_odo + self._offset if self._offset.any() else p_odo
            return InertialVerdict(out, float("nan"))
        if self._t and not time_s > self._t[-1]:
            raise InputError(
                f"inertial check: frames must move forward in time, got {time_s} after {self._t[-1]}"
            )
        cum = (self._cum[-1] if self._cum else np.zeros(3)) + np.asarray(velocity_change, np.float64)
        if self._since is None:
            flown = p_odo + self._offset if self._offset.any() else p_odo
        else:  # dead reckoning: on with the accelerometer
            self._velocity = self._velocity + np.asarray(velocity_change, np.float64)
            flown = self._out[-1] + self._velocity * (time_s - self._t[-1])
        self._t.append(float(time_s))
        self._odo.append(p_odo)
        self._out.append(flown)
        self._cum.append(cum)
        i = len(self._t) - 1
        j = self._window_start()
        if j is None:
            return InertialVerdict(flown, float("nan"), self._since is not None)
        if self._since is None:
            dv_odo = self._velocity_at(self._odo, i) - self._velocity_at(self._odo, j)
            dv_acc = self._mean_change_at(i) - self._mean_change_at(j)
            gap = float(np.linalg.norm(dv_odo - dv_acc))
            if gap <= s.max_disagreement_mps:
                return InertialVerdict(flown, gap)
            self._start_dead_reckoning(j)
            self.slips += 1
            return InertialVerdict(
                self._out[-1].copy(),
                gap,
                True,
                False,
                self._reason(gap, "dead reckoning from the accelerometer"),
            )
        # trusted again once a whole window after the slip agrees with the accelerometer, and the
        # odometry's velocity is not far from the dead-reckoned one
        gap = float(np.linalg.norm(self._velocity_at(self._odo, i) - self._velocity))
        if self._t[j] >= self._detected_t and gap <= s.max_disagreement_mps:
            dv_odo = self._velocity_at(self._odo, i) - self._velocity_at(self._odo, j)
            dv_acc = self._mean_change_at(i) - self._mean_change_at(j)
            if float(np.linalg.norm(dv_odo - dv_acc)) <= s.recover_mps:
                self._since = None
                self._offset = flown - p_odo
                return InertialVerdict(flown, gap)
        lost = time_s - self._since > s.max_dead_reckoning_s
        what = f"dead reckoning for {time_s - self._since:.1f} s"
        return InertialVerdict(flown, gap, True, lost, self._reason(gap, what))

    def _reason(self, gap: float, what: str) -> str:
        return f"the odometry disagrees with the accelerometer by {gap:.1f} m/s: {what}"

    def _start_dead_reckoning(self, j: int) -> None:
        """Replace the flown positions after frame ``j`` (the window's start, the last trusted)
        with dead reckoning from there: the velocity at ``j`` plus the accelerometer's changes."""
        i = len(self._t) - 1
        base = self._mean_change_at(j)
        v0 = self._velocity_at(self._out, j)
        for m in range(j + 1, i + 1):
            v = v0 + self._cum[m] - base
            self._out[m] = self._out[m - 1] + v * (self._t[m] - self._t[m - 1])
        self._velocity = v0 + self._cum[i] - base
        self._since = self._t[j]
        self._detected_t = self._t[i]
