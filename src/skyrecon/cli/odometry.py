"""``skyrecon odometry``: the camera's trajectory from a stereo sequence (stereo visual odometry).

SEQUENCE is a KITTI odometry layout (``image_2/``, ``image_3/``, ``calib.txt``, optional
``poses.txt``/``times.txt``) or a EuRoC/ASL layout (``mav0/cam0``, ``mav0/cam1`` with ``data.csv``
and ``sensor.yaml``; rectified here) or a ROS bag / MCAP file (``--left-topic``, ``--right-topic``,
optional ``--pose-topic`` as ground truth; see ``skyrecon.io.rosbag_input``). Writes to ``--out``:

* ``poses.txt``: KITTI format, row-major 3x4 ``world_from_left_camera`` per frame (GPS-fused when
  ``--gps`` is given; the plain odometry then goes to ``poses_odometry.txt``). Without
  ``--init-pose`` the world is the first frame's left camera (OpenCV axes).
* ``trajectory.txt``: the same poses in TUM format (``timestamp tx ty tz qx qy qz qw``, for ``evo``).
* ``odometry.json``: settings, summary (frames, rate, lost/degraded counts with reasons, timing
  percentiles, loop closure: loops accepted and rejected with reasons, largest correction), metrics
  against ground truth, GPS statistics, one record per frame.
* ``report.html``: trajectory top view, speed, features, tracking-state timeline.

Loop closure is on (``--no-loop-closure`` turns it off): when the flight comes back to a place it
saw, the keyframes are corrected by a pose-graph optimisation and ``poses.txt`` holds the corrected
trajectory; a loop that fails a check is dropped and reported, never applied.

Ground truth: ``--gt`` (KITTI poses.txt by frame, TUM or EuRoC csv by time), else what the sequence
carries (KITTI ``poses.txt``, EuRoC ``state_groundtruth_estimate0``).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
from pathlib import Path
from typing import Any

import numpy as np

from skyrecon.cli.bag_options import add_bag_options, bag_topics
from skyrecon.cli.common import add_command, add_record_option, info, output_dir, positive_int, recording
from skyrecon.core.rigid import Rigid3
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError, SkyreconError
from skyrecon.eval.odometry_metrics import OdometryMetrics, evaluate_odometry
from skyrecon.io.atomic import write_text_atomic
from skyrecon.io.gps import GpsFix, read_gps_csv
from skyrecon.io.jsonio import write_json
from skyrecon.io.sequence import format_poses
from skyrecon.io.stereo_input import StereoInput, open_stereo_sequence
from skyrecon.io.trajectory import format_tum, read_trajectory
from skyrecon.odometry.gps import GpsFusion
from skyrecon.odometry.report import render_odometry_report
from skyrecon.odometry.run import OdometryEngine, OdometryRun, run_odometry, summarize_run
from skyrecon.progress import progress
from skyrecon.record.sequence import OdometryRecording

EXAMPLES = """  skyrecon render sequence --frames 100 --out flight/ && skyrecon odometry flight/ --out vo/
  skyrecon odometry MH_01_easy/ --out vo/ --max-frames 500       # EuRoC/ASL layout (mav0/)
  skyrecon odometry flight/ --out vo/ --gt other_poses.txt --gps gps.csv
  skyrecon odometry flight/ --out vo/ --init-pose gt              # start in the ground truth's world
  skyrecon odometry flight_bag/ --left-topic /stereo/left/image_raw --right-topic /stereo/right/image_raw \
      --pose-topic /stereo/left/pose --out vo/                     # ROS 2 bag, ROS 1 .bag or .mcap
  skyrecon odometry flight/ --out vo/ --record vo.rrd             # poses, images, tracks: 'rerun vo.rrd'
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = add_command(
        subparsers,
        "odometry",
        help="camera trajectory from a stereo sequence (visual odometry, optional GPS)",
        description=__doc__.split("\n\n")[0].split(": ", 1)[1],
        examples=EXAMPLES,
    )
    p.add_argument("sequence", help="sequence directory (KITTI or EuRoC/ASL layout), ROS bag or .mcap")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--gt", metavar="POSES", help="ground truth: KITTI poses.txt, TUM file or EuRoC data.csv")
    p.add_argument(
        "--gps", metavar="FILE", help="GPS fixes: CSV 'time_s, x, y, z[, accuracy_m]' in local metres"
    )
    p.add_argument(
        "--init-pose",
        nargs="+",
        metavar="POSE",
        help="world_from_left of the first frame: 'gt' (the ground truth's), 12 numbers (row-major 3x4) "
        "or a file whose first pose is used (KITTI or TUM)",
    )
    p.add_argument("--max-frames", type=positive_int, help="use only the first N frames")
    p.add_argument("--no-loop-closure", action="store_true", help="pure odometry: no loop closure")
    add_bag_options(p)
    add_record_option(p)
    return p


