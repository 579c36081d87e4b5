"""Delivery missions at delivery speeds: 6, 10, 12 and 15 m/s, the same seeds at each speed.

For each cruise speed this flies every seed with `skyrecon demo`'s mission (640x480, 200 m city)
and prints: delivered, collisions (TRUE geometry), the minimum true clearance (target above the
1 m safety margin), the mean speed achieved over the mission as a share of the cruise speed
(mean over missions and the worst one), how often the stopping rule set the speed limit, whether
the stopping rule held in every cycle, and the loop's p99 latency (worst mission).

Targets (issue "Safe at delivery speed"): 0 collisions and clearance above the margin at every
speed; at least 19 of 20 delivered at 12 m/s; mean speed at least 70 % of 12 m/s; loop p99 at most
50 ms. The rig (0.3 m baseline: its map reaches 17 m, where a quarter pixel of disparity error
moves depth 1.5 m) and the braking limit (5 m/s^2) support about 11.5 m/s: at 12 and 15 m/s the
drone warns and flies at most that.

What a wider rig buys (``--baseline``, as ``skyrecon demo --baseline``): the trusted range grows
as the square root of the baseline (same depth error at its end), and with it the speed the
drone can stop from; the table at the start lists it for 0.3, 0.45 and 0.6 m.

Usage:
  .venv/bin/python benchmarks/mission/speeds.py                        # seeds 0..19, 4 speeds
  .venv/bin/python benchmarks/mission/speeds.py --speeds 15 --baseline 0.6   # a 0.6 m rig at 15 m/s
  .venv/bin/python benchmarks/mission/speeds.py --seeds 5 --first-seed 100 --speeds 10 12
Resumable: a mission whose folder has a mission.json is read back (``--fresh`` flies it again).
Writes OUT/speeds.json and benchmarks/mission/results_speeds.json (for the default run: 20 seeds
from 0 at the four speeds; other runs write OUT/speeds.json only).
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
from skyrecon.mission.batch import MissionJob, fly_job  # noqa: E402
from skyrecon.mission.perception import hit_range_m  # noqa: E402
from skyrecon.mission.safety import rig_supported_speed  # noqa: E402

KEYS = (
    "seed",
    "success",
    "reason",
    "collisions",
    "min_clearance_m",
    "mean_speed_mps",
    "speed_ratio",
    "stop_limited_fraction",
    "stop_rule_ok",
    "loop_ms_p99",
)


def _row(folder: Path) -> dict | None:
    p = folder / "mission.json"
    if not p.is_file():
        return None
    doc = json.loads(p.read_text())
    return None if doc.get("reason") == "error" else {k: doc.get(k) for k in KEYS}


def _summary(speed: float, rows: list[dict], margin: float) -> dict:
    def vals(k):
        return [r[k] for r in rows if r.get(k) is not None]

    ratio = vals("speed_ratio")
    return {
        "speed_mps": speed,
        "missions": len(rows),
        "delivered": sum(bool(r.get("success")) for r in rows),
        "collisions": sum(int(r.get("collisions") or 0) for r in rows),
        "min_clearance_m": min(vals("min_clearance_m"), default=None),
        "clearance_ok": all(v > margin for v in vals("min_clearance_m")),
        "speed_ratio_mean": round(float(np.mean(ratio)), 3) if ratio else None,
        "speed_ratio_worst": min(ratio, default=None),
        "stop_limited_mean": round(float(np.mean(vals("stop_limited_fraction"))), 3) if rows else None,
        "stop_rule_ok": all(bool(r.get("stop_rule_ok")) for r in rows),
        "loop_ms_p99_worst": max(vals("loop_ms_p99"), default=None),
        "failures": [f"seed {r['seed']}: {r.get('reason')}" for r in rows if not r.get("success")],
    }


def main() -> int:
    install_sigterm()  # kill PID stops the missions' worker processes too
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--speeds", type=float, nargs="+", default=[6.0, 10.0, 12.0, 15.0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--parallel", type=int, default=2, help="missions at once (default 2)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "mission" / "out_speeds"))
    ap.add_argument("--fresh", action="store_true")
    ap.add_argument("--baseline", type=float, help="stereo baseline, metres (default 0.3, the product's rig)")
    args = ap.parse_args()

    base = MissionConfig()
    print("baseline m  depth range m  map range m  rig supports m/s")
    for b in (0.3, 0.45, 0.6):
        c = base.with_baseline(b)
        print(f"{b:>10g} {c.max_range_m:>14.1f} {hit_range_m(c):>12.1f} {rig_supported_speed(c):>17.1f}")
    if args.baseline is not None:
        base = base.with_baseline(args.baseline)
        if args.out == ap.get_default("out"):
            args.out += f"_baseline_{args.baseline:g}"
    out = Path(args.out)
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    jobs, folders = [], {}
    for v in args.speeds:
        cfg = base.with_overrides(cruise_speed_mps=v)
        for s in seeds:
            folder = out / f"speed_{v:g}" / f"seed_{s:04d}"
            folders[(v, s)] = folder
            if args.fresh or _row(folder) is None:
                jobs.append(MissionJob(s, str(folder), cfg.to_dict(), quiet=True))
    print(
        f"{len(jobs)} missions to fly ({len(args.speeds)} speeds x {len(seeds)} seeds), {args.parallel} at a time"
    )
    t0 = time.perf_counter()
    if jobs:
        ProcessExecutor(args.parallel).map(fly_job, jobs, desc="missions")
    results = []
    for v in args.speeds:
        rows = [_row(folders[(v, s)]) or {"seed": s, "success": False, "reason": "error"} for s in seeds]
        results.append(_summary(v, rows, base.safety_margin_m))
    hdr = (
        f"{'m/s':>4} {'deliv':>6} {'coll':>4} {'min clr m':>9} {'speed/cruise':>13} {'worst':>6} "
        f"{'stop-limited':>12} {'rule held':>9} {'p99 ms':>7}"
    )
    print(
        f"\nbraking {base.max_accel_mps2:g} m/s^2, map to {hit_range_m(base):.1f} m: the rig supports "
        f"{rig_supported_speed(base):.1f} m/s\n{hdr}\n" + "-" * len(hdr)
    )
    for r in results:
        print(
            f"{r['speed_mps']:>4g} {r['delivered']:>3}/{r['missions']:<2} {r['collisions']:>4} "
            f"{r['min_clearance_m'] or float('nan'):>9.2f} {r['speed_ratio_mean'] or float('nan'):>13.2f} "
            f"{r['speed_ratio_worst'] or float('nan'):>6.2f} {r['stop_limited_mean'] or float('nan'):>12.2f} "
            f"{'yes' if r['stop_rule_ok'] else 'NO':>9} {r['loop_ms_p99_worst'] or float('nan'):>7.1f}"
            + (f"   {'; '.join(r['failures'])}" if r["failures"] else "")
        )
    print(f"\nwall time {time.perf_counter() - t0:.0f} s for {len(jobs)} missions flown now")
    rig = {
        "baseline_m": base.baseline_m,
        "max_range_m": round(base.max_range_m, 2),
        "map_range_m": round(hit_range_m(base), 2),
    }
    doc = json.dumps({"cpu_count": os.cpu_count(), "rig": rig, "seeds": seeds, "speeds": results}, indent=2)
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "speeds.json", doc + "\n")
    if args.seeds == 20 and args.first_seed == 0 and sorted(args.speeds) == sorted(ap.get_default("speeds")):
        name = (
            "results_speeds.json"
            if args.baseline is None
            else f"results_speeds_baseline_{args.baseline:g}.json"
        )
        write_text_atomic(ROOT / "benchmarks" / "mission" / name, doc + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
