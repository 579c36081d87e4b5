"""Plans from where the drone has been: every flown camera position to every other.

For each seed this renders a stereo flight (``skyrecon render sequence``), maps it from stereo
(``skyrecon map``, which marks the flown track free with the vehicle's radius) and plans between
camera positions (every ``--every``-th frame, all ordered pairs) with ``skyrecon plan``'s settings
(clearance 2 m, unknown space not flyable, start / goal snapped to the nearest usable point within
``--snap-radius``). Each path is checked against the TRUE city: the smallest true distance along
it (sampled every 0.1 m) must stay above the drone radius (0.35 m) for no collision.

Prints, per seed and in total: queries, planned, snapped endpoints, collisions, the smallest true
clearance, and the median planning time.

Usage:
  .venv/bin/python benchmarks/planning/flown.py                      # seeds 0..2, 40 frames
  .venv/bin/python benchmarks/planning/flown.py --seeds 5 --frames 60 --every 3
  .venv/bin/python benchmarks/planning/flown.py --plain               # plain facades and ground (issue #13)

Results go to ``results_flown.json`` (``results_flown_plain.json`` with --plain).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from skyrecon.io.atomic import write_text_atomic  # noqa: E402
from skyrecon.io.sequence import read_sequence  # noqa: E402
from skyrecon.mapping import load_map, read_flown_path  # noqa: E402
from skyrecon.planning import plan_with_flown_path  # noqa: E402
from skyrecon.sim import generate_city  # noqa: E402

DRONE_RADIUS_M = 0.35


def _cli(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "skyrecon", *args, "--quiet"], check=True)


def _true_clearance(city, waypoints: np.ndarray) -> float:
    pts = [waypoints[:1]]
    for a, b in zip(waypoints[:-1], waypoints[1:]):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / 0.1)))
        pts.append(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
    return float(city.distance(np.concatenate(pts), include_ground=True).min())


def run_seed(
    seed: int, frames: int, every: int, snap: float, clearance: float, work: Path, plain: bool = False
) -> dict:
    seq_dir, map_dir = work / f"flight_{seed}", work / f"map_{seed}"
    extra = ["--plain"] if plain else []
    _cli("render", "sequence", "--seed", str(seed), "--frames", str(frames), *extra, "--out", str(seq_dir))
    _cli("map", str(seq_dir), "--out", str(map_dir))
    seq = read_sequence(seq_dir)
    assert seq.world_from_left is not None
    centres = np.array([p.t for p in seq.world_from_left])[::every]
    occ = load_map(map_dir)
    track = read_flown_path(map_dir)
    city = generate_city(seed, plain=plain)
    rows = []
    for i, s in enumerate(centres):
        for j, g in enumerate(centres):
            if i == j:
                continue
            t0 = time.perf_counter()
            r = plan_with_flown_path(occ, s, g, clearance, track, snap_radius_m=snap)
            ms = 1e3 * (time.perf_counter() - t0)
            clr = _true_clearance(city, r.waypoints) if r.success else None
            rows.append(
                {
                    "ok": r.success,
                    "reason": r.reason,
                    "snapped": sum(k in r.adjusted for k in ("start", "goal")),
                    "retraced": r.adjusted.get("route") == "flown_path",
                    "ms": ms,
                    "clr": clr,
                }
            )
    ok = [r for r in rows if r["ok"]]
    clr = [r["clr"] for r in ok]
    return {
        "seed": seed,
        "queries": len(rows),
        "planned": len(ok),
        "snapped_endpoints": int(sum(r["snapped"] for r in rows)),
        "retraced": int(sum(r["retraced"] for r in rows)),
        "collisions": int(sum(c < DRONE_RADIUS_M for c in clr)),
        "min_true_clearance_m": round(min(clr), 3) if clr else None,
        "median_ms": round(float(np.median([r["ms"] for r in rows])), 1),
        "failures": sorted({r["reason"] for r in rows if not r["ok"]}),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--every", type=int, default=4, help="use every N-th camera position (default 4)")
    ap.add_argument("--snap-radius", type=float, default=3.0, help="as skyrecon plan's (default 3 m)")
    ap.add_argument("--clearance", type=float, default=2.0)
    ap.add_argument("--plain", action="store_true", help="the plain city (skyrecon render sequence --plain)")
    args = ap.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            r = run_seed(
                seed, args.frames, args.every, args.snap_radius, args.clearance, Path(tmp), args.plain
            )
            results.append(r)
            print(
                f"seed {seed}: {r['planned']}/{r['queries']} planned, {r['snapped_endpoints']} endpoints snapped, "
                f"{r['retraced']} retrace the flown path, {r['collisions']} collisions, min true clearance {r['min_true_clearance_m']} m, "
                f"median {r['median_ms']} ms" + (f", failures {r['failures']}" if r["failures"] else ""),
                flush=True,
            )
    total = {
        "queries": sum(r["queries"] for r in results),
        "planned": sum(r["planned"] for r in results),
        "collisions": sum(r["collisions"] for r in results),
        "min_true_clearance_m": min(
            (r["min_true_clearance_m"] for r in results if r["min_true_clearance_m"] is not None),
            default=None,
        ),
    }
    print(
        f"total: {total['planned']}/{total['queries']} planned, {total['collisions']} collisions, "
        f"min true clearance {total['min_true_clearance_m']} m (drone radius {DRONE_RADIUS_M} m)"
    )
    doc = {"settings": vars(args), "seeds": results, "total": total}
    write_text_atomic(
        ROOT
        / "benchmarks"
        / "planning"
        / ("results_flown_plain.json" if args.plain else "results_flown.json"),
        json.dumps(doc, indent=2) + "\n",
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
