"""One mission from seed to files, and many missions in parallel with a summary.

:func:`fly_and_write` is what ``skyrecon demo`` does for one seed; :func:`run_missions` fans
seeds ``seed, seed + 1, ...`` out over the executor (:func:`skyrecon.executor.get_executor`,
one process per mission), each mission in its own folder ``seed_NNNN/``, and writes
``summary.json``, ``summary.md`` and ``summary.html`` beside them.

Missions running side by side share the cores: their loop rates then measure a loaded machine
(the loop rate target is for one mission on the machine).
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skyrecon.executor import get_executor
from skyrecon.io.atomic import write_text_atomic
from skyrecon.mission.config import MissionConfig
from skyrecon.mission.loop import run_mission
from skyrecon.mission.outputs import write_mission_outputs, write_refused_outputs
from skyrecon.mission.scenario import ImpossibleMission, make_scenario
from skyrecon.record import Recorder
from skyrecon.report.mission_report import render_summary_report
from skyrecon.sim import generate_city

SUMMARY_KEYS = (
    "seed",
    "success",
    "reason",
    "collisions",
    "min_clearance_m",
    "clearance_ok",
    "path_length_m",
    "straight_line_m",
    "shortest_feasible_m",
    "length_ratio",
    "replans",
    "loop_hz",
    "loop_ms_p99",
    "flight_time_s",
    "mean_speed_mps",
    "speed_ratio",
    "stop_limited_fraction",
    "stop_rule_ok",
    "wall_s",
    "pose_source",
    "drift_m",
    "ate_m",
    "pose_lost_cycles",
    "moving_obstacles",
    "min_clearance_static_m",
    "min_clearance_moving_m",
)


@dataclass
class Outcome:
    """How a mission ended: ``doc`` is what ``mission.json`` holds; ``refused`` when the input
    made it impossible (nothing was flown); ``out`` the mission folder."""

    doc: dict
    refused: bool
    out: Path


def fly_and_write(
    seed: int,
    out: str | Path,
    cfg: MissionConfig,
    start=None,
    goal=None,
    on_cycle: Callable | None = None,
    on_scenario: Callable | None = None,
    cloud_format: str = "ply",
    recorder: Recorder | None = None,
) -> Outcome:
    """Generate the scenario, fly it and write every output to ``out``.

    An impossible mission (:class:`ImpossibleMission`) is not raised: its ``mission.json`` and
    ``report.html`` say why, and the outcome is ``refused``.

    Args:
        seed: city seed; start, goal: optional (3,) world metres (both or neither).
        cfg: mission settings.
        on_cycle: progress callback ``(CycleRecord, Navigator)`` per cycle.
        on_scenario: called with the Scenario before take-off.
        cloud_format: ``ply``, ``las`` or ``laz`` for the map's occupied-voxel cloud.
        recorder: logs the flight for a viewer (:mod:`skyrecon.record`), or None.
    """
    out = Path(out)
    try:
        scenario = make_scenario(seed, cfg, start, goal)
    except ImpossibleMission as e:
        city = None
        try:
            city = generate_city(int(seed), cfg.city_size_m, plain=cfg.plain)
        except Exception:  # noqa: BLE001 - the picture is optional; the reason is what matters
            city = None
        doc = write_refused_outputs(out, e.reason, e.code, seed, cfg, start, goal, city)
        return Outcome(doc, True, out)
    if on_scenario is not None:
        on_scenario(scenario)
    result = run_mission(scenario, cfg, on_cycle=on_cycle, recorder=recorder)
    doc = write_mission_outputs(result, out, cloud_format=cloud_format)
    return Outcome(doc, False, out)


def read_mission_json(folder: str | Path, cfg: MissionConfig | None = None) -> dict | None:
    """The ``mission.json`` of a finished mission folder, or None when it has none (or it is
    unreadable, or the mission ended in an error): for resuming batches and benchmarks. With
    ``cfg``, None also when the folder was flown with other settings (its ``config``, missing
    fields taken as their defaults, differs from ``cfg``): a resumed benchmark flies it again
    rather than mixing in a flight of other settings. (The code it was flown with is not
    recorded: a folder flown by older code with the same settings is still read back.)"""
    p = Path(folder) / "mission.json"
    if not p.is_file():
        return None
    try:
        doc = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if doc.get("reason") == "error":
        return None
    if cfg is not None and not _same_settings(doc.get("config"), cfg):
        return None
    return doc


def _same_settings(flown: dict | None, cfg: MissionConfig) -> bool:
    """Whether a ``mission.json`` ``config`` (missing fields: defaults) holds the settings of ``cfg``."""
    if not isinstance(flown, dict):
        return False
    try:
        was = MissionConfig.from_dict(flown).to_dict()
    except (TypeError, ValueError):
        return False
    return json.dumps(was, sort_keys=True, default=str) == json.dumps(
        cfg.to_dict(), sort_keys=True, default=str
    )


def mission_line(doc: dict) -> str:
    """One line describing a mission outcome (for stderr)."""
    seed = doc.get("seed")
    if doc.get("success"):
        return (
            f"seed {seed}: delivered, {doc['path_length_m']:.1f} m flown (x{doc['length_ratio']:.3f} of the "
            f"shortest {doc['shortest_feasible_m']:.1f} m), min clearance {doc['min_clearance_m']:.2f} m, "
            f"{doc['collisions']} collisions, {doc['replans']} replans, loop {doc['loop_hz']:.1f} Hz"
        )
    what = "not flown" if doc.get("loop_hz") is None and not doc.get("path_length_m") else "FAILED"
    return f"seed {seed}: {what} ({doc.get('reason')}): {doc.get('message', '')}"


@dataclass(frozen=True)
class MissionJob:
    """One mission of a batch (picklable): seed, output folder, settings as a dict."""

    seed: int
    out: str
    config: dict
    quiet: bool = False
    cloud_format: str = "ply"


def fly_job(job: MissionJob) -> dict:
    """Executor entry point: fly one mission, write its folder, print its line; returns its summary row."""
    t0 = time.perf_counter()
    cfg = MissionConfig.from_dict(job.config)
    try:
        outcome = fly_and_write(job.seed, job.out, cfg, cloud_format=job.cloud_format)
        doc = outcome.doc
    except Exception as e:  # noqa: BLE001 - one broken mission must not lose the batch
        doc = {
            "seed": job.seed,
            "success": False,
            "reason": "error",
            "message": f"{type(e).__name__}: {e}",
            "collisions": 0,
        }
        write_text_atomic(Path(job.out) / "mission.json", json.dumps(doc, indent=2) + "\n")
    row = {k: doc.get(k) for k in SUMMARY_KEYS}
    row["message"] = doc.get("message", "")
    row["folder"] = Path(job.out).name
    row["wall_s"] = round(time.perf_counter() - t0, 1)
    if not job.quiet:
        print(mission_line(doc), file=sys.stderr, flush=True)
    return row


def summarize(rows: Sequence[dict]) -> dict:
    """Totals over missions: counts, worst clearance and ratio, loop-rate median and minimum, and the
    loop's worst per-mission p99 latency (milliseconds, rendering excluded)."""
    n = len(rows)
    ok = [r for r in rows if r.get("success")]
    ratios = [r["length_ratio"] for r in rows if r.get("length_ratio") is not None]
    hz = [r["loop_hz"] for r in rows if r.get("loop_hz")]
    clr = [r["min_clearance_m"] for r in rows if r.get("min_clearance_m") is not None]
    p99 = [r["loop_ms_p99"] for r in rows if r.get("loop_ms_p99") is not None]
    drift = [r["drift_m"] for r in rows if r.get("drift_m") is not None]
    ate = [r["ate_m"] for r in rows if r.get("ate_m") is not None]
    return {
        "missions": n,
        "succeeded": len(ok),
        "collisions": int(sum(int(r.get("collisions") or 0) for r in rows)),
        "min_clearance_m": min(clr) if clr else None,
        "length_ratio_median": float(np.median(ratios)) if ratios else None,
        "length_ratio_max": max(ratios) if ratios else None,
        "loop_hz_median": float(np.median(hz)) if hz else None,
        "loop_hz_min": min(hz) if hz else None,
        "loop_ms_p99_max": max(p99) if p99 else None,
        "drift_m_max": max(drift) if drift else None,
        "ate_m_max": max(ate) if ate else None,
    }


