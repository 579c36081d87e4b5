"""A simulated urban-canyon GPS receiver over the synthetic city.

Error model (world frame, z up, metres), for a true antenna position sampled at ``rate_hz``:

* white noise: ``noise_m`` horizontal, twice that vertical (1-sigma);
* a correlated bias: first-order Gauss-Markov (time constant ``bias_tau_s``, stationary 1-sigma
  ``bias_m`` horizontal, twice vertical);
* the urban canyon: rays are cast from the antenna towards the sky (``n_azimuths`` directions at
  ``elevation_deg``) and the blocked share ``b`` measured against the city's buildings. Where
  ``b > multipath_at`` a multipath episode may start (probability ``jump_rate_hz`` per second scaled by
  ``b``): a horizontal jump of ``jump_m`` (+-30 %) across the street, lasting 2-8 s; the stated accuracy
  grows only mildly with ``b`` (receivers under-report multipath); where ``b > dropout_at`` there is
  no fix at all.

Deterministic in ``seed``; the receiver is stateful, so feed it in time order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from skyrecon.errors import InputError
from skyrecon.io.gps import GpsFix
from skyrecon.sim.city import City

__all__ = ["UrbanGpsSettings", "UrbanCanyonGps", "simulate_gps"]


@dataclass(frozen=True)
class UrbanGpsSettings:
    """Parameters of :class:`UrbanCanyonGps` (metres, seconds, degrees); see the module docstring."""

    rate_hz: float = 5.0
    noise_m: float = 1.0
    bias_m: float = 2.0
    bias_tau_s: float = 30.0
    jump_m: float = 20.0
    jump_rate_hz: float = 0.1
    jump_duration_s: tuple[float, float] = (2.0, 8.0)
    multipath_at: float = 0.3
    dropout_at: float = 0.85
    n_azimuths: int = 16
    elevation_deg: float = 35.0
    base_accuracy_m: float = 2.5


@dataclass
class UrbanCanyonGps:
    """A stateful receiver: call :meth:`fix` at increasing times (see the module docstring).

    Attributes:
        city: the scene whose buildings block the sky.
        seed: the only source of randomness.
        settings: :class:`UrbanGpsSettings`.
        log: per call ``(time_s, blocked_share, in_jump)`` for tests and reports.
    """

    city: City
    seed: int = 0
    settings: UrbanGpsSettings = field(default_factory=UrbanGpsSettings)
    log: list[tuple[float, float, bool]] = field(default_factory=list)

    def __post_init__(self) -> None:
        s = self.settings
        if not (s.rate_hz > 0 and s.bias_tau_s > 0 and s.noise_m >= 0 and s.bias_m >= 0):
            raise InputError(f"invalid GPS settings {s}")
        self._rng = np.random.default_rng(self.seed)
        self._bias = self._rng.normal(0.0, 1.0, 3) * s.bias_m * np.array([1.0, 1.0, 2.0])
        self._t: float | None = None
        self._jump = np.zeros(3)
        self._jump_until = -math.inf
        az = np.linspace(0, 2 * np.pi, s.n_azimuths, endpoint=False)
        el = math.radians(s.elevation_deg)
        self._dirs = np.stack(
            [np.cos(az) * math.cos(el), np.sin(az) * math.cos(el), np.full_like(az, math.sin(el))], 1
        )

    def blocked_share(self, position: np.ndarray) -> float:
        """Share of the sky probe rays from ``position`` (3,) that hit a building (0..1)."""
        d = self.city.raycast(
            np.asarray(position, np.float64).reshape(1, 3), self._dirs, include_ground=False
        )
        return float(np.mean(np.isfinite(d)))

    def fix(self, time_s: float, true_position: np.ndarray) -> GpsFix | None:
        """The receiver's output at ``time_s`` for the antenna at ``true_position`` (3,) world metres;
        None during a dropout."""
        s = self.settings
        p = np.asarray(true_position, np.float64).reshape(3)
        dt = 1.0 / s.rate_hz if self._t is None else max(0.0, time_s - self._t)
        self._t = time_s
        a = math.exp(-dt / s.bias_tau_s)
        sigma = s.bias_m * np.array([1.0, 1.0, 2.0])
        self._bias = a * self._bias + math.sqrt(max(0.0, 1 - a * a)) * sigma * self._rng.normal(0, 1, 3)
        b = self.blocked_share(p)
        u = self._rng.random()  # drawn every call so the stream does not depend on the branch taken
        side = self._rng.normal(0, 1, 2)
        length = s.jump_m * self._rng.uniform(0.7, 1.3)
        duration = self._rng.uniform(*s.jump_duration_s)
        if time_s >= self._jump_until and b > s.multipath_at and u < s.jump_rate_hz * dt * (1 + 4 * b):
            direction = side / max(float(np.linalg.norm(side)), 1e-9)
            self._jump = np.array([direction[0], direction[1], 0.0]) * length
            self._jump_until = time_s + duration
        in_jump = time_s < self._jump_until
        self.log.append((float(time_s), b, bool(in_jump)))
        noise = self._rng.normal(0, 1, 3) * s.noise_m * np.array([1.0, 1.0, 2.0])
        if b > s.dropout_at:
            return None
        measured = p + self._bias + noise + (self._jump if in_jump else 0.0)
        accuracy = s.base_accuracy_m * (1.0 + b)
        return GpsFix(time_s, measured, accuracy)


def simulate_gps(
    city: City,
    times_s: np.ndarray,
    positions: np.ndarray,
    seed: int = 0,
    settings: UrbanGpsSettings | None = None,
) -> list[GpsFix]:
    """Fixes at ``settings.rate_hz`` along a trajectory given at ``times_s`` (N,) with true antenna
    ``positions`` (N, 3) world metres (linearly interpolated between samples)."""
    s = settings or UrbanGpsSettings()
    t = np.asarray(times_s, np.float64)
    P = np.asarray(positions, np.float64).reshape(-1, 3)
    if len(t) != len(P) or len(t) < 1:
        raise InputError(f"{len(t)} times for {len(P)} positions")
    rx = UrbanCanyonGps(city, seed, s)
    out = []
    for tf in np.arange(t[0], t[-1] + 1e-9, 1.0 / s.rate_hz):
        p = np.array([np.interp(tf, t, P[:, k]) for k in range(3)])
        f = rx.fix(float(tf), p)
        if f is not None:
            out.append(f)
    return out
