"""``skyrecon map``: build an occupancy map (world frame, metres) from depth as the drone flies.

SOURCE is one of:

* a KITTI-layout stereo sequence (``image_2/``, ``image_3/``, ``calib.txt``, ``poses.txt``): depth
  from the stereo engine, poses from ``poses.txt``, frame by frame through
  :class:`skyrecon.mapping.StereoMapper` (measured disparities only, obstacles only within the
  rig's trusted range; see :mod:`skyrecon.mapping.stereo_sequence`); with ``--depth SUBDIR`` the
  depth maps ``SOURCE/SUBDIR/<frame>.pfm`` are used instead (e.g. ``depth_2`` written by
  ``skyrecon render``) with the plain map settings;
* a EuRoC/ASL sequence or a ROS bag / MCAP file (``--left-topic``, ``--right-topic``, ``--pose-topic``;
  see ``skyrecon.io.rosbag_input``), opened like ``skyrecon odometry`` opens it;
* a fused point cloud (``.ply``, world frame) seen from ``--origin X Y Z``;
* or, with ``--merge MAP_DIR ...`` and no SOURCE, earlier maps of separate flights over the same area
  (same world frame and voxel size), merged into one by adding their evidence
  (:func:`skyrecon.mapping.merge.merge_maps`).

Writes MAP_DIR with ``map.json`` + ``blocks.npz`` (the map, see ``skyrecon.mapping.storage``),
``occupied.ply`` (centres of occupied voxels; ``--format las|laz`` for LAS/LAZ), ``footprint.geojson``
(occupied columns 2 m above the lowest occupied voxel; lon/lat with ``--geo-origin``), ``preview.png``
and ``map_summary.json``. The map
directory is replaced as a whole at the end, so an interrupted run leaves the old map intact.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from skyrecon.cli.bag_options import add_bag_options, bag_topics
from skyrecon.cli.common import (
    add_cloud_format,
    add_command,
    add_executor_options,
    add_record_option,
    describe_executor,
    info,
    open_executor,
    positive_float,
    positive_int,
    recording,
)
from skyrecon.core.rigid import Rigid3
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError
from skyrecon.io.atomic import make_temp_dir, sweep_stale_temps, write_text_atomic
from skyrecon.io.checkpoint import Checkpoint
from skyrecon.io.depth_dir import iter_depth_maps, sequence_depth_paths
from skyrecon.io.ply import read_ply
from skyrecon.io.sequence import StereoSequence
from skyrecon.io.stereo_input import StereoInput, open_stereo_sequence
from skyrecon.mapping import (
    MapConfig,
    OccupancyMap,
    StereoMapper,
    StereoMapSettings,
    export_occupied_ply,
    map_depth_sequence,
    map_stereo_sequence,
    save_map,
    write_flown_path,
    write_map_preview,
    write_octomap_bt,
)
from skyrecon.mapping.ground_level import GroundSettings
from skyrecon.mapping.merge import merge_maps
from skyrecon.mapping.occupancy import load_map
from skyrecon.mapping.tiles import TiledMap, is_tiled_map
from skyrecon.mapping.tiles import describe as describe_tiled
from skyrecon.planning.geo_export import write_footprint_geojson
from skyrecon.progress import progress
from skyrecon.record import NullRecorder, Recorder
from skyrecon.record.sequence import MapRecording

EXAMPLES = """  skyrecon map flight/ --out flight_map/ --voxel-size 0.2
  skyrecon map flight/ --depth depth_2 --out gt_map/        # use depth maps instead of stereo
  skyrecon map flight/ --poses odometry --out vo_map/       # poses from visual odometry
  skyrecon map fused.ply --origin 0 0 30 --out cloud_map/
  skyrecon map flight.mcap --left-topic /stereo/left/image_raw --right-topic /stereo/right/image_raw \
      --pose-topic /stereo/left/pose --out bag_map/
  skyrecon map flight/ --out flight_map/ --record map.rrd   # frames, depth, voxels: 'rerun map.rrd'
  skyrecon map --merge monday_map/ tuesday_map/ --out district_map/   # one map from several flights
  skyrecon map /shared/f1 /shared/f2 /shared/f3 --executor dask --scheduler tcp://head:8786 --out /shared/map/
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = add_command(
        subparsers,
        "map",
        help="occupancy map from a stereo sequence, depth maps or a point cloud",
        description=__doc__.split("\n\n")[0].split(": ", 1)[1],
        examples=EXAMPLES,
    )
    p.add_argument(
        "source",
        nargs="*",
        help="sequence directory (KITTI, EuRoC), ROS bag / .mcap, or .ply point cloud (none with --merge); "
        "several sequences: one flight each, mapped side by side on the executor, then merged",
    )
    p.add_argument(
        "--tile-size",
        type=positive_float,
        metavar="M",
        help="with --merge or several sequences: write a tiled map (square tiles of about M metres on disk, loaded on demand by "
        "'skyrecon plan'), for districts too large to hold in memory at once",
    )
    p.add_argument(
        "--merge",
        nargs="+",
        metavar="MAP_DIR",
        help="merge these maps of separate flights (same world frame and voxel size) into --out, "
        "adding their evidence voxel by voxel",
    )
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
        "--flat-ground",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="plain streets on flat terrain: learn the ground level over the flight and mark the ground "
        "where the matcher's guesses agree with it (hits only, never free space); on by default, "
        "--no-flat-ground for steep or stepped terrain",
    )
    p.add_argument(
        "--max-disparity", type=positive_int, default=128, help="stereo search range, pixels (default 128)"
    )
    p.add_argument("--frames", type=positive_int, help="use only the first N frames")
    p.add_argument(
        "--poses",
        choices=("file", "odometry"),
        default="file",
        help="camera poses of a sequence: 'file' reads poses.txt (default); 'odometry' estimates them "
        "with stereo visual odometry first (see 'skyrecon odometry'), starting from the first pose of "
        "poses.txt when there is one, else from a level camera at the origin (world z up)",
    )
    p.add_argument(
        "--origin", type=float, nargs=3, metavar=("X", "Y", "Z"), help="sensor position for a .ply source"
    )
    p.add_argument(
        "--vehicle-radius",
        type=float,
        default=0.5,
        help="the camera track is space the vehicle flew through: voxels within this radius of it are "
        "marked free, metres (default 0.5; 0 marks only the voxels the track crosses)",
    )
    p.add_argument("--bt", action="store_true", help="also write an OctoMap .bt file (map.bt)")
    p.add_argument(
        "--geo-origin",
        type=float,
        nargs=3,
        metavar=("LAT", "LON", "ALT"),
        help="geographic position of the world origin: footprint.geojson in lon/lat (else local metres)",
    )
    p.add_argument(
        "--workspace",
        help="where a sequence's progress is checkpointed, so that a killed run resumes when rerun with the "
        "same arguments (default OUT/workspace; removed when the map is written)",
    )
    add_cloud_format(p)
    add_bag_options(p)
    add_executor_options(
        p, "flights mapped side by side with several sequences (default: all cores, or $SKYRECON_WORKERS)"
    )
    add_record_option(p)
    return p


