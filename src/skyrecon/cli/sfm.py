"""``skyrecon sfm``: camera poses and a sparse coloured 3D model from a folder of photos or flight frames.

Reads every image of IMAGES_DIR (png, jpg, jpeg, tif, tiff, ppm, pgm, bmp; sorted by name, numbers
in names compared as numbers) and one camera matrix ``K.txt`` for the input image size, and writes:

* ``sparse/cameras.txt``, ``sparse/images.txt``, ``sparse/points3D.txt``: COLMAP text model
  (intrinsics at the INPUT image size whatever ``--max-image-size`` is; poses as COLMAP stores
  them: ``cam_from_world`` quaternion + translation; COLMAP's pixel convention);
* ``sparse.ply``: the coloured points (binary PLY, the model's own frame; ``--format las|laz`` for
  ``sparse.las``/``sparse.laz``), with ``--frusta`` also
  the camera frusta (red; the first image green);
* ``transforms.json``: nerfstudio cameras (image paths relative to ``--out``);
* ``report.html``: reprojection-error histogram, track lengths, top view of cameras and points;
* ``sfm.json``: registered / total, left-out images with the reason, mean reprojection error,
  points, pairing, warnings, timings (``summary.json`` holds the same plus per-stage diagnostics).

Images that cannot be used (too little texture, no overlap, duplicates, another size than the
others, unreadable) are left out: the model of the others is written, a ``warning:`` line names
the left-out images, and ``sfm.json`` says why. Exit status 2 only when no model can be made.
The model is in its own gauge (arbitrary scale and orientation): ``skyrecon align`` puts it in a
metric, georeferenced frame.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import time
from collections import Counter
from collections.abc import Collection
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from skyrecon.cli.common import (
    add_cloud_format,
    add_command,
    add_executor_options,
    add_record_option,
    describe_executor,
    info,
    open_executor,
    output_dir,
    positive_int,
    recording,
)
from skyrecon.core.intrinsics import Intrinsics
from skyrecon.errors import InputError, SkyreconError
from skyrecon.io.atomic import write_text_atomic
from skyrecon.io.calib import read_K_txt
from skyrecon.io.multiview import image_size_from_header
from skyrecon.record.reconstruction import log_sfm
from skyrecon.sfm import SfMResult, SfMSettings, run_sfm, write_sfm_outputs
from skyrecon.sfm._pool import run_scoped_executor
from skyrecon.sfm.pairs import resolve_pair_mode

EXAMPLES = """  skyrecon sfm photos/images --camera photos/K.txt --out model/
  skyrecon sfm fountain/images --camera fountain/images/K.txt --max-image-size 1024 --frusta --out fountain_sfm/
  skyrecon sfm flight/frames --camera K.txt --pairing sequential --window 8 --workers 8 --out flight_sfm/
  skyrecon sfm photos/images --camera photos/K.txt --executor dask --scheduler tcp://head:8786 --out /shared/model/
  skyrecon render images --views 10 --out photos/ && skyrecon sfm photos/images --camera photos/K.txt --out model/
  skyrecon sfm photos/images --camera photos/K.txt --out model/ --record model.mcap   # for Foxglove
