"""Stereo visual odometry: skyrecon's engine vs the OpenCV baseline a user would assemble.

Scenes: ``generate_city(seed, 240 m, low_texture_fraction=0.3)`` (a third of the buildings with
plain, almost textureless facades). Flights: a drone route along the streets (``flight_path``:
turns at intersections with rounded corners, about 48 deg/s of yaw at 5 m/s), at 16 m with +-4 m
altitude changes, 5 m/s, 10 frames/s, camera pitched down 12 degrees, plus fast-yaw segments (the
camera swings +-45 degrees at up to 90 deg/s for 3 s, twice per 100 m). Rendered with exact poses
at 640x480 (90 degree field of view, 0.3 m baseline: the delivery drone's rig) and cached as KITTI
sequences under ``--cache`` (rendering is the slow part; a second run reads the cache).

Methods, on the same frames in the same run, both started at the true first pose:
  skyrecon   ``skyrecon.odometry.engine.StereoOdometry`` (default settings), the trajectory after
             its refinement (``trajectory()``);
  opencv     ``opencv_vo.OpenCVStereoVO``: StereoSGBM depth + goodFeaturesToTrack +
             calcOpticalFlowPyrLK + solvePnPRansac frame to frame (see that file).
ORB-SLAM3 is not on PyPI and does not build here (no pip wheel, needs Pangolin/OpenCV C++
sources), so it is not compared.

Scores (``skyrecon.eval.odometry_metrics``): ATE RMSE after SE(3) alignment, RPE over 100 m
(translation RMSE), drift in % of distance (KITTI way over 25/50/100 m sub-paths), tracking rate
(frames per second of ``track`` calls, wall clock, on this shared machine), lost frames; and the
GPS-fused error (``skyrecon.odometry.gps`` with ``skyrecon.sim.gps.simulate_gps``, urban canyon,
not aligned). The table shows every seed, the worst case over seeds and the ratios
skyrecon / opencv (below 1 is better for the errors, above 1 for the rate).

Usage:
  .venv/bin/python benchmarks/odometry/run.py                    # 3 seeds x 500 m at 640x480
  .venv/bin/python benchmarks/odometry/run.py --quick            # 1 seed, 100 m at 320x240
  .venv/bin/python benchmarks/odometry/run.py --seeds 1 2 --length-m 300 --methods opencv
Writes benchmarks/odometry/results.json (or --out).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from opencv_vo import OpenCVStereoVO  # noqa: E402

from skyrecon.core.rigid import Rigid3  # noqa: E402
from skyrecon.eval.odometry_metrics import evaluate_odometry  # noqa: E402
from skyrecon.io.sequence import is_sequence_dir, read_sequence, write_sequence  # noqa: E402
from skyrecon.odometry.gps import GpsFusion  # noqa: E402
from skyrecon.odometry.run import run_odometry, summarize_run  # noqa: E402
from skyrecon.sim import generate_city, render_stereo  # noqa: E402
from skyrecon.sim.gps import simulate_gps  # noqa: E402
from skyrecon.sim.scenes import default_rig, flight_path, look_from  # noqa: E402

SPEED_MPS, FPS = 5.0, 10.0


def yaw_swings(s_m: np.ndarray, t_s: np.ndarray, every_m: float = 50.0, rate_dps: float = 90.0) -> np.ndarray:
    """(N,) extra yaw, radians: a +-45 degree swing (one sine period, peak rate ``rate_dps``) that
    starts every ``every_m`` metres of path (at 20 m into each stretch)."""
    amp = math.radians(45.0)
    period = 2 * math.pi * amp / math.radians(rate_dps)
    out = np.zeros(len(s_m))
    for start in np.arange(20.0, s_m[-1], every_m):
        t0 = float(np.interp(start, s_m, t_s))
        m = (t_s >= t0) & (t_s < t0 + period)
        out[m] = amp * np.sin(2 * math.pi * (t_s[m] - t0) / period)
    return out


def make_flight(seed: int, length_m: float, width: int, height: int, cache: Path) -> Path:
    """Render (or reuse) the flight of ``seed`` as a KITTI sequence; returns its directory."""
    n = int(round(length_m / SPEED_MPS * FPS)) + 1
    root = cache / f"vo_seed{seed}_{int(length_m)}m_{width}x{height}"
    if is_sequence_dir(root) and (root / "poses.txt").is_file() and len(read_sequence(root)) == n:
        return root
    city = generate_city(seed, 240.0, low_texture_fraction=0.3)
    rig = default_rig(width, height, 90.0, 0.3)
    pos, yaw = flight_path(
        city, n, seed, SPEED_MPS, FPS, altitude_m=16.0, altitude_wobble_m=4.0, clearance_m=2.5
    )
    t = np.arange(n) / FPS
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))])
    yaw = yaw + yaw_swings(s, t)
    poses = [
        look_from(p, a, math.radians(12.0)).inverse().with_frames("world", "left") for p, a in zip(pos, yaw)
    ]
    t0 = time.perf_counter()

    def frames():
        for k, p in enumerate(poses):
            f = render_stereo(city, rig, p.inverse())
            if k % 100 == 0:
                print(
                    f"  seed {seed}: rendered {k}/{n} frames ({time.perf_counter() - t0:.0f} s)", flush=True
                )
            yield f.left, f.right

    write_sequence(root, rig, frames(), poses)
    (root / "city_seed.txt").write_text(f"{seed}\n")
    return root


def make_engine(method: str, rig, init: Rigid3):
    if method == "opencv":
        return OpenCVStereoVO(rig, max_disparity=128, init_world_from_left=init)
    engine = importlib.import_module("skyrecon.odometry.engine")
    return engine.StereoOdometry(rig, engine.OdometrySettings(), init)


def run_method(method: str, root: Path, seed: int, max_frames: int | None) -> dict:
    seq = read_sequence(root)
    n = min(len(seq), max_frames or len(seq))
    gt = seq.world_from_left[:n]  # type: ignore[index]
    t = np.arange(n) / FPS
    city = generate_city(seed, 240.0, low_texture_fraction=0.3)
    fixes = simulate_gps(city, t, np.array([p.t for p in gt]), seed=seed)
    engine = make_engine(method, seq.rig, gt[0])
    result = run_odometry(engine, (seq.frame(i) for i in range(n)), t, fixes, GpsFusion(rotation_known=True))
    summary = summarize_run(result)
    m = evaluate_odometry(result.odometry, gt, t)
    fused_err = np.array([np.linalg.norm(a.t - b.t) for a, b in zip(result.fused or [], gt)])
    return {
        "method": method,
        "seed": seed,
        "frames": n,
        "path_m": round(m.path_length_m, 1),
        "ate_m": m.ate_rmse_m,
        "rpe100_m": m.rpe_100m["trans_rmse_m"],
        "drift_pct": m.drift_pct,
        "rot_deg_per_100m": m.drift["rotation_deg_per_100m"],
        "fps": summary["fps"],
        "track_ms": summary["track_ms"],
        "lost": summary["lost"],
        "degraded": summary["degraded"],
        "reasons": summary["reasons"],
        "gps_fused_rmse_m": float(np.sqrt(np.mean(fused_err**2))) if len(fused_err) else None,
        "gps_rejected": summary.get("gps", {}).get("rejected"),
    }


COLUMNS = [
    ("ate_m", "ATE m", "{:.3f}"),
    ("rpe100_m", "RPE100 m", "{:.3f}"),
    ("drift_pct", "drift %", "{:.2f}"),
    ("fps", "fps", "{:.1f}"),
    ("lost", "lost", "{:d}"),
    ("gps_fused_rmse_m", "GPS+VO m", "{:.2f}"),
]
HIGHER_IS_BETTER = {"fps"}


def _cell(v, fmt: str) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return fmt.format(int(v) if fmt == "{:d}" else v)


def worst(rows: list[dict], method: str) -> dict:
    mine = [r for r in rows if r["method"] == method]
    out: dict = {"method": method, "seed": "worst"}
    for key, _, _ in COLUMNS:
        vals = [r[key] for r in mine if r[key] is not None]
        if not vals:
            out[key] = None
        else:
            out[key] = min(vals) if key in HIGHER_IS_BETTER else max(vals)
    return out


def print_table(rows: list[dict], methods: list[str]) -> list[dict]:
    header = f"{'method':<9} {'seed':>5} {'path m':>7} " + " ".join(f"{h:>9}" for _, h, _ in COLUMNS)
    print(header)
    print("-" * len(header))
    for r in rows:
        print(
            f"{r['method']:<9} {r['seed']!s:>5} {r['path_m']:>7} "
            + " ".join(f"{_cell(r[k], f):>9}" for k, _, f in COLUMNS)
        )
    worst_rows = [worst(rows, m) for m in methods]
    for w in worst_rows:
        print(
            f"{w['method']:<9} {'worst':>5} {'':>7} "
            + " ".join(f"{_cell(w[k], f):>9}" for k, _, f in COLUMNS)
        )
    if "skyrecon" in methods and "opencv" in methods:
        a, b = worst_rows[methods.index("skyrecon")], worst_rows[methods.index("opencv")]
        ratios = {}
        for k, _, _ in COLUMNS:
            if a[k] is not None and b[k] not in (None, 0):
                ratios[k] = a[k] / b[k]
        print(
            f"{'ratio':<9} {'worst':>5} {'':>7} "
            + " ".join(f"{(f'{ratios[k]:.2f}' if k in ratios else '-'):>9}" for k, _, _ in COLUMNS)
        )
        print("(ratio = skyrecon / opencv on the worst case over seeds; < 1 is better except fps)")
    return worst_rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--length-m", type=float, default=500.0)
    ap.add_argument("--size", type=int, nargs=2, default=[640, 480], metavar=("W", "H"))
    ap.add_argument("--frames", type=int, help="track only the first N frames of each flight")
    ap.add_argument("--quick", action="store_true", help="1 seed, 100 m, 320x240")
    ap.add_argument("--methods", nargs="+", default=["skyrecon", "opencv"], choices=["skyrecon", "opencv"])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "skyrecon_vo_bench")
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("results.json"))
    args = ap.parse_args()
    if args.quick:
        args.seeds, args.length_m, args.size = args.seeds[:1], 100.0, [320, 240]
    methods = list(args.methods)
    if "skyrecon" in methods and importlib.util.find_spec("skyrecon.odometry.engine") is None:
        print("skyrecon.odometry.engine is not available in this checkout: running the baseline only")
        methods.remove("skyrecon")
    args.cache.mkdir(parents=True, exist_ok=True)
    rows = []
    for seed in args.seeds:
        t0 = time.perf_counter()
        root = make_flight(seed, args.length_m, args.size[0], args.size[1], args.cache)
        print(f"seed {seed}: flight ready in {time.perf_counter() - t0:.0f} s ({root})", flush=True)
        for method in methods:
            t0 = time.perf_counter()
            rows.append(run_method(method, root, seed, args.frames))
            print(f"  {method}: {time.perf_counter() - t0:.0f} s", flush=True)
    print()
    worst_rows = print_table(rows, methods)
    doc = {
        "config": {
            "seeds": args.seeds,
            "length_m": args.length_m,
            "size": args.size,
            "frames": args.frames,
            "speed_mps": SPEED_MPS,
            "fps": FPS,
            "baseline_m": 0.3,
            "hfov_deg": 90.0,
            "low_texture_fraction": 0.3,
            "yaw_swings": "+-45 deg at up to 90 deg/s, every 50 m",
        },
        "methods": methods,
        "rows": rows,
        "worst": worst_rows,
        "notes": "ORB-SLAM3 is not installable from pip here; not compared.",
    }
    args.out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
