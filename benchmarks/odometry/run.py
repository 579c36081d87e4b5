"""Stereo visual odometry: skyrecon's engine vs the OpenCV baseline a user would assemble.

Scenes: ``generate_city(seed, 240 m, low_texture_fraction=0.3)`` (a third of the buildings with
plain, almost textureless facades; ``--low-texture-fraction`` for plainer cities, reported as flight
kind ``route-plain<fraction>``). Flights: a drone route along the streets (``flight_path``:
turns at intersections with rounded corners, about 48 deg/s of yaw at 5 m/s), at 16 m with +-4 m
altitude changes, 5 m/s, 10 frames/s, camera pitched down 12 degrees, plus fast-yaw segments (the
camera swings +-45 degrees at up to 90 deg/s for 3 s, twice per 100 m). Rendered with exact poses
at 640x480 (90 degree field of view, 0.3 m baseline: the delivery drone's rig) and cached as KITTI
sequences under ``--cache`` (rendering is the slow part; a second run reads the cache).
Two kinds of flight (``--flights``): ``route``, the random routes above, which never come back to a
place (``--length-m``, 500 m: 537 m flown with the swings), and ``circuit``, a closed circuit around
a rectangle of inner streets flown 1.5 times (``--circuit-length-m``, 560 m: the second lap
revisits about 200 m of the first), same altitude changes and yaw swings (``circuit_path``).

Methods, on the same frames in the same run, both started at the true first pose:
  skyrecon   ``skyrecon.odometry.engine.StereoOdometry`` (default settings: loop closure on), the
             trajectory after its refinement and loop closure (``trajectory()``);
  skyrecon-nolc  the same with ``loop_closure=False``;
  opencv     ``opencv_vo.OpenCVStereoVO``: StereoSGBM depth + goodFeaturesToTrack +
             calcOpticalFlowPyrLK + solvePnPRansac frame to frame (see that file).
ORB-SLAM3 is not on PyPI and does not build here (no pip wheel, needs Pangolin/OpenCV C++
sources), so it is not compared.

Scores (``skyrecon.eval.odometry_metrics``): ATE RMSE after SE(3) alignment, RPE over 100 m
(translation RMSE), drift in % of distance (KITTI way over 25/50/100 m sub-paths), tracking rate
(frames per second of ``track`` calls, wall clock, on this shared machine), lost frames; and the
absolute errors without alignment (both start at the true pose): "VO abs" (the odometry alone),
"GPS" (the simulated urban-canyon fixes, ``skyrecon.sim.gps.simulate_gps``: 2 m horizontal / 4 m
vertical correlated bias, 1 m noise, 20 m multipath jumps) and "GPS+VO" (``skyrecon.odometry.gps``
fusing the two); ATE in % of the distance; loops accepted and rejected by loop closure. The table
shows every seed, the worst case over seeds and the ratios skyrecon / opencv (below 1 is better
for the errors, above 1 for the rate), one table per kind of flight.

Usage:
  .venv/bin/python benchmarks/odometry/run.py                    # 3 seeds x (route, circuit) at 640x480
  .venv/bin/python benchmarks/odometry/run.py --flights circuit --seeds 1 --out c1.json   # one part,
  .venv/bin/python benchmarks/odometry/run.py --merge c1.json c2.json r1.json   # ... parts combined
  .venv/bin/python benchmarks/odometry/run.py --seeds 8 9 10 --flights route --low-texture-fraction 0.6 \
      --out plain.json                                             # plainer cities: their own table
  .venv/bin/python benchmarks/odometry/run.py --seeds 1 2 3 --flights route --length-m 200 --camera-noise 1.5 \
      --out noisy.json                                             # a noisy camera: its own table
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

from skyrecon.cli.common import add_camera_noise_option  # noqa: E402
from skyrecon.core.rigid import Rigid3  # noqa: E402
from skyrecon.eval.odometry_metrics import evaluate_odometry  # noqa: E402
from skyrecon.io.sequence import is_sequence_dir, read_sequence, write_sequence  # noqa: E402
from skyrecon.odometry.gps import GpsFusion  # noqa: E402
from skyrecon.odometry.run import run_odometry, summarize_run  # noqa: E402
from skyrecon.sim import generate_city, render_stereo  # noqa: E402
from skyrecon.sim.gps import simulate_gps  # noqa: E402
from skyrecon.sim.scenes import _sample, _Segment, default_rig, flight_path, look_from  # noqa: E402
from skyrecon.sim.sensor_noise import add_sensor_noise  # noqa: E402

SPEED_MPS, FPS = 5.0, 10.0
LOW_TEXTURE_FRACTION = 0.3  # the default share of buildings with plain facades


def plain_tag(low_texture_fraction: float) -> str:
    """``""`` for the default city, else ``"plain<fraction>"``: names a plainer city's cached
    flights and its table."""
    return "" if low_texture_fraction == LOW_TEXTURE_FRACTION else f"plain{low_texture_fraction:g}"


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


def circuit_path(
    city, n: int, seed: int, laps: float = 1.5, altitude_m: float = 16.0, wobble_m: float = 4.0
) -> tuple[np.ndarray, np.ndarray]:
    """Positions (n, 3) and headings (n,) of a closed circuit around a rectangle of inner streets,
    flown ``laps`` times at ``SPEED_MPS`` (corners rounded with half the street width), so that the
    second lap revisits the first one's places. The rectangle is the one whose perimeter is closest
    to the distance / ``laps`` and that keeps 2.5 m clear of every obstacle; ``seed`` picks the
    direction and the altitude wobble's phase."""
    xs, ys = city.street_centers
    wx, wy = city.street_widths
    length = (n - 1) * SPEED_MPS / FPS
    rects = [
        (i0, i1, j0, j1)
        for i0 in range(1, len(xs) - 2)
        for i1 in range(i0 + 1, len(xs) - 1)
        for j0 in range(1, len(ys) - 2)
        for j1 in range(j0 + 1, len(ys) - 1)
    ]
    perim = [2 * (xs[i1] - xs[i0] + ys[j1] - ys[j0]) for i0, i1, j0, j1 in rects]
    rng = np.random.default_rng(seed)
    ccw = bool(rng.integers(2))
    phase = rng.uniform(0, 2 * np.pi)
    s = np.arange(n) * SPEED_MPS / FPS
    for k in np.argsort(np.abs(np.array(perim) - length / laps)):
        i0, i1, j0, j1 = rects[k]
        corners = [(i0, j0), (i1, j0), (i1, j1), (i0, j1)]
        if not ccw:
            corners = corners[::-1]
        pts = [np.array([xs[a], ys[b]]) for a, b in corners]
        radius = [0.5 * min(wx[a], wy[b]) for a, b in corners]
        segs = []
        cur = (pts[0] + pts[1]) / 2
        m = 1
        while sum(g.length for g in segs) < length + 50.0:
            c, c_next, prev = pts[m % 4], pts[(m + 1) % 4], pts[(m - 1) % 4]
            d_in = (c - prev) / np.linalg.norm(c - prev)
            d_out = (c_next - c) / np.linalg.norm(c_next - c)
            r = radius[m % 4]
            p_start = c - d_in * r
            segs.append(_Segment("line", float(np.linalg.norm(p_start - cur)), cur, d_in))
            centre = p_start + d_out * r
            a0 = math.atan2(p_start[1] - centre[1], p_start[0] - centre[0])
            turn = np.sign(d_in[0] * d_out[1] - d_in[1] * d_out[0])
            segs.append(_Segment("arc", r * np.pi / 2, centre, np.array([a0, turn * np.pi / 2]), r))
            cur = c + d_out * r
            m += 1
        pos2, yaw = _sample(segs, s)
        z = altitude_m + wobble_m * np.sin(2 * np.pi * s / 45.0 + phase)
        pos = np.column_stack([pos2, z])
        mid = (pos[1:] + pos[:-1]) / 2
        if np.all(city.distance(np.vstack([pos, mid]), include_ground=True) >= 2.5):
            return pos, yaw
    raise RuntimeError(f"city {seed}: no circuit keeps 2.5 m clear of the obstacles")


