"""Structure from motion on long flights: 250 / 500 / 1000 frames of 1024 px, cost per frame and memory.

The flight: ``sim.flight_poses`` over a 400 m synthetic city (5 m/s, 10 frames/s, turns at the
intersections, camera pitched 12 degrees down), rendered at 1024x768 (80 degree field of view) as PNG
once into ``--cache``. For each length N the first N frames go to the command a user runs:

    skyrecon sfm FRAMES/ --camera K.txt --pairing sequential --out OUT/ --quiet

in its own process. Its whole process tree is measured (``skyrecon.eval.process_tree``: the
command and its feature/matching pool workers): reported per N are wall time, CPU time, both per
frame, peak resident memory of the tree (target <= 4 GB at 1000 frames), registered frames, and
the camera-centre error against the true poses after a similarity alignment (median and max, % of
the flight's extent), and the stages' and the mapper's times from the run's ``sfm.json``. Targets
(issue "Beyond one machine"): cost per frame flat within 20 % from 250 to 1000 frames, peak memory
at most 4 GB at 1000 frames. On a shared machine the wall time is noisy: CPU time per frame is what
predicts a cluster.

With ``--unordered`` the frames are an unordered photo set instead (default 2000 frames): linked
under hashed names, so their order says nothing, and matched with ``--pairing retrieval``, whose
pairs per photo are bounded; the rows then also report the pairs matched. Target: all photos
registered in bounded memory (features and matches on disk in the workspace).

The route of a flight depends on its length: the frames of a run are the first N of the route of
the longest N asked for (cached per route length). ``skyrecon warmup --only sfm`` and an untimed
``--warmup`` run of 30 frames come first, so that no figure carries the kernels' compilation (a
checkout without the installed cache compiles them once).

Usage:
  .venv/bin/python benchmarks/scale/sfm_flight.py                   # 250, 500, 1000 frames
  .venv/bin/python benchmarks/scale/sfm_flight.py --frames 100 200  # quicker
  .venv/bin/python benchmarks/scale/sfm_flight.py --unordered       # 2000 unordered photos
Writes benchmarks/scale/sfm_flight_results.json (sfm_unordered_results.json; or --out).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from skyrecon.core import Intrinsics, Rigid3  # noqa: E402
from skyrecon.eval.process_tree import run_measured  # noqa: E402
from skyrecon.eval.sfm_metrics import evaluate_sfm_poses  # noqa: E402
from skyrecon.io.colmap import read_colmap_text  # noqa: E402
from skyrecon.io.images import write_image  # noqa: E402


def _render_frames(args: tuple) -> None:
    """Render frames ``ks`` of the flight into ``frames_dir`` (one pool task)."""
    seed, intr, poses, ks, frames_dir = args
    from skyrecon.sim import generate_city, render

    city = generate_city(seed, 400.0)
    for k in ks:
        f = frames_dir / f"frame_{k:04d}.png"
        if not f.is_file():
            write_image(f, render(city, intr, poses[k].inverse()).image)


def render_flight(n: int, cache: Path, seed: int, width: int) -> tuple[Path, Intrinsics]:
    """Render (or reuse) the flight of ``n`` frames; returns its folder (``frames/``, ``K.txt``,
    ``cam_from_world.npy``) and camera.

    The route of a flight depends on its length, so the cache is keyed by it
    (``flight_seed{seed}_{width}px_{n}f``): a shorter run uses the first frames of the longest
    route it asks for, never frames of another route. Frames render on all cores.
    """
    from concurrent.futures import ProcessPoolExecutor

    from skyrecon.sim import flight_poses, generate_city

    height = width * 3 // 4
    intr = Intrinsics.from_fov(width, height, 80.0)
    d = cache / f"flight_seed{seed}_{width}px_{n}f"
    frames_dir = d / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    poses_file = d / "cam_from_world.npy"
    if not poses_file.is_file() or not all((frames_dir / f"frame_{k:04d}.png").is_file() for k in range(n)):
        poses = flight_poses(generate_city(seed, 400.0), n, seed, speed_mps=5.0, fps=10.0)
        t0 = time.perf_counter()
        workers = os.cpu_count() or 1
        chunks = [(seed, intr, poses, range(k, min(k + 50, n)), frames_dir) for k in range(0, n, 50)]
        with ProcessPoolExecutor(workers) as pool:
            for i, _ in enumerate(pool.map(_render_frames, chunks), 1):
                print(
                    f"  rendered {min(i * 50, n)}/{n} frames ({time.perf_counter() - t0:.0f} s)", flush=True
                )
        np.save(poses_file, np.array([p.inverse().matrix for p in poses]))
    K = intr.K
    (d / "K.txt").write_text("\n".join(" ".join(f"{v:.6f}" for v in row) for row in K) + "\n")
    return d, intr


def photo_name(seed: int, k: int) -> str:
    """The unordered set's name of frame ``k``: a hash, so that name order says nothing of flight order."""
    return f"photo_{hashlib.sha1(f'{seed}:{k}'.encode()).hexdigest()[:10]}.png"


