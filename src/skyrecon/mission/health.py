"""Sensor and computer health, judged from the data the navigator receives (never from the
simulator's knowledge of what it injected).

Per cycle :meth:`SensorHealth.check` looks at the frame (or its absence), its timestamp, the
stereo result and the previous cycle's loop time, and says whether the depth is fresh and
trustworthy, and if not, why:

* ``no_frame``: nothing arrived this cycle;
* ``stale``: the frame was captured more than ``max_age_s`` ago (latency);
* ``black``, ``black_left``, ``black_right``: an image is (nearly) uniform black;
* ``frozen``: the frame is bit-identical to the previous one although the drone moved or
  turned in between (so the camera or its driver is stuck);
* ``noisy``: the image noise (Immerkaer's estimator,
  :func:`skyrecon.core.image_noise.image_noise_sigma`) is above ``max_noise``; below that the
  noise level is passed on (``Health.noise_sigma``) so that stereo's texture test stands above it;
* ``grainy``: the image noise is above ``grainy_noise`` (but not ``noisy``): the depth is
  used, but stereo sees less and later through the noise (a crossing drone among it), so the
  drone flies slower (``MissionConfig.grainy_speed_mps``);
* ``glare``: more than ``max_saturated`` of the image is saturated (the depth there is masked
  out, the rest is used: glare alone does not stop the drone);
* ``no_depth``: the images look fine but stereo measured almost nothing;
* ``overrun``: the previous cycle took longer than the latency budget (the map update is then
  skipped, the safety checks are not);
* ``slow``: the previous cycle took over ``slow_factor`` times the loop's usual time (the median
  of the last cycles) although within the budget: the CPU is starved; nothing is skipped yet;
* ``gps_rejected``: the pose source's GPS fusion refused a fix this cycle as too far from where
  the odometry says the drone is (a multipath jump): the pose goes on from the odometry; the
  depth is not affected.

Frames and units: seconds, grey levels (0-255), fractions of the image.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from skyrecon.core.image_noise import image_noise_sigma

#: Reasons that make the depth of the cycle untrustworthy (the drone stops using it).
UNTRUSTED = {"no_frame", "stale", "black", "black_left", "black_right", "frozen", "noisy", "no_depth"}

#: Which health reasons reveal which injected fault (for the fault report).
REVEALS = {
    "blackout": {"black"},
    "freeze": {"frozen"},
    "drop": {"no_frame"},
    "one-eye": {"black_left", "black_right"},
    "latency": {"stale"},
    "cpu": {"overrun", "slow"},
    "glare": {"glare"},
    "noise": {"noisy"},
    "gps-jump": {"gps_rejected"},
}


@dataclass
class Health:
    """One cycle's verdict: ``trusted`` (fresh, trustworthy depth), ``reasons`` (see the module
    docstring), ``glare_mask`` ((H, W) bool saturated pixels, or None) and ``noise_sigma`` (the
    left image's noise, grey levels; None when not measured: no frame, or a black one)."""

    trusted: bool
    reasons: list[str] = field(default_factory=list)
    glare_mask: np.ndarray | None = None
    noise_sigma: float | None = None


@dataclass
class SensorHealth:
    """Judges each cycle's data (see the module docstring).

    Attributes:
        max_age_s: a frame older than this is stale, seconds.
        black_mean, black_std: an image darker and flatter than this is black, grey levels.
        max_noise: image noise above this is untrustworthy, grey levels.
        grainy_noise: image noise above this (up to ``max_noise``) is ``grainy``, grey levels.
        max_saturated: share of saturated pixels above which glare is reported.
        min_measured: below this share of measured pixels the depth is missing.
        budget_ms: the loop's latency budget, milliseconds.
        slow_factor: a cycle this many times slower than the usual one is ``slow``.
    """

    max_age_s: float = 0.15
    black_mean: float = 12.0
    black_std: float = 4.0
    max_noise: float = 6.0
    grainy_noise: float = 1.0
    max_saturated: float = 0.03
    min_measured: float = 0.05
    budget_ms: float = 100.0
    slow_factor: float = 1.3
    _loop_ms: list[float] = field(default_factory=list)  # the last cycles' times (at most 50)
    _prev: np.ndarray | None = None
    _frozen: bool = False

    def _black(self, img: np.ndarray) -> bool:
        small = img[::4, ::4]
        return bool(small.mean() < self.black_mean and small.std() < self.black_std)

    def check_frame(
        self, now_s: float, left, right, stamp_s: float, last_loop_ms: float, moved: bool = True
    ) -> Health:
        """What the frame itself says, before stereo runs (``left``/``right`` None: no frame;
        ``moved``: the drone moved or turned since the previous frame, by its own estimate)."""
        reasons = []
        if last_loop_ms > self.budget_ms:
            reasons.append("overrun")
        elif len(self._loop_ms) >= 5 and last_loop_ms > self.slow_factor * float(np.median(self._loop_ms)):
            reasons.append("slow")
        if last_loop_ms > 0:
            self._loop_ms = [*self._loop_ms[-49:], float(last_loop_ms)]
        if left is None or right is None:
            return Health(False, reasons + ["no_frame"])
        if now_s - stamp_s > self.max_age_s:
            reasons.append("stale")
        bl, br = self._black(left), self._black(right)
        if bl and br:
            reasons.append("black")
        elif bl:
            reasons.append("black_left")
        elif br:
            reasons.append("black_right")
        probe = left[::7, ::7, 1]
        same = self._prev is not None and np.array_equal(probe, self._prev)
        # once stuck, the camera stays suspect until its image changes (the drone then holds still)
        self._frozen = bool(same and (moved or self._frozen))
        if self._frozen:
            reasons.append("frozen")
        self._prev = probe.copy()
        glare = None
        noise = None
        if not (bl or br):
            gray = cv2.cvtColor(left, cv2.COLOR_RGB2GRAY)
            sat = gray >= 250
            if sat.mean() > self.max_saturated:
                reasons.append("glare")
                # the blob's rim matches wrongly too (each camera sees the flare elsewhere)
                k = max(3, int(0.04 * gray.shape[1]) | 1)
                glare = cv2.dilate(sat.view(np.uint8), np.ones((k, k), np.uint8)) > 0
            noise = image_noise_sigma(gray)
            if noise > self.max_noise:
                reasons.append("noisy")
            elif noise > self.grainy_noise:
                reasons.append("grainy")
        return Health(not (set(reasons) & UNTRUSTED), reasons, glare, noise)

    def check_depth(self, health: Health, measured_fraction: float) -> Health:
        """Add what stereo says (``measured_fraction`` of pixels measured) to the frame's verdict."""
        if health.trusted and measured_fraction < self.min_measured:
            health.reasons.append("no_depth")
            health.trusted = False
        return health
