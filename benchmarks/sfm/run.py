"""Structure from motion: skyrecon's run_sfm vs pycolmap's incremental pipeline, side by side.

Scenes:
  fountain  strecha-fountain-P11 (11 photos, 3072x2048, ground-truth cameras), resized once to a
            longer side of --sizes (default 1024 and 1536) and written as JPEG (quality 95)
            into a temporary folder that both pipelines read.
  flight    a synthetic drone flight over the generated city (sim.flight_poses, 5 m/s at
            10 fps, camera pitched 12 deg down, 480x360, 80 deg horizontal field of view),
            the first 100 / 200 / 300 frames (--frames), sequential pairing; exact poses.

Methods:
  skyrecon  run_sfm(paths, K, SfMSettings(max_image_size=None, sequential=...)) on the local
            process executor (all cores), fresh workspace (features extracted in the timing).
  pycolmap  extract_features (CPU SIFT, PINHOLE camera from K, one camera), match_exhaustive
            (CPU) or match_sequential for flights, incremental_mapping with the intrinsics
            fixed (refine focal length / principal point / extra parameters off).

Metrics (ground truth vs estimate, by image name):
  registered    images with a pose / images
  rot med/max   rotation error after the best global rotation (chordal mean), degrees
  ctr med/max   camera-centre error after a similarity (Umeyama) alignment, metres and % of
                the scene extent = the largest distance between two ground-truth camera centres
  reproj        mean reprojection error of the final model, pixels
  time          wall time of the whole pipeline (features + matching + mapping), seconds;
                ratio = skyrecon / pycolmap (the target is <= 0.5)

Usage:
  .venv/bin/python benchmarks/sfm/run.py                       # fountain 1024 + 1536, flights 100/200/300
  .venv/bin/python benchmarks/sfm/run.py --scenes fountain --sizes 1024 --repeat 2
  .venv/bin/python benchmarks/sfm/run.py --scenes flight --frames 100 200 300 --no-peer
Writes benchmarks/sfm/results.json. Never fails for being slow.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from skyrecon.core import Intrinsics, Rigid3  # noqa: E402
from skyrecon.eval.sfm_metrics import evaluate_sfm_poses  # noqa: E402
from skyrecon.features.detect import resize_longer_side  # noqa: E402
from skyrecon.io import read_image, read_strecha_cameras, write_image  # noqa: E402
from skyrecon.sfm import SfMSettings, run_sfm  # noqa: E402

try:
    import pycolmap  # type: ignore
except ImportError:  # pragma: no cover - optional peer
    pycolmap = None


@dataclass
class Row:
    scene: str
    method: str
    registered: int
    total: int
    rot_med: float
    rot_max: float
    ctr_med_m: float
    ctr_max_m: float
    ctr_med_pct: float
    ctr_max_pct: float
    extent_m: float
    reproj_px: float
    points: int
    seconds: float
    extra: dict = field(default_factory=dict)


def data_root() -> Path:
    env = os.environ.get("SKYRECON_DATA")
    return Path(env) if env else ROOT.parent / "shared" / "data"


# ----------------------------------------------------------------------------------------------
# inputs
# ----------------------------------------------------------------------------------------------
def fountain_inputs(size: int, work: Path) -> tuple[list[Path], Intrinsics, dict[str, Rigid3]]:
    root = data_root() / "strecha-fountain-P11"
    views = read_strecha_cameras(root / "gt_dense_cameras")
    out = work / f"fountain_{size}"
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    sx = 1.0
    for v in views:
        img = read_image(v.image_path)
        small, sx, _ = resize_longer_side(img, size)
        p = out / v.name
        ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(small[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 95])
        p.write_bytes(buf.tobytes())
        paths.append(p)
    intr = views[0].intrinsics.scaled(sx)
    return paths, intr, {v.name: v.cam_from_world for v in views}


def flight_inputs(n_max: int, cache: Path, seed: int = 3) -> tuple[list[Path], Intrinsics, dict[str, Rigid3]]:
    from skyrecon.sim import flight_poses, generate_city, render

    intr = Intrinsics.from_fov(480, 360, 80.0)
    d = cache / f"flight_seed{seed}_{n_max}"
    poses_file = d / "cam_from_world.npy"
    if not poses_file.is_file():
        d.mkdir(parents=True, exist_ok=True)
        city = generate_city(seed)
        poses = flight_poses(city, n_max, seed, speed_mps=5.0, fps=10.0)
        t0 = time.perf_counter()
        for k, wfc in enumerate(poses):
            write_image(d / f"frame_{k:04d}.png", render(city, intr, wfc.inverse()).image)
        print(f"  rendered {n_max} frames in {time.perf_counter() - t0:.0f} s", flush=True)
        np.save(poses_file, np.array([p.inverse().matrix for p in poses]))
    M = np.load(poses_file)
    paths = [d / f"frame_{k:04d}.png" for k in range(n_max)]
    gt = {p.name: Rigid3.from_matrix(M[k]) for k, p in enumerate(paths)}
    return paths, intr, gt


# ----------------------------------------------------------------------------------------------
# methods
# ----------------------------------------------------------------------------------------------
def _row(
    scene: str,
    method: str,
    est: dict[str, Rigid3],
    gt: dict[str, Rigid3],
    reproj: float,
    points: int,
    seconds: float,
    extra: dict,
) -> Row:
    ev = evaluate_sfm_poses(est, gt)
    s = ev.summary()
    return Row(
        scene,
        method,
        len(ev.names),
        len(gt),
        s["rotation_median_deg"],
        s["rotation_max_deg"],
        s["center_median_m"],
        s["center_max_m"],
        s["center_median_pct"],
        s["center_max_pct"],
        ev.extent_m,
        reproj,
        points,
        seconds,
        extra,
    )


def run_skyrecon(
    scene: str, paths: list[Path], intr: Intrinsics, gt: dict, sequential: bool, seed: int
) -> Row:
    ws = Path(tempfile.mkdtemp(prefix="sfm-bench-ws-"))
    try:
        t0 = time.perf_counter()
        res = run_sfm(
            paths, intr, SfMSettings(max_image_size=None, sequential=sequential), seed=seed, workspace=ws
        )
        dt = time.perf_counter() - t0
    finally:
        shutil.rmtree(ws, ignore_errors=True)
    est = {im.name: im.cam_from_world for im in res.reconstruction.images.values()}
    extra = {
        "timings": {k: round(v, 2) for k, v in res.timings.items()},
        "pairs": res.diagnostics.get("pairing"),
        "left_out": res.unregistered,
    }
    return _row(
        scene,
        "skyrecon",
        est,
        gt,
        res.mean_reprojection_error_px(),
        len(res.reconstruction.points3d),
        dt,
        extra,
    )


def _pose(img) -> Rigid3:
    T = img.cam_from_world() if callable(img.cam_from_world) else img.cam_from_world
    return Rigid3(T.rotation.matrix(), np.asarray(T.translation))


def run_pycolmap(scene: str, paths: list[Path], intr: Intrinsics, gt: dict, sequential: bool) -> Row:
    work = Path(tempfile.mkdtemp(prefix="sfm-bench-colmap-"))
    image_dir = paths[0].parent
    try:
        db = work / "database.db"
        ro = pycolmap.ImageReaderOptions()
        ro.camera_model = "PINHOLE"
        ro.camera_params = f"{intr.fx},{intr.fy},{intr.cx + 0.5},{intr.cy + 0.5}"
        t0 = time.perf_counter()
        pycolmap.extract_features(
            db,
            image_dir,
            image_names=[p.name for p in paths],
            camera_mode=pycolmap.CameraMode.SINGLE,
            reader_options=ro,
            device=pycolmap.Device.cpu,
        )
        t1 = time.perf_counter()
        if sequential:
            pycolmap.match_sequential(db, device=pycolmap.Device.cpu)
        else:
            pycolmap.match_exhaustive(db, device=pycolmap.Device.cpu)
        t2 = time.perf_counter()
        opts = pycolmap.IncrementalPipelineOptions()
        opts.ba_refine_focal_length = False
        opts.ba_refine_principal_point = False
        opts.ba_refine_extra_params = False
        opts.mapper.abs_pose_refine_focal_length = False
        opts.mapper.abs_pose_refine_extra_params = False
        (work / "sparse").mkdir()
        recs = pycolmap.incremental_mapping(db, image_dir, work / "sparse", opts)
        t3 = time.perf_counter()
    finally:
        pass
    best = max(recs.values(), key=lambda r: r.num_reg_images()) if recs else None
    est = {}
    reproj, points = float("nan"), 0
    if best is not None:
        for img in best.images.values():
            if getattr(img, "has_pose", True):
                est[img.name] = _pose(img)
        reproj = float(best.compute_mean_reprojection_error())
        points = int(best.num_points3D())
    shutil.rmtree(work, ignore_errors=True)
    extra = {
        "timings": {
            "features": round(t1 - t0, 2),
            "matching": round(t2 - t1, 2),
            "mapping": round(t3 - t2, 2),
        },
        "models": len(recs),
    }
    return _row(scene, "pycolmap", est, gt, reproj, points, t3 - t0, extra)


# ----------------------------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------------------------
def print_table(rows: list[Row]) -> None:
    head = (
        f"{'scene':<16}{'method':<10}{'reg':>8}{'rot med':>9}{'rot max':>9}{'ctr med m':>11}{'ctr max m':>11}"
        f"{'med %':>8}{'max %':>8}{'reproj':>8}{'points':>8}{'time s':>9}{'ratio':>7}"
    )
    print(head)
    print("-" * len(head))
    peer = {r.scene: r for r in rows if r.method == "pycolmap"}
    for r in rows:
        ratio = (
            r.seconds / peer[r.scene].seconds if r.method == "skyrecon" and r.scene in peer else float("nan")
        )
        print(
            f"{r.scene:<16}{r.method:<10}{f'{r.registered}/{r.total}':>8}{r.rot_med:>9.4f}{r.rot_max:>9.4f}"
            f"{r.ctr_med_m:>11.5f}{r.ctr_max_m:>11.5f}{r.ctr_med_pct:>8.4f}{r.ctr_max_pct:>8.4f}{r.reproj_px:>8.3f}"
            f"{r.points:>8d}{r.seconds:>9.1f}{ratio:>7.2f}"
        )
    print(
        "extent = largest distance between two ground-truth camera centres; rot after the best global "
        "rotation, ctr after a similarity alignment"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=["fountain", "flight"], choices=["fountain", "flight"])
    ap.add_argument("--sizes", nargs="+", type=int, default=[1024, 1536])
    ap.add_argument("--frames", nargs="+", type=int, default=[100, 200, 300])
    ap.add_argument("--repeat", type=int, default=1, help="runs per method (the fastest is kept)")
    ap.add_argument("--no-peer", action="store_true", help="skip pycolmap")
    ap.add_argument("--peer-flights", action="store_true", help="also run pycolmap on the flights (slow)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "skyrecon-sfm-bench")
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("results.json"))
    args = ap.parse_args()
    if pycolmap is None and not args.no_peer:
        print("pycolmap is not installed: running skyrecon only (pip install pycolmap for the peer)")
    peer = pycolmap is not None and not args.no_peer
    rows: list[Row] = []
    work = Path(tempfile.mkdtemp(prefix="sfm-bench-"))
    try:
        if "fountain" in args.scenes:
            if not (data_root() / "strecha-fountain-P11").is_dir():
                print(f"fountain data not found under {data_root()}; skipping")
            else:
                for size in args.sizes:
                    paths, intr, gt = fountain_inputs(size, work)
                    scene = f"fountain@{size}"
                    print(f"{scene}: {len(paths)} images {intr.width}x{intr.height}", flush=True)
                    for method in ["skyrecon", "pycolmap"] if peer else ["skyrecon"]:
                        best = None
                        for _ in range(args.repeat):
                            r = (
                                run_skyrecon(scene, paths, intr, gt, False, args.seed)
                                if method == "skyrecon"
                                else run_pycolmap(scene, paths, intr, gt, False)
                            )
                            print(
                                f"  {method}: {r.registered}/{r.total} registered, {r.seconds:.1f} s, "
                                f"{r.extra.get('timings')}",
                                flush=True,
                            )
                            best = r if best is None or r.seconds < best.seconds else best
                        rows.append(best)
        if "flight" in args.scenes:
            args.cache.mkdir(parents=True, exist_ok=True)
            n_max = max(args.frames)
            all_paths, intr, gt_all = flight_inputs(n_max, args.cache)
            for n in args.frames:
                paths = all_paths[:n]
                gt = {p.name: gt_all[p.name] for p in paths}
                scene = f"flight-{n}"
                print(f"{scene}: {n} frames {intr.width}x{intr.height}", flush=True)
                r = run_skyrecon(scene, paths, intr, gt, True, args.seed)
                print(
                    f"  skyrecon: {r.registered}/{r.total} registered, {r.seconds:.1f} s, {r.extra.get('timings')}",
                    flush=True,
                )
                rows.append(r)
                if peer and args.peer_flights:
                    r = run_pycolmap(scene, paths, intr, gt, True)
                    print(f"  pycolmap: {r.registered}/{r.total} registered, {r.seconds:.1f} s", flush=True)
                    rows.append(r)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print()
    print_table(rows)
    flights = [r for r in rows if r.scene.startswith("flight") and r.method == "skyrecon"]
    if len(flights) > 1:
        per = [r.seconds / r.total for r in flights]
        print("flight seconds per frame: " + ", ".join(f"{r.total}: {p:.2f}" for r, p in zip(flights, per)))
    args.out.write_text(json.dumps([r.__dict__ for r in rows], indent=2, default=float) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
