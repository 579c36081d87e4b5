"""The closed loop: render -> stereo -> map -> distance field -> check / replan -> fly.

One cycle per simulated ``1 / cycle_hz`` seconds:

1. **render** (the simulator, timed apart): the stereo pair from the drone's current TRUE pose;
2. **stereo**: disparity with the fast matcher, measured pixels to depth;
   **pose**: where the drone believes it is (:mod:`skyrecon.mission.pose_source`: the exact
   pose, or stereo visual odometry on the same frame reusing its disparity); everything below
   (map, plan, guidance) lives in that believed world;
3. **integrate**: the depth into the occupancy map at the believed pose (skipped while the pose
   is lost);
4. **distance**: the distance field and the planner's grid, where occupied voxels changed;
5. **check**: the rest of the path against the updated field (``Replanner.check``);
6. **replan**: from the current position when the path is blocked (or there is none);
7. **control**: how far ahead the path is observed free, the speed that allows (the stopping
   rule, :mod:`skyrecon.mission.safety`; a drone held still by unobserved space looks around it,
   :func:`~skyrecon.mission.guidance.scan_look_at`), the pursuit
   and look-at points (:mod:`skyrecon.mission.guidance`), and one step of the vehicle
   (:mod:`skyrecon.mission.vehicle`), carried back to the true world
   (:func:`~skyrecon.mission.pose_source.true_step`). A degraded pose caps the speed at
   ``degraded_speed_mps``; a lost one makes the drone hover.

Then the simulator checks the move against the TRUE geometry (``City.distance`` along the
segment flown, ground included): below ``drone_radius_m`` is a collision and ends the mission.
The mission also ends on arrival (the drone believes it is within ``arrival_tolerance_m`` of the
goal; the delivery counts when it truly is within ``arrival_tolerance_m + delivery_tolerance_m``)
or at the time limit. Stages 2-7 are "the loop" whose rate is reported (rendering excluded).

A city that moves (:mod:`skyrecon.sim.movers`): the frame is rendered from the scene as it is
at that instant; the tracker (:mod:`skyrecon.perception.movers`) keeps the movers out of the
map, and their predicted sweep (keep-out capsules) is checked against the path and avoided by
every replan (``replan_reason`` "mover"); the true clearance counts the movers at the true time.
A prior map (:mod:`skyrecon.mission.prior`) seeds the drone's map with weak beliefs.

Faults (:mod:`skyrecon.sim.faults`): what reaches the drone may be black, frozen, missing, late,
glared or noisy, and a starved CPU stretches the cycle; :mod:`skyrecon.mission.health` judges
each cycle's data, and :mod:`skyrecon.mission.failsafe` holds, returns or lands when the depth
cannot be trusted (untrusted depth never reaches the map; an overrun skips the map update, not
the safety checks).

Everything is deterministic in the scenario: the simulated clock advances by a fixed step, so
the flown path does not depend on how fast the machine is.
"""

from __future__ import annotations

import contextlib
import gc
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

from skyrecon.core import Rigid3
from skyrecon.errors import InputError
from skyrecon.mapping import OccupancyMap
from skyrecon.mapping.far_hits import FarHitFilter
from skyrecon.mission.config import MissionConfig
from skyrecon.mission.failsafe import Failsafe
from skyrecon.mission.guidance import (
    BackOff,
    Guidance,
    guide,
    hover,
    recovery_look_at,
    scan_look_at,
)
from skyrecon.mission.health import REVEALS, SensorHealth
from skyrecon.mission.navigator import CheckOutcome, Navigator, timed
from skyrecon.mission.perception import flight_perception, mission_rig
from skyrecon.mission.perception import hit_range_m as mission_hit_range_m
from skyrecon.mission.pose_source import (
    PoseReading,
    PoseSource,
    believed_state,
    est_from_true,
    make_pose_source,
    true_step,
)
from skyrecon.mission.prior import PriorMap, mission_prior
from skyrecon.mission.safety import SpeedLimit
from skyrecon.mission.scenario import Scenario
from skyrecon.mission.unseen import UNSEEN_AFTER_S
from skyrecon.mission.vehicle import DroneState, path_length, point_along, step
from skyrecon.mission.world_monitor import WorldMonitor
from skyrecon.odometry.types import TrackingState
from skyrecon.perception import GroundPlane, StereoDepth
from skyrecon.perception.movers import MoverSettings, MoverTracker, parse_mover_overrides
from skyrecon.record import NullRecorder, Recorder
from skyrecon.record.mission import MissionRecording
from skyrecon.sim import render_stereo
from skyrecon.sim.faults import Delivery, Fault, FaultInjector, parse_faults
from skyrecon.sim.sensor_noise import add_sensor_noise
from skyrecon.threads import blas_threads, kernel_threads

#: Milliseconds the simulated flight computer spends on one cycle (about the loop's median on
#: 2 cores); a ``cpu`` fault stretches it, and the health check sees the overrun from it.
NOMINAL_LOOP_MS = 50.0

#: Stages of the loop proper (rendering is the simulator's and is reported apart).
LOOP_STAGES = ("stereo", "pose", "movers", "integrate", "distance", "check", "replan", "control")
STAGES = ("render",) + LOOP_STAGES


