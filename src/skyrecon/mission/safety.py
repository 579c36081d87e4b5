"""The stopping rule: never faster than the drone can stop in space it has seen free.

At every cycle the commanded speed is bounded so that, reacting after ``reaction_s`` (one cycle
between sensing and acting plus the loop's latency budget) and braking at ``max_accel_mps2``,
the drone comes to rest before the end of the space it has observed free. Two stretches of
space are checked, and the tighter one wins:

* **along the path**: how far the planned path ahead is observed free
  (:meth:`~skyrecon.mission.navigator.Navigator.verified_distance`), never more than the
  stereo rig's trusted range (the map's range, :func:`skyrecon.mission.perception.hit_range_m`: at most
  ``MissionConfig.max_range_m``, 17 m for the default rig): nothing beyond it is mapped;
* **along the velocity**: a drone at speed cannot turn on the spot, so the straight line its
  momentum carries it along (the braking distance in the direction of its current velocity) must
  be known free and keep ``drone_radius_m + safety_margin_m`` from every mapped obstacle
  (:meth:`~skyrecon.mission.navigator.Navigator.free_along`).

With reaction time ``t`` and deceleration ``a``, the distance to stop from speed ``v`` is
``v t + v^2 / (2 a)``; the highest speed that stops within ``room`` metres is
``-a t + sqrt((a t)^2 + 2 a room)``. The same formula gives the speed a rig supports at all
(:func:`rig_supported_speed`): a cruise speed above it is capped, with a warning at the start.

Units: metres, seconds, m/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from skyrecon.mission.config import MissionConfig
from skyrecon.mission.perception import hit_range_m


def stopping_distance_m(speed_mps: float, accel_mps2: float, reaction_s: float) -> float:
    """Distance travelled from ``speed_mps`` until at rest: ``v t + v^2 / (2 a)``, metres."""
    v = max(0.0, float(speed_mps))
    return v * reaction_s + v * v / (2.0 * accel_mps2)


def stoppable_speed_mps(room_m: float, accel_mps2: float, reaction_s: float) -> float:
    """Highest speed from which the drone stops within ``room_m`` metres (0 when there is none)."""
    if not room_m > 0:
        return 0.0
    if math.isinf(room_m):
        return math.inf
    at = accel_mps2 * reaction_s
    return -at + math.sqrt(at * at + 2.0 * accel_mps2 * room_m)


def rig_supported_speed(cfg: MissionConfig) -> float:
    """Highest speed from which the drone stops within what its rig can ever verify free: the
    trusted range (:func:`~skyrecon.mission.perception.hit_range_m`) less the stop buffer, m/s."""
    return stoppable_speed_mps(hit_range_m(cfg) - cfg.verify_buffer_m, cfg.max_accel_mps2, cfg.reaction_s)


def speed_warning(cfg: MissionConfig) -> str:
    """A one-line warning when the cruise speed is above what the rig supports, else ''."""
    v = rig_supported_speed(cfg)
    if cfg.cruise_speed_mps <= v + 1e-9:
        return ""
    return (
        f"cruise speed {cfg.cruise_speed_mps:g} m/s is above what the stereo rig supports: it trusts depth to "
        f"{hit_range_m(cfg):.1f} m, and braking at {cfg.max_accel_mps2:g} m/s^2 after "
        f"{cfg.reaction_s:.2f} s the drone can stop within that from {v:.1f} m/s; "
        f"flying at most {v:.1f} m/s (a longer baseline or a higher braking limit raises it)"
    )


@dataclass(frozen=True)
class SpeedLimit:
    """The speed limit of one cycle and what set it.

    Attributes:
        value_mps: the limit, m/s (the vehicle's commanded speed never exceeds it).
        stop_mps: the stopping rule's part of it: the lower of the two free-space limits, m/s.
        reason: what bound it: "cruise", "rig", "path_seen", "momentum", "goal" or "turns".
        path_room_m: observed-free room along the path ahead (capped at the trusted range), metres.
        momentum_room_m: known-free room along the current velocity, metres (inf when hovering).
        path_mps: the speed from which the drone stops within ``path_room_m``, m/s.
        unobserved_in_range: the path's first unobserved point lies within the trusted range (so
            it, not the range, bounds ``path_room_m``, and a look can verify it).
    """

    value_mps: float
    stop_mps: float
    reason: str
    path_room_m: float
    momentum_room_m: float
    path_mps: float = math.inf
    unobserved_in_range: bool = False

    @property
    def stop_limited(self) -> bool:
        """The stopping rule (not cruise speed, the goal or the turns) set the limit."""
        return self.reason in ("path_seen", "momentum", "rig")


def speed_limit(
    cfg: MissionConfig,
    verified_m: float,
    momentum_room_m: float,
    to_go_m: float,
    turns_mps: float,
) -> SpeedLimit:
    """The speed limit for one cycle (see the module docstring).

    Args:
        cfg: mission settings (braking limit, trusted range, stop buffer, cycle and latency budget).
        verified_m: how far along the path ahead space is observed free, metres.
        momentum_room_m: how far along the current velocity space is known free with the safety
            distance, metres (``inf`` when the drone is about still).
        to_go_m: length of the rest of the path, metres (the drone stops at the goal).
        turns_mps: the speed allowed by the turns of the path ahead, m/s.
    """
    a, t = cfg.max_accel_mps2, cfg.reaction_s
    trusted = hit_range_m(cfg)
    path_room = max(0.0, min(verified_m, trusted) - cfg.verify_buffer_m)
    mom_room = max(0.0, momentum_room_m - cfg.verify_buffer_m) if math.isfinite(momentum_room_m) else math.inf
    candidates = {
        "cruise": cfg.cruise_speed_mps,
        "rig": rig_supported_speed(cfg),
        "path_seen": stoppable_speed_mps(path_room, a, t),
        "momentum": stoppable_speed_mps(mom_room, a, t),
        "goal": math.sqrt(2 * a * max(0.0, to_go_m)) + 0.2,
        "turns": turns_mps,
    }
    reason = min(candidates, key=lambda k: candidates[k])
    stop = min(candidates["path_seen"], candidates["momentum"], candidates["rig"])
    return SpeedLimit(
        float(candidates[reason]),
        float(stop),
        reason,
        path_room,
        mom_room,
        float(candidates["path_seen"]),
        verified_m < trusted - 1e-9,
    )