# ----- the engine -------------------------------------------------------------------------------
def make_engine(
    rig: StereoRig, init_world_from_left: Rigid3 | None, loop_closure: bool
) -> tuple[OdometryEngine, dict]:
    """The odometry engine for ``rig`` and the settings it runs with (as plain JSON values)."""
    try:
        engine_module = importlib.import_module("skyrecon.odometry.engine")
    except ImportError as exc:  # pragma: no cover - the engine ships with the package
        raise SkyreconError(f"the odometry engine is missing from this installation ({exc})") from None
    OdometrySettings, StereoOdometry = engine_module.OdometrySettings, engine_module.StereoOdometry
    settings = OdometrySettings()
    names = {f.name for f in dataclasses.fields(settings)} if dataclasses.is_dataclass(settings) else set()
    if not loop_closure:
        if "loop_closure" not in names:
            raise InputError("--no-loop-closure: this engine has no loop closure to turn off")
        settings = dataclasses.replace(settings, loop_closure=False)
    engine = StereoOdometry(rig, settings, init_world_from_left)
    as_dict = dataclasses.asdict(settings) if names else {}
    return engine, as_dict


# ----- inputs -----------------------------------------------------------------------------------
def _init_pose(args: argparse.Namespace, seq: StereoInput) -> Rigid3 | None:
    words = args.init_pose
    if not words:
        return None
    if words == ["gt"]:
        if not seq.world_from_left or seq.world_from_left[0] is None:
            raise InputError("--init-pose gt: there is no ground truth for the first frame (add --gt)")
        return seq.world_from_left[0].with_frames("world", "left")
    if len(words) == 1:
        traj = read_trajectory(words[0])
        return traj.poses[0].with_frames("world", "left")
    if len(words) != 12:
        raise InputError(
            f"--init-pose takes 'gt', a file or 12 numbers (row-major 3x4), got {len(words)} values"
        )
    try:
        M = np.array([float(w) for w in words]).reshape(3, 4)
    except ValueError:
        raise InputError(f"--init-pose: not numbers: {' '.join(words)}") from None
    return Rigid3.from_matrix(M, "world", "left")


def _metrics(run: OdometryRun, gt: list[Rigid3 | None] | None) -> OdometryMetrics | None:
    if gt is None:
        return None
    keep = [k for k, p in enumerate(gt[: len(run.odometry)]) if p is not None]
    if len(keep) < 2:
        return None
    est = [run.odometry[k] for k in keep]
    ref = [gt[k] for k in keep]
    m = evaluate_odometry(est, ref, run.timestamps_s[keep])  # type: ignore[arg-type]
    if run.fused is not None:
        err = np.array([np.linalg.norm(run.fused[k].t - gt[k].t) for k in keep])  # type: ignore[union-attr]
        m.extra["fused"] = {
            "rmse_m": float(np.sqrt(np.mean(err**2))),
            "max_m": float(err.max()),
            "note": "GPS-fused poses against the ground truth without alignment (the GPS world is taken "
            "to be the ground truth's)",
        }
    return m