@dataclass
class CycleRecord:
    """One cycle of the loop.

    Attributes:
        cycle: index from 0.
        time_s: simulated time at the start of the cycle, seconds.
        position: (3,) world metres at the start of the cycle; yaw, pitch_down radians.
        speed_mps: speed after the cycle's step.
        timings_ms: wall-clock milliseconds per stage (:data:`STAGES`).
        clearance_m: smallest true distance to an obstacle (ground included) along the step
            flown in this cycle, metres.
        replanned: a new path was planned this cycle; replan_ok: it succeeded.
        path_clear: the path was clear before any replanning.
        verified_m: how far ahead the path was observed free, metres.
        to_go_m: length of the remaining planned path, metres.
        measured_fraction: share of pixels the matcher measured.
        speed_limit_mps: the cycle's speed limit; stop_limit_mps: the stopping rule's part of it
            (:mod:`skyrecon.mission.safety`); limit_reason: what set the limit.
        momentum_room_m: known-free room along the velocity at the start of the cycle, metres.
        est_position: (3,) where the drone believed it was, metres (None: same as ``position``);
        pose_state: ``ok``, ``degraded`` or ``lost``; pose_reason: why not ok.
        clearance_static_m, clearance_moving_m: the true clearance along the step to the static
            city (ground included) and to the movers (true geometry at the true time), metres.
        replan_reason: why the path was replanned: "no_path" (none yet), "blocked" (the map
            showed the path inside the clearance), "mover" (a tracked mover's predicted sweep
            crossed it) or "unseen" (held a whole scan by space it cannot observe, it plans round
            it: :mod:`skyrecon.mission.unseen`); "" when not replanned.
        movers_tracked: confirmed tracks of moving objects after this cycle's update.
        health: what was wrong with the cycle's data, comma-separated (:mod:`skyrecon.mission.health`).
        image_noise: the left image's noise as the health check measured it, grey levels (the
            texture tests stand above it); None when no image was measured.
        mode: the failsafe mode (:mod:`skyrecon.mission.failsafe`): fly, hold, return or land; or
            retreat (flying normally, backing off to see a climb: :func:`~skyrecon.mission.guidance.retreat_path`).
    """

    cycle: int
    time_s: float
    position: np.ndarray
    yaw: float
    pitch_down: float
    speed_mps: float
    timings_ms: dict[str, float]
    clearance_m: float
    replanned: bool
    replan_ok: bool
    path_clear: bool
    verified_m: float
    to_go_m: float
    measured_fraction: float
    speed_limit_mps: float = 0.0
    stop_limit_mps: float = 0.0
    limit_reason: str = "hover"
    momentum_room_m: float = math.inf
    est_position: np.ndarray | None = None
    pose_state: str = "ok"
    pose_reason: str = ""
    clearance_static_m: float = math.inf
    clearance_moving_m: float = math.inf
    replan_reason: str = ""
    movers_tracked: int = 0
    health: str = ""
    mode: str = "fly"
    image_noise: float | None = None

    @property
    def pose_error_m(self) -> float:
        """Distance between the believed and the true position, metres."""
        if self.est_position is None:
            return 0.0
        return float(np.linalg.norm(self.est_position - self.position))

    @property
    def stop_limited(self) -> bool:
        """The stopping rule set this cycle's speed limit."""
        return self.limit_reason in ("path_seen", "momentum", "rig")

    @property
    def loop_ms(self) -> float:
        """Milliseconds of the loop proper (everything but rendering)."""
        return float(sum(self.timings_ms.get(k, 0.0) for k in LOOP_STAGES))

    def to_dict(self) -> dict:
        return {
            "cycle": self.cycle,
            "time_s": round(self.time_s, 3),
            "position": [round(float(v), 4) for v in self.position],
            "yaw_deg": round(math.degrees(self.yaw), 2),
            "pitch_down_deg": round(math.degrees(self.pitch_down), 2),
            "speed_mps": round(self.speed_mps, 3),
            "timings_ms": {k: round(v, 2) for k, v in self.timings_ms.items()},
            "loop_ms": round(self.loop_ms, 2),
            "clearance_m": round(self.clearance_m, 3),
            "replanned": self.replanned,
            "replan_ok": self.replan_ok,
            "path_clear": self.path_clear,
            "verified_m": round(self.verified_m, 2),
            "to_go_m": round(self.to_go_m, 2),
            "measured_fraction": round(self.measured_fraction, 4),
            "speed_limit_mps": round(self.speed_limit_mps, 3),
            "stop_limit_mps": round(self.stop_limit_mps, 3),
            "limit_reason": self.limit_reason,
            "momentum_room_m": round(self.momentum_room_m, 2)
            if math.isfinite(self.momentum_room_m)
            else None,
            "est_position": None
            if self.est_position is None
            else [round(float(v), 4) for v in self.est_position],
            "pose_error_m": round(self.pose_error_m, 4),
            "pose_state": self.pose_state,
            "pose_reason": self.pose_reason,
            "clearance_static_m": _finite(self.clearance_static_m),
            "clearance_moving_m": _finite(self.clearance_moving_m),
            "replan_reason": self.replan_reason,
            "movers_tracked": self.movers_tracked,
            "health": self.health,
            "mode": self.mode,
            "image_noise": None if self.image_noise is None else round(self.image_noise, 3),
        }


def _finite(v: float, nd: int = 3) -> float | None:
    return round(float(v), nd) if math.isfinite(v) else None


@dataclass
class PlanEvent:
    """A path the drone decided to follow: at ``cycle``, ``waypoints`` (K, 3) world metres;
    ``kind`` is "initial", "replan" or "escape" (planned from a nearby point at the full
    clearance because the drone was too close to a freshly mapped obstacle)."""

    cycle: int
    waypoints: np.ndarray
    kind: str
    reason: str = ""


@dataclass
class FrameSample:
    """A camera frame kept for the report: left image (H, W, 3) uint8 RGB and its disparity (H, W)
    float32 pixels (NaN invalid), at ``cycle``."""

    cycle: int
    left: np.ndarray
    disparity: np.ndarray
    label: str = ""


