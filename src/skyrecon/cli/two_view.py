"""``skyrecon two-view``: relative pose and a 3D model from two photos with known intrinsics.

Writes ``two_view.json`` (``R``, ``t`` with ``x_cam2 = R x_cam1 + t`` and ``|t| = 1``, ``F``,
``E``, ``num_matches``, ``num_inliers``, status, warnings, timings), ``sparse.ply`` and
``dense.ply`` (camera 1's frame; unit baseline unless ``--baseline`` gives metres), and pictures:
``matches.png``, ``epipolar.png``, ``rectified.png``, ``disparity.png``.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from skyrecon.cli.common import add_cloud_format, add_command, info, output_dir, positive_float, positive_int
from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import rotation_angle_deg
from skyrecon.errors import EstimationError, InputError
from skyrecon.io.atomic import write_text_atomic
from skyrecon.io.calib import read_K_txt
from skyrecon.io.disparity import colorize_disparity
from skyrecon.io.images import read_image, write_image
from skyrecon.io.las import write_point_cloud
from skyrecon.twoview import (
    TwoViewResult,
    TwoViewSettings,
    draw_epipolar_lines,
    draw_matches,
    draw_rectified_pair,
    reconstruct_two_view,
)

EXAMPLES = """  skyrecon two-view 0004.jpg 0005.jpg --camera K.txt --out pair/
  skyrecon two-view a.jpg b.jpg --camera K_a.txt --camera2 K_b.txt --baseline 1.6 --out pair/
  skyrecon two-view a.png b.png --camera K.txt --pose-method fundamental --fundamental lmeds --out pair/
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = add_command(
        subparsers,
        "two-view",
        help="relative pose, sparse and dense model from two photos",
        description=__doc__.split("\n\n")[0].split(": ", 1)[1],
        examples=EXAMPLES,
    )
    p.add_argument("image1")
    p.add_argument("image2")
    p.add_argument(
        "--camera", required=True, help="K.txt of the first camera (and of the second unless --camera2)"
    )
    p.add_argument("--camera2", help="K.txt of the second camera when it differs")
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    p.add_argument("--features", choices=["rootsift", "sift", "orb", "akaze"], default="rootsift")
    p.add_argument(
        "--max-image-size", type=positive_int, default=1536, help="longer side for features, pixels"
    )
    p.add_argument(
        "--pose-method",
        choices=["essential", "fundamental"],
        default="essential",
        help="essential: 5-point LO-RANSAC with K (default); fundamental: F first, then E = K2^T F K1",
    )
    p.add_argument(
        "--fundamental",
        choices=["ransac", "lmeds", "magsac", "8point", "7point"],
        default="ransac",
        help="estimator for F (FM_RANSAC, FM_LMEDS, MAGSAC++, FM_8POINT, FM_7POINT)",
    )
    p.add_argument(
        "--threshold", type=positive_float, default=1.0, help="inlier threshold, pixels (default 1)"
    )
    p.add_argument(
        "--dense-method",
        choices=["stereo", "epipolar"],
        default="stereo",
        help="stereo: rectify + disparity (default); epipolar: window search along epipolar lines",
    )
    p.add_argument(
        "--rectification",
        choices=["calibrated", "opencv", "uncalibrated"],
        default="calibrated",
        help="calibrated: from R, t (default); opencv: cv2.stereoRectify; uncalibrated: Hartley from F",
    )
    p.add_argument("--no-dense", action="store_true", help="skip the dense model")
    p.add_argument(
        "--baseline", type=positive_float, help="metric distance between the camera centres, metres"
    )
    p.add_argument("--seed", type=int, default=0, help="seed for RANSAC (same seed, same result)")
    add_cloud_format(p)
    return p


