"""``skyrecon map``: build an occupancy map (world frame, metres) from depth as the drone flies.

SOURCE is one of:

* a KITTI-layout stereo sequence (``image_2/``, ``image_3/``, ``calib.txt``, ``poses.txt``): depth
  from the stereo engine, poses from ``poses.txt``, frame by frame through
  :class:`skyrecon.mapping.StereoMapper` (measured disparities only, obstacles only within the
  rig's trusted range; see :mod:`skyrecon.mapping.stereo_sequence`); with ``--depth SUBDIR`` the
  depth maps ``SOURCE/SUBDIR/<frame>.pfm`` are used instead (e.g. ``depth_2`` written by
  ``skyrecon render``) with the plain map settings;
* a fused point cloud (``.ply``, world frame) seen from ``--origin X Y Z``.

Writes MAP_DIR with ``map.json`` + ``blocks.npz`` (the map, see ``skyrecon.mapping.storage``),
``occupied.ply`` (centres of occupied voxels), ``preview.png`` and ``map_summary.json``. The map
directory is replaced as a whole at the end, so an interrupted run leaves the old map intact.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from skyrecon.cli.common import add_command, info, positive_float, positive_int
from skyrecon.errors import InputError

EXAMPLES = """  skyrecon map flight/ --out flight_map/ --voxel-size 0.2
  skyrecon map flight/ --depth depth_2 --out gt_map/        # use depth maps instead of stereo
  skyrecon map fused.ply --origin 0 0 30 --out cloud_map/
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = add_command(
        subparsers,
        "map",
        help="occupancy map from a stereo sequence, depth maps or a point cloud",
        description=__doc__.split("\n\n")[0].split(": ", 1)[1],
        examples=EXAMPLES,
    )
    p.add_argument("source", help="sequence directory or .ply point cloud")
    p.add_argument("--out", required=True, help="map directory to write")
    p.add_argument("--voxel-size", type=positive_float, default=0.2, help="voxel edge, metres (default 0.2)")
    p.add_argument(
        "--max-range",
        type=positive_float,
        default=40.0,
        help="measurements farther than this carve free space only, metres (default 40)",
    )
    p.add_argument(
        "--max-depth-error",
        type=positive_float,
        help="stereo: mark obstacles only where a 0.25 px disparity error moves depth by less "
        "than this, metres (default 2 voxels); farther measurements carve free space only",
    )
    p.add_argument(
        "--depth", metavar="SUBDIR", help="use SOURCE/SUBDIR/<frame>.pfm depth maps instead of stereo"
    )
    p.add_argument("--method", default="skyrecon", help="stereo matcher (default skyrecon)")
    p.add_argument(
        "--max-disparity", type=positive_int, default=128, help="stereo search range, pixels (default 128)"
    )
    p.add_argument("--frames", type=positive_int, help="use only the first N frames")
    p.add_argument(
        "--origin", type=float, nargs=3, metavar=("X", "Y", "Z"), help="sensor position for a .ply source"
    )
    p.add_argument("--bt", action="store_true", help="also write an OctoMap .bt file (map.bt)")
    return p