@dataclass
class MissionResult:
    """Everything a mission produced.

    Attributes:
        scenario, config: what was flown, with which settings.
        success: arrived without collision (truly within the delivery tolerance of the goal).
        reason: '' on success, else why it ended: "collision", "timeout", "no_path",
            "missed_goal" (it believed it had arrived but was farther from the goal than the
            delivery tolerance: the pose estimate drifted).
        collisions: collisions with the true geometry (0 or 1: a collision ends the mission).
        records: one :class:`CycleRecord` per cycle.
        plans: every path followed (:class:`PlanEvent`).
        frames: a few camera frames (:class:`FrameSample`).
        final_position: (3,) world metres where the drone truly ended.
        final_est_position: (3,) where it believed it ended (the estimated world), metres.
        occ_map: the drone's map at the end.
        monitor: the simulator's judge of movers and changes (:class:`WorldMonitor`), or None.
        prior: the prior map the drone started from (:class:`~skyrecon.mission.prior.PriorMap`), or None.
        wall_s: wall-clock seconds of the whole mission (rendering and set-up included).
        setup_s: wall-clock seconds of set-up (map allocation, matcher warm-up).
    """

    scenario: Scenario
    config: MissionConfig
    success: bool
    reason: str
    collisions: int
    records: list[CycleRecord]
    plans: list[PlanEvent]
    frames: list[FrameSample]
    final_position: np.ndarray
    occ_map: OccupancyMap
    wall_s: float = 0.0
    setup_s: float = 0.0
    message: str = ""
    final_est_position: np.ndarray | None = None
    monitor: WorldMonitor | None = None
    prior: PriorMap | None = None
    world_summary: dict | None = None
    faults: list[dict] = field(default_factory=list)
    failsafe_events: list[dict] = field(default_factory=list)

    def flown_path(self) -> np.ndarray:
        """(N + 1, 3) positions of the drone, world metres: one per cycle, then the final one."""
        if not self.records:
            return self.final_position[None].copy()
        return np.vstack([np.array([r.position for r in self.records]), self.final_position[None]])


class _FrameKeeper:
    """Keeps a bounded, evenly spread set of frames of a run of unknown length."""

    def __init__(self, keep: int):
        self.keep = max(2, keep)
        self.period = 1
        self.frames: list[FrameSample] = []
        self.replan_frames: list[FrameSample] = []

    def offer(self, cycle: int, left: np.ndarray, disparity: np.ndarray, replanned: bool) -> None:
        if cycle % self.period == 0:
            self.frames.append(FrameSample(cycle, left, disparity))
            if len(self.frames) > 2 * self.keep:
                self.frames = self.frames[::2]
                self.period *= 2
        if (
            replanned
            and cycle > 0
            and len(self.replan_frames) < 2
            and (not self.replan_frames or cycle - self.replan_frames[-1].cycle >= 30)
        ):
            self.replan_frames.append(FrameSample(cycle, left, disparity, "replanned"))

    def result(self, last: FrameSample | None) -> list[FrameSample]:
        fr = self.frames + (
            [last] if last is not None and (not self.frames or self.frames[-1].cycle != last.cycle) else []
        )
        idx: list[int] = (
            np.unique(np.round(np.linspace(0, len(fr) - 1, min(self.keep, len(fr)))).astype(int)).tolist()
            if fr
            else []
        )
        chosen = [fr[i] for i in idx] + self.replan_frames
        return sorted(chosen, key=lambda f: f.cycle)


def _truth_clearance(
    scenario: Scenario, a: np.ndarray, b: np.ndarray, t0: float, t1: float
) -> tuple[float, float]:
    """Smallest true distance along the segment a -> b flown from time t0 to t1 (seconds) to the
    static city (ground included) and to the movers (each sample at its own time), metres."""
    n = max(2, int(math.ceil(np.linalg.norm(b - a) / 0.1)) + 1)
    u = np.linspace(0.0, 1.0, n)
    pts = a + (b - a) * u[:, None]
    static = float(scenario.city.distance(pts, include_ground=True).min())
    if scenario.movers is None:
        return static, math.inf
    return static, float(scenario.movers.mover_distance(pts, t0 + (t1 - t0) * u).min())


def _fault_injector(
    spec: str, seed: int, limit_s: float, pose_source: PoseSource
) -> tuple[list[Fault], FaultInjector | None]:
    """The mission's faults and their injector (None without faults); GPS faults are wired into
    the pose source's fixes, and refused when it uses no GPS."""
    uses_gps = hasattr(pose_source, "fix_offset")
    faults = parse_faults(spec, seed, limit_s, gps=uses_gps)
    injector = FaultInjector(faults, seed) if faults else None
    if injector is not None and injector.needs_gps:
        if not uses_gps:
            raise InputError(
                "a gps-jump fault needs a GPS: fly with the gps+odometry pose source (--pose-source gps+odometry)"
            )
        pose_source.fix_offset = injector.gps_offset  # type: ignore[attr-defined]
    return faults, injector


#: Faults that only show in the frames' content: while no frame arrives (a ``drop``) they cannot.
_IN_THE_FRAMES = {"blackout", "freeze", "one-eye", "latency", "glare", "noise"}


def fault_report(faults: list[Fault], records: list[CycleRecord]) -> list[dict]:
    """Each injected fault with its onset and when the navigator's health check first revealed
    it (``detected_s``, None if it never did, e.g. a fault after the mission ended).

    A fault that shows only in the frames' content cannot be seen while no frame arrives (another
    fault, ``drop``, hides it; the drone is already holding for that): ``visible_s`` is the first
    cycle of the fault with a frame, ``detect_delay_s`` counts from then, and a fault that ended
    before any frame arrived is ``masked`` (True) rather than undetected."""
    out = []
    for f in faults:
        during = [r for r in records if f.onset_s - 1e-9 <= r.time_s < f.onset_s + f.duration_s]
        visible = f.onset_s
        if f.name in _IN_THE_FRAMES:
            seen = next((r.time_s for r in during if "no_frame" not in r.health.split(",")), None)
            visible = f.onset_s if seen is None else max(f.onset_s, seen)
        hit = next(
            (
                r.time_s
                for r in records
                if r.time_s >= f.onset_s - 1e-9 and REVEALS[f.name] & set(r.health.split(","))
            ),
            None,
        )
        row = f.to_dict()
        row["detected_s"] = None if hit is None else round(hit, 3)
        row["visible_s"] = round(visible, 3)
        row["masked"] = bool(
            f.name in _IN_THE_FRAMES
            and during
            and hit is None
            and all("no_frame" in r.health.split(",") for r in during)
        )
        row["detect_delay_s"] = None if hit is None else round(max(0.0, hit - visible), 3)
        out.append(row)
    return out


