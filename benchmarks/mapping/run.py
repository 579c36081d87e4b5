"""Occupancy mapping: skyrecon vs OctoMap (octomap-python) on a synthetic city flight with exact depth.

Scene: ``generate_city(seed, 200 m)``, a drone flight (``flight_poses``, 60 frames by default),
640x480 depth rendered exactly (90 degree field of view).

Methods (same frames, same voxel size, same maximum range, in one run):
  skyrecon        OccupancyMap.integrate_depth on the full 640x480 depth images (Numba, all
                  cores; "-1thread": numba.set_num_threads(1)).
  octomap-sub     OcTree.insertPointCloud of the depth back-projected at 160x120 (every 4th pixel).
  octomap-full    OcTree.insertPointCloud of all pixels (slow: only the first --octomap-full-frames
                  frames); skyrecon is scored on the same frames for that comparison.

Scores against City.occupancy_grid (a voxel is occupied when it overlaps an obstacle; the ground
z <= 0 counts):
  precision       occupied voxels that overlap an obstacle / occupied voxels;
  recall          observed surface voxels (those holding a measured point, pushed 1 mm into the
                  surface) that are occupied / observed surface voxels;
  free-in-obst.   free voxels that overlap an obstacle / free voxels (unsafe mistakes).
Speed: wall time per frame (minimum over --repeats runs of the whole flight, after a warm-up
that compiles the Numba kernels), frames/s, input points (valid pixels) per second, and the
CPU time of skyrecon's integration run on one thread (numba.set_num_threads(1)), a measure that
other processes on a shared machine barely affect. Memory: skyrecon ``memory_bytes()`` (arrays incl. spare capacity), OctoMap
``memoryUsage()``.

Usage:
  .venv/bin/python benchmarks/mapping/run.py
  .venv/bin/python benchmarks/mapping/run.py --voxels 0.5 --frames 20 --octomap-full-frames 20
Writes benchmarks/mapping/results.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from skyrecon.mapping import OccupancyMap  # noqa: E402
from skyrecon.sim import generate_city, render  # noqa: E402
from skyrecon.sim.scenes import default_rig, flight_poses  # noqa: E402

try:
    import octomap  # type: ignore
except ImportError:  # pragma: no cover - optional peer
    octomap = None


def flight(seed: int, frames: int):
    city = generate_city(seed, 200.0)
    cam = default_rig().left
    poses = flight_poses(city, frames, seed)
    depths = [render(city, cam, p.inverse()).depth_m for p in poses]
    return city, cam, poses, depths


def cloud(cam, depth, pose, step: int = 1) -> np.ndarray:
    """(N, 3) float64 world points of the valid pixels (every ``step``-th row and column)."""
    dirs = cam.ray_directions()[::step, ::step]
    d = depth[::step, ::step]
    ok = np.isfinite(d)
    return pose.apply(dirs[ok] * d[ok, None].astype(np.float64))


def run_ours(cam, poses, depths, voxel, max_range, repeats, frames=None, threads=None):
    """Integrate the flight ``repeats`` times; per-frame minima of wall and thread CPU time."""
    frames = len(depths) if frames is None else frames
    n_threads = numba.get_num_threads()
    if threads is not None:
        numba.set_num_threads(threads)
    warm = OccupancyMap(voxel_size_m=voxel, max_range_m=max_range)
    warm.integrate_depth(depths[0], cam, poses[0])
    wall, cpu, parts = [], [], []
    m = None
    for _ in range(repeats):
        m = OccupancyMap(voxel_size_m=voxel, max_range_m=max_range)
        w, c, p = [], [], []
        for d, pose in zip(depths[:frames], poses[:frames]):
            t0, c0 = time.perf_counter(), time.thread_time()
            m.integrate_depth(d, cam, pose)
            w.append(time.perf_counter() - t0)
            c.append(time.thread_time() - c0)
            p.append(list(m.last_timing.values()))
        wall.append(w)
        cpu.append(c)
        parts.append(p)
    numba.set_num_threads(n_threads)
    wall = np.min(np.array(wall), axis=0)
    cpu = np.min(np.array(cpu), axis=0)
    parts = np.min(np.array(parts), axis=0).mean(axis=0)
    return m, wall, cpu, dict(zip(m.last_timing.keys(), (parts * 1000).round(2).tolist()))


def run_octomap(cam, poses, depths, voxel, max_range, step, frames):
    tree = octomap.OcTree(voxel)
    wall, npts = [], 0
    for d, pose in zip(depths[:frames], poses[:frames]):
        pts = np.ascontiguousarray(cloud(cam, d, pose, step))
        npts += len(pts)
        t0 = time.perf_counter()
        tree.insertPointCloud(pts, np.ascontiguousarray(pose.t), maxrange=max_range)
        wall.append(time.perf_counter() - t0)
    return tree, np.array(wall), npts


def ours_labels(m: OccupancyMap) -> tuple[np.ndarray, np.ndarray]:
    """(occupied voxels (N, 3), free voxels (M, 3)) int64 indices."""
    B = m.block_size
    blocks = m.grid.blocks
    thr = m.config.log_odds[4]
    out = []
    for sel in (blocks >= thr, blocks < thr):
        k, q = np.nonzero(sel)
        local = np.stack([q // (B * B), (q // B) % B, q % B], axis=1)
        out.append(m.grid.block_coords[k].astype(np.int64) * B + local)
    return out[0], out[1]


def octomap_labels(tree, voxel) -> tuple[np.ndarray, np.ndarray]:
    occ, free = tree.extractPointCloud()
    to_idx = lambda c: np.floor(np.asarray(c, dtype=np.float64).reshape(-1, 3) / voxel).astype(np.int64)  # noqa: E731
    return to_idx(occ), to_idx(free)


class Scorer:
    """Ground truth over a voxel box, and the observed surface voxels of a set of frames."""

    def __init__(self, city, cam, poses, depths, voxel, max_range, lo, hi):
        self.voxel, self.lo, self.hi = voxel, lo, hi
        self.gt = city.occupancy_grid(lo * voxel, voxel, tuple(hi - lo), include_ground=True)
        self.cam, self.poses, self.depths, self.max_range = cam, poses, depths, max_range

    def seen(self, frames: int) -> np.ndarray:
        keys = []
        dirs = self.cam.ray_directions()
        norm = np.linalg.norm(dirs, axis=2)
        for d, pose in zip(self.depths[:frames], self.poses[:frames]):
            ok = np.isfinite(d) & (d * norm <= self.max_range)
            pc = dirs[ok] * d[ok, None].astype(np.float64)
            pc += 1e-3 * pc / np.linalg.norm(pc, axis=1, keepdims=True)
            keys.append(self._flat(np.floor(pose.apply(pc) / self.voxel).astype(np.int64)))
        k = np.unique(np.concatenate(keys))
        return k[k >= 0]

    def _flat(self, idx: np.ndarray) -> np.ndarray:
        rel = idx - self.lo
        shape = self.hi - self.lo
        inside = np.all((rel >= 0) & (rel < shape), axis=1)
        out = np.full(len(idx), -1, np.int64)
        out[inside] = np.ravel_multi_index(tuple(rel[inside].T), tuple(shape))
        return out

    def score(self, occ: np.ndarray, free: np.ndarray, frames: int) -> dict:
        gt = self.gt.reshape(-1)
        fo, ff = self._flat(occ), self._flat(free)
        fo, ff = fo[fo >= 0], ff[ff >= 0]
        seen = self.seen(frames)
        return {
            "occupied": int(len(fo)),
            "free": int(len(ff)),
            "precision": float(gt[fo].mean()) if len(fo) else float("nan"),
            "recall": float(np.isin(seen, fo).mean()) if len(seen) else float("nan"),
            "free_in_obstacle": float(gt[ff].mean()) if len(ff) else float("nan"),
        }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--voxels", type=float, nargs="+", default=[0.5, 0.2])
    ap.add_argument("--max-range", type=float, default=60.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument(
        "--octomap-full-frames",
        type=int,
        nargs="+",
        default=[60, 5],
        help="frames integrated at full resolution by OctoMap, per voxel size",
    )
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("results.json"))
    args = ap.parse_args()

    t0 = time.perf_counter()
    city, cam, poses, depths = flight(args.seed, args.frames)
    print(
        f"scene: seed {args.seed}, {len(depths)} frames {cam.width}x{cam.height}, rendered in "
        f"{time.perf_counter() - t0:.1f} s; max range {args.max_range} m; "
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}"
    )
    if octomap is None:
        print("[skip] octomap-python is not installed: pip install octomap-python")
    results = []
    for vi, voxel in enumerate(args.voxels):
        n_full = min(args.frames, args.octomap_full_frames[min(vi, len(args.octomap_full_frames) - 1)])
        m, wall, _, parts = run_ours(cam, poses, depths, voxel, args.max_range, args.repeats)
        m1, wall1, cpu, _ = run_ours(cam, poses, depths, voxel, args.max_range, args.repeats, threads=1)
        npts = sum(int(np.isfinite(d).sum()) for d in depths)
        lo, hi = m.voxel_bounds()
        rows = []
        entries = [
            ("skyrecon", m, wall, npts, args.frames, m.memory_bytes()),
            ("skyrecon-1thread", m1, wall1, npts, args.frames, m1.memory_bytes()),
        ]
        if octomap is not None:
            tree, w_sub, n_sub = run_octomap(cam, poses, depths, voxel, args.max_range, 4, args.frames)
            entries.append(("octomap-sub", tree, w_sub, n_sub, args.frames, tree.memoryUsage()))
            if n_full > 0:
                tree_f, w_full, n_f = run_octomap(cam, poses, depths, voxel, args.max_range, 1, n_full)
                m_f, wall_f, _, _ = run_ours(cam, poses, depths, voxel, args.max_range, 1, n_full)
                n_pts_f = sum(int(np.isfinite(d).sum()) for d in depths[:n_full])
                entries.append((f"octomap-full[{n_full}]", tree_f, w_full, n_f, n_full, tree_f.memoryUsage()))
                entries.append((f"skyrecon[{n_full}]", m_f, wall_f, n_pts_f, n_full, m_f.memory_bytes()))
        # score everything over one box covering all maps
        for name, obj, *_ in entries:
            if name.startswith("octomap"):
                o, f = octomap_labels(obj, voxel)
                if len(f):
                    lo = np.minimum(lo, f.min(axis=0))
                    hi = np.maximum(hi, f.max(axis=0) + 1)
        scorer = Scorer(city, cam, poses, depths, voxel, args.max_range, lo, hi)
        for name, obj, w, n, frames, mem in entries:
            occ, free = octomap_labels(obj, voxel) if name.startswith("octomap") else ours_labels(obj)
            s = scorer.score(occ, free, frames)
            row = {
                "method": name,
                "voxel_m": voxel,
                "frames": frames,
                "ms_per_frame_mean": float(1000 * w.mean()),
                "ms_per_frame_median": float(1000 * np.median(w)),
                "frames_per_s": float(len(w) / w.sum()),
                "points_per_s": float(n / w.sum()),
                "memory_mb": float(mem / 1e6),
                **s,
            }
            if name == "skyrecon":
                row["cpu_ms_per_frame_one_thread"] = float(1000 * cpu.mean())
                row["stage_ms"] = parts
            rows.append(row)
        base = rows[0]["ms_per_frame_mean"]
        print(f"\nvoxel {voxel} m")
        print(
            f"{'method':<20}{'ms/frame':>10}{'median':>9}{'frames/s':>10}{'Mpts/s':>9}{'MB':>8}"
            f"{'precision':>11}{'recall':>8}{'free-in-obst':>14}{'time/skyrecon':>15}"
        )
        for r in rows:
            print(
                f"{r['method']:<20}{r['ms_per_frame_mean']:>10.1f}{r['ms_per_frame_median']:>9.1f}"
                f"{r['frames_per_s']:>10.2f}{r['points_per_s'] / 1e6:>9.2f}{r['memory_mb']:>8.1f}"
                f"{r['precision']:>11.4f}{r['recall']:>8.4f}{r['free_in_obstacle']:>14.5f}"
                f"{r['ms_per_frame_mean'] / base:>15.2f}"
            )
        sk = rows[0]
        print(
            f"skyrecon stages (ms, mean of per-frame minima): {sk['stage_ms']}; on one thread: "
            f"{sk['cpu_ms_per_frame_one_thread']:.1f} ms CPU per frame (unaffected by other processes' load)"
        )
        results.extend(rows)
    args.out.write_text(
        json.dumps(
            {
                "seed": args.seed,
                "frames": args.frames,
                "max_range_m": args.max_range,
                "load_average": os.getloadavg()[0],
                "results": results,
            },
            indent=2,
        )
        + "\n"
    )
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