def summary_markdown(rows: Sequence[dict], totals: dict) -> str:
    """A Markdown table of the missions and a line of totals."""

    def f(v, fmt="{:.2f}"):
        return (
            "–"
            if v is None
            else (
                ("yes" if v else "no")
                if isinstance(v, bool)
                else (fmt.format(v) if isinstance(v, float) else str(v))
            )
        )

    lines = [
        "| seed | success | collisions | min clearance m | flown m | shortest m | ratio | replans | loop Hz | reason |",
        "|---:|:---:|---:|---:|---:|---:|---:|---:|---:|:---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.get('seed')} | {f(r.get('success'))} | {f(r.get('collisions'))} | {f(r.get('min_clearance_m'))} | "
            f"{f(r.get('path_length_m'), '{:.1f}')} | {f(r.get('shortest_feasible_m'), '{:.1f}')} | "
            f"{f(r.get('length_ratio'), '{:.3f}')} | {f(r.get('replans'))} | {f(r.get('loop_hz'), '{:.1f}')} | "
            f"{r.get('reason') or ''} |"
        )
    lines.append("")
    lines.append(
        f"{totals['succeeded']} of {totals['missions']} delivered, {totals['collisions']} collisions, "
        f"min clearance {f(totals['min_clearance_m'])} m, length ratio median {f(totals['length_ratio_median'], '{:.3f}')} "
        f"(worst {f(totals['length_ratio_max'], '{:.3f}')}), loop median {f(totals['loop_hz_median'], '{:.1f}')} Hz "
        f"(slowest {f(totals['loop_hz_min'], '{:.1f}')} Hz), loop p99 at most {f(totals.get('loop_ms_p99_max'), '{:.1f}')} ms"
    )
    return "\n".join(lines) + "\n"