def _strided_mask(mask: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """A full-resolution (H, W) mask on the depth's (h, w) grid (any pixel of a cell marks it)."""
    fy, fx = mask.shape[0] // shape[0], mask.shape[1] // shape[1]
    m = mask[: shape[0] * fy, : shape[1] * fx].reshape(shape[0], fy, shape[1], fx)
    return np.asarray(m.any(axis=(1, 3)), dtype=bool)


#: Speed of an escape's first leg whichever way the camera looks, m/s (see :func:`_follow`).
ESCAPE_SPEED_MPS = 3.0


def _follow(
    nav: Navigator,
    rest: np.ndarray,
    believed: DroneState,
    momentum_m: float,
    degraded: bool,
    cfg: MissionConfig,
    grainy: bool = False,
) -> tuple[float, Guidance]:
    """Guidance along the path ahead ``rest`` (K, 3), with how far it is observed free, metres;
    no faster than ``degraded_speed_mps`` on a ``degraded`` pose, nor than ``grainy_speed_mps``
    on ``grainy`` images (:mod:`skyrecon.mission.health`); on an escape's first leg at up to
    :data:`ESCAPE_SPEED_MPS` whichever way the camera looks."""
    verified = nav.verified_distance(rest, cfg.verify_horizon_m, cfg.verify_skip_m)
    short = arrival_cut(rest, verified, nav.goal, cfg)
    if short is not None:
        rest = short
        verified = nav.verified_distance(rest, cfg.verify_horizon_m, cfg.verify_skip_m)
    g = guide(rest, believed, verified, cfg, momentum_m)
    if degraded and g.speed_limit > cfg.degraded_speed_mps:
        g.speed_limit = cfg.degraded_speed_mps
    if grainy and g.speed_limit > cfg.grainy_speed_mps:
        g.speed_limit = cfg.grainy_speed_mps
    if nav.escaping(believed.position):
        # a sidestep out of a mover's way (or off an obstacle) cannot wait for the drone to turn
        # round first: its leg is clear by construction, and the stopping rule still holds
        # (mission seed 118: turning to face an escape point behind it, a hovering drone was
        # flown into by another drone)
        g.blind_mps = ESCAPE_SPEED_MPS
    return verified, g


#: Where a path to the goal whose end is not observed stops instead: this share of the arrival
#: tolerance short of the goal (see :func:`arrival_cut`).
ARRIVAL_CUT_SHARE = 0.5


def arrival_cut(
    rest: np.ndarray, verified_m: float, goal: np.ndarray, cfg: MissionConfig
) -> np.ndarray | None:
    """The path ahead ``rest`` (K, 3) cut :data:`ARRIVAL_CUT_SHARE` of ``cfg.arrival_tolerance_m``
    short of the ``goal`` (3,), when it ends there and what is not observed free of it
    (``verified_m`` along it, :meth:`Navigator.verified_distance`) lies within the arrival
    tolerance of its end; else None.

    The delivery is made within the arrival tolerance of the goal, so the drone need not fly the
    path's last metre, nor see it: held 1.9 m from its goal by an unobserved voxel beside the
    goal, noisy plain seed 2 hovered 30 s and went home. Cut, the path ends inside the arrival
    sphere (arc length is at least the straight distance), and the stopping rule holds on it as
    on any path: the drone stops at its new end at the latest.
    """
    if len(rest) < 2 or verified_m >= cfg.verify_horizon_m:
        return None
    if float(np.linalg.norm(rest[-1] - goal)) > (1.0 - ARRIVAL_CUT_SHARE) * 0.5 * cfg.arrival_tolerance_m:
        return None  # the path ends elsewhere (an escape point): the goal is not in reach
    to_go = path_length(rest)
    if to_go - verified_m > cfg.arrival_tolerance_m:
        return None
    end = to_go - ARRIVAL_CUT_SHARE * cfg.arrival_tolerance_m
    if end <= 0.0:
        return None
    before = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(rest, axis=0), axis=1))]) < end
    return np.vstack([rest[before], point_along(rest, end)[None]])


def _stall_count(
    stalled: int, held_by: str, mode: str, speed_mps: float, limit: SpeedLimit | None
) -> tuple[int, str]:
    """The cycles held still while following a path, and what held the speed, after a cycle in
    failsafe ``mode`` at ``speed_mps`` with the speed ``limit`` (None: hovering).

    Flying (``mode`` "fly"), held still by a limit: one more cycle, held by its reason; moving:
    0, held by its reason; hovering without a path: 0 and "". A failsafe hold while still and
    already stalled carries the count on (one more cycle) and keeps what held it: the scan round
    a blind spot (:func:`~skyrecon.mission.guidance.scan_look_at`) may turn the camera to a plain
    wall filling the view, a frame with no depth, and the failsafe holds for that cycle;
    restarting the count there restarted the scan, which turned to the same wall a second
    later, so it never got past it nor held long enough to plan round the blind spot (noisy
    textured delivery seed 10 scanned the same 2.6 s for 30 s and turned home). Any other mode:
    0 and ""."""
    still = speed_mps < 0.05
    if mode == "fly":
        if still and limit is not None:
            return stalled + 1, limit.reason
        return 0, limit.reason if limit is not None else ""
    if mode == "hold" and still and stalled > 0:
        return stalled + 1, held_by
    return 0, ""


def _unseen_due(
    mode: str,
    backoff: BackOff,
    outcome: CheckOutcome,
    conflict_m: float,
    held_by: str,
    stalled_s: float,
    since_tried_s: float,
) -> bool:
    """Whether to plan round unobserved space now (:meth:`Navigator.avoid_unseen`): flying a
    clear path (failsafe ``mode`` "fly", not backing off, no mover's sweep on it at
    ``conflict_m``), held still ``stalled_s`` seconds by unobserved space (``held_by``
    "path_seen"), at least :data:`~skyrecon.mission.unseen.UNSEEN_AFTER_S` of each since the
    last try (``since_tried_s`` ago)."""
    return (
        mode == "fly"
        and not backoff.active
        and outcome.clear
        and not math.isfinite(conflict_m)
        and held_by == "path_seen"
        and stalled_s >= UNSEEN_AFTER_S
        and since_tried_s >= UNSEEN_AFTER_S
    )


