"""``skyrecon mvs``: dense multi-view stereo with known cameras: depth maps and one fused cloud.

Writes ``fused.ply`` (world frame, colours and normals; ``--format las|laz`` for LAS/LAZ), ``depth/<image stem>.pfm`` (depth along
the optical axis at the working resolution, metres, NaN unknown), ``mvs.json`` (settings,
neighbours, depth ranges, timings, warnings), ``mesh.ply`` with ``--mesh``, and pictures:
``depth.png`` (every depth map) and ``preview.png`` (the fused cloud seen from the first cameras).
Each view's depth is kept in ``OUT/workspace/`` as soon as it is computed: a killed run, rerun
with the same arguments, computes only the views it had not finished.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
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
    positive_float,
    positive_int,
    recording,
)
from skyrecon.core import PosedView
from skyrecon.errors import EstimationError
from skyrecon.io.disparity import colorize_depth
from skyrecon.io.images import write_image
from skyrecon.mvs import MVSResult, MVSSettings, load_views_and_images, run_mvs, save_mvs_result
from skyrecon.mvs.planar_prior import PlanarPriorSettings
from skyrecon.mvs.preview import render_cloud
from skyrecon.mvs.settings import DEPTH_METHODS, FUSION_METHODS
from skyrecon.mvs.topology import TOPOLOGIES
from skyrecon.record.reconstruction import log_mvs
from skyrecon.report.figures import contact_sheet

EXAMPLES = """  skyrecon mvs fountain/images --cameras fountain/cameras --out fountain_mvs/
  skyrecon mvs temple/ --cameras temple/templeR_par.txt --out temple_mvs/ --max-image-size 640
  skyrecon mvs run/images --cameras run/sparse --out dense/ --mesh      # cameras from skyrecon sfm
  skyrecon mvs rock/images --cameras rock/calib --topology 360 --fusion concat --out rock_concat/
  skyrecon mvs run/images --cameras run/sparse --out dense/ --record dense.rrd   # 'rerun dense.rrd'
  skyrecon mvs run/images --cameras run/sparse --executor dask --scheduler tcp://head:8786 --out /shared/dense/
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = add_command(
        subparsers,
        "mvs",
        help="dense depth maps and a fused point cloud from many images with known cameras",
        description=__doc__.split("\n\n")[0].split(": ", 1)[1],
        examples=EXAMPLES,
    )
    p.add_argument("images_dir", help="directory of the images")
    p.add_argument(
        "--cameras",
        required=True,
        help="COLMAP text model directory, Middlebury *_par.txt, directory of Strecha *.camera "
        "files or of HALCON camera files",
    )
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    p.add_argument(
        "--topology",
        choices=list(TOPOLOGIES),
        default=None,
        help="which views are matched: auto (default: best neighbours per view) or a ring topology",
    )
    p.add_argument(
        "--fusion",
        choices=list(FUSION_METHODS),
        default="consistency",
        help="consistency: keep depths that agree across views (default); "
        "concat: the write-up's method (pairwise SGBM, clouds concatenated)",
    )
    p.add_argument(
        "--depth-method",
        choices=list(DEPTH_METHODS),
        default=None,
        help="patchmatch: multi-view PatchMatch (default); pairwise: rectified stereo per pair",
    )
    p.add_argument(
        "--max-image-size",
        type=positive_int,
        default=640,
        help="longer side of the working images, pixels (default 640)",
    )
    p.add_argument(
        "--num-sources", type=positive_int, default=None, help="source views per reference view (auto)"
    )
    p.add_argument(
        "--depth-range",
        type=positive_float,
        nargs=2,
        metavar=("NEAR", "FAR"),
        help="depth range of every view, metres (default: estimated from sparse matches)",
    )
    p.add_argument(
        "--voxel-size", type=positive_float, help="average the fused points in voxels of this size, metres"
    )
    p.add_argument(
        "--mesh", action="store_true", help="also write mesh.ply (TSDF fusion + surface extraction)"
    )
    p.add_argument(
        "--no-planar-prior",
        action="store_true",
        help="leave plain (textureless) regions without depth instead of giving them supported planes",
    )
    p.add_argument(
        "--allow-extra-images",
        action="store_true",
        help="ignore image files that no camera refers to (default: an error)",
    )
    add_executor_options(p, "workers for per-view depth (default: all cores, or $SKYRECON_WORKERS)")
    p.add_argument(
        "--workspace",
        help="where each view's depth is kept as soon as it is computed, so that a killed run resumes "
        "when rerun with the same arguments (default OUT/workspace)",
    )
    add_cloud_format(p)
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice (same seed, same result)")
    add_record_option(p)
    return p