def run(args: argparse.Namespace) -> int:
    from skyrecon.mapping import OccupancyMap, export_occupied_ply, save_map, write_octomap_bt

    source = Path(args.source)
    if not source.exists():
        raise InputError("not found; give a sequence directory or a .ply point cloud", source)
    t0 = time.perf_counter()
    if source.is_file() and source.suffix.lower() == ".ply":
        occ = OccupancyMap(voxel_size_m=args.voxel_size, max_range_m=args.max_range)
        summary = _integrate_cloud(occ, source, args)
    else:
        occ, summary = _integrate_sequence(source, args)
    max_range = occ.config.max_range_m
    seconds = time.perf_counter() - t0
    counts = occ.counts()
    if counts.get("occupied", 0) == 0:
        raise InputError(
            "no occupied voxel was observed: check the depth (metres?), the poses and --max-range", source
        )

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError("--out must be a directory, but a file of that name exists", out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        save_map(occ, tmp)
        n_occ = export_occupied_ply(occ, tmp / "occupied.ply")
        if args.bt:
            write_octomap_bt(occ, tmp / "map.bt")
        _write_preview(occ, tmp / "preview.png", summary.pop("track", None))
        summary.update(
            voxel_size_m=args.voxel_size,
            max_range_m=round(max_range, 2),
            seconds=round(seconds, 2),
            voxels={k: int(v) for k, v in counts.items()},
            memory_mb=round(occ.memory_bytes() / 1e6, 1),
        )
        (tmp / "map_summary.json").write_text(json.dumps(summary, indent=2))
        _replace_dir(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if not args.quiet:
        info(
            f"map of {summary.get('frames', 1)} input(s): {n_occ} occupied, {counts.get('free', 0)} free voxels "
            f"at {args.voxel_size} m in {seconds:.1f} s"
            + (f" ({summary['frames_per_s']:.1f} frames/s)" if "frames_per_s" in summary else "")
        )
        info(f"wrote {out}/map.json, blocks.npz, occupied.ply, preview.png")
    return 0


def _integrate_sequence(root: Path, args) -> tuple:
    """(map, summary) of a sequence: stereo through StereoMapper, or ``--depth`` maps."""
    from skyrecon.io.pfm import read_pfm
    from skyrecon.io.sequence import read_sequence
    from skyrecon.mapping import OccupancyMap, StereoMapper, StereoMapSettings
    from skyrecon.mapping.stereo_sequence import StereoMapTimings
    from skyrecon.progress import progress

    seq = read_sequence(root)
    if seq.world_from_left is None:
        raise InputError(
            "the sequence has no poses.txt; a map needs one world_from_left_camera pose per frame", root
        )
    n = min(len(seq), args.frames or len(seq))
    rig = seq.rig
    if args.depth is None:
        mapper = StereoMapper(
            rig,
            StereoMapSettings(
                voxel_size_m=args.voxel_size,
                max_range_m=args.max_range,
                method=args.method,
                max_disparity=args.max_disparity,
                max_depth_error_m=args.max_depth_error,
            ),
        )
        _ = mapper.matcher  # build (and warm up) the matcher before the first frame
        occ, timings = mapper.map, mapper.timings
    else:
        occ, timings = (
            OccupancyMap(voxel_size_m=args.voxel_size, max_range_m=args.max_range),
            StereoMapTimings(),
        )
    for i in progress(range(n), desc="map frames"):
        try:
            if args.depth is None:
                left, right = seq.frame(i)
                mapper.add_frame(left, right, seq.world_from_left[i])
            else:
                path = root / args.depth / f"{seq.left_paths[i].stem}.pfm"
                t0 = time.perf_counter()
                depth = read_pfm(path)
                if depth.shape != rig.left.shape:
                    raise InputError(
                        f"depth map is {depth.shape[1]}x{depth.shape[0]}, images are {rig.left.width}x{rig.left.height}",
                        path,
                    )
                t1 = time.perf_counter()
                occ.integrate_depth(depth, rig.left, seq.world_from_left[i])
                timings.depth_s.append(t1 - t0)
                timings.integrate_s.append(time.perf_counter() - t1)
        except InputError as exc:
            raise InputError(f"frame {seq.left_paths[i].stem}: {exc}") from None
    summary = timings.summary()
    summary.pop("frames", None)
    return occ, {
        "source": str(root),
        "frames": n,
        "depth_from": args.depth or f"stereo ({args.method})",
        **summary,
        "track": np.array([p.t for p in seq.world_from_left[:n]]),
    }


def _integrate_cloud(occ, path: Path, args) -> dict:
    from skyrecon.io.ply import read_ply

    if args.origin is None:
        raise InputError(
            "a point cloud needs the sensor position it was seen from: add --origin X Y Z (world, metres)",
            path,
        )
    cloud = read_ply(path)
    if len(cloud) == 0:
        raise InputError("the point cloud is empty", path)
    occ.integrate_points(cloud.points.astype(np.float64), np.asarray(args.origin, dtype=np.float64))
    return {"source": str(path), "frames": 1, "points": len(cloud)}


def _write_preview(occ, path: Path, track: np.ndarray | None) -> None:
    """Top view of the occupied voxels (darker = higher) with the camera track."""
    write_map_preview(occ, path, [] if track is None else [track])


def write_map_preview(occ, path: Path, paths: list[np.ndarray]) -> None:
    """Top view of a map's occupied voxels (darker = higher) with paths drawn on top."""
    from skyrecon.io.images import write_image
    from skyrecon.report.figures import height_map_image

    centers = occ.occupied_centers()
    if len(centers) == 0:
        return
    lo, hi = centers.min(axis=0) - 5, centers.max(axis=0) + 5
    for track in paths:
        if len(track):
            lo[:2] = np.minimum(lo[:2], np.asarray(track)[:, :2].min(axis=0) - 5)
            hi[:2] = np.maximum(hi[:2], np.asarray(track)[:, :2].max(axis=0) + 5)
    px_per_m = min(8.0, 1600.0 / max(hi[0] - lo[0], hi[1] - lo[1]))
    write_image(path, height_map_image(centers, (lo[0], lo[1], hi[0], hi[1]), paths, px_per_m=px_per_m))


def _replace_dir(new: Path, target: Path) -> None:
    """Put directory ``new`` at ``target``; an existing target is swapped out, then removed."""
    old = None
    if target.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{target.name}.old.", dir=target.parent))
        os.rmdir(old)
        os.replace(target, old)
    os.replace(new, target)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