# Arguments that change only how outputs are written, not the map: left out of the checkpoint key.
_OUTPUT_ONLY = {"out", "quiet", "debug", "format", "bt", "geo_origin", "workspace", "record", "command"}


def _checkpoint(root: Path, args: argparse.Namespace, n: int) -> Checkpoint:
    """The checkpoint of this run of a sequence (see :mod:`skyrecon.io.checkpoint`)."""
    key = {k: v for k, v in sorted(vars(args).items()) if k not in _OUTPUT_ONLY and not callable(v)}
    key.update(source=str(root.resolve()), frames_used=n)
    return Checkpoint(_checkpoint_path(args), key)


def _checkpoint_path(args: argparse.Namespace) -> Path:
    """Where the map's checkpoint lives: ``--workspace`` or ``OUT/workspace``."""
    workspace = Path(args.workspace) if args.workspace else Path(args.out) / "workspace"
    return workspace / "map-checkpoint.pkl"


def run(args: argparse.Namespace) -> int:
    if args.merge:
        if args.source:
            raise InputError(f"give either SOURCE ({' '.join(args.source)}) or --merge MAP_DIR ..., not both")
        return _merge(args)
    if not args.source:
        raise InputError("give a SOURCE to map (a sequence, bag or .ply) or --merge MAP_DIR ...")
    if len(args.source) > 1:
        return _map_flights(args)
    if args.tile_size:
        raise InputError(
            "--tile-size goes with --merge or several sequences: map each flight, then merge the maps into tiles"
        )
    args.source = args.source[0]
    source = Path(args.source)
    if not source.exists():
        raise InputError("not found; give a sequence directory or a .ply point cloud", source)
    with recording(args) as recorder:
        t0 = time.perf_counter()
        range_hint = None
        if source.is_file() and source.suffix.lower() == ".ply":
            occ, summary, track = _map_cloud(source, args, recorder)
        else:
            occ, summary, track, range_hint = _map_sequence(source, args, recorder)
        seconds = time.perf_counter() - t0
        _check_and_write(occ, summary, track, seconds, source, args, range_hint)
    return 0


