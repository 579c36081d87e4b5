"""Writing a mission to disk (every file atomically).

A mission folder holds:

* ``mission.json``: the metrics (:func:`~skyrecon.mission.metrics.mission_metrics`) at the top
  level, plus ``scenario`` (start, goal, seed...), ``config`` (every setting), ``plans`` (each
  path followed: cycle, kind, waypoints in world metres) and ``files``;
* ``path.json``: the flown track as a ``skyrecon.path`` (waypoints (N, 3) world metres, one per
  cycle, the final position last), with the start, the goal and the last planned path;
* ``cycles.json``: one record per cycle (pose, speed, per-stage milliseconds, true clearance,
  replanning);
* ``map/``: the drone's final occupancy map (``skyrecon.mapping.save_map``, compressed) and
  ``occupied.ply`` (centres of its occupied voxels, world frame; ``.las``/``.laz`` with that format);
* ``overview.png`` and ``report.html`` (self-contained);
* ``view/index.html``: the 3D view of the map, the flown track and the last planned path
  (:mod:`skyrecon.viewer`, opens from disk), embedded in ``report.html``.

A refused mission (impossible input) gets ``mission.json`` with ``success: false`` and the
``reason`` and ``report.html`` saying why.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skyrecon.io.atomic import write_text_atomic
from skyrecon.io.images import write_image
from skyrecon.io.jsonio import dumps_json
from skyrecon.mapping import export_occupied_ply, save_map
from skyrecon.mission.config import MissionConfig
from skyrecon.mission.loop import MissionResult
from skyrecon.mission.metrics import mission_metrics
from skyrecon.planning import write_path_json
from skyrecon.report.mission_report import overview_image, render_mission_report, render_refused_report
from skyrecon.viewer import map_scene, write_page

#: At most this many occupied voxels in the report's 3D view (a uniform subsample beyond).
VIEW_MAX_VOXELS = 400_000

FORMAT = "skyrecon.mission"
VERSION = 1


def write_mission_outputs(
    result: MissionResult, out_dir: str | Path, save_the_map: bool = True, cloud_format: str = "ply"
) -> dict:
    """Write every output of a flown mission to ``out_dir`` (created if missing).

    ``cloud_format`` (``ply``, ``las`` or ``laz``) is the format of the map's occupied-voxel cloud.

    Returns:
        The metrics dict that was written to ``mission.json`` (with its ``files``).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    m = mission_metrics(result)
    sc = result.scenario
    flown = result.flown_path()
    files = {
        "report": "report.html",
        "path": "path.json",
        "cycles": "cycles.json",
        "overview": "overview.png",
    }
    last_plan = result.plans[-1].waypoints if result.plans else np.zeros((0, 3))
    write_path_json(
        out / "path.json",
        flown,
        kind="flown",
        seed=sc.seed,
        start=sc.start,
        goal=sc.goal,
        success=result.success,
        last_planned_path=last_plan,
    )
    write_text_atomic(
        out / "cycles.json",
        dumps_json(
            {
                "format": "skyrecon.mission.cycles",
                "version": 1,
                "cycles": [r.to_dict() for r in result.records],
            }
        ),
    )
    if save_the_map:
        save_map(result.occ_map, out / "map", compress=True)
        export_occupied_ply(result.occ_map, out / "map" / "occupied.ply", fmt=cloud_format)
        files.update(map="map/", occupied=f"map/occupied.{cloud_format}")
    box = sc.box
    over = overview_image(
        sc.city,
        (box.origin[0], box.origin[1], box.upper[0], box.upper[1]),
        result.occ_map.occupied_centers(),
        [p.waypoints for p in result.plans],
        sc.shortest.waypoints if sc.shortest.success else None,
        flown,
        sc.start,
        sc.goal,
    )
    write_image(out / "overview.png", over)
    view = map_scene(
        f"mission, seed {sc.seed}",
        result.occ_map.occupied_centers(),
        float(result.occ_map.config.voxel_size_m),
        flown,
        last_plan,
    )
    write_page(view.subsampled(VIEW_MAX_VOXELS, seed=0), out / "view")
    files["view"] = "view/index.html"
    m["files"] = files
    doc = {
        "format": FORMAT,
        "version": VERSION,
        **m,
        "scenario": sc.to_dict(),
        "config": result.config.to_dict(),
        "plans": [
            {
                "cycle": p.cycle,
                "kind": p.kind,
                "length_m": float(np.linalg.norm(np.diff(p.waypoints, axis=0), axis=1).sum()),
                "waypoints": np.round(p.waypoints, 3).tolist(),
            }
            for p in result.plans
        ],
    }
    write_text_atomic(out / "mission.json", dumps_json(doc))
    write_text_atomic(out / "report.html", render_mission_report(result, m, view_src="view/index.html"))
    return m


def write_refused_outputs(
    out_dir: str | Path,
    message: str,
    code: str,
    seed: int,
    cfg: MissionConfig,
    start=None,
    goal=None,
    city=None,
) -> dict:
    """Write ``mission.json`` and ``report.html`` for a mission refused before take-off.

    Returns:
        The dict written to ``mission.json``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    def as_list(p):
        return None if p is None else [float(v) for v in np.asarray(p, dtype=float).reshape(-1)]

    doc = {
        "format": FORMAT,
        "version": VERSION,
        "success": False,
        "reason": code,
        "message": message,
        "collisions": 0,
        "min_clearance_m": None,
        "path_length_m": 0.0,
        "straight_line_m": None,
        "shortest_feasible_m": None,
        "length_ratio": None,
        "replans": 0,
        "loop_hz": None,
        "stage_ms": {},
        "seed": int(seed),
        "scenario": {"seed": int(seed), "start": as_list(start), "goal": as_list(goal)},
        "config": cfg.to_dict(),
        "files": {"report": "report.html"},
    }
    if start is not None and goal is not None:
        s, g = np.asarray(start, dtype=float).reshape(-1), np.asarray(goal, dtype=float).reshape(-1)
        if s.shape == g.shape == (3,) and np.all(np.isfinite(s)) and np.all(np.isfinite(g)):
            doc["straight_line_m"] = round(float(np.linalg.norm(g - s)), 3)
    write_text_atomic(out / "mission.json", dumps_json(doc))
    write_text_atomic(out / "report.html", render_refused_report(message, code, seed, cfg, city, start, goal))
    return doc