"""

#: File name endings read as images (case-insensitive).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".ppm", ".pgm", ".bmp")


def _image_size_arg(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a number of pixels (0: the input size), got {text!r}"
        ) from None
    if value < 0 or 0 < value < 64:
        raise argparse.ArgumentTypeError(f"expected 0 (the input size) or at least 64 pixels, got {value}")
    return value


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = add_command(
        subparsers,
        "sfm",
        help="camera poses and a sparse 3D model from many photos (structure from motion)",
        description=__doc__.split("\n\n")[0].split(": ", 1)[1],
        examples=EXAMPLES,
    )
    p.add_argument("images_dir", metavar="IMAGES_DIR", help="folder of the images (not searched recursively)")
    p.add_argument(
        "--camera",
        required=True,
        metavar="K.txt",
        help="3x3 camera matrix for the input image size (3 lines of 3 numbers, pixels)",
    )
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    p.add_argument(
        "--max-image-size",
        type=_image_size_arg,
        default=1600,
        metavar="PX",
        help="longer side of the images used for features, pixels; outputs stay at the input size "
        "(default 1600; 0: the input size)",
    )
    p.add_argument(
        "--pairing",
        choices=["auto", "exhaustive", "sequential", "retrieval"],
        default="auto",
        help="which image pairs to match: exhaustive (every pair), sequential (flight frames in name "
        "order: a window of following frames, frames further ahead and loop candidates by image "
        "retrieval), retrieval (each image with its most similar ones); auto (default): exhaustive "
        "up to 50 images, else sequential when the names are numbered frames, else retrieval",
    )
    p.add_argument(
        "--window",
        type=positive_int,
        default=None,
        help="sequential pairing: match each frame with the next N frames (default 6)",
    )
    p.add_argument(
        "--seed", type=int, default=0, help="seed of every random choice (same seed, same model; default 0)"
    )
    add_executor_options(p, "workers for features and matching (default: all cores, or $SKYRECON_WORKERS)")
    p.add_argument("--frusta", action="store_true", help="add the camera frusta to sparse.ply")
    add_cloud_format(p)
    p.add_argument(
        "--workspace", help="feature cache directory, reused by later runs (default OUT/workspace)"
    )
    add_record_option(p)
    return p


# ----------------------------------------------------------------------------------------------
# inputs
# ----------------------------------------------------------------------------------------------
def _natural_key(name: str) -> list:
    return [
        (0, int(part), part) if part.isdigit() else (1, 0, part.lower()) for part in re.split(r"(\d+)", name)
    ]


def list_images(images_dir: str | Path) -> list[Path]:
    """The image files of a directory (not recursive, hidden files skipped), sorted by name with
    numbers compared as numbers (``frame2`` before ``frame10``)."""
    d = Path(images_dir)
    if not d.exists():
        raise InputError("images directory not found; check the path", d)
    if not d.is_dir():
        raise InputError("is not a directory; give the folder that holds the images", d)
    paths = [
        p
        for p in d.iterdir()
        if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in IMAGE_EXTENSIONS
    ]
    paths.sort(key=lambda p: _natural_key(p.name))
    if len(paths) < 2:
        found = "no image" if not paths else f"only one image ({paths[0].name})"
        raise InputError(
            f"structure from motion needs at least two images, found {found} "
            f"(accepted: {', '.join(e[1:] for e in IMAGE_EXTENSIONS)})",
            d,
        )
    return paths


def _camera_for(k_path: str, paths: list[Path]) -> tuple[Intrinsics, tuple[int, int]]:
    """The intrinsics of K.txt at the size most images have (images of other sizes are left out
    by the pipeline, each with the reason); returns (intrinsics, (width, height))."""
    sizes = [image_size_from_header(p) for p in paths]
    counts = Counter(s for s in sizes if s is not None)
    if not counts:
        raise InputError(
            f"none of the {len(paths)} images can be read ({', '.join(p.name for p in paths[:5])}"
            + (" ..." if len(paths) > 5 else "")
            + ")"
        )
    top = max(counts.values())
    size = next(s for s in sizes if s is not None and counts[s] == top)  # ties: the first image's size
    cam = read_K_txt(k_path, size[0], size[1])
    example = next(p for p, s in zip(paths, sizes) if s == size)
    if not (-0.5 <= cam.cx <= cam.width - 0.5 and -0.5 <= cam.cy <= cam.height - 0.5):
        raise InputError(
            f"the principal point ({cam.cx:.1f}, {cam.cy:.1f}) lies outside the {cam.width}x{cam.height} images "
            f"(e.g. {example.name}); is this K for another image size? (scale fx, fy, cx, cy by the resize factor)",
            k_path,
        )
    return cam, size


def _camera_warnings(cam: Intrinsics, k_path: str) -> list[str]:
    off = max(abs(cam.cx - (cam.width - 1) / 2) / cam.width, abs(cam.cy - (cam.height - 1) / 2) / cam.height)
    if off > 0.2:
        return [
            f"the principal point ({cam.cx:.0f}, {cam.cy:.0f}) of {Path(k_path).name} is far from the centre of the "
            f"{cam.width}x{cam.height} images; is this K for another image size?"
        ]
    return []


# ----------------------------------------------------------------------------------------------
# the command
# ----------------------------------------------------------------------------------------------
def _settings(args: argparse.Namespace, names: list[str]) -> SfMSettings:
    """The pipeline settings of the arguments, with ``--pairing auto`` resolved for these images."""
    settings = SfMSettings(max_image_size=args.max_image_size or None)
    pair_kw: dict[str, Any] = {"mode": resolve_pair_mode(args.pairing, names, settings.pairing)}
    if args.window is not None:
        pair_kw["window"] = args.window
    return replace(settings, pairing=replace(settings.pairing, **pair_kw))


def _image_prefix(images_dir: str, out: Path) -> str:
    """The images directory relative to ``out`` (absolute on another drive), ending in ``/``."""
    try:
        return (
            os.path.relpath(Path(images_dir).resolve(), out.resolve()).replace(os.sep, "/").rstrip("/") + "/"
        )
    except ValueError:  # another drive
        return Path(images_dir).resolve().as_posix().rstrip("/") + "/"


def _run_record(
    args: argparse.Namespace,
    cam: Intrinsics,
    size: tuple[int, int],
    settings: SfMSettings,
    workers: int,
    workspace: Path,
) -> dict[str, Any]:
    """The head of ``sfm.json``: the command, its inputs and the settings it ran with."""
    return {
        "command": "skyrecon sfm",
        "images_dir": str(Path(args.images_dir)),
        "camera": str(Path(args.camera)),
        "K": cam.K.tolist(),
        "image_size": list(size),
        "settings": {
            "max_image_size": args.max_image_size or None,
            "pairing_requested": args.pairing,
            "pairing": settings.pairing.mode,
            "window": settings.pairing.window,
            "seed": args.seed,
            "workers": workers,
            "workspace": str(workspace),
        },
    }


def _run_pipeline(
    args: argparse.Namespace,
    paths: list[Path],
    cam: Intrinsics,
    size: tuple[int, int],
    settings: SfMSettings,
    base: Any,
    workspace: Path,
    t_start: float,
) -> tuple[SfMResult, int, dict[str, Any], list[str]]:
    """Run the pipeline on ``base`` (a local process executor kept alive across the stages); on
    failure write ``sfm.json`` with the error. Returns (result, workers, run record, warnings)."""
    out = Path(args.out)
    n = len(paths)
    pairing = settings.pairing.mode
    executor, release = run_scoped_executor(base)
    workers = int(getattr(executor, "workers", 1) or 1)
    pre_warnings = _camera_warnings(cam, args.camera)
    cli = _run_record(args, cam, size, settings, workers, workspace)
    if not args.quiet:
        info(
            f"{n} images ({size[0]}x{size[1]}) in {args.images_dir}; features at "
            f"{args.max_image_size or 'input'} px, {pairing} pairing, {describe_executor(executor)}"
        )
    try:
        result = run_sfm(paths, cam, settings, executor=executor, seed=args.seed, workspace=workspace)
    except SkyreconError as exc:
        failed = {
            **cli,
            "status": "failed",
            "error": " ".join(str(exc).split()),
            "num_images": n,
            "num_registered": 0,
            "warnings": pre_warnings,
            "timings_s": {"total_wall": time.perf_counter() - t_start},
        }
        write_text_atomic(out / "sfm.json", json.dumps(failed, indent=2) + "\n")
        raise
    finally:
        release()
    return result, workers, cli, pre_warnings


def run(args: argparse.Namespace) -> int:
    t_start = time.perf_counter()
    paths = list_images(args.images_dir)
    cam, size = _camera_for(args.camera, paths)
    out = output_dir(args.out)
    workspace = Path(args.workspace) if args.workspace else out / "workspace"
    settings = _settings(args, [p.name for p in paths])
    with open_executor(args) as base:
        result, _, cli, pre_warnings = _run_pipeline(
            args, paths, cam, size, settings, base, workspace, t_start
        )

    t0 = time.perf_counter()
    files = write_sfm_outputs(
        out,
        result,
        frusta=args.frusta,
        image_prefix=_image_prefix(args.images_dir, out),
        title=f"Structure from motion: {Path(args.images_dir).name}",
        cloud_format=args.format,
    )
    write_s = time.perf_counter() - t0
    warnings = pre_warnings + [w for w in result.warnings if w not in pre_warnings]
    summary = {
        **cli,
        "status": "complete" if not result.unregistered else "partial",
        **result.to_json_dict(),
        "note": result.note,
        "warnings": warnings,
    }
    summary["timings_s"] = {
        **summary.get("timings_s", {}),
        "write": write_s,
        "total_wall": time.perf_counter() - t_start,
    }
    summary["files"] = sorted([*files, "sfm.json"])
    write_text_atomic(out / "sfm.json", json.dumps(summary, indent=2, allow_nan=False) + "\n")
    with recording(args) as recorder:
        if recorder.enabled:
            log_sfm(recorder, result.reconstruction, paths)
    _say(args, result, warnings, files, out, time.perf_counter() - t_start)
    return 0


def _say(
    args: argparse.Namespace,
    result: SfMResult,
    warnings: list[str],
    files: Collection[str],
    out: Path,
    seconds: float,
) -> None:
    """Left-out images always (a partial model is a success with a caveat); the rest unless quiet."""
    left, n = result.unregistered, len(result.images)
    if left:
        listed = "; ".join(f"{name}: {why}" for name, why in list(left.items())[:8])
        more = f"; and {len(left) - 8} more" if len(left) > 8 else ""
        info(
            f"warning: {len(left)} of {n} images left out of the model: {listed}{more}; details in {out / 'sfm.json'}"
        )
    if args.quiet:
        return
    for w in warnings:
        if "were left out of the model" not in w:
            info(f"warning: {w}")
    err = result.mean_reprojection_error_px()
    tl = [len(p.track) for p in result.reconstruction.points3d.values()]
    info(
        f"registered {result.num_registered} of {n} images, {len(result.reconstruction.points3d)} points, mean "
        f"reprojection error {err:.2f} px, mean track length {np.mean(tl) if tl else 0:.1f}, in {seconds:.1f} s"
    )
    info(
        f"wrote {out}/sparse/ (COLMAP text), sparse.{args.format}"
        + (" (with frusta)" if args.frusta else "")
        + (", transforms.json" if "transforms.json" in files else "")
        + ", report.html, sfm.json"
    )
