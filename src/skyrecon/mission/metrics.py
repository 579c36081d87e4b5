"""The numbers a mission is judged by (``mission.json``).

* ``success``: arrived within the tolerance of the goal without touching anything;
* ``collisions``: contacts with the TRUE geometry (true distance below the drone radius);
* ``min_clearance_m``: smallest true distance to any obstacle (ground included) along the
  flown track, sampled every 0.1 m; ``clearance_ok``: it stayed above ``safety_margin_m``;
* ``path_length_m``: length of the flown track; ``straight_line_m``: start to goal;
  ``shortest_feasible_m``: the planner's path in the true city at the same clearance and
  altitude band; ``length_ratio``: flown / shortest feasible;
* ``replans``: cycles in which a new path was planned after the first one;
* ``loop_hz``: 1000 / median milliseconds of the loop without rendering;
* ``loop_ms_p50/p95/p99/max``: the loop's milliseconds per cycle (rendering excluded), and
  ``latency_overruns``: cycles slower than the latency budget the stopping rule assumes;
* the stopping rule (:mod:`skyrecon.mission.safety`): ``speed_supported_mps`` (the highest
  speed the rig's trusted range lets the drone stop from), ``mean_speed_mps`` (flown length over
  flight time) and ``speed_ratio`` (over the cruise speed), ``stop_limited_fraction`` (share of
  cycles whose speed limit the stopping rule set), ``braking_cycles`` (cycles braking at full
  deceleration because the limit fell below the speed), ``retreats`` (times the drone backed off
  along its flown track to see a climb its camera could not look at,
  :func:`~skyrecon.mission.guidance.retreat_path`) and ``stop_rule_ok`` (every cycle was
  within the stopping rule's limit or braking at full deceleration along a line checked free);
* the pose (:mod:`skyrecon.mission.pose_source`): ``pose_source``; ``drift_m``: distance between
  where the drone believed it was and where it truly was at the end; ``ate_m``: RMS of that
  distance over every cycle (the estimated and the true world share the take-off pose, so no
  alignment); ``pose_degraded_cycles``, ``pose_lost_cycles`` and ``pose_reasons`` (count per reason);
* the city that moves (:func:`dynamic_metrics`): ``moving_obstacles``,
  ``min_clearance_static_m``, ``min_clearance_moving_m``, ``replan_reasons``, ``dynamic``
  (mover detection recall and error, phantom trails, vacated voxels, changes seen) and
  ``prior_map`` (what the cameras changed in the prior);
* faults (:mod:`skyrecon.sim.faults`, :mod:`skyrecon.mission.failsafe`): ``outcome``
  (delivered, hovering, returned, landed, collision, timeout, missed_goal), ``faults`` (each
  injected fault, its onset and when the health check revealed it) and ``failsafe_events``;
* ``image_noise_median``: the median noise of the left images, grey levels, as the health
  check measured it (the texture tests stand above it; ``MissionConfig.camera_noise`` sets the
  simulated cameras' noise);
* ``stage_ms``: per stage (render, stereo, integrate, distance, check, replan, control, loop)
  the median, 95th percentile and mean in milliseconds.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from skyrecon.mission.loop import LOOP_STAGES, STAGES, CycleRecord, MissionResult
from skyrecon.mission.prior import prior_changes
from skyrecon.mission.safety import rig_supported_speed, speed_warning
from skyrecon.mission.vehicle import path_length


def _stats(values: np.ndarray | Sequence[float]) -> dict:
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        return {"median": None, "p95": None, "mean": None, "max": None}
    return {
        "median": round(float(np.median(v)), 3),
        "p95": round(float(np.percentile(v, 95)), 3),
        "mean": round(float(v.mean()), 3),
        "max": round(float(v.max()), 3),
    }


def stop_rule_holds(records: list[CycleRecord], max_accel_mps2: float, dt: float) -> list[bool]:
    """Per cycle: the speed after the cycle's step is within the stopping rule's limit, or the
    drone braked at full deceleration (the speed fell by ``max_accel_mps2 * dt``, or to 0)."""
    out, prev = [], 0.0
    for r in records:
        braked = r.speed_mps <= max(0.0, prev - 0.999 * max_accel_mps2 * dt) + 1e-9
        out.append(bool(r.speed_mps <= r.stop_limit_mps + 1e-6 or braked))
        prev = r.speed_mps
    return out


def _percentiles(loop_ms: np.ndarray) -> dict:
    keys = ("loop_ms_p50", "loop_ms_p95", "loop_ms_p99", "loop_ms_max")
    if loop_ms.size == 0:
        return dict.fromkeys(keys)
    vals = [*np.percentile(loop_ms, [50, 95, 99]), loop_ms.max()]
    return {k: round(float(v), 2) for k, v in zip(keys, vals)}


def _median_noise(records: list[CycleRecord]) -> float | None:
    """Median image noise the health check measured over the flight, grey levels (None: none
    measured)."""
    v = [r.image_noise for r in records if r.image_noise is not None]
    return round(float(np.median(v)), 3) if v else None


def pose_metrics(result: MissionResult) -> dict:
    """``pose_source``, ``drift_m``, ``ate_m`` and the degraded and lost cycles of a mission."""
    recs = result.records
    err = np.array([r.pose_error_m for r in recs]) if recs else np.zeros(0)
    end_est = result.final_est_position
    drift = 0.0 if end_est is None else float(np.linalg.norm(end_est - result.final_position))
    reasons: dict[str, int] = {}
    for r in recs:
        if r.pose_state != "ok":
            reasons[r.pose_reason or r.pose_state] = reasons.get(r.pose_reason or r.pose_state, 0) + 1
    return {
        "pose_source": result.config.pose_source,
        "drift_m": round(drift, 3),
        "ate_m": round(float(np.sqrt(np.mean(err**2))), 3) if err.size else None,
        "pose_degraded_cycles": int(sum(r.pose_state == "degraded" for r in recs)),
        "pose_lost_cycles": int(sum(r.pose_state == "lost" for r in recs)),
        "pose_reasons": reasons,
    }


def outcome_of(result: MissionResult) -> str:
    """How the mission ended in one word: ``delivered``, ``hovering``, ``returned``, ``landed``,
    ``collision``, ``timeout`` (or ``missed_goal``: it believed it had arrived, but drifted)."""
    if result.success:
        return "delivered"
    return result.reason or "timeout"


def dynamic_metrics(result: MissionResult) -> dict:
    """The city that moves: ``moving_obstacles``, ``min_clearance_static_m`` and
    ``min_clearance_moving_m`` (true geometry, true time), ``replan_reasons``, the movers'
    detection and the changes since the prior (``dynamic``, see
    :mod:`skyrecon.mission.world_monitor`) and what the cameras changed in the prior (``prior_map``)."""
    recs = result.records
    c_static = [r.clearance_static_m for r in recs]
    c_moving = [r.clearance_moving_m for r in recs if np.isfinite(r.clearance_moving_m)]
    reasons: dict[str, int] = {}
    for r in recs:
        if r.replanned and r.replan_reason:
            reasons[r.replan_reason] = reasons.get(r.replan_reason, 0) + 1
    world = result.world_summary or {}
    return {
        "moving_obstacles": int(world.get("moving_obstacles", 0)),
        "min_clearance_static_m": round(float(min(c_static)), 3) if c_static else None,
        "min_clearance_moving_m": round(float(min(c_moving)), 3) if c_moving else None,
        "replan_reasons": reasons,
        "dynamic": world or None,
        "prior_map": None if result.prior is None else prior_changes(result.prior, result.occ_map),
    }


def mission_metrics(result: MissionResult) -> dict:
    """The metrics of a flown mission as a JSON-ready dict (see the module docstring)."""
    sc, cfg = result.scenario, result.config
    recs = result.records
    flown = path_length(result.flown_path())
    shortest = sc.shortest.length_m if sc.shortest.success else None
    loop = np.array([r.loop_ms for r in recs])
    stage_ms = {k: _stats([r.timings_ms.get(k, 0.0) for r in recs]) for k in STAGES}
    stage_ms["loop"] = _stats(loop)
    min_clear = float(min(r.clearance_m for r in recs)) if recs else None
    replans = max(0, sum(1 for r in recs if r.replanned and r.replan_ok) - 1)
    med = float(np.median(loop)) if len(loop) else float("nan")
    m = {
        "success": bool(result.success),
        "reason": result.reason,
        "message": result.message,
        "collisions": int(result.collisions),
        "min_clearance_m": round(min_clear, 3) if min_clear is not None else None,
        "safety_margin_m": cfg.safety_margin_m,
        "clearance_ok": bool(min_clear is not None and min_clear > cfg.safety_margin_m),
        "drone_radius_m": cfg.drone_radius_m,
        "planning_clearance_m": cfg.clearance_m,
        "path_length_m": round(flown, 3),
        "straight_line_m": round(sc.straight_line_m, 3),
        "shortest_feasible_m": round(shortest, 3) if shortest is not None else None,
        "length_ratio": round(flown / shortest, 4) if shortest and result.success else None,
        "replans": int(replans),
        "replan_attempts": int(sum(1 for r in recs if r.replanned)),
        "loop_hz": round(1000.0 / med, 2) if med > 0 else None,
        "loop_stages": list(LOOP_STAGES),
        "stage_ms": stage_ms,
        **_percentiles(loop),
        "latency_overruns": int(np.sum(loop > 1e3 * cfg.latency_budget_s)),
        "speed_supported_mps": round(rig_supported_speed(cfg), 2),
        "mean_speed_mps": round(flown / (len(recs) * cfg.dt), 3) if recs else None,
        "speed_ratio": round(flown / (len(recs) * cfg.dt) / cfg.cruise_speed_mps, 4) if recs else None,
        "stop_limited_fraction": round(float(np.mean([r.stop_limited for r in recs])), 4) if recs else None,
        "braking_cycles": int(sum(1 for r in recs if r.speed_mps > r.stop_limit_mps + 1e-6)),
        "retreats": int(
            sum(
                1
                for a, b in zip([None, *recs], recs)
                if b.mode == "retreat" and (a is None or a.mode != "retreat")
            )
        ),
        "stop_rule_ok": all(stop_rule_holds(recs, cfg.max_accel_mps2, cfg.dt)),
        "warnings": [w for w in (speed_warning(cfg),) if w],
        "cycles": len(recs),
        "flight_time_s": round(len(recs) * cfg.dt, 2),
        "distance_to_goal_m": round(float(np.linalg.norm(result.final_position - sc.goal)), 3),
        "mean_measured_fraction": round(float(np.mean([r.measured_fraction for r in recs])), 4)
        if recs
        else None,
        "image_noise_median": _median_noise(recs),
        "wall_s": round(result.wall_s, 2),
        "setup_s": round(result.setup_s, 2),
        "seed": int(sc.seed),
        "map_voxels": result.occ_map.counts(),
        **pose_metrics(result),
        **dynamic_metrics(result),
        "outcome": outcome_of(result),
        "faults": result.faults,
        "failsafe_events": result.failsafe_events,
    }
    if not result.success and not m["reason"]:
        m["reason"] = "unknown"
    return m
