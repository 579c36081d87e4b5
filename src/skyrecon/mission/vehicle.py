"""The simulated drone: a point mass with speed, acceleration and turn-rate limits, and the
guidance that makes it follow a path with its camera facing the way it goes.

World frame z up, metres, seconds; yaw in radians from +x towards +y; the camera's pitch is
positive downwards. The left camera sits at the drone's position.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyrecon.core import Rigid3
from skyrecon.mission.config import MissionConfig
from skyrecon.sim import look_from


def wrap_angle(a: float) -> float:
    """An angle in radians mapped to [-pi, pi)."""
    return (a + math.pi) % (2 * math.pi) - math.pi


@dataclass
class DroneState:
    """Where the drone is and how it moves.

    Attributes:
        position: (3,) world metres (the left camera's centre).
        velocity: (3,) world m/s.
        yaw: heading of the body and camera, radians from +x towards +y.
        pitch_down: camera tilt below the horizon, radians.
        time_s: simulated time, seconds.
    """

    position: np.ndarray
    velocity: np.ndarray
    yaw: float
    pitch_down: float
    time_s: float = 0.0

    @property
    def speed(self) -> float:
        return float(np.linalg.norm(self.velocity))

    def cam_from_world(self) -> Rigid3:
        """Pose of the left camera (OpenCV axes), ``cam_from_world``."""
        return look_from(self.position, self.yaw, self.pitch_down).with_frames("cam", "world")


def path_length(points: np.ndarray) -> float:
    """Length of a polyline (N, 3), metres."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


def point_along(path: np.ndarray, s: float) -> np.ndarray:
    """The (3,) point at arc length ``s`` metres along a polyline (K, 3) (clamped to its ends)."""
    if len(path) == 1:
        return path[0].copy()
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    if s >= cum[-1]:
        return path[-1].copy()
    k = int(np.searchsorted(cum, s, side="right")) - 1
    k = min(max(k, 0), len(seg) - 1)
    f = (s - cum[k]) / max(seg[k], 1e-12)
    return path[k] + f * (path[k + 1] - path[k])


def sample_path(path: np.ndarray, step: float, max_length: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` metres along a polyline (K, 3), up to ``max_length`` (the last sample
    sits at ``min(length, max_length)``).

    Returns:
        (N, 3) points (the first is ``path[0]``) and (N,) their arc lengths, metres.
    """
    path = np.asarray(path, dtype=np.float64).reshape(-1, 3)
    if len(path) < 2:
        return path[:1].copy(), np.zeros(min(len(path), 1))
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    end = min(float(cum[-1]), max_length)
    s = np.arange(0.0, end + 1e-9, step)
    if s[-1] < end - 1e-6:
        s = np.append(s, end)
    pts = np.stack([np.interp(s, cum, path[:, k]) for k in range(3)], axis=1)
    return pts, s


def turn_speed(turn_rad: float, cfg: MissionConfig) -> float:
    """Highest speed at which the drone takes a corner of ``turn_rad`` radians without cutting it
    by more than the room the clearance leaves (``clearance_m - drone_radius_m - safety_margin_m``,
    at least 0.25 m), m/s (at least 1).

    Turning at its acceleration limit ``a`` from speed ``v`` the drone flies an arc of radius
    ``v^2 / a``, which passes ``r (1 / cos(turn / 2) - 1)`` inside the corner.
    """
    room = max(0.25, cfg.clearance_m - cfg.drone_radius_m - cfg.safety_margin_m)
    excess = 1.0 / max(math.cos(0.5 * min(abs(turn_rad), 0.99 * math.pi)), 1e-6) - 1.0
    if excess < 1e-9:
        return math.inf
    return max(1.0, math.sqrt(cfg.max_accel_mps2 * room / excess))


def corner_speed_limit(path: np.ndarray, cfg: MissionConfig, horizon_m: float) -> float:
    """Highest speed from which the drone can slow down for the turns of ``path`` (K, 3) (starting
    at the drone) within ``horizon_m``: each turn of angle a at distance s allows
    ``sqrt(turn_speed(a)^2 + 2 a_max s)`` (:func:`turn_speed`)."""
    limit = cfg.cruise_speed_mps
    if len(path) < 3:
        return limit
    seg = np.diff(path, axis=0)
    length = np.linalg.norm(seg, axis=1)
    s = 0.0
    for k in range(len(seg) - 1):
        s += length[k]
        if s > horizon_m:
            break
        a, b = seg[k], seg[k + 1]
        na, nb = np.linalg.norm(a), np.linalg.norm(b)
        if na < 1e-9 or nb < 1e-9:
            continue
        cos_t = float(np.clip(a @ b / (na * nb), -1.0, 1.0))
        v_turn = turn_speed(math.acos(cos_t), cfg)
        limit = min(limit, math.sqrt(v_turn**2 + 2 * cfg.max_accel_mps2 * s))
    return limit


def step(
    state: DroneState,
    carrot: np.ndarray,
    speed_limit: float,
    cfg: MissionConfig,
    look_at: np.ndarray | None = None,
    look_within_rad: float | None = None,
    brake: bool = False,
    blind_mps: float = 0.0,
) -> DroneState:
    """Advance the drone by one cycle towards ``carrot`` (3,) world metres.

    The heading turns towards ``look_at`` (3,) (default: the carrot; with ``look_within_rad``
    its bearing is first clamped to within that angle of the direction to the carrot) at most
    ``max_yaw_rate_deg_s``; the drone moves only while the camera looks within
    ``max_heading_error_deg`` of its direction of motion (slower the larger the error), at most
    ``speed_limit``, its velocity changing by at most ``max_accel_mps2 * dt``. The camera
    pitches towards the look-at point (plus ``camera_pitch_deg``) at most
    ``max_camera_pitch_rate_deg_s``, within ``max_camera_pitch_deg`` down and
    ``max_camera_pitch_up_deg`` up: up too, since a climb's path must be seen before it is flown
    (capping the pitch at 5 degrees up was tried: seed 4 of the mission benchmark then hovered for
    30 s under a climb it could not look at), but not 30 degrees (the sky filled the view and the
    odometry drifted: 15 was chosen on mission seeds 1, 4, 9 and 19).

    With ``brake`` the drone brakes at ``max_accel_mps2`` along its current velocity instead (the
    stopping rule's response when it is faster than it can stop in the space ahead: braking in a
    straight line keeps it on the line that was checked free).

    ``blind_mps`` lets the drone move at up to that speed whichever way the camera looks: only
    for backing off along its own flown track (swept free by its body) while it keeps looking at
    what it backs off to see (:func:`skyrecon.mission.guidance.retreat_path`).
    """
    dt = cfg.dt
    p = state.position
    d = np.asarray(carrot, dtype=np.float64) - p
    dist = float(np.linalg.norm(d))
    horiz = float(math.hypot(d[0], d[1]))
    q = (
        np.asarray(look_at, dtype=np.float64) if look_at is not None else np.asarray(carrot, dtype=np.float64)
    ) - p
    q_h = float(math.hypot(q[0], q[1]))
    yaw = state.yaw
    if q_h > 0.3 or horiz > 0.3:
        # a look-at straight above or below has no bearing: face the way the drone goes (else
        # the heading froze and, the motion being beyond max_heading_error_deg of it, the
        # drone never moved: a failsafe return down a steep flown track hovered until its
        # time limit in dynamic mission 103 with the see-through test)
        bearing = math.atan2(q[1], q[0]) if q_h > 0.3 else math.atan2(d[1], d[0])
        if look_within_rad is not None and horiz > 0.3:
            motion = math.atan2(d[1], d[0])
            bearing = motion + float(np.clip(wrap_angle(bearing - motion), -look_within_rad, look_within_rad))
        err = wrap_angle(bearing - yaw)
        max_turn = math.radians(cfg.max_yaw_rate_deg_s) * dt
        yaw = wrap_angle(yaw + float(np.clip(err, -max_turn, max_turn)))
    if horiz > 0.3:  # how far the camera looks from the direction of motion
        err = abs(wrap_angle(math.atan2(d[1], d[0]) - yaw))
        facing = max(0.0, 1.0 - err / math.radians(cfg.max_heading_error_deg))
    else:
        facing = 1.0
    speed = min(speed_limit, cfg.cruise_speed_mps) * facing
    speed = max(speed, min(speed_limit, blind_mps))
    speed = min(speed, dist / dt)  # never overshoot the carrot within one cycle
    v_des = d / dist * speed if dist > 1e-9 else np.zeros(3)
    dv = v_des - state.velocity
    n = float(np.linalg.norm(dv))
    max_dv = cfg.max_accel_mps2 * dt
    if n > max_dv:
        dv *= max_dv / n
    v = state.velocity + dv
    if brake:
        speed_now = state.speed
        v = (
            state.velocity * (max(0.0, speed_now - max_dv) / speed_now)
            if speed_now > 1e-9
            else state.velocity
        )
    climb = math.atan2(q[2], max(q_h, 1e-6)) if float(np.linalg.norm(q)) > 0.3 else 0.0
    target = float(
        np.clip(
            math.radians(cfg.camera_pitch_deg) - climb,
            -math.radians(cfg.max_camera_pitch_up_deg),
            math.radians(cfg.max_camera_pitch_deg),
        )
    )
    max_tilt = math.radians(cfg.max_camera_pitch_rate_deg_s) * dt
    pitch = state.pitch_down + float(np.clip(target - state.pitch_down, -max_tilt, max_tilt))
    return DroneState(p + v * dt, v, yaw, pitch, state.time_s + dt)