@dataclass(frozen=True)
class _FlightJob:
    """One sequence of a multi-flight map (a picklable work item)."""

    index: int
    source: str
    options: dict[str, Any]
    out: str


def _build_flight(job: _FlightJob) -> dict[str, Any]:
    """Map one flight into ``job.out`` (a complete map directory, written atomically), unless a
    previous run already finished it with the same options; returns its summary."""
    out = Path(job.out)
    done = out / "flight_done.json"
    key = {"source": str(Path(job.source).resolve()), "options": job.options}
    if done.is_file():
        try:
            old = json.loads(done.read_text())
            if old.get("key") == key:
                return {**old["summary"], "reused": True}
        except (OSError, ValueError):
            pass
    args = argparse.Namespace(**job.options)
    args.source, args.out, args.quiet = job.source, job.out, True
    args.workspace = str(out.parent / f"{out.name}-workspace")
    occ, summary, track, _ = _map_sequence(Path(job.source), args)
    _write_map_dir(occ, out, summary, track, False)
    write_text_atomic(done, json.dumps({"key": key, "summary": summary}, default=str) + "\n")
    shutil.rmtree(args.workspace, ignore_errors=True)
    return {**summary, "reused": False}


def _map_flights(args: argparse.Namespace) -> int:
    """Several sequences: each flight mapped on its own (side by side on the executor, each into
    ``WORKSPACE/flights/<k>``, reused when rerun), then merged into ``--out`` (tiled with --tile-size)."""
    t0 = time.perf_counter()
    if args.record:
        raise InputError("--record takes one sequence; record the flights one at a time")
    sources = [Path(s) for s in args.source]
    for src in sources:
        if not src.exists():
            raise InputError("not found; give sequence directories (or bags)", src)
        if src.is_file() and src.suffix.lower() == ".ply":
            raise InputError("several sources must be sequences; map a cloud on its own", src)
    workspace = Path(args.workspace) if args.workspace else Path(args.out) / "workspace"
    skip = {
        "source",
        "out",
        "workspace",
        "merge",
        "tile_size",
        "record",
        "quiet",
        "debug",
        "bt",
        "format",
        "geo_origin",
        "command",
        "func",
        "workers",  # where the flights are mapped does not change their maps
        "executor",
        "scheduler",
    }
    options = {k: v for k, v in sorted(vars(args).items()) if k not in skip and not callable(v)}
    jobs = [
        _FlightJob(k, str(src), options, str(workspace / "flights" / f"{k:03d}"))
        for k, src in enumerate(sources)
    ]
    with open_executor(args) as executor:
        if not args.quiet:
            info(f"mapping {len(jobs)} flights ({describe_executor(executor)})")
        summaries = executor.map(_build_flight, jobs, desc="flights")
    dirs = [Path(j.out) for j in jobs]
    if args.tile_size:
        code = _merge_to_tiles(args, dirs, t0)
    else:
        flights = [
            {"source": str(s), "frames": f.get("frames"), "reused": f.get("reused")}
            for s, f in zip(sources, summaries, strict=True)
        ]
        _, n_occ = _merge_and_write(args, dirs, [str(s) for s in sources], {"flights": flights})
        if not args.quiet:
            info(
                f"map of {len(sources)} flights: {n_occ} occupied voxels at {args.voxel_size} m "
                f"in {time.perf_counter() - t0:.1f} s ({sum(1 for f in summaries if f.get('reused'))} reused)"
            )
        code = 0
    shutil.rmtree(workspace, ignore_errors=True)
    return code


