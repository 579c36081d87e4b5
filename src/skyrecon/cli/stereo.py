"""``skyrecon stereo``: dense disparity, depth and a coloured point cloud from a stereo pair or sequence.

For a pair it writes ``disparity.pfm`` and ``disparity.png``; with ``--calib`` also ``depth.pfm``,
``depth.png`` and ``points.ply`` (left camera frame, metres), and ``stereo.json`` with timings,
density and (with ``--gt``) the error against ground truth. An unrectified calibration (OpenCV
YAML with distortion and R, T) is rectified first; outputs are then in the rectified left frame.

For a KITTI-layout sequence directory (``image_2/``, ``image_3/``, ``calib.txt``) it processes
every frame with one reusable matcher and writes ``disparity/NNNNNN.pfm``, ``depth/NNNNNN.pfm``,
a few pictures and ``stereo.json`` with frames per second. A ROS bag or ``.mcap`` file (with
``--left-topic``/``--right-topic``) is read the same way, its synchronized pairs as frames ``NNNNNN``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skyrecon.cli.bag_options import add_bag_options, bag_topics
from skyrecon.cli.common import (
    add_cloud_format,
    add_command,
    add_executor_options,
    info,
    open_executor,
    output_dir,
    positive_float,
    positive_int,
)
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError
from skyrecon.eval.stereo_metrics import evaluate_disparity
from skyrecon.io.calib import read_stereo_calib
from skyrecon.io.disparity import colorize_depth, colorize_disparity, read_disparity
from skyrecon.io.images import read_image_with_alpha, write_image
from skyrecon.io.jsonio import write_json
from skyrecon.io.las import write_point_cloud
from skyrecon.io.pfm import read_pfm, write_pfm
from skyrecon.io.rosbag_input import is_bag
from skyrecon.io.sequence import StereoSequence, is_sequence_dir
from skyrecon.io.stereo_input import StereoInput, open_stereo_sequence
from skyrecon.progress import progress
from skyrecon.report.figures import contact_sheet
from skyrecon.stereo import create_matcher, disparity_to_depth, disparity_to_points, rectify_rig

EXAMPLES = """  skyrecon stereo left.png right.png --out out/                     # disparity only
  skyrecon stereo im0.png im1.png --calib calib.txt --out out/      # + depth.pfm, points.ply
  skyrecon stereo left.png right.png --calib calib.txt --gt disp0.pfm --out out/
  skyrecon stereo flight/ --out flight_depth/ --method skyrecon-fast   # a KITTI-layout sequence
  skyrecon stereo flight.mcap --left-topic /stereo/left/image_raw --right-topic /stereo/right/image_raw \
      --frames 1 --out first_pair/                                     # a ROS bag or MCAP file
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = add_command(
        subparsers,
        "stereo",
        help="disparity, depth and point clouds from a stereo pair or sequence",
        description=__doc__.split("\n\n")[0].split(": ", 1)[1],
        examples=EXAMPLES,
    )
    p.add_argument(
        "inputs", nargs="+", metavar="LEFT RIGHT | SEQUENCE_DIR", help="a rectified pair or a sequence dir"
    )
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    p.add_argument(
        "--calib", help="Middlebury calib.txt, KITTI calib (P2:/P3:) or OpenCV YAML (K1 D1 K2 D2 R T)"
    )
    p.add_argument(
        "--method",
        default="skyrecon",
        help="matcher: skyrecon (default), skyrecon-fast, opencv-sgbm, opencv-bm",
    )
    p.add_argument(
        "--census-tolerance",
        default="0",
        metavar="auto|LEVELS",
        help="skyrecon matchers: a census bit counts only a neighbour darker by more than this many "
        "grey levels (default 0, the classic census); 'auto': three times the camera noise measured "
        "on each image, so that noise does not scramble plain surfaces (what 'skyrecon map' uses; "
        "it needs flat areas such as sky, walls or road to measure the noise)",
    )
    p.add_argument(
        "--max-disparity",
        type=positive_int,
        help="largest disparity searched, pixels (default: calib ndisp or 128)",
    )
    p.add_argument(
        "--min-disparity", type=int, default=0, help="smallest disparity searched, pixels (default 0)"
    )
    p.add_argument("--min-depth", type=float, default=0.0, help="points closer than this are dropped, metres")
    p.add_argument(
        "--max-depth", type=positive_float, default=float("inf"), help="points farther are dropped, metres"
    )
    p.add_argument(
        "--gt", help="ground-truth disparity (PFM, KITTI 16-bit PNG or Middlebury PGM) to score against"
    )
    p.add_argument("--frames", type=positive_int, help="sequence: process only the first N frames")
    add_cloud_format(p)
    add_bag_options(p)
    add_executor_options(
        p,
        "sequence: frames matched side by side by this many workers (default: one frame after another in "
        "this process, which measures the real-time rate; any of --executor/--workers/--scheduler fans out)",
    )
    return p


