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
* **backing off to see** (:func:`out_of_reach`, :func:`retreat_path`): a drone held still by an
  unobserved point it cannot look at (a climb steeper than the camera's upward reach: its tilt
  bound plus half the vertical field of view, 52 degrees for the default rig) flies back along
  its own flown track (swept free by its body), slowly and with its camera kept on that point
  (``MissionConfig.backoff_looks_ahead``: looking where it flies, then holding to look at the
  point), until the point lies well within the reach, then comes on again seeing it. A tracked
  mover's predicted sweep across the way back ends it (:meth:`BackOff.yield_to_movers`). Scanning
  from where it stands cannot help: the gimbal is at its bound (mission seed 10 on odometry
  hovered 30 s under a 58 degree climb and returned).

World frame, metres, m/s, radians.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from skyrecon.mission.config import MissionConfig
from skyrecon.mission.safety import SpeedLimit, speed_limit
from skyrecon.mission.vehicle import DroneState, corner_speed_limit, path_length, point_along, sample_path
from skyrecon.planning.replan import remaining_path


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
        blind_mps: speed allowed whichever way the camera looks (see :func:`~skyrecon.mission.vehicle.step`).
    """

    carrot: np.ndarray
    speed_limit: float
    look_at: np.ndarray
    look_within_rad: float | None
    to_go_m: float
    limit: SpeedLimit | None = None
    blind_mps: float = 0.0


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


#: A drone held still this long (seconds) by a point it cannot look at backs off to see it.
RETREAT_AFTER_S = 3.0
#: It backs off until the point lies this far (degrees) inside the camera's vertical reach.
RETREAT_VIEW_MARGIN_DEG = 12.0
#: Most it backs off along its flown track, metres.
RETREAT_MAX_M = 25.0
#: It backs off at most this fast, m/s, looking at the point, not where it goes (its own track,
#: swept free by its body): turning round to face the track lost the odometry's pose (above the
#: roofs, the view back held nothing near enough for stereo depth).
RETREAT_SPEED_MPS = 1.5
#: Backing off more often than this in one mission does not help: the no-progress failsafe acts.
MAX_RETREATS = 3
#: A back-off ends after twice the time its way back takes at :data:`RETREAT_SPEED_MPS` plus this,
#: seconds, arrived or not: the no-progress failsafe's clock stops while backing off, and held-out
#: dynamic mission 179 circled the end of a short way back for 112 s until the time limit, never
#: returning home.
RETREAT_SLACK_S = 10.0
#: At the end of the way back the drone holds this long (seconds) with its camera on the point it
#: backed off to see, so that the point is observed before it flies on (looking where it flew, it
#: had not seen it: dynamic seed 129 climbed to the same unobserved point three times).
RETREAT_LOOK_S = 2.0


#: Degrees inside the edge of the camera's vertical reach that still count as out of reach (the
#: edge of the image sees little).
REACH_MARGIN_DEG = 5.0
#: With ``MissionConfig.reach_aware_verify``: the back-off's margin instead (the top rows of the
#: image seldom carve free space: held-out seed 248 waited 20 s on a point 7 degrees inside).
REACH_AWARE_MARGIN_DEG = 12.0


def vertical_reach_rad(cfg: MissionConfig) -> tuple[float, float]:
    """How far above and below the horizon the camera can see with its gimbal at its bounds
    (the tilt bound plus half the vertical field of view), radians: (up, down)."""
    half = math.atan(0.5 * cfg.height / cfg.focal_px)
    return math.radians(cfg.max_camera_pitch_up_deg) + half, math.radians(cfg.max_camera_pitch_deg) + half


def out_of_reach_mask(
    position: np.ndarray, points: np.ndarray, cfg: MissionConfig, margin_deg: float = REACH_MARGIN_DEG
) -> np.ndarray:
    """Whether each of ``points`` (N, 3) world metres lies above or below what the camera at
    ``position`` (3,) can see at any tilt, less ``margin_deg``: (N,) bool."""
    up, down = vertical_reach_rad(cfg)
    m = math.radians(margin_deg)
    d = np.asarray(points, dtype=np.float64).reshape(-1, 3) - np.asarray(position, dtype=np.float64)
    e = np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1]))
    return (e > up - m) | (e < -(down - m))


def out_of_reach(
    position: np.ndarray, point: np.ndarray, cfg: MissionConfig, margin_deg: float = REACH_MARGIN_DEG
) -> bool:
    """:func:`out_of_reach_mask` for one ``point`` (3,)."""
    return bool(out_of_reach_mask(position, point, cfg, margin_deg)[0])


def retreat_path(way_back: np.ndarray, point: np.ndarray, cfg: MissionConfig) -> np.ndarray | None:
    """The start of the flown track back (``way_back`` (K, 3), from the drone; see
    :meth:`~skyrecon.mission.failsafe.Failsafe.way_back`) up to the first place from which
    ``point`` (3,) lies :data:`RETREAT_VIEW_MARGIN_DEG` inside the camera's vertical reach, at most
    :data:`RETREAT_MAX_M` along it. Returns (M >= 2, 3) world metres, or None when the track is
    too short to gain anything (under 1 m)."""
    pts, s = sample_path(way_back, 0.25, RETREAT_MAX_M)
    if len(pts) < 2 or s[-1] < 1.0:
        return None
    ok = np.array([not out_of_reach(q, point, cfg, RETREAT_VIEW_MARGIN_DEG) for q in pts])
    ok[s < 1.0] = False
    k = int(np.argmax(ok)) if ok.any() else len(pts) - 1
    return pts[: k + 1 : 4] if k % 4 == 0 else np.vstack([pts[: k + 1 : 4], pts[k]])


@dataclass
class BackOff:
    """Backing off along the flown track to see a point of the path the camera cannot look at.

    Attributes:
        path: (M, 3) the way back being flown (:func:`retreat_path`), world metres; None when
            not backing off.
        look: (3,) the point it backs off to see, world metres.
        count: times it has backed off this mission (at most :data:`MAX_RETREATS`).
        started_s: simulated time the current back-off was first flown, seconds (None: not yet).
        looking_since_s: simulated time it arrived at the end of the way back and began looking
            at :attr:`look`, seconds (None: not yet).
    """

    path: np.ndarray | None = None
    look: np.ndarray = field(default_factory=lambda: np.zeros(3))
    count: int = 0
    started_s: float | None = None
    looking_since_s: float | None = None

    @property
    def active(self) -> bool:
        return self.path is not None

    def cancel(self) -> None:
        self.path, self.started_s, self.looking_since_s = None, None, None

    def time_limit_s(self) -> float:
        """How long the current back-off may last, seconds (see :data:`RETREAT_SLACK_S`)."""
        length = 0.0 if self.path is None else path_length(self.path)
        return 2.0 * length / RETREAT_SPEED_MPS + RETREAT_SLACK_S

    def label(self, mode: str) -> str:
        """The cycle's mode for the log: "retreat" while backing off in the failsafe ``mode`` "fly"."""
        return "retreat" if self.path is not None and mode == "fly" else mode

    def consider(
        self,
        rest: np.ndarray,
        verified_m: float,
        stalled_s: float,
        limit: SpeedLimit | None,
        position: np.ndarray,
        way_back: Callable[[np.ndarray], np.ndarray],
        cfg: MissionConfig,
        mode: str = "fly",
    ) -> bool:
        """Begin backing off when the drone has been held still ``stalled_s`` >=
        :data:`RETREAT_AFTER_S` seconds by the first unobserved point of ``rest`` (K, 3) (at
        ``verified_m`` along it) and that point is out of the camera's reach from ``position``;
        ``way_back(position)`` gives the flown track back; only in the failsafe ``mode`` "fly".
        Returns whether it began."""
        if (
            mode != "fly"
            or self.path is not None
            or self.count >= MAX_RETREATS
            or stalled_s < RETREAT_AFTER_S
            or limit is None
            or limit.reason != "path_seen"
            or len(rest) < 2
        ):
            return False
        q = point_along(rest, verified_m)
        margin = REACH_AWARE_MARGIN_DEG if cfg.reach_aware_verify else REACH_MARGIN_DEG
        if not out_of_reach(position, q, cfg, margin):
            return False
        self.path = retreat_path(way_back(position), q, cfg)
        if self.path is None:
            return False
        self.look, self.count = q, self.count + 1
        return True

    def yield_to_movers(
        self,
        position: np.ndarray,
        keep_out: np.ndarray | None,
        conflict: Callable[[np.ndarray, np.ndarray], float],
    ) -> bool:
        """Stop backing off when the way back from ``position`` (3,) meets a mover's predicted
        sweep: ``keep_out`` (K, 7) capsules or None, ``conflict(way, keep_out)`` the arc length
        (m) where the path ``way`` (M, 3) meets one, inf if nowhere (the navigator's
        ``mover_conflict``).
        The way back was free when flown but knows nothing of movers; the plan and its escapes
        do. Returns whether it stopped."""
        if self.path is None or keep_out is None or not len(keep_out):
            return False
        holding = self.looking_since_s is not None  # holding still at the end: any mover ends it
        if not holding and not math.isfinite(conflict(remaining_path(self.path, position), keep_out)):
            return False
        self.cancel()
        return True

    def guide(
        self, position: np.ndarray, state: DroneState, cfg: MissionConfig, momentum_room_m: float
    ) -> Guidance:
        """Guidance back along :attr:`path` at most :data:`RETREAT_SPEED_MPS`
        (``state.time_s`` is the clock; it ends after :meth:`time_limit_s` in any case).

        With ``cfg.backoff_looks_ahead`` off (the default) the camera stays on :attr:`look` and
        the drone flies back blind (the track was free when flown); done on arrival. On, it
        looks where it flies (other things move: in session 26, dynamic seed 123 backed off
        blind into a drone it never saw), holds at the end for :data:`RETREAT_LOOK_S` with the
        camera on :attr:`look` (now within its reach), then is done.
        """
        assert self.path is not None
        if self.started_s is None:
            self.started_s = state.time_s
        g = guide(remaining_path(self.path, position), state, cfg.verify_horizon_m, cfg, momentum_room_m)
        g.speed_limit = min(g.speed_limit, RETREAT_SPEED_MPS)
        arrived = g.to_go_m < 0.3 and state.speed < 0.2
        if not cfg.backoff_looks_ahead:  # blind, the camera on the point; done on arrival
            g.look_at, g.look_within_rad, g.blind_mps = self.look.copy(), None, RETREAT_SPEED_MPS
            if arrived or state.time_s - self.started_s >= self.time_limit_s():
                self.cancel()
            return g
        if self.looking_since_s is None and arrived:
            self.looking_since_s = state.time_s  # arrived: hold and look at the point
        if self.looking_since_s is not None:
            g = hover(position, self.look)
        looked = self.looking_since_s is not None and state.time_s - self.looking_since_s >= RETREAT_LOOK_S
        if looked or state.time_s - self.started_s >= self.time_limit_s():
            self.cancel()
        return g


def hover(position: np.ndarray, goal: np.ndarray) -> Guidance:
    """No path to follow: stay, and look towards the goal."""
    p = np.asarray(position, dtype=np.float64)
    return Guidance(p.copy(), 0.0, np.asarray(goal, dtype=np.float64), None, float(np.linalg.norm(goal - p)))