def make_flight(
    seed: int,
    length_m: float,
    width: int,
    height: int,
    cache: Path,
    circuit: bool = False,
    low_texture_fraction: float = LOW_TEXTURE_FRACTION,
) -> Path:
    """Render (or reuse) the flight of ``seed`` as a KITTI sequence; returns its directory. ``circuit``:
    the closed circuit of :func:`circuit_path` (revisits its start) instead of a random route;
    ``low_texture_fraction``: the share of buildings with plain facades."""
    n = int(round(length_m / SPEED_MPS * FPS)) + 1
    kind = "circuit" if circuit else "vo"
    root = cache / f"{kind}_seed{seed}_{int(length_m)}m_{width}x{height}"
    if plain_tag(low_texture_fraction):
        root = root.with_name(f"{root.name}_{plain_tag(low_texture_fraction)}")
    if is_sequence_dir(root) and (root / "poses.txt").is_file() and len(read_sequence(root)) == n:
        return root
    city = generate_city(seed, 240.0, low_texture_fraction=low_texture_fraction)
    rig = default_rig(width, height, 90.0, 0.3)
    if circuit:
        pos, yaw = circuit_path(city, n, seed)
    else:
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
    settings = engine.OdometrySettings()  # loop closure on (the default)
    if method == "skyrecon-nolc":
        settings = engine.OdometrySettings(loop_closure=False)
    return engine.StereoOdometry(rig, settings, init)