def _merge(args: argparse.Namespace) -> int:
    """``--merge``: load every map, add their evidence, write the merged map directory."""
    t0 = time.perf_counter()
    dirs = [Path(d) for d in args.merge]
    out = Path(args.out).resolve()
    for d in dirs:
        if d.resolve() == out:
            raise InputError("--out must not be one of the maps being merged; choose another directory", d)
    if args.tile_size:
        return _merge_to_tiles(args, dirs, t0)
    blocks, n_occ = _merge_and_write(
        args, dirs, [str(d) for d in dirs], {"merged_from": [str(d) for d in dirs]}
    )
    if not args.quiet:
        info(
            f"merged {len(dirs)} maps into {args.out}: {blocks} blocks, {n_occ} occupied voxels "
            f"({time.perf_counter() - t0:.1f} s)",
        )
    return 0


def _merge_and_write(
    args: argparse.Namespace, dirs: list[Path], names: list[str], summary: dict[str, Any]
) -> tuple[int, int]:
    """Load the maps in ``dirs``, add their evidence and write the map directory ``--out`` (its summary
    starts with ``summary``); returns (blocks, occupied voxels written)."""
    maps = [load_map(d) for d in progress(dirs, desc="loading maps")]
    merged = merge_maps(maps, names)
    summary = {
        **summary,
        "voxel_size_m": merged.voxel_size,
        "blocks_per_input": [int(m.grid.count) for m in maps],
        "blocks": int(merged.grid.count),
        "occupied_per_input": [int(len(m.occupied_centers())) for m in maps],
        "note": "flown paths are not merged (each belongs to its own flight); their carved free space is",
    }
    del maps
    n_occ = _write_map_dir(merged, Path(args.out), summary, None, args.bt, args.format, args.geo_origin)
    return int(merged.grid.count), n_occ


