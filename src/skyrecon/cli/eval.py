"""``skyrecon eval``: score results against ground truth.

``skyrecon eval stereo PRED GT`` scores a disparity map (PFM, KITTI 16-bit PNG or Middlebury
PGM/PNG at 1/4 pixel) against ground truth of the same size: bad-pixel rates at 1 and 2 px, KITTI
D1 (error > 3 px and > 5 %), end-point error and density. Pixels without a prediction count as
errors in the rates.
"""

from __future__ import annotations

import argparse

from skyrecon.cli.common import add_command
from skyrecon.errors import InputError
from skyrecon.eval.stereo_metrics import evaluate_disparity
from skyrecon.io.disparity import read_disparity, read_middlebury_disparity_pgm
from skyrecon.io.jsonio import write_json

EXAMPLES = """  skyrecon eval stereo out/disparity.pfm cones/disp2.pgm
  skyrecon eval stereo out/disparity.pfm training/disp_occ_0/000046_10.png --json scores.json
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = add_command(
        subparsers,
        "eval",
        help="score results against ground truth",
        description=__doc__.split("\n\n")[0].split(": ", 1)[1],
        examples=EXAMPLES,
    )
    p.add_argument("what", choices=["stereo"], help="what to evaluate")
    p.add_argument("prediction", help="the result to score")
    p.add_argument("ground_truth", help="the ground truth")
    p.add_argument(
        "--gt-scale",
        type=float,
        help="8-bit ground truth: disparity = value / scale (default 4, Middlebury 2003)",
    )
    p.add_argument("--json", help="also write the scores to this JSON file")
    return p


def run(args: argparse.Namespace) -> int:
    pred = read_disparity(args.prediction)
    if args.gt_scale is not None:
        if not args.gt_scale > 0:
            raise InputError(f"--gt-scale must be positive, got {args.gt_scale}")
        gt = read_middlebury_disparity_pgm(args.ground_truth, scale=args.gt_scale)
    else:
        gt = read_disparity(args.ground_truth)
    if pred.shape != gt.shape:
        raise InputError(
            f"the prediction is {pred.shape[1]}x{pred.shape[0]} but the ground truth is "
            f"{gt.shape[1]}x{gt.shape[0]}; evaluate at the ground truth's resolution",
            args.prediction,
        )
    scores = evaluate_disparity(pred, gt)
    print(
        f"bad-1px {100 * scores['bad1']:.2f} %  bad-2px {100 * scores['bad2']:.2f} %  "
        f"D1 {100 * scores['d1']:.2f} %  EPE {scores['epe']:.3f} px  density {100 * scores['density']:.1f} %  "
        f"({int(scores['n_gt'])} ground-truth pixels)"
    )
    if args.json:
        write_json(args.json, {k: float(v) for k, v in scores.items()})
    return 0