def _settings(args: argparse.Namespace) -> TwoViewSettings:
    """The two-view settings the arguments ask for."""
    settings = TwoViewSettings()
    return replace(
        settings,
        features=replace(settings.features, method=args.features, max_image_size=args.max_image_size),
        pose_method=args.pose_method,
        fundamental_method=args.fundamental,
        threshold_px=args.threshold,
        dense=not args.no_dense,
        dense_method=args.dense_method,
        rectification=args.rectification,
        baseline_m=args.baseline,
    )


def run(args: argparse.Namespace) -> int:
    image1, image2 = read_image(args.image1), read_image(args.image2)
    h1, w1 = image1.shape[:2]
    h2, w2 = image2.shape[:2]
    cam1 = read_K_txt(args.camera, w1, h1)
    cam2 = read_K_txt(args.camera2 or args.camera, w2, h2)
    _check_K_fits(cam1, args.camera, args.image1)
    _check_K_fits(cam2, args.camera2 or args.camera, args.image2)
    out = output_dir(args.out)
    try:
        result = reconstruct_two_view(image1, image2, cam1, cam2, _settings(args), seed=args.seed)
    except EstimationError as exc:
        raise EstimationError(f"{args.image1} and {args.image2}: {exc}") from None

    summary = result.to_json_dict()
    write_text_atomic(out / "two_view.json", json.dumps(summary, indent=2, allow_nan=False))
    _write_models_and_pictures(out, result, image1, image2, args.seed, args.format)
    if not args.quiet:
        for warning in result.warnings:
            info(f"warning: {warning}")
    if result.status in ("failed", "no_translation"):
        why = result.warnings[0] if result.warnings else "no relative pose could be estimated"
        raise EstimationError(f"{args.image1} and {args.image2}: {why} (details in {out / 'two_view.json'})")
    if not args.quiet and result.R is not None and result.t is not None:
        t = result.t
        angle = rotation_angle_deg(result.R)
        info(
            f"{result.num_inliers} of {result.num_matches} matches agree on the pose ({result.status}): "
            f"rotation {angle:.2f} deg, direction t = [{t[0]:+.3f} {t[1]:+.3f} {t[2]:+.3f}]"
        )
        dense_n = 0 if result.dense is None else len(result.dense.cloud)
        info(
            f"{len(result.sparse)} sparse and {dense_n} dense points in {result.timings.get('total', float('nan')):.1f} s; "
            f"wrote {out}/two_view.json, sparse.ply" + (", dense.ply" if dense_n else "") + " and pictures"
        )
    return 0


def _write_models_and_pictures(
    out: Path, result: TwoViewResult, image1: np.ndarray, image2: np.ndarray, seed: int, fmt: str = "ply"
) -> None:
    """sparse.ply, dense.ply and the pictures (matches, epipolar lines, rectified pair, disparity)
    that the result has."""
    if len(result.matches):
        write_image(
            out / "matches.png",
            draw_matches(image1, image2, result.x1, result.x2, result.inliers, seed=seed),
        )
    if result.F is not None:
        inl = result.inliers
        write_image(
            out / "epipolar.png",
            draw_epipolar_lines(image1, image2, result.F, result.x1[inl], result.x2[inl], seed=seed),
        )
    if len(result.sparse):
        write_point_cloud(out / "sparse.ply", result.sparse, fmt)
    if result.dense is not None:
        write_point_cloud(out / "dense.ply", result.dense.cloud, fmt)
        if result.dense.left is not None and result.dense.right is not None:
            write_image(out / "rectified.png", draw_rectified_pair(result.dense.left, result.dense.right))
        if result.dense.disparity is not None:
            write_image(out / "disparity.png", colorize_disparity(result.dense.disparity))


def _check_K_fits(cam: Intrinsics, k_path: str, image_path: str) -> None:
    """A principal point far outside the image means the K is for another image size."""
    if not (0 <= cam.cx <= cam.width and 0 <= cam.cy <= cam.height):
        raise InputError(
            f"the principal point ({cam.cx:.0f}, {cam.cy:.0f}) lies outside the {cam.width}x{cam.height} image "
            f"{Path(image_path).name}; is this K for another image size?",
            k_path,
        )