def run(args: argparse.Namespace) -> int:
    seq = open_stereo_sequence(args.sequence, bag_topics(args))
    out = Path(args.out)
    if out.resolve() == seq.root.resolve():
        raise InputError(
            "--out is the sequence directory; its poses.txt would be overwritten: choose another", out
        )
    if args.gt:
        seq.use_groundtruth(args.gt)
    fixes: list[GpsFix] | None = read_gps_csv(args.gps) if args.gps else None
    init = _init_pose(args, seq)
    n = min(len(seq), args.max_frames or len(seq))
    if n < 2:
        raise InputError(f"odometry needs at least 2 frames, the sequence has {n}", seq.root)
    engine, settings = make_engine(seq.rig, init, not args.no_loop_closure)
    fusion = None
    if fixes is not None:
        fusion = GpsFusion(rotation_known=init is not None)
        if fixes[-1].time_s < seq.timestamps_s[0] or fixes[0].time_s > seq.timestamps_s[n - 1]:
            raise InputError(
                f"the GPS times ({fixes[0].time_s:.3f}..{fixes[-1].time_s:.3f} s) do not overlap the frames' "
                f"({seq.timestamps_s[0]:.3f}..{seq.timestamps_s[n - 1]:.3f} s)",
                args.gps,
            )
    frames = progress((seq.frame(i) for i in range(n)), total=n, desc="odometry", unit="frame")
    gt = seq.world_from_left[:n] if seq.world_from_left is not None else None
    with recording(args) as recorder:
        observer = OdometryRecording(recorder, seq.rig.left) if recorder.enabled else None
        result = run_odometry(engine, frames, seq.timestamps_s[:n], fixes, fusion, on_frame=observer)
        if observer is not None:
            observer.finish(result.odometry, result.timestamps_s, result.fused, gt)
    summary = summarize_run(result)
    metrics = _metrics(result, gt)
    _write_outputs(out, result, summary, metrics, settings, seq, args, gt, fixes, init)
    if not args.quiet:
        line = (
            f"odometry: {summary['frames']} frames, {summary['distance_m']:.1f} m, {summary['fps']} fps, "
            f"{summary['lost']} lost, {summary['degraded']} degraded"
        )
        if metrics is not None:
            d = metrics.drift_pct
            line += f"; ATE {metrics.ate_rmse_m:.3f} m, drift " + (
                f"{d:.2f} %" if d is not None else "n/a (< 25 m)"
            )
        lc = summary.get("loop_closure")
        if lc and lc.get("enabled"):
            line += (
                f"; loops {lc['accepted']} accepted, {lc['rejected']} rejected"
                f" (largest correction {lc['max_correction_m']:.2f} m)"
            )
        if "gps" in summary:
            g = summary["gps"]
            line += f"; GPS {g['accepted']}/{g['fixes']} fixes used"
        info(line)
        info(f"wrote {out}/poses.txt, trajectory.txt, odometry.json, report.html")
    return 0


def _write_outputs(
    out: Path,
    result: OdometryRun,
    summary: dict[str, Any],
    metrics: OdometryMetrics | None,
    settings: dict,
    seq: StereoInput,
    args: argparse.Namespace,
    gt: list[Rigid3 | None] | None,
    fixes: list[GpsFix] | None,
    init: Rigid3 | None,
) -> None:
    out = output_dir(out)
    poses = result.poses
    write_text_atomic(out / "poses.txt", format_poses(poses))
    if result.fused is not None:
        write_text_atomic(out / "poses_odometry.txt", format_poses(result.odometry))
    write_text_atomic(out / "trajectory.txt", format_tum(result.timestamps_s, poses))
    doc: dict[str, Any] = {
        "source": str(seq.root),
        "layout": seq.layout,
        "rig": {
            "fx": seq.rig.left.fx,
            "fy": seq.rig.left.fy,
            "cx": seq.rig.left.cx,
            "cy": seq.rig.left.cy,
            "width": seq.rig.left.width,
            "height": seq.rig.left.height,
            "baseline_m": seq.rig.baseline_m,
        },
        "times_assumed_10hz": seq.times_assumed,
        "settings": settings,
        "options": {
            "max_frames": args.max_frames,
            "loop_closure": bool(settings.get("loop_closure", not args.no_loop_closure)),
            "init_world_from_left": init.matrix3x4.tolist() if init is not None else None,
            "gps": args.gps,
        },
        "ground_truth": seq.gt_source or None,
        "summary": summary,
        "metrics": metrics.as_json() if metrics is not None else None,
        "frames": [e.as_json() for e in result.estimates],
    }
    write_json(out / "odometry.json", doc)
    gps_pos = np.array([f.position for f in fixes]) if fixes else None
    page = render_odometry_report(result, summary, str(seq.root), gt, metrics, gps_pos)
    write_text_atomic(out / "report.html", page)