def _replan(
    nav: Navigator,
    p: np.ndarray,
    keep: np.ndarray | None,
    outcome: CheckOutcome,
    conflict_m: float,
    unseen: bool,
    plans: list[PlanEvent],
    cycle: int,
) -> tuple[bool, bool, str, str]:
    """The cycle's replanning at ``p`` (3,): round unobserved space when ``unseen`` is due
    (:meth:`Navigator.avoid_unseen`; when nothing goes round it, nothing changes), else when the
    path check ``outcome`` found it blocked or a mover's sweep (``keep`` capsules) meets it at
    ``conflict_m``. A new plan is appended to ``plans``.

    Returns:
        (replanned, replan_ok, replan_reason (see :class:`CycleRecord`), the failed plan's
        message or "").
    """
    around = nav.avoid_unseen(p, keep) if unseen else None
    if around is not None:
        reason = "unseen"
        r, how = around
    elif outcome.clear and not math.isfinite(conflict_m):
        return False, False, "", ""
    else:
        reason = (
            "mover"
            if outcome.clear or outcome.evading
            else ("no_path" if not len(nav.waypoints) else "blocked")
        )
        r, how = nav.replan(p, keep)
    if not r.success:
        return True, False, reason, r.message
    kind = "initial" if not plans else ("escape" if how == "escape" else "replan")
    plans.append(PlanEvent(cycle, r.waypoints.copy(), kind, r.reason))
    return True, True, reason, ""


def _failsafe_guidance(
    failsafe: Failsafe, mode: str, p: np.ndarray, believed: DroneState, goal: np.ndarray, cfg: MissionConfig
) -> Guidance:
    """Guidance while the failsafe holds, returns or lands (see :mod:`skyrecon.mission.failsafe`)."""
    if mode == "return":
        back = failsafe.way_back(p)
        if len(back) >= 2:  # the way back was flown, so it is free: the stopping rule's horizon is seen
            g = guide(back, believed, cfg.verify_horizon_m, cfg)
            g.speed_limit = min(g.speed_limit, cfg.degraded_speed_mps)
            return g
    if mode == "land":
        g = hover(p, goal)
        g.carrot, g.speed_limit = failsafe.landing_target(p), 1.0
        g.look_at = p + np.array([math.cos(believed.yaw), math.sin(believed.yaw), -1.0]) * 5.0
        return g
    return hover(p, goal)


def _map_update(
    nav: Navigator,
    tracker: MoverTracker | None,
    depth,
    cam_from_world,
    time_s: float,
    flown_from: np.ndarray,
    left: np.ndarray | None = None,
    far_hits: FarHitFilter | None = None,
) -> tuple[float, float]:
    """Track the movers in this frame's depth (and its ``left`` image: clusters on no texture
    are not movers) and integrate the rest into the static map (the movers' pixels are kept
    out, so they leave no trail; with ``far_hits``, the far pixels the frame before does not
    confirm only carve free space in front of them). Returns (movers ms, integrate ms)."""
    depth_for_map, movers_ms = depth.depth_m, 0.0
    world_from_cam = cam_from_world.inverse().with_frames("world", "cam")
    t0 = time.perf_counter()
    carve_only = (
        far_hits.unconfirmed(depth.depth_m, depth.intrinsics, world_from_cam, time_s)
        if far_hits is not None
        else None
    )
    far_ms = 1e3 * (time.perf_counter() - t0)
    if tracker is not None:
        mf = tracker.update(
            time_s,
            depth.depth_m,
            depth.intrinsics,
            world_from_cam,
            nav.map,
            fine=depth.fine,
            image=left,
            matches=depth.matches,
        )
        movers_ms = mf.ms
        if mf.dynamic_mask.any():
            depth_for_map = depth.depth_m.copy()
            depth_for_map[mf.dynamic_mask] = np.nan
    _, integrate_ms = timed(
        nav.integrate, depth_for_map, depth.intrinsics, cam_from_world, flown_from, carve_only
    )
    return movers_ms, integrate_ms + far_ms


def _camera_noise(frame, sigma: float, rng: np.random.Generator):
    """The rendered frame as the cameras deliver it: with their own steady noise of ``sigma``
    grey levels (``MissionConfig.camera_noise``; the frame itself for 0)."""
    if not sigma > 0:
        return frame
    left, right = add_sensor_noise(frame.left, sigma, rng), add_sensor_noise(frame.right, sigma, rng)
    return replace(frame, left=left, right=right)


def _sense(
    injector: FaultInjector | None,
    health_check: SensorHealth,
    stereo: StereoDepth,
    frame,
    time_s: float,
    last_loop_ms: float,
    moved: bool,
    horizon_row_px: float | None = None,
    ground: GroundPlane | None = None,
):
    """What reaches the drone this cycle and what it makes of it: (the delivery, its health, the
    depth or None, the (left, right) images or None, milliseconds of the drone's sensing: the
    health checks and stereo, not the simulator's fault injection). Saturated (glare) pixels are
    taken out of the depth; the rest is used. ``horizon_row_px``: where the horizon lies in the
    image at the camera's pitch (plain sky above it is open air, see
    :meth:`~skyrecon.perception.StereoDepth.compute`); ``ground``: the ground as the camera sees
    it (plain ground bordered by measured ground is open air well above it, ibid.)."""
    delivery = (
        injector.deliver(time_s, frame.left, frame.right)
        if injector is not None
        else Delivery(frame.left, frame.right, time_s)
    )
    t0 = time.perf_counter()
    health = health_check.check_frame(
        time_s, delivery.left, delivery.right, delivery.stamp_s, last_loop_ms, moved
    )
    if delivery.left is None or delivery.right is None:
        return delivery, health, None, None, 1e3 * (time.perf_counter() - t0)
    depth = stereo.compute(
        delivery.left,
        delivery.right,
        noise_sigma=health.noise_sigma,
        horizon_row_px=horizon_row_px,
        ground=ground,
    )
    if health.glare_mask is not None:
        depth.depth_m[_strided_mask(health.glare_mask, depth.depth_m.shape)] = np.nan
    health = health_check.check_depth(health, depth.measured_fraction)
    return delivery, health, depth, (delivery.left, delivery.right), 1e3 * (time.perf_counter() - t0)