def run_method(
    method: str,
    root: Path,
    seed: int,
    max_frames: int | None,
    flight: str = "route",
    low_texture_fraction: float = LOW_TEXTURE_FRACTION,
    camera_noise: float = 0.0,
) -> dict:
    """Track flight ``root`` with ``method`` and score it; ``flight`` labels the row (its table).
    ``camera_noise``: grey levels of white sensor noise added to every image as it is read (seeded
    by the flight's seed, the same for every method)."""
    seq = read_sequence(root)
    n = min(len(seq), max_frames or len(seq))
    gt = seq.world_from_left[:n]  # type: ignore[index]
    t = np.arange(n) / FPS
    city = generate_city(seed, 240.0, low_texture_fraction=low_texture_fraction)
    fixes = simulate_gps(city, t, np.array([p.t for p in gt]), seed=seed)
    engine = make_engine(method, seq.rig, gt[0])
    noise_rng = np.random.default_rng([seed, 7919])

    def frames():
        for i in range(n):
            left, right = seq.frame(i)
            yield (
                add_sensor_noise(left, camera_noise, noise_rng),
                add_sensor_noise(right, camera_noise, noise_rng),
            )

    result = run_odometry(engine, frames(), t, fixes, GpsFusion(rotation_known=True))
    summary = summarize_run(result)
    m = evaluate_odometry(result.odometry, gt, t)
    fused_err = np.array([np.linalg.norm(a.t - b.t) for a, b in zip(result.fused or [], gt)])
    abs_err = np.array([np.linalg.norm(a.t - b.t) for a, b in zip(result.odometry, gt)])
    gps_err = np.array(
        [np.linalg.norm(f.position - gt[min(int(round(f.time_s * FPS)), n - 1)].t) for f in fixes]
    )
    loops = summary.get("loop_closure") or {}
    return {
        "flight": flight,
        "method": method,
        "seed": seed,
        "frames": n,
        "path_m": round(m.path_length_m, 1),
        "ate_m": m.ate_rmse_m,
        "ate_pct": 100.0 * m.ate_rmse_m / max(m.path_length_m, 1e-9),
        "end_error_m": float(abs_err[-1]),
        "loops_accepted": loops.get("accepted"),
        "loops_rejected": loops.get("rejected"),
        "loop_rejected_reasons": loops.get("rejected_reasons"),
        "loop_max_correction_m": loops.get("max_correction_m"),
        "pose_graph_solves": loops.get("pose_graph_solves"),
        "pose_graph_ms_max": loops.get("pose_graph_ms_max"),
        "rpe100_m": m.rpe_100m["trans_rmse_m"],
        "drift_pct": m.drift_pct,
        "rot_deg_per_100m": m.drift["rotation_deg_per_100m"],
        "fps": summary["fps"],
        "track_ms": summary["track_ms"],
        "lost": summary["lost"],
        "degraded": summary["degraded"],
        "reasons": summary["reasons"],
        "vo_abs_rmse_m": float(np.sqrt(np.mean(abs_err**2))),
        "gps_rmse_m": float(np.sqrt(np.mean(gps_err**2))) if len(gps_err) else None,
        "gps_fused_rmse_m": float(np.sqrt(np.mean(fused_err**2))) if len(fused_err) else None,
        "gps_rejected": summary.get("gps", {}).get("rejected"),
    }


