"""``skyrecon render``: write a synthetic scene with exact ground truth to disk.

So that every other command can be tried without data of one's own:

* ``stereo``: a rectified stereo pair from a street in the city (``left.png``, ``right.png``,
  ``calib.txt`` with KITTI ``P2:``/``P3:`` lines, ``K.txt``, ground-truth ``gt_disparity.pfm``,
  ``gt_depth.pfm``, ``gt_points.ply`` in the left camera frame, ``preview.png``).
* ``sequence``: a stereo flight in the KITTI-odometry layout (``image_2/``, ``image_3/``,
  ``calib.txt``, ``poses.txt`` = world_from_left_camera) plus ground-truth depth in ``depth_2/``;
  with ``--format ros2`` instead a ROS 2 bag (OUT is the bag directory: ``metadata.yaml``,
  ``<OUT name>.db3``), with ``--format mcap`` a single ``OUT/flight.mcap``: images, camera info and
  poses on the topics of ``skyrecon.io.rosbag_output`` (``/stereo/left/image_raw``,
  ``/stereo/right/image_raw``, ``/stereo/left/pose``, ...), frames 0.1 s apart from time 0 (the
  times KITTI assumes without ``times.txt``).
* ``ring``: a multi-view ring of images around a small scene, cameras as a COLMAP text model
  in ``sparse/`` (what ``skyrecon mvs --cameras`` reads), ground-truth depth in ``depth/``.
* ``images``: a monocular photo set orbiting a small scene (for two-view and SfM), ``K.txt``
  and ground-truth cameras in ``gt_sparse/``.
* ``survey``: a lawn-mower aerial survey of the city (for ``skyrecon survey``): nadir JPEGs in
  ``images/`` with EXIF GPS around ``--origin`` (noise ``--gps-noise``, a few grossly wrong tags),
  focal length and sensor width; ``cameras_true.txt``, ``gt_sparse/``, ``K.txt``, ``gcp_list.txt``
  (OpenDroneMap format, UTM) and ``survey_truth.json``.

Each writes ``scene.json`` with the seed and settings that regenerate it.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from skyrecon.cli.common import add_command, info, output_dir, positive_float, positive_int
from skyrecon.core import DepthMap, Image, Intrinsics, Reconstruction
from skyrecon.errors import InputError
from skyrecon.io.atomic import write_text_atomic
from skyrecon.io.calib import write_K_txt, write_kitti_calib
from skyrecon.io.colmap import write_colmap_text
from skyrecon.io.disparity import colorize_disparity
from skyrecon.io.images import write_image
from skyrecon.io.pfm import write_pfm
from skyrecon.io.ply import write_ply
from skyrecon.io.rosbag_output import TOPICS, write_stereo_bag
from skyrecon.io.sequence import write_sequence
from skyrecon.progress import progress
from skyrecon.report.figures import contact_sheet, top_down_map
from skyrecon.sim import (
    default_rig,
    flight_poses,
    generate_city,
    generate_object_scene,
    orbit_views,
    render_stereo,
    render_views,
    ring_views,
    street_view_pose,
)

EXAMPLES = """  skyrecon render stereo --seed 3 --out scene/
  skyrecon render sequence --frames 60 --out flight/
  skyrecon render sequence --plain --seed 3 --out plain_flight/
  skyrecon render sequence --frames 60 --format mcap --out flight_mcap/    # flight_mcap/flight.mcap
  skyrecon render ring --views 12 --out ring/
  skyrecon render ring --plain --views 12 --out ring-plain/
  skyrecon render images --views 10 --out photos/
  skyrecon render survey --photos 100 --width 1600 --height 1200 --out survey_photos/
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = add_command(
        subparsers,
        "render",
        help="write a synthetic scene or flight with exact ground truth",
        description=__doc__.split("\n\n")[0] + " Pick what to render:",
        examples=EXAMPLES,
    )
    p.add_argument("kind", choices=["stereo", "sequence", "ring", "images", "survey"], help="what to render")
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    p.add_argument("--seed", type=int, default=0, help="city seed; same seed, same scene (default 0)")
    p.add_argument("--width", type=positive_int, default=640, help="image width in pixels (default 640)")
    p.add_argument("--height", type=positive_int, default=480, help="image height in pixels (default 480)")
    p.add_argument(
        "--hfov", type=positive_float, default=90.0, help="horizontal field of view, degrees (default 90)"
    )
    p.add_argument(
        "--baseline", type=positive_float, default=0.3, help="stereo baseline, metres (default 0.3)"
    )
    p.add_argument("--frames", type=positive_int, default=30, help="sequence: number of frames (default 30)")
    p.add_argument("--views", type=positive_int, default=12, help="ring/images: number of views (default 12)")
    p.add_argument(
        "--city-size", type=positive_float, default=200.0, help="city side length, metres (default 200)"
    )
    p.add_argument(
        "--format",
        choices=["kitti", "ros2", "mcap"],
        default="kitti",
        help="sequence: KITTI layout (default), a ROS 2 bag directory (sqlite3) or OUT/flight.mcap",
    )
    p.add_argument(
        "--plain",
        action="store_true",
        help="low-texture surfaces: stereo/sequence a city of plain and glass facades on plain grey "
        "ground; ring/images plain grey ground, plain walls and one glass face",
    )
    g = p.add_argument_group("survey")
    g.add_argument(
        "--photos", type=positive_int, help="survey: about this many photos (default: cover the city)"
    )
    g.add_argument(
        "--altitude",
        type=positive_float,
        default=80.0,
        help="survey: height above ground, metres (default 80)",
    )
    g.add_argument(
        "--overlap",
        type=float,
        nargs=2,
        default=(0.8, 0.7),
        metavar=("FORWARD", "SIDE"),
        help="survey: forward and side overlap of the photos (default 0.8 0.7)",
    )
    g.add_argument(
        "--gps-noise", type=float, default=3.0, help="survey: horizontal GPS noise sigma, metres (default 3)"
    )
    g.add_argument(
        "--wrong-tags", type=int, help="survey: photos with a grossly wrong tag (default 2 %%, at least 1)"
    )
    g.add_argument(
        "--tilt", type=float, default=2.0, help="survey: random camera tilt sigma, degrees (default 2)"
    )
    g.add_argument(
        "--origin",
        type=float,
        nargs=3,
        metavar=("LAT", "LON", "ALT"),
        help="survey: geographic position of the city's origin (default 47.3769 8.5417 408)",
    )
    return p