def run(args: argparse.Namespace) -> int:
    views, _ = load_views_and_images(
        args.images_dir, args.cameras, allow_extra_images=args.allow_extra_images
    )
    changes: dict[str, Any] = dict(max_image_size=args.max_image_size, seed=args.seed)
    if args.depth_method is not None:
        changes["depth_method"] = args.depth_method
    if args.num_sources is not None:
        changes["num_sources"] = args.num_sources
    if args.depth_range is not None:
        changes["depth_range"] = tuple(args.depth_range)
    if args.voxel_size is not None:
        changes["voxel_size_m"] = args.voxel_size
    if getattr(args, "no_planar_prior", False):
        changes["planar_prior"] = PlanarPriorSettings(enabled=False)
    settings = MVSSettings.from_names(args.topology, args.fusion, args.mesh, **changes)
    out = output_dir(args.out)
    workspace = Path(args.workspace) if args.workspace else out / "workspace"
    with open_executor(args) as executor:
        if not args.quiet:
            info(
                f"{len(views)} views; depth by {settings.depth_method}, topology {settings.topology}, "
                f"fusion {settings.fusion}, longer side at most {settings.max_image_size or 'full'} px, "
                f"{describe_executor(executor)}"
            )
        result = run_mvs(views, None, settings, executor=executor, workspace=workspace)
    if len(result.cloud) == 0:
        save_mvs_result(result, out, settings, args.format)
        why = "; ".join(result.warnings) or "no depth was consistent across views"
        raise EstimationError(f"no 3D points were reconstructed: {why} (details in {out / 'mvs.json'})")
    paths = save_mvs_result(result, out, settings, args.format)
    _pictures(result, views, out)
    with recording(args) as recorder:
        if recorder.enabled:
            log_mvs(recorder, views, result)
    if not args.quiet:
        for warning in result.warnings:
            info(f"warning: {warning}")
        t = result.timings_s
        steps = ", ".join(f"{k} {v:.1f} s" for k, v in t.items() if k != "total")
        info(
            f"{len(result.cloud)} fused points from {len(result.depth_maps)} depth maps in {t.get('total', 0):.1f} s "
            f"({steps})"
        )
        prior = prior_summary(result.diagnostics)
        if prior:
            info(prior)
        written = [f"fused.{args.format}", "depth/*.pfm", "mvs.json", "depth.png", "preview.png"]
        if "mesh" in paths:
            written.insert(1, "mesh.ply")
        info(f"wrote {out}/" + ", ".join(written))
    return 0


def prior_summary(diagnostics: dict[str, Any]) -> str | None:
    """One line on what the planar prior filled (None when it did not run): the views whose plain
    segments took a plane and the pixels, and what the second pass (planes shared between views)
    added."""
    views = (diagnostics.get("planar_prior") or {}).get("views") or {}
    if not views:
        return None
    first = [int(v.get("filled_px", 0)) for v in views.values()]
    second = [int(v.get("shared_planes", {}).get("filled_px", 0)) for v in views.values()]
    line = (
        f"planar prior: plain segments took a plane in {sum(f > 0 for f in first)} of {len(views)} views "
        f"({sum(first)} px)"
    )
    if any(second):
        line += f"; planes shared between views filled {sum(second)} px more in {sum(n > 0 for n in second)}"
    return line


def _pictures(result: MVSResult, views: Sequence[PosedView], out: Path) -> None:
    """depth.png: a contact sheet of the depth maps; preview.png: the cloud from up to 3 cameras."""
    stems = list(result.depth_maps)
    if stems:
        finite = np.concatenate(
            [dm.depth_m[np.isfinite(dm.depth_m)].ravel()[::7] for dm in result.depth_maps.values()]
        )
        lo, hi = np.percentile(finite, [1, 99]) if finite.size else (None, None)
        tiles = [colorize_depth(result.depth_maps[s].depth_m, lo, hi) for s in stems[:24]]
        write_image(
            out / "depth.png", contact_sheet(tiles, stems[:24], columns=min(4, len(tiles)), tile_width=320)
        )
    picks = sorted({0, len(views) // 3, (2 * len(views)) // 3})
    tiles, labels = [], []
    for k in picks:
        dm = result.depth_maps.get(Path(views[k].name).stem)
        intr = dm.intrinsics if dm is not None else views[k].intrinsics
        tiles.append(render_cloud(result.cloud, intr, views[k].cam_from_world, point_px=2))
        labels.append(f"fused cloud from {views[k].name}")
    write_image(out / "preview.png", contact_sheet(tiles, labels, columns=len(tiles), tile_width=480))