COLUMNS = [
    ("ate_m", "ATE m", "{:.3f}"),
    ("ate_pct", "ATE %", "{:.3f}"),
    ("rpe100_m", "RPE100 m", "{:.3f}"),
    ("drift_pct", "drift %", "{:.2f}"),
    ("fps", "fps", "{:.1f}"),
    ("lost", "lost", "{:d}"),
    ("vo_abs_rmse_m", "VO abs m", "{:.2f}"),
    ("gps_rmse_m", "GPS m", "{:.2f}"),
    ("gps_fused_rmse_m", "GPS+VO m", "{:.2f}"),
    ("loops_accepted", "loops ok", "{:d}"),
    ("loops_rejected", "loops rej", "{:d}"),
]
HIGHER_IS_BETTER = {"fps"}


def _cell(v, fmt: str) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return fmt.format(int(v) if fmt == "{:d}" else v)


def worst(rows: list[dict], method: str, flight: str) -> dict:
    mine = [r for r in rows if r["method"] == method and r["flight"] == flight]
    out: dict = {"flight": flight, "method": method, "seed": "worst"}
    for key, _, _ in COLUMNS:
        vals = [r[key] for r in mine if r[key] is not None]
        if not vals:
            out[key] = None
        elif key.startswith("loops_"):
            out[key] = sum(vals)  # loops: the total over seeds
        else:
            out[key] = min(vals) if key in HIGHER_IS_BETTER else max(vals)
    return out