def run(args: argparse.Namespace) -> int:
    if args.hfov >= 170:
        raise InputError(f"--hfov must be below 170 degrees for a pinhole camera, got {args.hfov}")
    out = output_dir(args.out)
    t0 = time.perf_counter()
    summary = {
        "stereo": _render_stereo,
        "sequence": _render_sequence,
        "ring": _render_ring,
        "images": _render_images,
        "survey": _render_survey,
    }[args.kind](args, out)
    settings = {k: v for k, v in vars(args).items() if k not in ("command", "debug", "quiet", "out")}
    write_text_atomic(
        out / "scene.json", json.dumps({"generator": "skyrecon render", **settings, **summary}, indent=2)
    )
    if not args.quiet:
        info(f"rendered {args.kind} (seed {args.seed}) to {out} in {time.perf_counter() - t0:.1f} s")
        for key, value in summary.items():
            info(f"  {key}: {value}")
    return 0


# ----- stereo ------------------------------------------------------------------
def _render_stereo(args, out: Path) -> dict:
    city = generate_city(args.seed, size_m=args.city_size, plain=args.plain)
    rig = default_rig(args.width, args.height, args.hfov, args.baseline)
    left_from_world = street_view_pose(city, args.seed)
    frame = render_stereo(city, rig, left_from_world)
    write_image(out / "left.png", frame.left)
    write_image(out / "right.png", frame.right)
    write_kitti_calib(out / "calib.txt", rig)
    write_K_txt(out / "K.txt", rig.left)
    write_pfm(out / "gt_disparity.pfm", frame.disparity_left_px)
    write_pfm(out / "gt_depth.pfm", frame.depth_left_m)
    disp_png = colorize_disparity(frame.disparity_left_px)
    write_image(out / "gt_disparity.png", disp_png)
    cloud = DepthMap(frame.depth_left_m, rig.left).to_points_cam(frame.left)
    write_ply(out / "gt_points.ply", cloud)
    write_image(
        out / "preview.png",
        contact_sheet([frame.left, frame.right, disp_png], ["left", "right", "gt disparity"]),
    )
    d = frame.disparity_left_px[np.isfinite(frame.disparity_left_px)]
    return {
        "size": f"{args.width}x{args.height}",
        "baseline_m": args.baseline,
        "max_disparity_px": round(float(d.max()), 2) if d.size else None,
        "valid_pixels": f"{100 * d.size / frame.disparity_left_px.size:.1f} %",
        "points": len(cloud),
    }


