"""Guidance: from the path ahead to a speed limit, a pursuit point and where the camera looks.

Given the rest of the path (starting at the drone) and how far along it space has been
observed free (:meth:`~skyrecon.mission.navigator.Navigator.verified_distance`):

* **speed limit** (:func:`~skyrecon.mission.safety.speed_limit`): the lowest of the cruise
  speed, the speeds from which the drone can stop ``verify_buffer_m`` before the first
  unobserved point of the path and before the end of the known-free space along its current
  velocity (the stopping rule), the speed from which it can stop at the goal, and the speed
  allowed by the turns ahead (:func:`~skyrecon.mission.vehicle.corner_speed_limit`);
* **pursuit point** (carrot): on the path 1 to 2.5 m ahead (further when faster);
* **look-at point**: the first unobserved point when there is one within the horizon and it
  (nearly) sets the speed limit (the drone turns to look at it, and stops if it must); an
  unobserved point that costs no speed (beyond the trusted range, where no look can verify it,
  or behind a tighter turn) is looked at only as far as the direction of motion allows: kept
  within half ``max_heading_error_deg`` of it, as the path point ``verify_horizon_m`` ahead is
  when the whole horizon is observed. (Looking unclamped at a point that costs no speed could
  turn the camera more than ``max_heading_error_deg`` from the motion and hold the drone still
  for good: seen at 12 and 15 m/s with the turns setting the limit.)

World frame, metres, m/s, radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyrecon.mission.config import MissionConfig
from skyrecon.mission.safety import SpeedLimit, speed_limit
from skyrecon.mission.vehicle import DroneState, corner_speed_limit, point_along


@dataclass
class Guidance:
    """What the vehicle is told for one cycle.

    Attributes:
        carrot: (3,) pursuit point, world metres.
        speed_limit: m/s.
        limit: the speed limit with what set it (None when hovering without a path).
        look_at: (3,) where the camera should look, world metres.
        look_within_rad: clamp of the look-at bearing around the direction of motion, or None.
        to_go_m: length of the rest of the path, metres.
    """

    carrot: np.ndarray
    speed_limit: float
    look_at: np.ndarray
    look_within_rad: float | None
    to_go_m: float
    limit: SpeedLimit | None = None


def guide(
    rest: np.ndarray,
    state: DroneState,
    verified_m: float,
    cfg: MissionConfig,
    momentum_room_m: float = math.inf,
) -> Guidance:
    """Guidance along ``rest`` (K >= 2, 3) world metres, whose first ``verified_m`` metres are
    observed free (``cfg.verify_horizon_m`` when all of the horizon is), with ``momentum_room_m``
    metres known free along the drone's current velocity."""
    horizon = cfg.verify_horizon_m
    to_go = float(np.linalg.norm(np.diff(rest, axis=0), axis=1).sum())
    limit = speed_limit(cfg, verified_m, momentum_room_m, to_go, corner_speed_limit(rest, cfg, horizon))
    carrot = point_along(rest, max(1.0, min(2.5, 0.4 * state.speed + 1.0)))
    clamp = 0.5 * math.radians(cfg.max_heading_error_deg)
    if verified_m < horizon:
        look = point_along(rest, verified_m)
        within = None if unobserved_binds(limit) else clamp
    else:
        look, within = point_along(rest, min(horizon, to_go)), clamp
    return Guidance(carrot, limit.value_mps, look, within, to_go, limit)


#: How close (m/s) the speed an unobserved point allows must come to the limit for the drone to
#: turn freely to look at it.
UNOBSERVED_BINDS_MPS = 1.0


def unobserved_binds(limit: SpeedLimit) -> bool:
    """Whether the first unobserved point of the path (nearly) sets the speed limit: it lies
    within the trusted range (beyond it no look can verify it, and the rig's own limit is what
    binds), and the speed from which the drone stops before it (``limit.path_mps``) is within
    :data:`UNOBSERVED_BINDS_MPS` of the limit."""
    return limit.unobserved_in_range and limit.path_mps <= limit.value_mps + UNOBSERVED_BINDS_MPS


#: Yaw offsets (degrees) and look-at heights (metres) of the scan of a stalled drone, one per second.
_SCAN = ((30.0, 0.0), (-30.0, 0.0), (0.0, -1.0), (15.0, 1.0), (-15.0, 1.0), (0.0, 0.0))


def scan_look_at(look_at: np.ndarray, position: np.ndarray, stalled_s: float) -> np.ndarray:
    """Where a drone held still by unobserved space just ahead looks: after a second without
    progress it looks around the point it must see (yaw 30 degrees either way, then up and down),
    so that the same blind spot of the same view does not hold it forever (a voxel that one
    view leaves unknown is seen from another). ``look_at``, ``position`` (3,) world metres."""
    if stalled_s < 1.0:
        return look_at
    yaw_deg, dz = _SCAN[int(stalled_s - 1.0) % len(_SCAN)]
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    d = np.asarray(look_at, dtype=np.float64) - position
    return position + np.array([c * d[0] - s * d[1], s * d[0] + c * d[1], d[2] + dz])


def recovery_look_at(position: np.ndarray, yaw0: float, lost_s: float, pitch_down_deg: float) -> np.ndarray:
    """Where a drone that has lost its pose looks to find it again: ahead and down (where there
    is texture, not the sky) along the heading ``yaw0`` (radians) it had when the loss began; still
    lost after a second, 45 degrees further every second, so that a view with too few near
    features does not hold it forever. ``position`` (3,) world metres; returns (3,) the point."""
    yaw = yaw0 + math.radians(45.0) * math.floor(lost_s)
    pitch = math.radians(pitch_down_deg)
    c = math.cos(pitch)
    return np.asarray(position, np.float64) + 20.0 * np.array(
        [math.cos(yaw) * c, math.sin(yaw) * c, -math.sin(pitch)]
    )


def hover(position: np.ndarray, goal: np.ndarray) -> Guidance:
    """No path to follow: stay, and look towards the goal."""
    p = np.asarray(position, dtype=np.float64)
    return Guidance(p.copy(), 0.0, np.asarray(goal, dtype=np.float64), None, float(np.linalg.norm(goal - p)))
