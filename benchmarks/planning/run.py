"""3-D path planning: skyrecon vs OMPL (RRT*, BIT*) on a synthetic 200 m x 200 m x 60 m city.

Map: ``generate_city(seed, 200 m)`` turned into a fully known occupancy map at --voxel (0.5 m)
from ``City.occupancy_grid`` (voxels overlapping an obstacle are occupied; the ground counts).
Queries: --pairs random start / goal pairs in free space (x, y in [-95, 95] m, z in --z-range,
2..50 m by default (--z-range 2 20 keeps them among the buildings),
at least clearance + margin + 0.2 m from every obstacle, true geometry), planned at
--clearance (2 m) between min_z = 1 m and max_z = 60 m (or the tallest building, if taller).

Methods (one collision model for all: a point is valid when the trilinearly interpolated
distance field is at least clearance + margin, margin = voxel * sqrt(3) / 2, inside the
altitude band; motions are checked exactly with skyrecon's line-of-sight test):
  skyrecon        Planner defaults (Lazy Theta* on a 1.5 m lattice, then full resolution if
                  needed; shortening and smoothing).
  reference       Lazy Theta* on the full 0.5 m grid (any-angle) + the same taut-string
                  shortening, no time limit: an upper bound on the shortest feasible path.
  ompl-<planner>-<T>s  OMPL RRT* / BIT* (path-length objective) for T seconds, on the first
                  --ompl-pairs pairs; "raw" is the path they return, "simpl" after
                  OMPL's PathSimplifier (shortcutting + smoothing; its time is not counted).
Path-length ratios are to the best path any method found for that pair (best known, the
shortest feasible path up to the methods' accuracy) and to the straight line (a lower bound).
Safety: every path is sampled every 5 cm and checked against City.distance (true geometry):
collisions (distance <= 0) and clearance violations (distance < clearance).

Usage:
  .venv/bin/python benchmarks/planning/run.py
  .venv/bin/python benchmarks/planning/run.py --pairs 30 --ompl-pairs 5 --ompl-budgets 1
Writes benchmarks/planning/results.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from skyrecon.mapping import OccupancyMap  # noqa: E402
from skyrecon.planning import Planner, _geom  # noqa: E402
from skyrecon.sim import generate_city  # noqa: E402

try:
    from ompl import base as ob  # type: ignore
    from ompl import geometric as og  # type: ignore
except ImportError:  # pragma: no cover - optional peer
    ob = og = None


def build(seed: int, voxel: float, height: float = 60.0):
    """The city, its fully known map (x, y in [-100, 100] m, z in [-1, height + 4] m), the flight ceiling."""
    city = generate_city(seed, 200.0)
    top = max(height, city.max_height_m)
    origin = np.array([-100.0, -100.0, -1.0])
    shape = (int(round(200 / voxel)), int(round(200 / voxel)), int(np.ceil((top + 5.0) / voxel)))
    occ = city.occupancy_grid(origin, voxel, shape, include_ground=True)
    return city, OccupancyMap.from_occupancy_grid(occ, origin, voxel_size_m=voxel), top


def sample_pairs(city, n: int, min_dist: float, rng, z_range=(2.0, 50.0)) -> tuple[np.ndarray, np.ndarray]:
    pts = []
    while len(pts) < 2 * n:
        p = rng.uniform([-95, -95, z_range[0]], [95, 95, z_range[1]], size=(500, 3))
        pts.extend(p[city.distance(p, include_ground=True) > min_dist])
    pts = np.array(pts[: 2 * n])
    return pts[0::2], pts[1::2]


def true_min_distance(city, w: np.ndarray) -> float:
    segs = [
        a + (b - a) * np.linspace(0, 1, max(2, int(np.ceil(np.linalg.norm(b - a) / 0.05)) + 1))[:, None]
        for a, b in zip(w[:-1], w[1:])
    ]
    return float(city.distance(np.concatenate(segs), include_ground=True).min())


def ompl_solve(grid, planner_name: str, budget: float, s: np.ndarray, g: np.ndarray, lo, hi):
    """(raw length or inf, simplified length or inf, solve seconds, raw waypoints)."""
    space = ob.RealVectorStateSpace(3)
    bounds = ob.RealVectorBounds(3)
    for i in range(3):
        bounds.setLow(i, float(lo[i]))
        bounds.setHigh(i, float(hi[i]))
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)
    ctx = grid.ctx()
    dist, origin, inv_v, zmin, zmax, thr = (
        grid.dist,
        grid.origin,
        grid.inv_v,
        grid.zmin,
        grid.zmax,
        grid.threshold,
    )

    def valid(state) -> bool:
        return _geom.trilinear(dist, origin, inv_v, zmin, zmax, state[0], state[1], state[2]) >= thr

    class Motion(ob.MotionValidator):
        def checkMotion(self, s1, s2, *rest):  # noqa: N802 (OMPL's name)
            return bool(
                _geom.clear(*ctx, np.array([s1[0], s1[1], s1[2]]), np.array([s2[0], s2[1], s2[2]]), True)
            )

    si.setStateValidityChecker(valid)
    mv = Motion(si)
    si.setMotionValidator(mv)
    si.setup()
    pdef = ob.ProblemDefinition(si)
    a, b = space.allocState(), space.allocState()
    for i in range(3):
        a[i], b[i] = float(s[i]), float(g[i])
    pdef.setStartAndGoalStates(a, b)
    pdef.setOptimizationObjective(ob.PathLengthOptimizationObjective(si))
    pl = getattr(og, planner_name)(si)
    pl.setProblemDefinition(pdef)
    pl.setup()
    t0 = time.perf_counter()
    status = pl.solve(budget)
    dt = time.perf_counter() - t0
    if not pdef.hasExactSolution():
        return np.inf, np.inf, dt, None, str(status)
    path = pdef.getSolutionPath()
    w = np.array([[path.getState(i)[k] for k in range(3)] for i in range(path.getStateCount())])
    raw = float(np.linalg.norm(np.diff(w, axis=0), axis=1).sum())
    og.PathSimplifier(si).simplifyMax(path)
    w2 = np.array([[path.getState(i)[k] for k in range(3)] for i in range(path.getStateCount())])
    simp = float(np.linalg.norm(np.diff(w2, axis=0), axis=1).sum())
    return raw, simp, dt, w2, str(status)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--voxel", type=float, default=0.5)
    ap.add_argument("--pairs", type=int, default=100)
    ap.add_argument("--clearance", type=float, default=2.0)
    ap.add_argument(
        "--z-range",
        type=float,
        nargs=2,
        default=[2.0, 50.0],
        help="altitude range of the random start and goal points, metres",
    )
    ap.add_argument("--ompl-pairs", type=int, default=20)
    ap.add_argument("--ompl-budgets", type=float, nargs="+", default=[1.0, 5.0])
    ap.add_argument("--ompl-planners", nargs="+", default=["RRTstar", "BITstar"])
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("results.json"))
    args = ap.parse_args()

    t0 = time.perf_counter()
    city, m, top = build(args.seed, args.voxel)
    print(
        f"city seed {args.seed}: {len(city.boxes)} boxes, {len(city.cylinders)} cylinders, tallest "
        f"{city.max_height_m:.1f} m, ceiling {top:.1f} m; "
        f"map {m.grid.count} blocks at {args.voxel} m in {time.perf_counter() - t0:.1f} s; "
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}"
    )
    t0 = time.perf_counter()
    ours = Planner(m, args.clearance, min_z=1.0, max_z=top)
    ref = Planner(ours.df, args.clearance, min_z=1.0, max_z=top, levels=(1,), max_expansions=20_000_000)
    rng = np.random.default_rng(args.seed)
    S, G = sample_pairs(city, args.pairs, args.clearance + ours.margin + 0.2, rng, tuple(args.z_range))
    ours.plan(S[0], G[0])  # builds the distance field and grid, compiles the kernels
    ref._grid = ours._grid
    print(
        f"setup (distance field, dense grid, compilation): {time.perf_counter() - t0:.1f} s; "
        f"{args.pairs} pairs, clearance {args.clearance} m + margin {ours.margin:.3f} m"
    )

    rows = {"skyrecon": [], "reference": []}
    for name, P in (("skyrecon", ours), ("reference", ref)):
        for s, g in zip(S, G):
            c0, w0 = time.thread_time(), time.perf_counter()
            r = P.plan(s, g)
            wall, cpu = time.perf_counter() - w0, time.thread_time() - c0
            td = true_min_distance(city, r.waypoints) if r.success else np.nan
            rows[name].append(
                {
                    "success": r.success,
                    "length": r.length_m,
                    "wall_s": wall,
                    "cpu_s": cpu,
                    "true_min_m": td,
                    "reason": r.reason,
                    "expansions": r.expansions,
                }
            )
    if ob is not None:
        grid = ours._grid
        lo = np.array([-100.0, -100.0, 1.0])
        hi = np.array([100.0, 100.0, top])
        for pname in args.ompl_planners:
            for T in args.ompl_budgets:
                key = f"ompl-{pname}-{T:g}s"
                rows[key + "-raw"], rows[key + "-simpl"] = [], []
                for s, g in zip(S[: args.ompl_pairs], G[: args.ompl_pairs]):
                    raw, simp, dt, w, status = ompl_solve(grid, pname, T, s, g, lo, hi)
                    td = true_min_distance(city, w) if w is not None else np.nan
                    rows[key + "-raw"].append(
                        {
                            "success": np.isfinite(raw),
                            "length": raw,
                            "wall_s": dt,
                            "cpu_s": dt,
                            "true_min_m": td,
                            "reason": status,
                        }
                    )
                    rows[key + "-simpl"].append(
                        {
                            "success": np.isfinite(simp),
                            "length": simp,
                            "wall_s": dt,
                            "cpu_s": dt,
                            "true_min_m": td,
                            "reason": status,
                        }
                    )
    else:
        print("[skip] OMPL is not installed: pip install ompl")

    L = {k: np.array([r["length"] for r in v]) for k, v in rows.items()}
    straight = np.linalg.norm(G - S, axis=1)
    best = np.min(
        np.stack([np.pad(v, (0, args.pairs - len(v)), constant_values=np.inf) for v in L.values()]), axis=0
    )
    summary = []
    print(
        f"\n{'method':<26}{'pairs':>6}{'success':>9}{'ms mean':>9}{'median':>8}{'p95':>8}{'max':>8}"
        f"{'len/best mean':>14}{'median':>8}{'max':>8}{'>1.02':>7}{'len/straight':>13}{'collisions':>11}{'<clear.':>8}"
    )
    for k, v in rows.items():
        n = len(v)
        if n == 0:  # e.g. --ompl-pairs 0
            continue
        ok = np.array([r["success"] for r in v], dtype=bool)
        t = np.array([r["wall_s"] for r in v]) * 1000
        ratio = L[k][ok] / best[:n][ok]
        rs = L[k][ok] / straight[:n][ok]
        td = np.array([r["true_min_m"] for r in v])[ok]
        row = {
            "method": k,
            "pairs": n,
            "success": int(ok.sum()),
            "ms_mean": float(t.mean()),
            "ms_median": float(np.median(t)),
            "ms_p95": float(np.percentile(t, 95)),
            "ms_max": float(t.max()),
            "cpu_ms_mean": float(np.mean([r["cpu_s"] for r in v]) * 1000),
            "ratio_best_mean": float(ratio.mean()) if len(ratio) else None,
            "ratio_best_median": float(np.median(ratio)) if len(ratio) else None,
            "ratio_best_max": float(ratio.max()) if len(ratio) else None,
            "over_1_02": int((ratio > 1.02).sum()),
            "ratio_straight_mean": float(rs.mean()) if len(rs) else None,
            "collisions": int((td <= 0).sum()),
            "clearance_violations": int((td < args.clearance).sum()),
            "true_min_distance_m": float(td.min()) if len(td) else None,
            "failures": sorted({r["reason"] for r in v if not r["success"]}),
        }
        summary.append(row)
        print(
            f"{k:<26}{n:>6}{row['success']:>9}{row['ms_mean']:>9.1f}{row['ms_median']:>8.1f}{row['ms_p95']:>8.1f}"
            f"{row['ms_max']:>8.1f}{row['ratio_best_mean'] or float('nan'):>14.4f}"
            f"{row['ratio_best_median'] or float('nan'):>8.4f}{row['ratio_best_max'] or float('nan'):>8.4f}"
            f"{row['over_1_02']:>7}{row['ratio_straight_mean'] or float('nan'):>13.4f}"
            f"{row['collisions']:>11}{row['clearance_violations']:>8}"
        )
    sk = summary[0]
    print(
        f"\nskyrecon: CPU {sk['cpu_ms_mean']:.1f} ms per query (single thread), true minimum distance to obstacles "
        f"{sk['true_min_distance_m']:.3f} m (clearance {args.clearance} m); failures: {sk['failures'] or 'none'}"
    )
    args.out.write_text(
        json.dumps(
            {
                "seed": args.seed,
                "voxel_m": args.voxel,
                "clearance_m": args.clearance,
                "z_range_m": args.z_range,
                "straight_line_pairs": int(sum(r["expansions"] == 0 for r in rows["skyrecon"])),
                "load_average": os.getloadavg()[0],
                "summary": summary,
                "per_pair": {k: v for k, v in rows.items()},
            },
            indent=2,
            default=float,
        )
        + "\n"
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