def _ending(
    scenario: Scenario,
    cfg: MissionConfig,
    state: DroneState,
    believed: DroneState,
    mode: str,
    clearance: float,
    moving: bool,
    limit_s: float,
    failsafe: Failsafe,
) -> tuple[str, bool, str] | None:
    """How the mission ends after this cycle, if it does: (reason, success, message)."""
    t = state.time_s
    if clearance < cfg.drone_radius_m:
        what = "a moving obstacle" if moving else "an obstacle"
        return (
            "collision",
            False,
            f"collision at t = {t:.1f} s near {np.round(state.position, 1).tolist()}: "
            f"{clearance:.2f} m from {what} (drone radius {cfg.drone_radius_m:g} m)",
        )
    if mode == "return" and np.linalg.norm(believed.position - scenario.start) <= cfg.arrival_tolerance_m:
        return "returned", False, f"returned to the take-off point at t = {t:.1f} s (failsafe)"
    if mode == "land" and state.position[2] <= cfg.drone_radius_m + 0.35:
        return (
            "landed",
            False,
            f"landed at t = {t:.1f} s near {np.round(state.position, 1).tolist()} (failsafe)",
        )
    if np.linalg.norm(believed.position - scenario.goal) <= cfg.arrival_tolerance_m:
        miss = float(np.linalg.norm(state.position - scenario.goal))
        tol = cfg.arrival_tolerance_m + cfg.delivery_tolerance_m
        if miss <= tol:
            return "", True, f"arrived in {t:.1f} s"
        return (
            "missed_goal",
            False,
            f"believed it had arrived at t = {t:.1f} s but was {miss:.1f} m from the goal "
            f"(pose drift; tolerance {tol:g} m)",
        )
    if t >= limit_s:
        if mode != "fly":
            return (
                "hovering",
                False,
                f"time limit of {limit_s:.0f} s reached hovering safely ({failsafe.events[-1]['reason']})",
            )
        d = float(np.linalg.norm(state.position - scenario.goal))
        return "timeout", False, f"time limit of {limit_s:.0f} s reached {d:.1f} m from the goal"
    return None


def run_mission(
    scenario: Scenario,
    cfg: MissionConfig,
    on_cycle: Callable[[CycleRecord, Navigator], None] | None = None,
    keep_frames: int = 4,
    pose_source: PoseSource | None = None,
    recorder: Recorder | None = None,
) -> MissionResult:
    """Fly one mission in closed loop (see the module docstring).

    Args:
        scenario: city, start and goal (:func:`~skyrecon.mission.scenario.make_scenario`).
        cfg: the mission settings.
        on_cycle: called after every cycle with its record and the navigator (progress display).
        keep_frames: how many evenly spread camera frames to keep for the report.
        pose_source: where the drone's pose comes from (None: ``cfg.pose_source``).
        recorder: logs every cycle for a viewer (:mod:`skyrecon.record.mission`); outside the
            timed stages, so the loop rate is not affected.
    Returns:
        MissionResult (never raises for a failed flight: ``success`` and ``reason`` say how it ended).
        The loop's Numba kernels and OpenBLAS products run on ``cfg.loop_threads`` threads
        (see :mod:`skyrecon.threads`), and the objects that exist before the flight
        are left out of Python's cyclic garbage collection (:func:`frozen_heap`).
    """
    with kernel_threads(cfg.loop_threads), blas_threads(cfg.loop_threads), frozen_heap():
        return _fly(scenario, cfg, on_cycle, keep_frames, pose_source, recorder)


@contextlib.contextmanager
def frozen_heap() -> Iterator[None]:
    """Collect once, then keep every object alive now out of the cyclic collector's scans until
    the block ends (:func:`gc.freeze`). A full collection walks every tracked object: with the
    city, the map and the kernels loaded that is about 50 ms, once or twice a mission, in
    whatever stage it falls on (dynamic seed 102: the movers stage 48 ms on one cycle). After the
    freeze a collection only walks what the flight itself made."""
    gc.collect()
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def _mover_tracker(cfg: MissionConfig, hit_range: float) -> MoverTracker | None:
    """The flight's mover tracker (None with ``track_movers`` off). Movers
    are told from the static map where it holds obstacles (farther, a static surface's points
    fall in space carved free and would pass for movers): its range is the map's hit range."""
    if not cfg.track_movers:
        return None
    return MoverTracker(
        MoverSettings(
            **{
                "max_range_m": hit_range,
                "fine_range_m": cfg.max_range_m,
                **parse_mover_overrides(cfg.tracker_settings),
            }
        )
    )