def run_one(flight: Path, n: int, out: Path, workers: int | None, unordered_seed: int | None = None) -> dict:
    """``skyrecon sfm`` on the first ``n`` frames, in its own process.

    With ``unordered_seed`` the frames are linked under hashed names (:func:`photo_name`) and
    matched by ``--pairing retrieval``, as a photo set with no order is; else by
    ``--pairing sequential``.
    """
    unordered = unordered_seed is not None
    sub = out / (f"photos_{n}" if unordered else f"frames_{n}")
    sub.mkdir(parents=True, exist_ok=True)
    name_of = {k: photo_name(unordered_seed, k) if unordered else f"frame_{k:04d}.png" for k in range(n)}
    for k in range(n):
        link = sub / name_of[k]
        if not link.exists():
            link.symlink_to(flight / "frames" / f"frame_{k:04d}.png")
    model = out / f"model_{n}{'_unordered' if unordered else ''}"
    cmd = [sys.executable, "-m", "skyrecon", "sfm", str(sub), "--camera", str(flight / "K.txt")]
    cmd += ["--pairing", "retrieval" if unordered else "sequential", "--out", str(model), "--quiet"]
    if workers:
        cmd += ["--workers", str(workers)]
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    m = run_measured(cmd, env=env, capture=False)
    if m.returncode != 0:
        raise SystemExit(f"skyrecon sfm failed on {n} frames (exit {m.returncode})")
    rec = read_colmap_text(model / "sparse")
    M = np.load(flight / "cam_from_world.npy")
    gt = {name_of[k]: Rigid3.from_matrix(M[k]) for k in range(n)}
    est = {im.name: im.cam_from_world for im in rec.images.values()}
    s = evaluate_sfm_poses(est, gt).summary()
    run = json.loads((model / "sfm.json").read_text())
    mapper = run["diagnostics"]["mapper"]
    return {
        "frames": n,
        "pairing": run["diagnostics"]["pairing"]["mode"],
        "pairs": int(run["diagnostics"]["pairing"]["num_pairs"]),
        "pairs_verified": int(run["diagnostics"]["pairs_verified"]),
        "registered": len(est),
        "wall_s": m.wall_s,
        "wall_s_per_frame": m.wall_s / n,
        "cpu_s": m.cpu_s,
        "cpu_s_per_frame": m.cpu_s / n,
        "peak_mb": m.peak_gb * 1000.0,
        "center_median_pct": s["center_median_pct"],
        "center_max_pct": s["center_max_pct"],
        "stages_s": {k: round(v, 1) for k, v in run["timings_s"].items()},
        "mapper_s": {
            "global_ba": round(mapper["global_ba_s"], 1),
            "loop_closures": round(sum(loop.get("seconds", 0.0) for loop in mapper["loops"]), 1),
            "local_ba": round(mapper["local_ba_s"], 1),
            "triangulation": round(mapper["triangulation_s"], 1),
        },
        "loops_closed": int(mapper["loops_detected"]),
        "global_ba_runs": mapper.get("global_ba_runs", []),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, nargs="+", help="default 250 500 1000; 2000 with --unordered")
    ap.add_argument(
        "--unordered",
        action="store_true",
        help="the frames as an unordered photo set: hashed names, --pairing retrieval",
    )
    ap.add_argument("--width", type=int, default=1024)
    ap.add_argument("--seed", type=int, default=4)
    ap.add_argument("--workers", type=int)
    ap.add_argument(
        "--warmup",
        type=int,
        default=30,
        help="frames of an untimed first run (loads or compiles the kernels); 0: none",
    )
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "skyrecon_sfm_scale")
    ap.add_argument("--out", type=Path, help="default sfm_flight_results.json (sfm_unordered_results.json)")
    args = ap.parse_args()
    if args.frames is None:
        args.frames = [2000] if args.unordered else [250, 500, 1000]
    if args.out is None:
        name = "sfm_unordered_results.json" if args.unordered else "sfm_flight_results.json"
        args.out = Path(__file__).with_name(name)
    unordered_seed = args.seed if args.unordered else None
    flight, _ = render_flight(max(args.frames), args.cache, args.seed, args.width)
    work = Path(tempfile.mkdtemp(prefix="skyrecon_sfm_scale_"))
    if args.warmup:
        # what a user runs after installing (it compiles the kernels the tiny run does not reach:
        # the tiled factorisation of large systems), then a short untimed flight
        env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
        run_measured(
            [sys.executable, "-m", "skyrecon", "warmup", "--only", "sfm", "--force"], env=env, capture=False
        )
        run_one(flight, args.warmup, work, args.workers, unordered_seed)
    rows = []
    for n in sorted(args.frames):
        row = run_one(flight, n, work, args.workers, unordered_seed)
        rows.append(row)
        print(
            f"{n:5d} frames: {row['pairs']} {row['pairing']} pairs ({row['pairs'] / n:.1f} per frame), "
            f"{row['registered']} registered, wall {row['wall_s']:.0f} s "
            f"({row['wall_s_per_frame']:.2f} s/frame), CPU {row['cpu_s']:.0f} s ({row['cpu_s_per_frame']:.2f} s/frame), "
            f"peak {row['peak_mb']:.0f} MB, centre error median {row['center_median_pct']:.3f} % "
            f"max {row['center_max_pct']:.3f} % of the extent",
            flush=True,
        )
    base = rows[0]["cpu_s_per_frame"]
    for r in rows:
        r["cpu_per_frame_vs_first"] = r["cpu_s_per_frame"] / base
    print(
        "CPU per frame relative to the shortest: "
        + ", ".join(f"{r['frames']}: {r['cpu_per_frame_vs_first']:.2f}" for r in rows)
    )
    args.out.write_text(
        json.dumps({"config": {k: str(v) for k, v in vars(args).items()}, "rows": rows}, indent=2) + "\n"
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
