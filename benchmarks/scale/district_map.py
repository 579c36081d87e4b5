"""A district-scale map: 1 km x 1 km at 0.5 m from many flights, in tiles, with queries and plans.

What it does, each phase in its own process so that its peak memory is its own:

1. **flights**: a 1 km x 1 km synthetic city (``generate_city(seed, 1000)``, buildings up to 60 m) is
   flown by ``--flights`` survey flights, each over its own strip of the district (lawn-mower lines
   along x at ``--altitude`` m, 50 m apart, a frame every ``--step`` (15) m, camera pitched 50 degrees down and
   turned alternately left and right, 320x240, 90 degree field of view, exact depth). Each flight builds
   its own map (0.5 m voxels, 80 m range) and saves it: these are the "maps of separate flights".
2. **merge**: ``skyrecon map --merge FLIGHT_MAPS... --tile-size 64 --out district/`` (the command a user
   runs), one map at a time into tiles on disk. Reported: wall time and peak memory (target <= 4 GB).
3. **queries**: ``--queries`` occupancy queries at random points anywhere in the district (0-100 m
   high), each on a freshly opened map with an empty tile cache, so every query reads its tile from
   disk (the worst case); p50 / p99 / max milliseconds (target < 100 ms).
4. **plans**: ``--plans`` paths between random street points at 15 m, at least 600 m apart, below
   22 m (so they must go around the buildings, along the streets), clearance 2 m, with ``skyrecon.planning.tiled``;
   each path is checked against the TRUE city geometry (``City.distance``): its smallest clearance is
   reported (it must stay above 0, the drone's body; the planner keeps 2 m to the mapped voxels).

Usage:
  .venv/bin/python benchmarks/scale/district_map.py                       # 1 km, 8 flights
  .venv/bin/python benchmarks/scale/district_map.py --size 400 --flights 2 --queries 200 --plans 2
Writes benchmarks/scale/district_results.json (or --out). The work folder (--work, default a temporary
folder) holds the flight maps and the tiled map; --keep keeps it.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def flight_poses(
    size_m: float, strip: tuple[float, float], altitude_m: float, spacing_m: float, step_m: float
):
    """``world_from_cam`` poses of lawn-mower lines along x over the y strip ``[y0, y1)``."""
    from skyrecon.sim.scenes import look_from

    half = size_m / 2.0
    poses = []
    for k, y in enumerate(np.arange(strip[0] + spacing_m / 2, strip[1], spacing_m)):
        xs = np.arange(-half, half + 1e-6, step_m)
        if k % 2:
            xs = xs[::-1]
        heading = 0.0 if k % 2 == 0 else math.pi
        for j, x in enumerate(xs):
            # look ahead and alternately to the left and right, so that facades are seen too
            yaw = heading + (0.6 if j % 2 else -0.6)
            cam_from_world = look_from(np.array([x, y, altitude_m]), yaw, math.radians(50.0))
            poses.append(cam_from_world.inverse().with_frames("world", "cam"))
    return poses


def build_flight(job: tuple[int, float, float, float, float, float, int, str]) -> dict:
    """One survey flight's map (a picklable task: runs on any executor). Returns its summary."""
    from skyrecon.core import Intrinsics
    from skyrecon.mapping import OccupancyMap, save_map
    from skyrecon.sim import generate_city, render

    index, size, y0, y1, altitude, step, seed, out = job
    t0 = time.process_time()
    city = generate_city(seed, size)
    K = Intrinsics.from_fov(320, 240, 90.0)
    occ = OccupancyMap(voxel_size_m=0.5, max_range_m=80.0)
    poses = flight_poses(size, (y0, y1), altitude, 50.0, step)
    for world_from_cam in poses:
        r = render(city, K, world_from_cam.inverse().with_frames("cam", "world"))
        occ.integrate_depth(r.depth_m, K, world_from_cam)
    save_map(occ, out)
    return {
        "map": out,
        "frames": len(poses),
        "blocks": int(occ.grid.count),
        "cpu_s": time.process_time() - t0,
    }


def phase_flights(args: argparse.Namespace) -> dict:
    from skyrecon.executor import get_executor

    edges = np.linspace(-args.size / 2, args.size / 2, args.flights + 1)
    jobs = [
        (
            f,
            args.size,
            edges[f],
            edges[f + 1],
            args.altitude,
            args.step,
            args.seed,
            str(Path(args.work) / f"flight_{f}"),
        )
        for f in range(args.flights)
    ]
    t0 = time.perf_counter()
    executor = get_executor(args.executor, args.workers)
    try:
        rows = executor.map(build_flight, jobs, desc="flights")
    finally:
        close = getattr(executor, "close", None)
        if close is not None:
            close()
    for r in rows:
        print(
            f"  flight {r['map']}: {r['frames']} frames, {r['blocks']} blocks, {r['cpu_s']:.0f} s CPU",
            flush=True,
        )
    return {
        "maps": [r["map"] for r in rows],
        "frames": sum(r["frames"] for r in rows),
        "seconds": time.perf_counter() - t0,
        "cpu_s": sum(r["cpu_s"] for r in rows),
        "executor": args.executor,
        "workers": args.workers,
        "peak_mb": _peak_mb(),
    }