def _merge_to_tiles(args: argparse.Namespace, dirs: list[Path], t0: float) -> int:
    """``--merge ... --tile-size M``: add the maps one at a time into a tiled map (memory: one input
    map and one tile), built beside ``--out`` and swapped in at the end."""
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError("--out must be a directory, but a file of that name exists", out)
    out.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale_temps(out.parent, recursive=False)
    tmp = make_temp_dir(out.parent, out.name)
    try:
        tiled = None
        for d in progress(dirs, desc="merging maps"):
            if is_tiled_map(d):
                src = TiledMap.open(d)
                pieces = ((f"{d}:{k[0]}_{k[1]}", src.tile_map(k)) for k in src.tile_ids())
                config = src.config
            else:
                occ = load_map(d)
                pieces = (item for item in [(str(d), occ)])
                config = occ.config
            if tiled is None:
                tiled = TiledMap.create(tmp, config, args.tile_size)
            for name, piece in pieces:
                tiled.add_map(piece, name)
        assert tiled is not None
        summary = {"merged_from": [str(d) for d in dirs], **describe_tiled(tiled)}
        (tmp / "map_summary.json").write_text(json.dumps(summary, indent=2))
        _replace_dir(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if not args.quiet:
        info(
            f"merged {len(dirs)} maps into the tiled map {out}: {summary['tiles']} tiles of "
            f"{summary['tile_size_m']:g} m, {summary['blocks']} blocks ({time.perf_counter() - t0:.1f} s)"
        )
    return 0


_COARSE_VOXEL_M = 0.5  # the voxel of the flight map and the stereo benchmarks


def _range_hint(settings: StereoMapSettings, rig: StereoRig) -> str:
    """What maps obstacles farther than the stereo map's trusted range (where a disparity error
    of a quarter pixel moves depth by 2 voxels, :meth:`StereoMapSettings.hit_range_m`)."""
    if settings.perception.max_depth_error_m is not None:
        return "a larger --max-depth-error reaches farther (and puts far obstacles less precisely)"
    if settings.voxel_size_m < _COARSE_VOXEL_M:
        coarse_m = replace(settings, voxel_size_m=_COARSE_VOXEL_M).hit_range_m(rig)
        return f"--voxel-size {_COARSE_VOXEL_M:g} trusts depth to {coarse_m:.1f} m, or set --max-depth-error (metres)"
    return "fly closer to what should be mapped, or set --max-depth-error (metres)"


def _check_and_write(
    occ: OccupancyMap,
    summary: dict[str, Any],
    track: np.ndarray | None,
    seconds: float,
    source: Path,
    args: argparse.Namespace,
    range_hint: str | None = None,
) -> None:
    """Refuse an empty map, write the map folder and say what was done. ``range_hint``: for a
    stereo map whose trusted range is short of ``--max-range``, what reaches farther
    (:func:`_range_hint`); the range is ``summary["trusted_range_m"]``."""
    counts = occ.counts()
    trusted = summary.get("trusted_range_m")
    if counts.get("occupied", 0) == 0:
        if range_hint is not None:
            raise InputError(
                f"no occupied voxel was observed within {trusted:.1f} m, the range to which stereo depth "
                f"is trusted at {args.voxel_size:g} m voxels: {range_hint}",
                source,
            )
        raise InputError(
            "no occupied voxel was observed: check the depth (metres?), the poses and --max-range", source
        )
    summary.update(
        voxel_size_m=args.voxel_size,
        max_range_m=round(occ.config.max_range_m, 2),
        seconds=round(seconds, 2),
        voxels={k: int(v) for k, v in counts.items()},
        memory_mb=round(occ.memory_bytes() / 1e6, 1),
    )
    out = Path(args.out)
    n_occ = _write_map_dir(occ, out, summary, track, args.bt, args.format, args.geo_origin)
    if args.workspace:  # (the default workspace went with the old OUT when the new one was swapped in)
        Checkpoint(_checkpoint_path(args), None).clear()
    if not args.quiet:
        info(
            f"map of {summary.get('frames', 1)} input(s): {n_occ} occupied, {counts.get('free', 0)} free voxels "
            f"at {args.voxel_size} m in {seconds:.1f} s"
            + (f" ({summary['frames_per_s']:.1f} frames/s)" if "frames_per_s" in summary else "")
        )
        if summary.get("ground_level_m") is not None:
            info(
                f"flat ground: level at z = {summary['ground_level_m']:.2f} m; plain streets marked just under it"
            )
        if range_hint is not None:
            hint = f"; {range_hint}" if args.voxel_size < _COARSE_VOXEL_M else ""
            info(
                f"stereo depth is trusted to {trusted:.1f} m at {args.voxel_size:g} m voxels: obstacles farther are not mapped{hint}"
            )
        info(f"wrote {out}/map.json, blocks.npz, occupied.{args.format}, footprint.geojson, preview.png")


def _map_sequence(
    root: Path, args: argparse.Namespace, recorder: Recorder | None = None
) -> tuple[OccupancyMap, dict[str, Any], np.ndarray, str | None]:
    """(map, summary, camera track (N, 3) world metres, range hint) of a sequence: stereo, or
    ``--depth`` maps; each frame logged to ``recorder``
    (:class:`~skyrecon.record.sequence.MapRecording`). The range hint (:func:`_range_hint`) is
    there for a stereo map whose trusted range is short of ``--max-range``."""
    recorder = recorder or NullRecorder()
    seq = open_stereo_sequence(root, bag_topics(args))
    n = min(len(seq), args.frames or len(seq))
    odometry_summary: dict[str, Any] | None = None
    if getattr(args, "poses", "file") == "odometry":
        poses, odometry_summary = _odometry_poses(seq, n)
    else:
        poses = _known_poses(seq, n)
    if args.depth is not None and not isinstance(seq.sequence, StereoSequence):
        raise InputError("--depth reads depth maps of a KITTI-layout sequence; this input has none", root)
    ckpt = _checkpoint(root, args, n)
    saved = ckpt.load()
    first = saved[0] if saved is not None and 0 < saved[0] < n else 0
    if first and not args.quiet:
        info(f"resuming from frame {first} of {n} (checkpoint in {ckpt.path.parent})")
    if args.depth is None:
        settings = StereoMapSettings(
            voxel_size_m=args.voxel_size,
            max_range_m=args.max_range,
            ground=GroundSettings() if args.flat_ground else None,
        ).with_overrides(
            method=args.method, max_disparity=args.max_disparity, max_depth_error_m=args.max_depth_error
        )
        observer = MapRecording(recorder, seq.timestamps_s, args.max_disparity) if recorder.enabled else None
        mapper = StereoMapper(seq.rig, settings)
        if first:
            mapper.restore(saved[1])  # type: ignore[index]
        frames = (seq.frame(i) for i in range(first, n))
        built = map_stereo_sequence(
            progress(frames, total=n, initial=first, desc="map frames"),
            seq.rig,
            poses,
            mapper=mapper,
            first_frame=first,
            # the state waits for the frame being integrated (StereoMapper.overlap): only when due
            after_frame=lambda done, m: (
                ckpt.save(done, m.resume_state()) if done < n and ckpt.due() else None
            ),
            on_frame=observer,
        )
        occ, timings = built.map, built.timings
        trusted_m: float | None = built.hit_range_m
        ground_z = built.ground.z_m if built.ground is not None else None
        range_hint = _range_hint(settings, seq.rig) if built.hit_range_m < args.max_range else None
    else:
        assert isinstance(seq.sequence, StereoSequence)
        depths = iter_depth_maps(sequence_depth_paths(seq.sequence, args.depth)[first:n], seq.rig.left)
        config = MapConfig(voxel_size_m=args.voxel_size, max_range_m=args.max_range)
        observer = (
            MapRecording(recorder, seq.timestamps_s, image_of=lambda i: seq.frame(i)[0])
            if recorder.enabled
            else None
        )
        built_d = map_depth_sequence(
            progress(depths, total=n, initial=first, desc="map frames"),
            seq.rig.left,
            poses,
            config,
            resume=saved[1] if first else None,  # type: ignore[index]
            first_frame=first,
            after_frame=lambda done, b: ckpt.save(done, b) if done < n else None,
            on_frame=observer,
        )
        occ, timings = built_d.map, built_d.timings
        trusted_m, range_hint, ground_z = None, None, None
    summary_ckpt = {"resumed_from_frame": first, "checkpoints_written": ckpt.saves}
    summary = timings.summary()
    summary.pop("frames", None)
    summary = {
        "source": str(root),
        "frames": n,
        "depth_from": args.depth or f"stereo ({args.method})",
        **summary,
    }
    if trusted_m is not None:
        summary["trusted_range_m"] = round(trusted_m, 2)
        # the flat ground (see --flat-ground): the level learnt, None when none was found or it is off
        summary["ground_level_m"] = None if ground_z is None else round(float(ground_z), 3)
    if odometry_summary is not None:
        summary["poses_from"] = "odometry"
        summary["odometry"] = odometry_summary
    track = np.array([p.t for p in poses])
    if not (np.isfinite(args.vehicle_radius) and args.vehicle_radius >= 0):
        raise InputError(
            f"--vehicle-radius must be a non-negative number of metres, got {args.vehicle_radius}"
        )
    summary["flown_free_voxels"] = occ.mark_flown_free(track, args.vehicle_radius)
    summary["vehicle_radius_m"] = args.vehicle_radius
    summary["checkpoint"] = summary_ckpt
    if observer is not None:
        observer.finish(occ)
    return occ, summary, track, range_hint


# a level camera looking along world +x: camera x right = world -y, y down = world -z, z forward = world +x
_LEVEL_WORLD_FROM_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _known_poses(seq: StereoInput, n: int) -> list[Rigid3]:
    """``world_from_left`` of the first ``n`` frames from the sequence (poses.txt, ground truth, pose topic)."""
    if seq.world_from_left is None:
        what = "a --pose-topic" if seq.layout == "rosbag" else "poses.txt"
        raise InputError(
            f"the sequence has no poses ({what}); a map needs one world_from_left_camera pose per frame "
            "(or estimate them: --poses odometry)",
            seq.root,
        )
    missing = [i for i, p in enumerate(seq.world_from_left[:n]) if p is None]
    if missing:
        raise InputError(
            f"{len(missing)} of the {n} frames have no pose (first: frame {missing[0]} at "
            f"{seq.timestamps_s[missing[0]]:.3f} s); use --frames or --poses odometry",
            seq.root,
        )
    return [p for p in seq.world_from_left[:n] if p is not None]


def _odometry_poses(seq: StereoInput, n: int) -> tuple[list[Rigid3], dict[str, Any]]:
    """``world_from_left`` of the first ``n`` frames estimated by stereo visual odometry, and the
    run's summary. The world: the first known pose of the sequence when there is one, else a level
    camera at the origin looking along +x (z up)."""
    from skyrecon.cli.odometry import make_engine
    from skyrecon.odometry.run import run_odometry, summarize_run

    if n < 2:
        raise InputError(f"odometry needs at least 2 frames, the sequence has {n}", seq.root)
    first = seq.world_from_left[0] if seq.world_from_left is not None else None
    if first is not None:
        init = first.with_frames("world", "left")
    else:
        init = Rigid3(_LEVEL_WORLD_FROM_CAM, np.zeros(3), "world", "left")
    engine, _ = make_engine(seq.rig, init, True)
    frames = progress((seq.frame(i) for i in range(n)), total=n, desc="odometry", unit="frame")
    result = run_odometry(engine, frames, seq.timestamps_s[:n])
    summary = summarize_run(result)
    info(
        f"odometry: {n} frames, {summary['distance_m']:.1f} m, {summary['lost']} lost, "
        f"{summary['degraded']} degraded"
    )
    brief = {k: summary[k] for k in ("frames", "distance_m", "fps", "ok", "degraded", "lost")}
    return result.odometry, brief


def _map_cloud(
    path: Path, args: argparse.Namespace, recorder: Recorder | None = None
) -> tuple[OccupancyMap, dict[str, Any], None]:
    """(map, summary, no track) of a point cloud seen from ``--origin``; the cloud and the occupied
    voxels logged to ``recorder``."""
    recorder = recorder or NullRecorder()
    if args.origin is None:
        raise InputError(
            "a point cloud needs the sensor position it was seen from: add --origin X Y Z (world, metres)",
            path,
        )
    cloud = read_ply(path)
    if len(cloud) == 0:
        raise InputError("the point cloud is empty", path)
    occ = OccupancyMap(voxel_size_m=args.voxel_size, max_range_m=args.max_range)
    occ.integrate_points(cloud.points.astype(np.float64), np.asarray(args.origin, dtype=np.float64))
    if recorder.enabled:
        recorder.set_time(0.0, 0)
        recorder.log_points("cloud", cloud.points, cloud.colors)
        recorder.log_voxels("map/occupied", occ.occupied_centers(), occ.voxel_size)
    return occ, {"source": str(path), "frames": 1, "points": len(cloud)}, None


def _write_map_dir(
    occ: OccupancyMap,
    out: Path,
    summary: dict[str, Any],
    track: np.ndarray | None,
    bt: bool,
    fmt: str = "ply",
    geo_origin: list[float] | None = None,
) -> int:
    """Write the map directory ``out`` as a whole (built beside it, then swapped in); returns
    the number of occupied voxels written to ``occupied.ply``."""
    if out.exists() and not out.is_dir():
        raise InputError("--out must be a directory, but a file of that name exists", out)
    out.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale_temps(out.parent, recursive=False)
    tmp = make_temp_dir(out.parent, out.name)
    try:
        save_map(occ, tmp)
        if track is not None:
            write_flown_path(tmp, track, float(summary.get("vehicle_radius_m", 0.0)))
        n_occ = export_occupied_ply(occ, tmp / "occupied.ply", fmt=fmt)
        write_footprint_geojson(tmp / "footprint.geojson", occ, geo_origin)
        if bt:
            write_octomap_bt(occ, tmp / "map.bt")
        write_map_preview(occ, tmp / "preview.png", [] if track is None else [track])
        (tmp / "map_summary.json").write_text(json.dumps(summary, indent=2))
        _replace_dir(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return n_occ


def _replace_dir(new: Path, target: Path) -> None:
    """Put directory ``new`` at ``target``; an existing target is swapped out, then removed."""
    old = None
    if target.exists():
        old = make_temp_dir(target.parent, f"{target.name}.old")
        os.rmdir(old)
        os.replace(target, old)
    os.replace(new, target)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