def _fly(
    scenario: Scenario,
    cfg: MissionConfig,
    on_cycle: Callable[[CycleRecord, Navigator], None] | None,
    keep_frames: int,
    pose_source: PoseSource | None,
    recorder: Recorder | None,
) -> MissionResult:
    """:func:`run_mission`'s flight, on the threads it set."""
    t_start = time.perf_counter()
    rig = mission_rig(cfg)
    perception = flight_perception(cfg)
    stereo = StereoDepth(rig, perception)
    stereo.warm_up()  # the matcher and the kernels of a noisy frame, before the first cycle
    # the map's range is the rig's trusted range: nearer depth marks obstacles and carves free
    # space; farther depth carves free space up to it only. (Carving farther, up to a far surface
    # whose depth is metres uncertain, cut through real surfaces measured too far: their points,
    # seen again from nearer, then lay in "free" space and passed for movers; truth seed 15 hovered
    # 30 s behind such a phantom.)
    hit_range = mission_hit_range_m(cfg)
    prior = mission_prior(scenario, cfg)
    nav = Navigator(cfg, scenario.box, scenario.goal, hit_range, prior=prior)
    tracker = _mover_tracker(cfg, hit_range)
    far_hits = (
        FarHitFilter(
            cfg.far_hit_confirm_m, rig.left.fx * rig.baseline_m, hit_range, min_tol_m=cfg.voxel_size_m
        )
        if cfg.far_hit_confirm_m is not None
        else None
    )
    nav.warm_up(stereo.intrinsics)  # load the map's kernels now, not in the first cycle
    world = scenario.movers
    monitor = (
        WorldMonitor(scenario, cfg.voxel_size_m, hit_range) if world is not None or scenario.changes else None
    )
    reach_m = cfg.cruise_speed_mps * cfg.mover_horizon_s + cfg.stopping_distance_m
    limit_s = cfg.time_limit_for(scenario.straight_line_m)
    health_check = SensorHealth(budget_ms=1e3 * cfg.latency_budget_s)
    moved = False  # the drone moved or turned in the last cycle (a frozen camera's image would not change)
    failsafe = Failsafe(cfg)
    last_loop_ms = 0.0
    setup_s = time.perf_counter() - t_start
    state = DroneState(
        scenario.start.copy(), np.zeros(3), scenario.start_yaw, math.radians(cfg.camera_pitch_deg)
    )
    records: list[CycleRecord] = []
    plans: list[PlanEvent] = []
    keeper = _FrameKeeper(keep_frames)
    last_frame = None
    reason, success, collisions = "", False, 0
    message = ""
    cycle = 0
    p_prev = scenario.start.copy()
    stalled = 0  # cycles held still while following a path (see guidance.scan_look_at)
    held_by = ""  # what held the speed last cycle (SpeedLimit.reason)
    unseen_tried_s = -math.inf  # when unseen spots were last sought (mission.unseen)
    backoff = BackOff()  # backing off to see a climb the camera cannot look at
    if pose_source is None:
        pose_source = make_pose_source(
            cfg.pose_source,
            rig,
            state.cam_from_world().inverse().with_frames("world", "left"),
            scenario.seed,
            scenario.city,
            max_accel_mps2=cfg.max_accel_mps2,
        )
    faults, injector = _fault_injector(cfg.faults, scenario.seed, limit_s, pose_source)
    camera_rng = np.random.default_rng([int(scenario.seed), 0xCA3E7A])
    truth = pose_source.name == "truth"
    lost_cycles, lost_yaw0 = 0, 0.0  # cycles lost since the pose was last trusted, the heading then
    trusted_run = 0  # consecutive cycles with a pose (not lost)
    believed = state
    reading = PoseReading(state.cam_from_world().inverse().with_frames("world", "left"), TrackingState.OK)
    est_from_world = Rigid3.identity("est", "world")
    recording = MissionRecording(
        recorder or NullRecorder(),
        rig.left,
        cfg.voxel_size_m,
        cfg.max_disparity,
        scenario.start,
        scenario.goal,
    )
    while True:
        true_p = state.position.copy()
        ms: dict[str, float] = {}
        true_cam_from_world = state.cam_from_world()
        t_render = time.perf_counter()
        scene_now = world.snapshot(state.time_s) if world is not None else scenario.city
        frame = _camera_noise(
            render_stereo(scene_now, rig, true_cam_from_world.with_frames("left", "world")),
            cfg.camera_noise,
            camera_rng,
        )
        ms["render"] = 1e3 * (time.perf_counter() - t_render)
        true_world_from_left = true_cam_from_world.inverse().with_frames("world", "left")
        horizon_row = rig.left.cy - rig.left.fy * math.tan(state.pitch_down)  # the gimbal's pitch
        ground = nav.ground_plane(believed.cam_from_world())  # where the drone believes it is
        delivery, health, depth, fresh, ms["stereo"] = _sense(
            injector, health_check, stereo, frame, state.time_s, last_loop_ms, moved, horizon_row, ground
        )
        ms["pose"] = 0.0
        if depth is not None and fresh is not None:
            reading = pose_source.read(
                fresh[0], fresh[1], state.time_s, depth.disparity, true_world_from_left
            )
            ms["pose"] = reading.ms
            est_from_world = est_from_true(reading.world_from_left, true_world_from_left)
            health.reasons.extend(["gps_rejected"] * bool(getattr(pose_source, "rejected_fix", False)))
        # no frame: the pose is carried on by the last estimate of where the estimated world lies
        believed = state if truth else believed_state(state, est_from_world)
        lost = reading.state == TrackingState.LOST
        p = believed.position.copy()
        cam_from_world = reading.world_from_left.inverse().with_frames("cam", "world")
        mode = failsafe.update(state.time_s, health.trusted, health.reasons, p, nav.map)
        ms["movers"] = ms["integrate"] = 0.0
        # no map update from a pose or depth that cannot be trusted; an overrun skips it too
        if depth is not None and not lost and health.trusted and "overrun" not in health.reasons:
            ms["movers"], ms["integrate"] = _map_update(
                nav, tracker, depth, cam_from_world, state.time_s, p_prev, fresh[0], far_hits
            )
            p_prev = p
        rewritten, ms["distance"] = timed(nav.update_distance)
        t0 = time.perf_counter()
        outcome = nav.check(p, rewritten)
        keep = tracker.keep_out(cfg.mover_horizon_s, cfg.mover_margin_m) if tracker is not None else None
        conflict_m = math.inf
        if keep is not None and len(keep) and outcome.clear and len(nav.waypoints):
            conflict_m = nav.mover_conflict(nav.rest(p), keep, reach_m)
        # backing off blind or looking ahead, a mover's sweep across the way back ends it (dynamic
        # seed 123 backed off blind for 3 s into a drone it tracked, its escapes computed but unused)
        backoff.yield_to_movers(p, keep, partial(nav.mover_conflict, reach_m=reach_m))
        ms["check"] = 1e3 * (time.perf_counter() - t0)
        t0 = time.perf_counter()
        due = _unseen_due(
            mode, backoff, outcome, conflict_m, held_by, stalled * cfg.dt, state.time_s - unseen_tried_s
        )
        if due:
            unseen_tried_s = state.time_s
        replanned, replan_ok, replan_reason, failed = _replan(
            nav, p, keep, outcome, conflict_m, due, plans, cycle
        )
        if failed:
            message = failed
        failsafe.progress(state.time_s, float(np.linalg.norm(scenario.goal - p)), p, nav.map, backoff.active)
        ms["replan"] = 1e3 * (time.perf_counter() - t0)
        # control: how far the path is seen free, how fast we may go, where we look
        t0 = time.perf_counter()
        rest = nav.rest(p) if len(nav.waypoints) else np.zeros((0, 3))
        momentum = nav.free_along(p, believed.velocity, cfg.verify_horizon_m)
        recovering = lost or lost_cycles > 0  # hold still and look around until the pose holds again
        path_ok = (outcome.clear and not math.isfinite(conflict_m)) or replan_ok
        if mode != "fly":
            backoff.cancel()
            verified, g = 0.0, _failsafe_guidance(failsafe, mode, p, believed, scenario.goal, cfg)
        elif backoff.active and not recovering:
            verified, g = cfg.verify_horizon_m, backoff.guide(p, believed, cfg, momentum)
        elif len(rest) >= 2 and path_ok and not recovering:
            degraded = reading.state == TrackingState.DEGRADED
            verified, g = _follow(nav, rest, believed, momentum, degraded, cfg, "grainy" in health.reasons)
        else:
            verified, g = 0.0, hover(p, scenario.goal)
            if recovering:
                lost_cycles += 1
                if lost_cycles == 1:
                    lost_yaw0 = believed.yaw
                g.look_at = recovery_look_at(p, lost_yaw0, lost_cycles * cfg.dt, cfg.camera_pitch_deg)
        trusted_run = trusted_run + 1 if not lost else 0
        if trusted_run >= 5:  # a re-initialisation lost again at the next frame is still lost
            lost_cycles = 0
        # (a failsafe flies a path it already knows; it does not stop to look around)
        stalled, held_by = _stall_count(stalled, held_by, mode, believed.speed, g.limit)
        if stalled and mode == "fly":
            g.look_at = scan_look_at(g.look_at, p, stalled * cfg.dt)
        # held still by a point it cannot look at: back off along the flown track to see it
        backoff.consider(rest, verified, stalled * cfg.dt, g.limit, p, failsafe.way_back, cfg, mode)
        brake = g.limit is not None and believed.speed > g.limit.stop_mps + 1e-9
        new_believed = step(
            believed,
            g.carrot,
            g.speed_limit,
            cfg,
            look_at=g.look_at,
            look_within_rad=g.look_within_rad,
            brake=brake,
            blind_mps=g.blind_mps,
        )
        new_state = new_believed if truth else true_step(state, believed, new_believed, est_from_world)
        ms["control"] = 1e3 * (time.perf_counter() - t0)
        if backoff.label(mode) == "fly":  # the way back: flown normally, not while backing off
            failsafe.remember(p)
        turn = abs(math.remainder(new_believed.yaw - believed.yaw, 2 * math.pi))
        moved = bool(np.linalg.norm(new_believed.position - believed.position) > 0.02 or turn > 0.002)
        c_static, c_moving = _truth_clearance(
            scenario, true_p, new_state.position, state.time_s, new_state.time_s
        )
        clearance = min(c_static, c_moving)
        rec = CycleRecord(
            cycle,
            state.time_s,
            true_p,
            state.yaw,
            state.pitch_down,
            new_state.speed,
            ms,
            clearance,
            replanned,
            replan_ok,
            outcome.clear,
            verified,
            g.to_go_m,
            0.0 if depth is None else depth.measured_fraction,
            g.speed_limit,
            g.limit.stop_mps if g.limit is not None else 0.0,
            g.limit.reason if g.limit is not None else "hover",
            momentum,
            None if truth else p,
            reading.state.value,
            reading.reason,
            c_static,
            c_moving,
            replan_reason,
            0 if tracker is None else sum(1 for t in tracker.tracks if t.moving),
            ",".join(health.reasons),
            backoff.label(mode),
            health.noise_sigma,
        )
        records.append(rec)
        # the simulated flight computer spends NOMINAL_LOOP_MS a cycle, stretched by a starved
        # CPU; judging overruns on it (not on this machine's wall clock) keeps missions deterministic
        last_loop_ms = NOMINAL_LOOP_MS * delivery.cpu_factor
        if monitor is not None:
            monitor.observe(
                state.time_s,
                true_world_from_left.t,
                frame.left_result.object_id,
                scene_now,
                tracker.tracks if tracker is not None else [],
                nav.map,
                None if truth else est_from_world,
                frame.left_result,
            )
        if depth is not None and delivery.left is not None:
            keeper.offer(cycle, delivery.left, depth.disparity, replanned)
            last_frame = FrameSample(cycle, delivery.left, depth.disparity)
        if on_cycle is not None:
            on_cycle(rec, nav)
        recording.cycle(
            cycle,
            state.time_s,
            reading.world_from_left,
            None if truth else true_world_from_left,
            delivery.left,
            depth,
            nav.map,
            plans,
            tracker.tracks if tracker is not None else None,
        )
        state, believed = new_state, new_believed
        cycle += 1
        ending = _ending(
            scenario, cfg, state, believed, mode, clearance, c_moving < c_static, limit_s, failsafe
        )
        if ending is not None:
            reason, success, why = ending
            collisions = int(reason == "collision")
            message = why + (
                f" (last planning problem: {message})" if reason == "timeout" and message else ""
            )
            break
    recording.finish(nav.map)
    return MissionResult(
        scenario,
        cfg,
        success,
        reason,
        collisions,
        records,
        plans,
        keeper.result(last_frame),
        state.position.copy(),
        nav.map,
        time.perf_counter() - t_start,
        setup_s,
        message,
        believed.position.copy(),
        monitor,
        prior,
        None
        if monitor is None
        else monitor.summary(nav.map, state.time_s, None if truth else est_from_world),
        fault_report(faults, records),
        failsafe.events,
    )