def phase_queries(args: argparse.Namespace) -> dict:
    from skyrecon.mapping.tiles import TiledMap

    rng = np.random.default_rng(args.seed)
    half = args.size / 2.0
    pts = np.column_stack(
        [
            rng.uniform(-half, half, args.queries),
            rng.uniform(-half, half, args.queries),
            rng.uniform(0, 100, args.queries),
        ]
    )
    cold, warm = [], []
    tiled = TiledMap.open(Path(args.work) / "district")
    for p in pts:
        tiled.drop_cache()
        t = time.perf_counter()
        tiled.log_odds_at(p[None])
        cold.append(1e3 * (time.perf_counter() - t))
        t = time.perf_counter()
        tiled.log_odds_at(p[None])
        warm.append(1e3 * (time.perf_counter() - t))
    c, w = np.array(cold), np.array(warm)
    return {
        "queries": len(pts),
        "cold_ms": {"p50": float(np.median(c)), "p99": float(np.percentile(c, 99)), "max": float(c.max())},
        "warm_ms": {"p50": float(np.median(w)), "p99": float(np.percentile(w, 99)), "max": float(w.max())},
        "peak_mb": _peak_mb(),
    }


def phase_plans(args: argparse.Namespace) -> dict:
    from skyrecon.mapping.tiles import TiledMap
    from skyrecon.planning.tiled import plan_on_tiles
    from skyrecon.sim import generate_city

    city = generate_city(args.seed, args.size)
    tiled = TiledMap.open(Path(args.work) / "district")
    rng = np.random.default_rng(args.seed + 1)
    half = args.size / 2.0 - 20.0
    rows = []
    tries = 0
    while len(rows) < args.plans and tries < 200:
        tries += 1
        a = np.array([rng.uniform(-half, half), rng.uniform(-half, half), 15.0])
        b = np.array([rng.uniform(-half, half), rng.uniform(-half, half), 15.0])
        if np.linalg.norm(a - b) < min(600.0, 0.6 * args.size):
            continue
        if city.distance(np.stack([a, b])).min() < 4.0 or tiled.is_occupied(np.stack([a, b])).any():
            continue
        if np.isnan(tiled.log_odds_at(np.stack([a, b]))).any():
            continue  # not mapped: not a fair query
        t = time.perf_counter()
        res = plan_on_tiles(tiled, a, b, 2.0, snap_radius_m=2.0, max_z=22.0)
        seconds = time.perf_counter() - t
        row = {
            "start": a.tolist(),
            "goal": b.tolist(),
            "success": res.success,
            "reason": res.reason,
            "seconds": seconds,
            "length_m": res.length_m if res.success else None,
            "straight_m": float(np.linalg.norm(a - b)),
            "pieces": res.adjusted.get("pieces"),
            "tiles_read": res.timings.get("tiles_read"),
        }
        if res.success:
            wp = np.asarray(res.waypoints)
            seg = np.concatenate(
                [
                    np.linspace(p, q, max(2, int(np.linalg.norm(q - p) / 0.25)))
                    for p, q in zip(wp[:-1], wp[1:])
                ]
            )
            row["true_min_clearance_m"] = float(city.distance(seg, include_ground=True).min())
        rows.append(row)
        print(
            f"  plan {len(rows)}: {'ok' if res.success else res.reason} {row['straight_m']:.0f} m straight, "
            f"{(row['length_m'] or 0):.0f} m path in {seconds:.1f} s, true clearance "
            f"{row.get('true_min_clearance_m', float('nan')):.2f} m",
            flush=True,
        )
    return {"plans": rows, "peak_mb": _peak_mb()}


PHASES = {"flights": phase_flights, "queries": phase_queries, "plans": phase_plans}


def run_phase(name: str, args: argparse.Namespace) -> dict:
    """Run one phase in a fresh interpreter and return its JSON answer."""
    cmd = [sys.executable, __file__, "--phase", name, *sys.argv[1:]]
    res = subprocess.run(cmd, capture_output=True, text=True)
    sys.stderr.write(res.stderr[-3000:] if res.returncode else "")
    lines = [line for line in res.stdout.splitlines() if line.startswith("{")]
    for line in res.stdout.splitlines():
        if not line.startswith("{"):
            print(line, flush=True)
    if res.returncode or not lines:
        raise SystemExit(f"phase {name} failed (exit {res.returncode})")
    return json.loads(lines[-1])


