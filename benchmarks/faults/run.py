"""Faults in flight: seeded delivery missions with a random mix of sensor and computer faults.

Every mission (``skyrecon demo --faults random``) gets 1-3 faults drawn from its seed (blackout,
freeze, drop, one-eye, latency, cpu, glare, noise; onsets 5 s to 70 % of the time limit,
durations 0.5-6 s, one in five lasting to the end). The drone must find each fault from its
data and stay safe. Judged on the TRUE geometry. Prints per mission and in total: how it ended
(delivered, hovering, returned, landed, collision, timeout), collisions, the worst true
clearance, the time to detect each fault type (worst and median, seconds after onset) and the
loop's p99 latency.

Targets (issue "Faults in flight and on the ground"): 0 collisions in 100; every mission
delivered, hovering safely, returned or landed; each fault detected within 0.3 s of its onset.

Usage:
  .venv/bin/python benchmarks/faults/run.py                   # 100 seeds, 2 at a time, 640x480
  .venv/bin/python benchmarks/faults/run.py --small --seeds 40 # 320x240, 100 m city (quicker)
  .venv/bin/python benchmarks/faults/run.py --failsafe land

Resumable (a mission folder with ``mission.json`` is read back; ``--fresh`` flies all again).
Writes ``OUT/summary.json`` and ``benchmarks/faults/results*.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "passive")

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

import numpy as np  # noqa: E402

from skyrecon.cli.main import install_sigterm  # noqa: E402
from skyrecon.executor import ProcessExecutor  # noqa: E402
from skyrecon.io.atomic import write_text_atomic  # noqa: E402
from skyrecon.mission import MissionConfig  # noqa: E402
from skyrecon.mission.batch import MissionJob, fly_job, read_mission_json  # noqa: E402
from skyrecon.mission.config import SMALL_BENCHMARK  # noqa: E402

SAFE_ENDS = ("delivered", "hovering", "returned", "landed")


def totals(docs: list[dict]) -> dict:
    """Figures over the missions."""
    ends: dict[str, int] = {}
    delays: dict[str, list[float]] = {}
    missed: dict[str, int] = {}
    masked: dict[str, int] = {}
    for d in docs:
        ends[d.get("outcome") or "?"] = ends.get(d.get("outcome") or "?", 0) + 1
        end_t = d.get("flight_time_s") or 0.0
        for f in d.get("faults") or []:
            if f["onset_s"] >= end_t - 0.2:
                continue  # the mission ended before this fault began
            if f.get("masked"):
                masked[f["name"]] = masked.get(f["name"], 0) + 1  # no frame arrived while it lasted
            elif f.get("detected_s") is None:
                missed[f["name"]] = missed.get(f["name"], 0) + 1
            else:
                delays.setdefault(f["name"], []).append(float(f["detect_delay_s"]))
    clr = [d["min_clearance_m"] for d in docs if d.get("min_clearance_m") is not None]
    p99 = [d["loop_ms_p99"] for d in docs if d.get("loop_ms_p99") is not None]
    return {
        "missions": len(docs),
        "ends": ends,
        "safe_ends": sum(ends.get(k, 0) for k in SAFE_ENDS),
        "collisions": sum(int(d.get("collisions") or 0) for d in docs),
        "min_clearance_m": min(clr) if clr else None,
        "detect_s": {
            k: {"n": len(v), "median": round(float(np.median(v)), 3), "worst": round(max(v), 3)}
            for k, v in sorted(delays.items())
        },
        "undetected": missed,
        "masked_by_missing_frames": masked,
        "loop_ms_p99_worst": max(p99) if p99 else None,
        "loop_ms_p99_median": float(np.median(p99)) if p99 else None,
    }


def main() -> int:
    install_sigterm()  # kill PID stops the missions' worker processes too
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--first-seed", type=int, default=200)
    ap.add_argument("--parallel", type=int, default=2)
    ap.add_argument("--fresh", action="store_true")
    ap.add_argument("--small", action="store_true", help="320x240 images, 100 m city, 50-90 m deliveries")
    ap.add_argument("--failsafe", default="return", choices=("return", "land", "hover"))
    ap.add_argument("--pose-source", default="truth", choices=("truth", "odometry", "gps+odometry"))
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "faults" / "out"))
    args = ap.parse_args()
    cfg = MissionConfig(faults="random", failsafe=args.failsafe, pose_source=args.pose_source)
    if args.small:
        cfg = cfg.with_overrides(**SMALL_BENCHMARK, map_padding_m=20.0)
    tag = ("_small" if args.small else "") + ("" if args.failsafe == "return" else f"_{args.failsafe}")
    tag += "" if args.pose_source == "truth" else f"_{args.pose_source}"
    out = Path(args.out + tag)
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    t0 = time.perf_counter()
    jobs = [
        MissionJob(s, str(out / f"seed_{s:04d}"), cfg.to_dict())
        for s in seeds
        if args.fresh or read_mission_json(out / f"seed_{s:04d}", cfg) is None
    ]
    if jobs:
        ProcessExecutor(workers=args.parallel).map(fly_job, jobs, desc="fault missions")
    docs = [d for s in seeds if (d := read_mission_json(out / f"seed_{s:04d}")) is not None]
    print(f"{'seed':>5} {'outcome':>10} {'coll':>4} {'min clr':>7} {'p99 ms':>7}  faults (detected after s)")
    for d in docs:
        fl = ", ".join(
            f"{f['name']}@{f['onset_s']}:"
            + ("-" if f.get("detect_delay_s") is None else f"{f['detect_delay_s']:.1f}")
            for f in d.get("faults") or []
        )
        print(
            f"{d['seed']:>5} {d.get('outcome'):>10} {d.get('collisions', 0):>4} "
            f"{d.get('min_clearance_m') or 0:>7.2f} {d.get('loop_ms_p99') or 0:>7.1f}  {fl}"
        )
    tot = totals(docs)
    print("\ntotals:", json.dumps(tot, indent=1))
    result = {"config": {"small": args.small, "failsafe": args.failsafe, "seeds": seeds}, "totals": tot}
    result["wall_s"] = round(time.perf_counter() - t0, 1)
    write_text_atomic(
        ROOT / "benchmarks" / "faults" / f"results{tag}.json", json.dumps(result, indent=1) + "\n"
    )
    write_text_atomic(out / "summary.json", json.dumps({"totals": tot}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