def run(args: argparse.Namespace) -> int:
    if len(args.inputs) == 1:
        path = Path(args.inputs[0])
        if not path.exists():
            raise InputError("not found; give LEFT RIGHT images or a sequence directory", path)
        if not (is_sequence_dir(path) or is_bag(path)):
            raise InputError(
                "is not a stereo sequence directory (image_2/, image_3/, calib.txt) nor a ROS bag; "
                "for a single pair give both LEFT and RIGHT images",
                path,
            )
        return _run_sequence(args, path)
    if len(args.inputs) != 2:
        raise InputError(f"expected LEFT RIGHT or one SEQUENCE_DIR, got {len(args.inputs)} paths")
    return _run_pair(args, Path(args.inputs[0]), Path(args.inputs[1]))


def _max_disparity(args: argparse.Namespace, calib_bound: int | None, width: int) -> int:
    value = args.max_disparity or calib_bound or min(128, width - 1)
    return int(value)


def _read_pair(left_path: Path, right_path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The two images as read (any depth, grey or colour); InputError when their sizes differ."""
    left, _ = read_image_with_alpha(left_path, "unchanged")
    right, _ = read_image_with_alpha(right_path, "unchanged")
    if left.shape[:2] != right.shape[:2]:
        raise InputError(
            f"the images differ in size: {left_path} is {left.shape[1]}x{left.shape[0]}, "
            f"{right_path} is {right.shape[1]}x{right.shape[0]}; stereo needs a pair of the same size"
        )
    return left, right


def _calibrate(
    calib_path: str, left: np.ndarray, right: np.ndarray
) -> tuple[StereoRig, int | None, np.ndarray, np.ndarray, bool]:
    """Read ``--calib`` and rectify the pair when the rig is not rectified.

    Returns:
        ``(rig, max_disparity, left, right, rectified_here)``: the rectified rig (metres),
        the file's disparity bound (pixels, or None), the (rectified) images and whether
        they were rectified here (then depth and points are in the rectified left frame).
    """
    height, width = left.shape[:2]
    calib = read_stereo_calib(calib_path, width, height)
    if calib.rig.is_rectified:
        return calib.rig, calib.max_disparity, left, right, False
    rect = rectify_rig(calib.rig)
    left_rect, right_rect = rect.apply(left, right)
    return rect.rig, calib.max_disparity, left_rect, right_rect, True


def _run_pair(args: argparse.Namespace, left_path: Path, right_path: Path) -> int:
    left, right = _read_pair(left_path, right_path)
    height, width = left.shape[:2]
    rig: StereoRig | None = None
    bound: int | None = None
    rectified_here = False
    if args.calib:
        rig, bound, left, right, rectified_here = _calibrate(args.calib, left, right)
    out = output_dir(args.out)
    max_disp = _max_disparity(args, bound, width)
    matcher = _matcher(args.method, max_disp, args.min_disparity, args.census_tolerance)
    t0 = time.perf_counter()
    if hasattr(matcher, "warmup"):
        matcher.warmup()  # compile or load the kernels now, so the timing below is the matching itself
    setup_ms = 1000 * (time.perf_counter() - t0)
    result = matcher.compute(left, right)
    disparity = result.disparity

    write_pfm(out / "disparity.pfm", disparity)
    write_image(out / "disparity.png", colorize_disparity(disparity))
    summary: dict[str, Any] = {
        "left": str(left_path),
        "right": str(right_path),
        "method": args.method,
        "census_tolerance": result.diagnostics.get("census_tolerance"),
        "size": [width, height],
        "disparity_range": [args.min_disparity, max_disp],
        "density": round(float(np.isfinite(disparity).mean()), 4),
        "milliseconds": round(result.timings_ms.get("total", float("nan")), 1),
        "timings_ms": {k: round(v, 2) for k, v in result.timings_ms.items()},
        "setup_ms": round(setup_ms, 1),
        "rectified_here": rectified_here,
    }
    if rig is not None:
        summary.update(_write_depth(out, disparity, rig, left, args.min_depth, args.max_depth, args.format))
    if args.gt:
        summary["metrics"] = _score(disparity, args.gt)
    write_json(out / "stereo.json", summary)
    if not args.quiet:
        _report_pair(summary, out, with_depth=rig is not None)
    return 0


def _write_depth(
    out: Path,
    disparity: np.ndarray,
    rig: StereoRig,
    left: np.ndarray,
    min_depth: float,
    max_depth: float,
    fmt: str = "ply",
) -> dict[str, Any]:
    """Write ``depth.pfm``, ``depth.png`` and ``points.ply`` (left camera frame of ``rig``, metres).

    Args:
        disparity: (H, W) float32 pixels, NaN invalid, of the rectified pair.
        rig: the rectified rig; ``left``: its (H, W[, 3]) left image, colouring the points.
        min_depth, max_depth: points outside this depth range are dropped, metres.
    Returns:
        The summary entries: ``points``, ``baseline_m``, ``focal_px``.
    """
    depth = disparity_to_depth(disparity, rig)
    write_pfm(out / "depth.pfm", depth)
    write_image(out / "depth.png", colorize_depth(depth))
    colour = left if left.ndim == 3 else None
    if colour is not None and colour.dtype != np.uint8:
        colour = (colour // 257).astype(np.uint8)
    cloud = disparity_to_points(disparity, rig, colour, min_depth, max_depth)
    write_point_cloud(out / "points.ply", cloud, fmt)
    return {"points": len(cloud), "baseline_m": rig.baseline_m, "focal_px": rig.left.fx}


def _score(disparity: np.ndarray, gt_path: str) -> dict[str, float]:
    """Bad-pixel rates, D1, EPE and density of ``disparity`` (H, W) against a ground-truth file."""
    gt = read_disparity(gt_path)
    if gt.shape != disparity.shape:
        raise InputError(
            f"the ground truth is {gt.shape[1]}x{gt.shape[0]} but the images are "
            f"{disparity.shape[1]}x{disparity.shape[0]}",
            gt_path,
        )
    return {k: round(float(v), 5) for k, v in evaluate_disparity(disparity, gt).items()}


def _report_pair(summary: dict[str, Any], out: Path, with_depth: bool) -> None:
    """Two lines on stderr: size, range, density, time (and scores); the files written."""
    (width, height), (lo, hi) = summary["size"], summary["disparity_range"]
    line = f"{summary['method']}: {width}x{height}, disparities {lo}..{hi}, "
    line += f"density {100 * summary['density']:.1f} %, {summary['milliseconds']:.0f} ms"
    if "metrics" in summary:
        m = summary["metrics"]
        line += f"; bad-1px {100 * m['bad1']:.1f} %, bad-2px {100 * m['bad2']:.1f} %, D1 {100 * m['d1']:.1f} %, EPE {m['epe']:.2f} px"
    info(line)
    info(f"wrote {out}/disparity.pfm, disparity.png" + (", depth.pfm, points.ply" if with_depth else ""))


def _run_sequence(args: argparse.Namespace, root: Path) -> int:
    if args.calib:
        raise InputError(
            "a sequence carries its own rectified calib.txt (KITTI P2:/P3:); drop --calib, "
            "or rectify the frames first and write their calib.txt",
            args.calib,
        )
    seq = open_stereo_sequence(root, bag_topics(args))
    n = min(len(seq), args.frames or len(seq))
    if n == 0:
        raise InputError("the sequence has no frames", root)
    out = output_dir(args.out)
    rig = seq.rig
    max_disparity = _max_disparity(args, None, rig.left.width)
    sample_at = set(np.linspace(0, n - 1, min(3, n)).round().astype(int).tolist())
    stems = [_stem(seq, i) for i in range(n)]
    fan_out = any(getattr(args, k, None) for k in ("executor", "workers", "scheduler"))
    if fan_out:
        chunk = max(1, min(16, -(-n // 8)))
        jobs = [
            _FramesJob(
                str(root),
                bag_topics(args),
                args.method,
                max_disparity,
                args.min_disparity,
                a,
                min(n, a + chunk),
                str(out),
                str(args.census_tolerance),
            )
            for a in range(0, n, chunk)
        ]
        with open_executor(args) as executor:
            compute_s = [t for part in executor.map(_match_frames, jobs, desc="stereo frames") for t in part]
    else:
        matcher = _matcher(args.method, max_disparity, args.min_disparity, args.census_tolerance)
        compute_s = [
            _match_frame(seq, matcher, i, out, stems[i]) for i in progress(range(n), desc="stereo frames")
        ]
    samples: list[np.ndarray] = []
    labels: list[str] = []
    for i in sorted(sample_at):
        samples += [seq.frame(i)[0], colorize_disparity(read_pfm(out / "disparity" / f"{stems[i]}.pfm"))]
        labels += [f"frame {stems[i]}", f"disparity {stems[i]}"]
    write_image(out / "preview.png", contact_sheet(samples, labels, columns=2))
    # the first frame includes one-time set-up (compilation, buffers): report steady state too
    # (fanned out, each worker's first frame does; the rate is then per worker, not per run)
    steady = compute_s[1:] if len(compute_s) > 1 else compute_s
    summary = {
        "sequence": str(root),
        "method": args.method,
        "frames": n,
        "size": [rig.left.width, rig.left.height],
        "fps": round(1.0 / float(np.median(steady)), 2),
        "median_ms_per_frame": round(1000 * float(np.median(steady)), 1),
        "first_frame_ms": round(1000 * compute_s[0], 1),
        "fanned_out": bool(fan_out),
    }
    write_json(out / "stereo.json", summary)
    if not args.quiet:
        info(
            f"{args.method}: {n} frames of {rig.left.width}x{rig.left.height}, "
            f"{summary['fps']:.1f} frames/s (median {summary['median_ms_per_frame']:.0f} ms, depth included)"
        )
        info(f"wrote {out}/disparity/, depth/, preview.png, stereo.json")
    return 0


@dataclass(frozen=True)
class _FramesJob:
    """Frames ``[first, stop)`` of a sequence to match (a picklable work item)."""

    root: str
    topics: Any
    method: str
    max_disparity: int
    min_disparity: int
    first: int
    stop: int
    out: str
    census_tolerance: str = "0"


def _matcher(method: str, max_disparity: int, min_disparity: int, census_tolerance: str):
    """The matcher ``method`` with its census tolerance (``--census-tolerance``: 'auto' or
    grey levels; skyrecon matchers only)."""
    text = str(census_tolerance).strip().lower()
    if text in ("", "0"):
        return create_matcher(method, max_disparity, min_disparity=min_disparity)
    if not method.startswith("skyrecon"):
        raise InputError(f"--census-tolerance is a setting of the skyrecon matchers, not of {method}")
    if text == "auto":
        tol: float | None = None
    else:
        try:
            tol = float(text)
        except ValueError:
            raise InputError(
                f"--census-tolerance must be 'auto' or grey levels, got {census_tolerance!r}"
            ) from None
    return create_matcher(method, max_disparity, min_disparity=min_disparity, census_tolerance=tol)


def _match_frames(job: _FramesJob) -> list[float]:
    """Match a chunk of frames (on a worker): opens the sequence, writes each frame's disparity and
    depth PFM into ``job.out``; returns the seconds each frame took."""
    seq = open_stereo_sequence(Path(job.root), job.topics)
    matcher = _matcher(job.method, job.max_disparity, job.min_disparity, job.census_tolerance)
    out = Path(job.out)
    times = []
    for i in range(job.first, job.stop):
        times.append(_match_frame(seq, matcher, i, out, _stem(seq, i)))
    return times


def _stem(seq: StereoInput, i: int) -> str:
    """The name frame ``i``'s outputs take: its left image's stem, else its index."""
    return seq.sequence.left_paths[i].stem if isinstance(seq.sequence, StereoSequence) else f"{i:06d}"


def _match_frame(seq: StereoInput, matcher: Any, i: int, out: Path, stem: str) -> float:
    """Frame ``i``: disparity and depth PFMs under ``out``; returns the seconds matching and depth took."""
    left, right = seq.frame(i)
    t0 = time.perf_counter()
    result = matcher.compute(left, right)
    depth = disparity_to_depth(result.disparity, seq.rig)
    seconds = time.perf_counter() - t0
    write_pfm(out / "disparity" / f"{stem}.pfm", result.disparity)
    write_pfm(out / "depth" / f"{stem}.pfm", depth)
    return seconds