def merge_phase(args: argparse.Namespace, maps: list[str]) -> dict:
    """The user's command, timed, with its peak memory (GNU time when present, else RUSAGE_CHILDREN)."""
    out = Path(args.work) / "district"
    cmd = [
        sys.executable,
        "-m",
        "skyrecon",
        "map",
        "--merge",
        *maps,
        "--tile-size",
        "64",
        "--out",
        str(out),
        "--quiet",
    ]
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t = time.perf_counter()
    subprocess.run(cmd, check=True, env={**__import__("os").environ, "PYTHONPATH": str(ROOT / "src")})
    seconds = time.perf_counter() - t
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    header = json.loads((out / "map.json").read_text())
    disk = sum(p.stat().st_size for p in (out / "tiles").iterdir())
    return {
        "seconds": seconds,
        "peak_mb": max(peak, before) / 1024.0,
        "tiles": header["num_tiles"],
        "blocks": header["num_blocks"],
        "disk_mb": disk / 1e6,
        "voxels_known_m": header["num_blocks"] * 512 / 1e6,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=float, default=1000.0, help="district side, metres (default 1000)")
    ap.add_argument("--flights", type=int, default=8)
    ap.add_argument("--altitude", type=float, default=70.0)
    ap.add_argument("--step", type=float, default=15.0, help="metres between frames along a line")
    ap.add_argument("--queries", type=int, default=1000)
    ap.add_argument("--plans", type=int, default=3)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument(
        "--executor", default="serial", help="where the flights are mapped: serial, process, dask"
    )
    ap.add_argument("--workers", type=int, default=1, help="workers of the executor (default 1)")
    ap.add_argument("--work", default=None)
    ap.add_argument("--keep", action="store_true")
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("district_results.json"))
    ap.add_argument("--phase", choices=sorted(PHASES), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.phase:
        print(json.dumps(PHASES[args.phase](args)))
        return
    made = args.work is None
    if made:
        args.work = tempfile.mkdtemp(prefix="skyrecon_district_")
        sys.argv += ["--work", args.work]
    try:
        print(f"district {args.size:g} m, {args.flights} flights (work folder {args.work})", flush=True)
        flights = run_phase("flights", args)
        print(
            f"flights: {flights['frames']} frames in {flights['seconds']:.0f} s wall, {flights['cpu_s']:.0f} s CPU "
            f"({args.executor}, {args.workers} worker(s))",
            flush=True,
        )
        merge = merge_phase(args, flights["maps"])
        print(
            f"merge: {merge['seconds']:.1f} s, peak {merge['peak_mb']:.0f} MB, {merge['tiles']} tiles, "
            f"{merge['blocks']} blocks ({merge['voxels_known_m']:.0f} M voxels), {merge['disk_mb']:.0f} MB on disk",
            flush=True,
        )
        queries = run_phase("queries", args)
        print(
            f"queries (cold tile cache, every query reads its tile): p50 {queries['cold_ms']['p50']:.1f} ms, "
            f"p99 {queries['cold_ms']['p99']:.1f} ms, max {queries['cold_ms']['max']:.1f} ms; warm p99 "
            f"{queries['warm_ms']['p99']:.2f} ms; peak {queries['peak_mb']:.0f} MB",
            flush=True,
        )
        plans = run_phase("plans", args)
        ok = [p for p in plans["plans"] if p["success"]]
        print(
            f"plans: {len(ok)}/{len(plans['plans'])} found, worst time "
            f"{max((p['seconds'] for p in plans['plans']), default=float('nan')):.1f} s, smallest true clearance "
            f"{min((p['true_min_clearance_m'] for p in ok), default=float('nan')):.2f} m, peak {plans['peak_mb']:.0f} MB",
            flush=True,
        )
        doc = {
            "config": {k: v for k, v in vars(args).items() if k not in ("phase", "out", "work")},
            "flights": flights,
            "merge": merge,
            "queries": queries,
            "plans": plans,
            "targets": {"peak_mb_max": 4096, "query_ms_max": 100},
            "peak_mb_worst": max(merge["peak_mb"], queries["peak_mb"], plans["peak_mb"]),
        }
        args.out.write_text(json.dumps(doc, indent=2) + "\n")
        print(f"wrote {args.out}")
    finally:
        if made and not args.keep:
            shutil.rmtree(args.work, ignore_errors=True)


if __name__ == "__main__":
    main()