def run_missions(
    seeds: Sequence[int],
    out: str | Path,
    cfg: MissionConfig,
    executor=None,
    quiet: bool = False,
    cloud_format: str = "ply",
) -> tuple[list[dict], dict]:
    """Fly one mission per seed (in parallel through ``executor``) and write the summary.

    Args:
        seeds: city seeds; mission ``s`` goes to ``out/seed_NNNN``.
        out: the batch folder.
        cfg: settings shared by every mission.
        executor: an :class:`~skyrecon.executor.Executor` (default ``get_executor()``).
        cloud_format: ``ply``, ``las`` or ``laz`` for each map's occupied-voxel cloud.
    Returns:
        (rows, totals): one summary row per mission, in seed order, and the totals.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [
        MissionJob(int(s), str(out / f"seed_{int(s):04d}"), cfg.to_dict(), quiet, cloud_format) for s in seeds
    ]
    ex = executor or get_executor()
    rows = ex.map(fly_job, jobs, desc="missions")
    totals = summarize(rows)
    write_text_atomic(
        out / "summary.json",
        json.dumps(
            {"format": "skyrecon.mission.summary", "version": 1, "totals": totals, "missions": rows}, indent=2
        )
        + "\n",
    )
    write_text_atomic(out / "summary.md", summary_markdown(rows, totals))
    write_text_atomic(out / "summary.html", render_summary_report(rows))
    return rows, totals
