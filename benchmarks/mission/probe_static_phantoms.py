"""Phantom movers in a static city: the tracks the delivery loop kept clear of where nothing moves.

The delivery missions of ``run.py`` fly a static city, but the loop's mover tracker
(:class:`skyrecon.perception.MoverTracker`) runs all the same; every track it confirms as moving
is a phantom there, and the planner keeps clear of it (``replan_reasons["mover"]`` in
``mission.json``). This flies missions as ``run.py`` does (``--plain``, ``--camera-noise``) and
prints, per phantom track the planner avoided: its frames, time span, detections (hits), the
share of frames it was coasting, the median distance of its centre from the true static city,
its median speed, the median points of its detections, its last half size and its first
position.

Session 59, textured seed 11 at 1.5 grey levels (115 replans, 72 of them "mover"; length ratio
1.349): four phantom tracks; two coasting at 2-7 m/s on 3-4 chance detections (air), two at
1.6-2.2 m from the buildings the drone rounded, one of them still (median speed 0) and avoided
for 10 s (a track that moved once is never released as static), where the drone circled for
13 s before taking the next street.

Usage:
  .venv/bin/python benchmarks/mission/probe_static_phantoms.py --seeds 11 --camera-noise 1.5
  .venv/bin/python benchmarks/mission/probe_static_phantoms.py --seeds 11 15 19 --camera-noise 1.5 --plain
  .venv/bin/python benchmarks/mission/probe_static_phantoms.py --seeds 11 --camera-noise 1.5 --detections
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "passive")  # as `skyrecon demo` does

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

import numpy as np  # noqa: E402

import skyrecon.perception.movers as movers  # noqa: E402
from skyrecon.cli.common import add_camera_noise_option  # noqa: E402
from skyrecon.mission import MissionConfig  # noqa: E402
from skyrecon.mission.batch import fly_and_write  # noqa: E402


def fly(seed: int, out: Path, cfg: MissionConfig) -> list[dict]:
    """Fly one mission; one row per avoided track-frame (see the module docstring)."""
    rows: list[dict] = []
    scenarios: list = []
    update = movers.MoverTracker.update

    def update_probe(self, time_s, *args, **kwargs):
        mf = update(self, time_s, *args, **kwargs)
        dets = {d.track_id: d for d in mf.detections}
        for t in mf.tracks:
            if t.avoided:
                d = dets.get(t.track_id)
                rows.append(
                    {
                        "t": float(time_s),
                        "id": int(t.track_id),
                        "pos": t.position.tolist(),
                        "speed": float(np.linalg.norm(t.velocity)),
                        "half_size": t.half_size.tolist(),
                        "coasting": bool(t.coasting),
                        "hits": int(t.hits),
                        "n_points": None if d is None else int(d.n_points),
                        "det_center": None if d is None else d.center.tolist(),
                    }
                )
        return mf

    movers.MoverTracker.update = update_probe
    try:
        fly_and_write(seed, out / f"seed_{seed:04d}", cfg, on_scenario=scenarios.append)
    finally:
        movers.MoverTracker.update = update
    if rows:
        city = scenarios[0].city
        to_static = city.distance(np.array([r["pos"] for r in rows]), include_ground=True)
        for r, d in zip(rows, to_static):
            r["to_static_m"] = float(d)
    return rows


def report(seed: int, rows: list[dict], mission: dict, verbose: bool = False) -> None:
    reasons = mission.get("replan_reasons", {})
    print(
        f"seed {seed}: length ratio {mission.get('length_ratio')}, replans {mission.get('replans')} {reasons}, "
        f"{len(rows)} avoided track-frames"
    )
    for i in sorted({r["id"] for r in rows}):
        sel = [r for r in rows if r["id"] == i]
        pts = [r["n_points"] for r in sel if r["n_points"]]
        print(
            f"  track {i:3d}: {len(sel):4d} frames, t {sel[0]['t']:.1f}-{sel[-1]['t']:.1f} s, hits {sel[-1]['hits']}, "
            f"coasting {np.mean([r['coasting'] for r in sel]):.2f}, "
            f"to static {np.median([r['to_static_m'] for r in sel]):.2f} m, "
            f"speed {np.median([r['speed'] for r in sel]):.2f} m/s, "
            f"points {np.median(pts) if pts else 0:.0f}, half size {np.round(sel[-1]['half_size'], 1).tolist()}, "
            f"at {np.round(sel[0]['pos'], 1).tolist()}"
        )
        seen = [(r["t"], r["det_center"]) for r in sel if r["det_center"] is not None]
        if verbose and seen:
            print(
                "    detections (t s: centre m): "
                + ", ".join(f"{t:.1f}: {np.round(c, 1).tolist()}" for t, c in seen)
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[11])
    ap.add_argument("--plain", action="store_true", help="the plain city (run.py --plain)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "mission" / "out_static_phantoms")
    ap.add_argument("--detections", action="store_true", help="also list each avoided track's detections")
    add_camera_noise_option(ap)
    args = ap.parse_args()
    cfg = MissionConfig(camera_noise=args.camera_noise, plain=args.plain)
    for seed in args.seeds:
        rows = fly(seed, args.out, cfg)
        mission = json.loads((args.out / f"seed_{seed:04d}" / "mission.json").read_text())
        report(seed, rows, mission, args.detections)


if __name__ == "__main__":
    main()
