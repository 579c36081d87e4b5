"""Two-view relative pose: skyrecon vs the OpenCV baseline vs PoseLib, on real and synthetic pairs.

Scenes:
  fountain  strecha-fountain-P11, all (i, i+1) and (i, i+2) pairs (19), GT cameras.
  object    rendered orbits around synthetic monuments (skyrecon.sim), exact GT.
  city      rendered drone flights over the synthetic city (forward motion), exact GT.

Methods (all on the same images, resized once to the longer side --size before timing):
  skyrecon  reconstruct_two_view with default settings (RootSIFT, mutual ratio matching,
            5-point LO-RANSAC, robust refinement); dense model timed separately with --dense.
  opencv    cv2.SIFT (defaults), BFMatcher ratio 0.8, cv2.findEssentialMat (RANSAC, 1 px,
            prob 0.999), cv2.recoverPose.
  poselib   poselib.estimate_relative_pose (max epipolar error 1 px) on the opencv matches.

Usage:
  .venv/bin/python benchmarks/two_view/run.py                      # everything
  .venv/bin/python benchmarks/two_view/run.py --scenes fountain --dense
Prints per-pair rows and a summary table (median / max errors in degrees, inliers, wall seconds per
pair from images in memory to the pose, CPU seconds of the process (all threads) for the same,
and ratios to the baseline); writes benchmarks/two_view/results.json. Image loading/rendering is
excluded and reported separately; the dense model (--dense) is timed separately.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from skyrecon.core import Intrinsics, PosedView  # noqa: E402
from skyrecon.errors import EstimationError  # noqa: E402
from skyrecon.eval.gt_geometry import relative_pose  # noqa: E402
from skyrecon.eval.pose_metrics import rotation_error_deg, translation_direction_error_deg  # noqa: E402
from skyrecon.features.detect import resize_longer_side  # noqa: E402
from skyrecon.twoview import TwoViewSettings, dense_model, reconstruct_two_view  # noqa: E402

try:
    import poselib  # type: ignore
except ImportError:  # pragma: no cover - optional peer
    poselib = None


@dataclass
class Pair:
    scene: str
    name: str
    image1: np.ndarray
    image2: np.ndarray
    intr1: Intrinsics
    intr2: Intrinsics
    R_gt: np.ndarray
    t_gt: np.ndarray


@dataclass
class Row:
    scene: str
    pair: str
    method: str
    rot_deg: float
    trans_deg: float
    inliers: int
    matches: int
    seconds: float
    extra: dict


# ----------------------------------------------------------------------------------------------
# data
# ----------------------------------------------------------------------------------------------
def _resize(image: np.ndarray, intr: Intrinsics, size: int) -> tuple[np.ndarray, Intrinsics]:
    small, sx, _ = resize_longer_side(image, size)
    return small, (intr.scaled(sx) if sx != 1.0 else intr)


def fountain_pairs(data: Path, size: int) -> tuple[list[Pair], float]:
    from skyrecon.io.images import read_image
    from skyrecon.io.multiview import read_strecha_cameras

    root = data / "strecha-fountain-P11"
    if not root.is_dir():
        print(f"[skip] fountain: {root} not found")
        return [], 0.0
    views = read_strecha_cameras(root / "gt_dense_cameras")
    t0 = time.perf_counter()
    imgs = []
    for v in views:
        small, intr = _resize(read_image(v.image_path), v.intrinsics, size)
        imgs.append((small, intr))
    load = time.perf_counter() - t0
    pairs = []
    for gap in (1, 2):
        for i in range(len(views) - gap):
            j = i + gap
            rel = relative_pose(views[i], views[j])
            pairs.append(
                Pair(
                    "fountain",
                    f"{i:02d}-{j:02d}",
                    imgs[i][0],
                    imgs[j][0],
                    imgs[i][1],
                    imgs[j][1],
                    rel.R,
                    rel.t,
                )
            )
    return pairs, load


def synthetic_pairs(kind: str, size: int) -> tuple[list[Pair], float]:
    try:
        from skyrecon.sim import flight_poses, generate_city, generate_object_scene, orbit_views, render_views
    except ImportError:
        print("[skip] synthetic: skyrecon.sim not available")
        return [], 0.0
    w, h = size, int(round(size * 2 / 3))
    intr = Intrinsics.from_fov(w, h, 60.0)
    t0 = time.perf_counter()
    pairs = []
    if kind == "object":
        for seed in (1, 2):
            scene = generate_object_scene(seed=seed)
            views = orbit_views(scene, 24, intr, seed=seed)
            idx = [(0, 1), (6, 7), (12, 14), (18, 20)]
            need = sorted({k for p in idx for k in p})
            rendered = dict(zip(need, render_views(scene, [views[k] for k in need])))
            for i, j in idx:
                rel = relative_pose(views[i], views[j])
                pairs.append(
                    Pair(
                        "object",
                        f"s{seed}:{i:02d}-{j:02d}",
                        rendered[i].image,
                        rendered[j].image,
                        intr,
                        intr,
                        rel.R,
                        rel.t,
                    )
                )
    else:
        city = generate_city(seed=3)
        poses = flight_poses(city, 60, seed=3, pitch_deg=25.0)
        views = [PosedView(f"f{k:03d}", intr, p.inverse()) for k, p in enumerate(poses)]
        idx = [(0, 6), (15, 21), (30, 36), (45, 51)]
        need = sorted({k for p in idx for k in p})
        rendered = dict(zip(need, render_views(city, [views[k] for k in need])))
        for i, j in idx:
            rel = relative_pose(views[i], views[j])
            pairs.append(
                Pair(
                    "city", f"{i:02d}-{j:02d}", rendered[i].image, rendered[j].image, intr, intr, rel.R, rel.t
                )
            )
    return pairs, time.perf_counter() - t0


# ----------------------------------------------------------------------------------------------
# methods
# ----------------------------------------------------------------------------------------------
def run_skyrecon(p: Pair, settings: TwoViewSettings, dense: bool) -> Row:
    c0, t0 = time.process_time(), time.perf_counter()
    r = reconstruct_two_view(p.image1, p.image2, p.intr1, p.intr2, replace(settings, dense=False), seed=0)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    rot = rotation_error_deg(r.R, p.R_gt) if r.R is not None else np.nan
    tr = translation_direction_error_deg(r.t, p.t_gt) if r.t is not None else np.nan
    extra = {k: round(v, 4) for k, v in r.timings.items()}
    extra.update(status=r.status, warnings=list(r.warnings), cpu_s=cpu)
    if dense and r.geometry.has_pose:
        t1 = time.perf_counter()
        try:
            d = dense_model(
                p.image1, p.image2, p.intr1, p.intr2, r.geometry, r.x1[r.inliers], r.x2[r.inliers], settings
            )
            extra["dense_points"] = len(d.cloud)
        except EstimationError as exc:
            extra["dense_error"] = str(exc)
        extra["dense"] = time.perf_counter() - t1
    return Row(p.scene, p.name, "skyrecon", rot, tr, r.num_inliers, r.num_matches, wall, extra)


def opencv_matches(p: Pair) -> tuple[np.ndarray, np.ndarray, float, float]:
    t0, c0 = time.perf_counter(), time.process_time()
    sift = cv2.SIFT_create()
    g1 = cv2.cvtColor(p.image1, cv2.COLOR_RGB2GRAY)
    g2 = cv2.cvtColor(p.image2, cv2.COLOR_RGB2GRAY)
    k1, d1 = sift.detectAndCompute(g1, None)
    k2, d2 = sift.detectAndCompute(g2, None)
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(d1, d2, k=2)
    good = [m[0] for m in knn if len(m) == 2 and m[0].distance < 0.8 * m[1].distance]
    x1 = np.array([k1[m.queryIdx].pt for m in good], np.float64)
    x2 = np.array([k2[m.trainIdx].pt for m in good], np.float64)
    return x1, x2, time.perf_counter() - t0, time.process_time() - c0


def run_opencv(p: Pair, x1: np.ndarray, x2: np.ndarray, t_feat: float, c_feat: float) -> Row:
    t0, c0 = time.perf_counter(), time.process_time()
    K = p.intr1.K
    E, mask = cv2.findEssentialMat(x1, x2, K, method=cv2.RANSAC, prob=0.999, threshold=1.0)
    if E is not None and E.shape[0] > 3:
        E = E[:3]
    n, R, t, mask2 = cv2.recoverPose(E, x1, x2, K, mask=mask)
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    return Row(
        p.scene,
        p.name,
        "opencv",
        rotation_error_deg(R, p.R_gt),
        translation_direction_error_deg(t.ravel(), p.t_gt),
        int(n),
        len(x1),
        t_feat + dt,
        {"pose_s": dt, "cpu_s": c_feat + dc},
    )


def run_poselib(p: Pair, x1: np.ndarray, x2: np.ndarray, t_feat: float, c_feat: float) -> Row | None:
    if poselib is None:
        return None

    def cam(intr: Intrinsics) -> dict:
        return {
            "model": "PINHOLE",
            "width": intr.width,
            "height": intr.height,
            "params": [intr.fx, intr.fy, intr.cx, intr.cy],
        }

    t0, c0 = time.perf_counter(), time.process_time()
    pose, info = poselib.estimate_relative_pose(
        x1, x2, cam(p.intr1), cam(p.intr2), {"max_epipolar_error": 1.0}, {}
    )
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    return Row(
        p.scene,
        p.name,
        "poselib",
        rotation_error_deg(pose.R, p.R_gt),
        translation_direction_error_deg(pose.t, p.t_gt),
        int(info["num_inliers"]),
        len(x1),
        t_feat + dt,
        {"pose_s": dt, "cpu_s": c_feat + dc},
    )


# ----------------------------------------------------------------------------------------------
# reporting
# ----------------------------------------------------------------------------------------------
def summarize(rows: list[Row]) -> dict:
    out: dict = {}
    for scene in sorted({r.scene for r in rows}):
        out[scene] = {}
        for method in ("skyrecon", "opencv", "poselib"):
            rs = [r for r in rows if r.scene == scene and r.method == method]
            if not rs:
                continue
            rot = np.array([r.rot_deg for r in rs])
            tr = np.array([r.trans_deg for r in rs])
            out[scene][method] = {
                "pairs": len(rs),
                "rot_median": float(np.nanmedian(rot)),
                "rot_max": float(np.nanmax(rot)),
                "trans_median": float(np.nanmedian(tr)),
                "trans_max": float(np.nanmax(tr)),
                "failures": int(np.sum(~np.isfinite(rot) | ~np.isfinite(tr))),
                "inliers_median": float(np.median([r.inliers for r in rs])),
                "seconds_mean": float(np.mean([r.seconds for r in rs])),
                "seconds_max": float(np.max([r.seconds for r in rs])),
                "cpu_seconds_mean": float(np.mean([r.extra.get("cpu_s", np.nan) for r in rs])),
            }
            if method == "skyrecon" and "dense" in rs[0].extra:
                out[scene][method]["dense_seconds_mean"] = float(np.mean([r.extra["dense"] for r in rs]))
                out[scene][method]["dense_seconds_max"] = float(np.max([r.extra["dense"] for r in rs]))
    return out


def print_table(summary: dict) -> None:
    hdr = (
        f"{'scene':9s} {'method':9s} {'pairs':>5s} {'rot med':>8s} {'rot max':>8s} {'t med':>8s} {'t max':>8s} "
        f"{'inl med':>8s} {'s/pair':>7s} {'cpu s':>6s}   ratios vs opencv (rot med, t med, s) | vs poselib (rot med, t med)"
    )
    print(hdr)
    print("-" * len(hdr))
    for scene, ms in summary.items():
        base = ms.get("opencv")
        pl = ms.get("poselib")
        for method, s in ms.items():
            line = (
                f"{scene:9s} {method:9s} {s['pairs']:5d} {s['rot_median']:8.4f} {s['rot_max']:8.4f} {s['trans_median']:8.4f} "
                f"{s['trans_max']:8.4f} {s['inliers_median']:8.0f} {s['seconds_mean']:7.3f} {s['cpu_seconds_mean']:6.2f}"
            )
            if base and method != "opencv":
                line += (
                    f"   {s['rot_median'] / base['rot_median']:.2f} {s['trans_median'] / base['trans_median']:.2f} "
                    f"{s['seconds_mean'] / base['seconds_mean']:.2f}"
                )
            if pl and method == "skyrecon":
                line += f" | {s['rot_median'] / pl['rot_median']:.2f} {s['trans_median'] / pl['trans_median']:.2f}"
            if "dense_seconds_mean" in s:
                line += f"   dense {s['dense_seconds_mean']:.1f} s (max {s['dense_seconds_max']:.1f})"
            print(line)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--data", type=Path, default=Path(os.environ.get("SKYRECON_DATA", ROOT.parent / "shared" / "data"))
    )
    ap.add_argument("--size", type=int, default=1536, help="longer image side, pixels")
    ap.add_argument("--scenes", default="fountain,object,city")
    ap.add_argument("--dense", action="store_true", help="also build (and time) the dense model")
    ap.add_argument("--methods", default="skyrecon,opencv,poselib")
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("results.json"))
    args = ap.parse_args(argv)
    methods = args.methods.split(",")
    settings = TwoViewSettings()

    pairs: list[Pair] = []
    load = {}
    for scene in args.scenes.split(","):
        if scene == "fountain":
            ps, t = fountain_pairs(args.data, args.size)
        else:
            ps, t = synthetic_pairs(scene, args.size)
        pairs += ps
        load[scene] = t
    print("image loading / rendering (excluded): " + ", ".join(f"{k} {v:.1f} s" for k, v in load.items()))
    # warm-up (numba compilation, OpenCV first-call costs) on the first pair, not timed
    if pairs and "skyrecon" in methods:
        run_skyrecon(pairs[0], settings, args.dense)

    rows: list[Row] = []
    print(
        f"{'scene':9s} {'pair':12s} {'method':9s} {'rot':>8s} {'trans':>8s} {'inl':>6s} {'match':>6s} {'sec':>6s}"
    )
    for p in pairs:
        this = []
        if "skyrecon" in methods:
            this.append(run_skyrecon(p, settings, args.dense))
        if "opencv" in methods or "poselib" in methods:
            x1, x2, t_feat, c_feat = opencv_matches(p)
            if "opencv" in methods:
                this.append(run_opencv(p, x1, x2, t_feat, c_feat))
            if "poselib" in methods:
                r = run_poselib(p, x1, x2, t_feat, c_feat)
                if r is not None:
                    this.append(r)
        for r in this:
            print(
                f"{r.scene:9s} {r.pair:12s} {r.method:9s} {r.rot_deg:8.4f} {r.trans_deg:8.4f} {r.inliers:6d} {r.matches:6d} {r.seconds:6.3f}"
                + (
                    f"  {r.extra.get('status')} {r.extra.get('warnings')}"
                    if r.method == "skyrecon" and r.extra.get("warnings")
                    else ""
                )
            )
        rows += this
        sys.stdout.flush()
    summary = summarize(rows)
    print()
    print_table(summary)
    args.out.write_text(
        json.dumps(
            {"summary": summary, "load_seconds": load, "size": args.size, "rows": [r.__dict__ for r in rows]},
            indent=1,
            default=float,
        )
    )
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