# ----- sequence ----------------------------------------------------------------
def _render_sequence(args, out: Path) -> dict:
    city = generate_city(args.seed, size_m=args.city_size, plain=args.plain)
    rig = default_rig(args.width, args.height, args.hfov, args.baseline)
    world_from_left = flight_poses(city, args.frames, args.seed)
    samples: list[np.ndarray] = []
    sample_at = set(np.linspace(0, args.frames - 1, min(4, args.frames)).round().astype(int).tolist())

    def frames():
        for i, pose in enumerate(progress(world_from_left, desc="render frames")):
            frame = render_stereo(city, rig, pose.inverse())
            write_pfm(out / "depth_2" / f"{i:06d}.pfm", frame.depth_left_m)
            if i in sample_at:
                samples.append(frame.left)
            yield frame.left, frame.right

    t0 = time.perf_counter()
    fmt = getattr(args, "format", "kitti")
    if fmt == "kitti":
        write_sequence(out, rig, frames(), world_from_left)
    else:
        times_ns = [i * 100_000_000 for i in range(args.frames)]
        bag = out / "flight.mcap" if fmt == "mcap" else out
        write_stereo_bag(
            bag, rig, frames(), times_ns, world_from_left, "mcap" if fmt == "mcap" else "sqlite3"
        )
    seconds = time.perf_counter() - t0
    track = np.array([p.t for p in world_from_left])
    plan = top_down_map(city.boxes, tuple(city.extent), [track], getattr(city, "cylinders", None))
    write_image(
        out / "preview.png",
        contact_sheet(
            [plan, *samples], ["flight (top view)", *[f"frame {i}" for i in sorted(sample_at)]], columns=3
        ),
    )
    length = float(np.linalg.norm(np.diff(track, axis=0), axis=1).sum()) if len(track) > 1 else 0.0
    topics = {}
    if fmt != "kitti":
        topics = {
            "bag": str(out / "flight.mcap" if fmt == "mcap" else out),
            "topics": {"left": TOPICS.left, "right": TOPICS.right, "pose": TOPICS.pose},
        }
    return {
        **topics,
        "frames": args.frames,
        "size": f"{args.width}x{args.height}",
        "flight_length_m": round(length, 1),
        "seconds_per_frame": round(seconds / args.frames, 3),
    }


# ----- ring and images ------------------------------------------------------------
def _write_views(out: Path, views, results, image_dir: str, model_dir: str, depth_dir: str | None) -> None:
    rec = Reconstruction(cameras={1: views[0].intrinsics})
    for k, (view, res) in enumerate(zip(views, results), start=1):
        write_image(out / image_dir / view.name, res.image)
        if depth_dir is not None:
            write_pfm(out / depth_dir / (Path(view.name).stem + ".pfm"), res.depth_m)
        rec.images[k] = Image(k, view.name, 1, view.cam_from_world)
    write_colmap_text(out / model_dir, rec)


def _object_scene_views(args, kind: str):
    scene = generate_object_scene(args.seed, plain=args.plain)
    cam = Intrinsics.from_fov(args.width, args.height, args.hfov)
    center = np.asarray(scene.center if hasattr(scene, "center") else [0.0, 0.0, 1.0], dtype=np.float64)
    radius = float(getattr(scene, "view_radius_m", 8.0))
    if kind == "ring":
        views = ring_views(center, radius, center[2] + radius * 0.5, args.views, cam)
    else:
        views = orbit_views(scene, args.views, cam, seed=args.seed)
    results = render_views(scene, progress(views, desc="render views"))
    return scene, cam, views, results


def _render_ring(args, out: Path) -> dict:
    _, cam, views, results = _object_scene_views(args, "ring")
    _write_views(out, views, results, "images", "sparse", "depth")
    write_K_txt(out / "K.txt", cam)
    write_image(
        out / "preview.png",
        contact_sheet(
            [r.image for r in results[:: max(1, len(results) // 6)]],
            [v.name for v in views[:: max(1, len(views) // 6)]],
            columns=3,
        ),
    )
    return {"views": len(views), "size": f"{args.width}x{args.height}", "cameras": str(out / "sparse")}


def _render_images(args, out: Path) -> dict:
    _, cam, views, results = _object_scene_views(args, "images")
    _write_views(out, views, results, "images", "gt_sparse", None)
    write_K_txt(out / "K.txt", cam)
    write_image(
        out / "preview.png",
        contact_sheet([r.image for r in results[:6]], [v.name for v in views[:6]], columns=3),
    )
    return {
        "views": len(views),
        "size": f"{args.width}x{args.height}",
        "ground_truth_cameras": str(out / "gt_sparse"),
    }


# ----- survey --------------------------------------------------------------------
def _render_survey(args, out: Path) -> dict:
    from skyrecon.sim.survey import DEFAULT_ORIGIN, SurveySettings, survey_views, write_survey

    if args.hfov == 90.0:  # the generic default: a survey camera's lens instead (8.8 mm on 13.2 mm)
        args.hfov = 73.7
    hfov = args.hfov
    settings = SurveySettings(
        width=args.width,
        height=args.height,
        hfov_deg=hfov,
        altitude_m=args.altitude,
        forward_overlap=args.overlap[0],
        side_overlap=args.overlap[1],
        photos=args.photos,
        tilt_deg=args.tilt,
        gps_sigma_m=args.gps_noise,
        wrong_tags=args.wrong_tags,
        origin=tuple(args.origin) if args.origin else DEFAULT_ORIGIN,
        seed=args.seed,
    )
    city = generate_city(args.seed, size_m=args.city_size, plain=args.plain)
    plan = survey_views(city, settings)
    return write_survey(out, city, plan)
