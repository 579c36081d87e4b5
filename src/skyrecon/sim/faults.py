"""Faults injected into the simulated drone's sensors and computer, by name and timing.

A fault specification is a comma-separated list of ``NAME@ONSET[+DURATION][:VALUE]``
(seconds of simulated time; no duration: to the end of the flight), or ``random`` (a seeded
mix), or ``none``::

    blackout@12+2          both cameras send black frames for 2 s from t = 12 s
    freeze@20+3            both cameras repeat their last frame
    drop@8+1.5             no frame arrives
    one-eye@15:right       one camera (left or right, default right) goes black
    latency@10+5:0.4       frames arrive 0.4 s late (their timestamps say so)
    cpu@30+6:3             the loop gets a third of the CPU (its cycles take 3x as long)
    glare@5+4:0.35         a saturated blob covering 35 % of the image
    noise@18+6:12          sensor noise raised to 12 grey levels (standard deviation)
    gps-jump@25+4:30       GPS fixes jump 30 m sideways (multipath); only with a GPS (the
                           ``gps+odometry`` pose source), and ``random`` draws it only then

The simulated cameras are noise-free unless the mission sets ``camera_noise`` (the ``noise``
fault adds more): a frozen frame is told from a still scene by the drone's own motion (a camera
that moved must see a changed image).

The injector changes only what the drone receives; it never tells the drone what it did (the
navigator must find out from the data, see :mod:`skyrecon.mission.health`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from skyrecon.errors import InputError
from skyrecon.sim.sensor_noise import add_sensor_noise

#: Fault names and their default value (None: no value).
FAULTS: dict[str, float | str | None] = {
    "blackout": None,
    "freeze": None,
    "drop": None,
    "one-eye": "right",
    "latency": 0.4,
    "cpu": 3.0,
    "glare": 0.35,
    "noise": 12.0,
    "gps-jump": 25.0,
}

#: Faults of the GPS receiver: they need a pose source that uses GPS.
GPS_FAULTS = frozenset({"gps-jump"})


@dataclass(frozen=True)
class Fault:
    """One injected fault: ``name`` (:data:`FAULTS`), from ``onset_s`` for ``duration_s``
    seconds (inf: to the end), with its ``value`` (eye, seconds, factor, fraction, sigma)."""

    name: str
    onset_s: float
    duration_s: float = math.inf
    value: float | str | None = None

    def active(self, t: float) -> bool:
        return self.onset_s <= t < self.onset_s + self.duration_s

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "onset_s": round(self.onset_s, 3),
            "duration_s": None if math.isinf(self.duration_s) else round(self.duration_s, 3),
            "value": self.value,
        }


def _bad(spec: str, why: str) -> InputError:
    names = ", ".join(FAULTS)
    return InputError(
        f"fault specification {spec!r}: {why}; write NAME@ONSET[+DURATION][:VALUE], comma-separated, "
        f"with NAME one of {names} (or 'random', or 'none')"
    )


def parse_faults(spec: str, seed: int = 0, flight_s: float = 60.0, gps: bool = False) -> list[Fault]:
    """Faults from a specification (see the module docstring).

    Args:
        spec: the specification; ``random`` draws 1-3 faults from ``seed`` within the first
            ``flight_s`` seconds (GPS faults too when ``gps``: the drone flies with a GPS).
    Raises:
        InputError: one line naming what cannot be parsed and listing the valid names.
    """
    s = (spec or "").strip()
    if s in ("", "none"):
        return []
    if s == "random":
        return random_faults(seed, flight_s, gps)
    out = []
    for part in s.split(","):
        item = part.strip()
        if "@" not in item:
            raise _bad(spec, f"{item!r} has no @ONSET")
        name, rest = item.split("@", 1)
        name = name.strip()
        if name not in FAULTS:
            raise _bad(spec, f"unknown fault {name!r}")
        value: float | str | None = FAULTS[name]
        if ":" in rest:
            rest, v = rest.split(":", 1)
            if name == "one-eye":
                if v not in ("left", "right"):
                    raise _bad(spec, f"one-eye takes left or right, got {v!r}")
                value = v
            elif value is None:
                raise _bad(spec, f"{name} takes no value")
            else:
                try:
                    value = float(v)
                except ValueError:
                    raise _bad(spec, f"{name} value {v!r} is not a number") from None
        try:
            onset, dur = (rest.split("+", 1) + ["inf"])[:2]
            onset_s, duration_s = float(onset), float(dur)
        except ValueError:
            raise _bad(spec, f"{item!r}: ONSET and DURATION must be seconds") from None
        if not (math.isfinite(onset_s) and onset_s >= 0 and duration_s > 0):
            raise _bad(spec, f"{item!r}: need ONSET >= 0 and DURATION > 0")
        if isinstance(value, float) and not (math.isfinite(value) and value > 0):
            raise _bad(spec, f"{item!r}: the value must be positive")
        out.append(Fault(name, onset_s, duration_s, value))
    return sorted(out, key=lambda f: f.onset_s)


def random_faults(seed: int, flight_s: float = 60.0, gps: bool = False) -> list[Fault]:
    """1-3 faults drawn from ``seed``: onsets in [5 s, 0.7 flight_s], durations 0.5-6 s (one in
    five to the end of the flight), values in plausible ranges; GPS faults only when ``gps``."""
    rng = np.random.default_rng([int(seed), 0xFA17])
    names = [n for n in FAULTS if gps or n not in GPS_FAULTS]
    out = []
    for _ in range(int(rng.integers(1, 4))):
        name = names[int(rng.integers(len(names)))]
        onset = float(rng.uniform(5.0, max(6.0, 0.7 * flight_s)))
        dur = math.inf if rng.random() < 0.2 else float(rng.uniform(0.5, 6.0))
        value: float | str | None = {
            "one-eye": "left" if rng.random() < 0.5 else "right",
            "latency": float(rng.uniform(0.15, 0.8)),
            "cpu": float(rng.uniform(1.5, 5.0)),
            "glare": float(rng.uniform(0.1, 0.5)),
            "noise": float(rng.uniform(4.0, 25.0)),
            "gps-jump": float(rng.uniform(10.0, 60.0)),
        }.get(name)
        out.append(Fault(name, round(onset, 1), dur if math.isinf(dur) else round(dur, 1), value))
    return sorted(out, key=lambda f: f.onset_s)


@dataclass
class Delivery:
    """What reaches the drone in one cycle: the frame (or None when it was dropped), the time
    its cameras captured it (``stamp_s``, seconds), and the CPU slowdown factor of the cycle."""

    left: np.ndarray | None
    right: np.ndarray | None
    stamp_s: float
    cpu_factor: float = 1.0


class FaultInjector:
    """Applies faults to the frames the simulator renders (deterministic by seed).

    Args:
        faults: the faults (:func:`parse_faults`).
        seed: seeds the sensor noise.
    """

    def __init__(self, faults: list[Fault], seed: int = 0):
        self.faults = list(faults)
        self._seed = int(seed)
        self.rng = np.random.default_rng([int(seed), 0x5E5])
        self._last: tuple[np.ndarray, np.ndarray] | None = None
        self._past: deque[tuple[float, np.ndarray, np.ndarray]] = deque(maxlen=64)

    def active(self, t: float) -> list[Fault]:
        return [f for f in self.faults if f.active(t)]

    @property
    def needs_gps(self) -> bool:
        """Whether a fault is of the GPS receiver (the pose source must use GPS)."""
        return any(f.name in GPS_FAULTS for f in self.faults)

    def gps_offset(self, t: float) -> np.ndarray:
        """(3,) metres added to the GPS fix taken at time ``t``: a ``gps-jump`` of its value in a
        horizontal direction drawn from the seed and the onset (zero when none is active)."""
        off = np.zeros(3)
        for f in self.active(t):
            if f.name == "gps-jump":
                a = np.random.default_rng([self._seed, int(round(f.onset_s * 10)), 0x6A]).uniform(
                    0, 2 * math.pi
                )
                off += float(f.value) * np.array([math.cos(a), math.sin(a), 0.0])  # type: ignore[arg-type]
        return off

    def deliver(self, t: float, left: np.ndarray, right: np.ndarray) -> Delivery:
        """The frame the drone receives at time ``t`` from the frame rendered at ``t``."""
        act = {f.name: f for f in self.active(t)}
        if "noise" in act:
            sigma = float(act["noise"].value)  # type: ignore[arg-type]
            left, right = add_sensor_noise(left, sigma, self.rng), add_sensor_noise(right, sigma, self.rng)
        if "glare" in act:
            frac = float(act["glare"].value)  # type: ignore[arg-type]
            h, w = left.shape[:2]
            r = math.sqrt(frac * h * w / math.pi)
            yy, xx = np.mgrid[0:h, 0:w]
            blob = (xx - 0.6 * w) ** 2 + (yy - 0.35 * h) ** 2 <= r * r
            left, right = left.copy(), right.copy()
            left[blob] = 255
            right[np.roll(blob, -int(0.01 * w), axis=1)] = 255
        self._past.append((t, left, right))
        stamp = t
        if "latency" in act:
            want = t - float(act["latency"].value)  # type: ignore[arg-type]
            old = [p for p in self._past if p[0] <= want + 1e-9]
            if old:
                stamp, left, right = old[-1]
            else:
                stamp, left, right = self._past[0]
        cpu = float(act["cpu"].value) if "cpu" in act else 1.0  # type: ignore[arg-type]
        if "drop" in act:
            return Delivery(None, None, stamp, cpu)
        if "freeze" in act and self._last is not None:
            left, right = self._last
        if "blackout" in act:
            left, right = np.zeros_like(left), np.zeros_like(right)
        if "one-eye" in act:
            if act["one-eye"].value == "left":
                left = np.zeros_like(left)
            else:
                right = np.zeros_like(right)
        if "freeze" not in act:
            self._last = (left, right)
        return Delivery(left, right, stamp, cpu)