def print_table(rows: list[dict], methods: list[str]) -> list[dict]:
    """Print one table per flight kind (every seed, the worst case, the ratio skyrecon / opencv);
    returns the worst-case rows."""
    worst_rows = []
    for flight in dict.fromkeys(r["flight"] for r in rows):
        mine = [r for r in rows if r["flight"] == flight]
        print(f"flights: {flight}")
        header = f"{'method':<14} {'seed':>5} {'path m':>7} " + " ".join(f"{h:>9}" for _, h, _ in COLUMNS)
        print(header)
        print("-" * len(header))
        for r in mine:
            print(
                f"{r['method']:<14} {r['seed']!s:>5} {r['path_m']:>7} "
                + " ".join(f"{_cell(r[k], f):>9}" for k, _, f in COLUMNS)
            )
        here = [worst(rows, m, flight) for m in methods]
        worst_rows += here
        for w in here:
            print(
                f"{w['method']:<14} {'worst':>5} {'':>7} "
                + " ".join(f"{_cell(w[k], f):>9}" for k, _, f in COLUMNS)
            )
        if "skyrecon" in methods and "opencv" in methods:
            a, b = here[methods.index("skyrecon")], here[methods.index("opencv")]
            ratios = {}
            for k, _, _ in COLUMNS:
                if not k.startswith("loops_") and a[k] is not None and b[k] not in (None, 0):
                    ratios[k] = a[k] / b[k]
            print(
                f"{'ratio':<14} {'worst':>5} {'':>7} "
                + " ".join(f"{(f'{ratios[k]:.2f}' if k in ratios else '-'):>9}" for k, _, _ in COLUMNS)
            )
        print()
    print("(ratio = skyrecon / opencv on the worst case over seeds; < 1 is better except fps;")
    print(" skyrecon: loop closure on, the default; skyrecon-nolc: off; loops: totals over seeds)")
    return worst_rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--length-m", type=float, default=500.0)
    ap.add_argument("--size", type=int, nargs=2, default=[640, 480], metavar=("W", "H"))
    ap.add_argument("--frames", type=int, help="track only the first N frames of each flight")
    ap.add_argument("--quick", action="store_true", help="1 seed, 100 m, 320x240")
    ap.add_argument(
        "--methods",
        nargs="+",
        default=["skyrecon", "skyrecon-nolc", "opencv"],
        choices=["skyrecon", "skyrecon-nolc", "opencv"],
    )
    ap.add_argument(
        "--flights",
        nargs="+",
        default=["route", "circuit"],
        choices=["route", "circuit"],
        help="route: random routes that never come back (--length-m); circuit: a closed circuit flown "
        "1.5 times (--circuit-length-m), the second lap revisits the first",
    )
    ap.add_argument("--circuit-length-m", type=float, default=560.0)
    ap.add_argument(
        "--low-texture-fraction",
        type=float,
        default=LOW_TEXTURE_FRACTION,
        help="share of buildings with plain, almost textureless facades (0-1)",
    )
    add_camera_noise_option(ap, "added to every image as it is read; the rows get their own table")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "skyrecon_vo_bench")
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("results.json"))
    ap.add_argument(
        "--merge",
        type=Path,
        nargs="+",
        metavar="JSON",
        help="combine the rows of earlier runs (e.g. one process per seed) into one table and --out",
    )
    args = ap.parse_args()
    if args.merge:
        docs = [json.loads(p.read_text()) for p in args.merge]
        rows = [r for d in docs for r in d["rows"]]
        methods = list(dict.fromkeys(m for d in docs for m in d["methods"]))
        worst_rows = print_table(rows, methods)
        doc = {**docs[0], "merged_from": [str(p) for p in args.merge], "methods": methods}
        doc.update(rows=rows, worst=worst_rows)
        args.out.write_text(json.dumps(doc, indent=2) + "\n")
        print(f"wrote {args.out}")
        return
    if args.quick:
        args.seeds, args.length_m, args.size = args.seeds[:1], 100.0, [320, 240]
        args.flights = ["route"]
    methods = list(args.methods)
    if importlib.util.find_spec("skyrecon.odometry.engine") is None:
        print("skyrecon.odometry.engine is not available in this checkout: running the baseline only")
        methods = [m for m in methods if m == "opencv"]
    args.cache.mkdir(parents=True, exist_ok=True)
    rows = []
    for flight in args.flights:
        length = args.circuit_length_m if flight == "circuit" else args.length_m
        for seed in args.seeds:
            t0 = time.perf_counter()
            root = make_flight(
                seed,
                length,
                args.size[0],
                args.size[1],
                args.cache,
                circuit=flight == "circuit",
                low_texture_fraction=args.low_texture_fraction,
            )
            print(
                f"{flight} seed {seed}: flight ready in {time.perf_counter() - t0:.0f} s ({root})", flush=True
            )
            tag = plain_tag(args.low_texture_fraction)
            label = f"{flight}-{tag}" if tag else flight  # a plainer city gets its own table
            if args.camera_noise > 0:
                label = f"{label}-noise{args.camera_noise:g}"  # and a noisy camera its own
            for method in methods:
                t0 = time.perf_counter()
                row = run_method(
                    method, root, seed, args.frames, label, args.low_texture_fraction, args.camera_noise
                )
                rows.append(
                    {
                        **row,
                        "low_texture_fraction": args.low_texture_fraction,
                        "camera_noise": args.camera_noise,
                    }
                )
                print(f"  {method}: {time.perf_counter() - t0:.0f} s", flush=True)
    print()
    worst_rows = print_table(rows, methods)
    doc = {
        "config": {
            "seeds": args.seeds,
            "length_m": args.length_m,
            "flights": args.flights,
            "circuit_length_m": args.circuit_length_m,
            "size": args.size,
            "frames": args.frames,
            "speed_mps": SPEED_MPS,
            "fps": FPS,
            "baseline_m": 0.3,
            "hfov_deg": 90.0,
            "low_texture_fraction": args.low_texture_fraction,
            "camera_noise": args.camera_noise,
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
