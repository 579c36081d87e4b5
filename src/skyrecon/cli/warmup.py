"""``skyrecon warmup``: compile every kernel the commands use, ahead of the first real run.

Numba compiles skyrecon's kernels on first use and caches them on disk (``$NUMBA_CACHE_DIR``, or
beside the sources, or ``~/.cache/skyrecon/numba`` for a read-only install). A fresh install would
pay that on the first run of each command. This command renders tiny synthetic inputs and runs
each command on them in-process (``render``, ``stereo``, ``two-view``, ``sfm``, ``mvs``,
``odometry``, ``map`` and ``plan``), so the kernels are compiled for exactly the argument types the commands use. The
groups run in ``--jobs`` processes.

Idempotent: a stamp in the cache (``skyrecon-warmup.json``: the groups done, for which sources,
Numba and CPU) makes a repeated warmup return at once; with ``--force`` it reruns the tiny inputs,
finds every kernel cached and compiles nothing (seconds).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import multiprocessing
import os
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np

from skyrecon.cli.common import add_command, info, positive_int
from skyrecon.cli.main import main as cli_main
from skyrecon.core import Intrinsics
from skyrecon.errors import InputError
from skyrecon.io import read_sequence, write_image
from skyrecon.io.calib import write_K_txt
from skyrecon.jit import (
    CompileRecorder,
    cache_fingerprint,
    mark_warm,
    read_warm_groups,
    set_compile_notice_enabled,
    warm_stamp_path,
)
from skyrecon.mapping import OccupancyMap, blocks, save_map
from skyrecon.perception.ground_plane import warm_kernels as warm_ground_plane
from skyrecon.planning.keep_out import warm_kernels as warm_keep_out
from skyrecon.sfm import tiled_cholesky
from skyrecon.sim import generate_object_scene, orbit_views, render_views

EXAMPLES = """  skyrecon warmup                  # after installing: compile everything once (about a minute)
  skyrecon warmup --jobs 2
  skyrecon warmup --only stereo,map
  skyrecon warmup --list           # the groups and the commands each runs, without running them
"""

TINY = "--width 256 --height 192"
"""Image size of the rendered inputs: small enough to run in a second once compiled."""

# Each group: the command lines it runs, with {IN} for the inputs and {OUT} for its outputs (every
# line also gets --quiet). "render" runs first, alone: it writes the inputs the others read, with
# the SfM photos (write_sfm_photos) and a map with a wall to plan around (write_wall_map).
GROUPS: dict[str, list[str]] = {
    "render": [
        f"render stereo --seed 2 --out {{IN}}/stereo {TINY}",
        f"render sequence --frames 3 --seed 3 --out {{IN}}/sequence {TINY}",
        f"render images --views 6 --seed 4 --out {{IN}}/images {TINY}",
    ],
    "stereo": [
        "stereo {IN}/stereo/left.png {IN}/stereo/right.png --calib {IN}/stereo/calib.txt --out {OUT}/pair",
        "stereo {IN}/sequence --out {OUT}/sequence",
    ],
    "two-view": [
        "two-view {IN}/images/images/orbit_000.png {IN}/images/images/orbit_001.png "
        "--camera {IN}/images/K.txt --out {OUT}/pair",
    ],
    "sfm": ["sfm {IN}/sfm/images --camera {IN}/sfm/K.txt --out {OUT}/model --workers 1"],
    "mvs": ["mvs {IN}/images/images --cameras {IN}/images/gt_sparse --out {OUT}/dense --workers 1"],
    "odometry": ["odometry {IN}/sequence --out {OUT}/vo"],
    "map": [
        "map {IN}/sequence --out {OUT}/stereo_map --voxel-size 0.5",
        "map {IN}/sequence --depth depth_2 --out {OUT}/map --voxel-size 0.5",
        "plan {OUT}/map --start {START} --goal {GOAL} --allow-unknown --out {OUT}/route",
        "plan {IN}/wall_map --start -8 0.3 5 --goal 8 -0.4 5 --clearance 1 --out {OUT}/around_wall",
    ],
}

EXTRA_KERNELS: dict[str, tuple[Callable[[], None], ...]] = {
    # paths the tiny inputs do not reach: the tiled factorisation of large reduced camera systems
    "sfm": (tiled_cholesky.warm_kernels,),
    # the delivery loop's keep-out volumes around tracked movers (no command line here plans around
    # one), the growth of a map's block table (a map of a wider flight than the tiny ones here) and
    # the ground prior's kernels (noisy frames only)
    "map": (warm_keep_out, blocks.warm_kernels, warm_ground_plane),
}
"""Per group, functions that compile kernels its command lines leave out (run before them)."""


@dataclass
class GroupResult:
    """What warming one group did: its wall time, the kernels compiled, and a failure if any."""

    name: str
    seconds: float
    compiled: list[str] = field(default_factory=list)
    error: str = ""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = add_command(
        subparsers,
        "warmup",
        help="compile the kernels of every command ahead of the first run",
        description=__doc__.split("\n\n")[0],
        examples=EXAMPLES,
    )
    p.add_argument(
        "--jobs", type=positive_int, default=os.cpu_count() or 1, help="processes (default: all cores)"
    )
    p.add_argument(
        "--only", help=f"comma-separated groups to warm, of {', '.join(GROUPS)} (render always runs)"
    )
    p.add_argument("--list", action="store_true", help="print the groups and their commands, run nothing")
    p.add_argument(
        "--force", action="store_true", help="run the groups even if the cache stamp says they are warm"
    )
    return p


def run(args: argparse.Namespace) -> int:
    groups = selected_groups(args.only)
    if args.list:
        for name in groups:
            for line in GROUPS[name]:
                print(f"{name}: skyrecon {line} --quiet")
        return 0
    fingerprint = cache_fingerprint()
    if not args.force and set(groups) <= read_warm_groups(fingerprint):
        info(
            f"warmup: already done for these sources and this CPU ({warm_stamp_path()}); --force runs it again"
        )
        return 0
    info(f"warming {len(groups)} groups in up to {args.jobs} processes; Numba cache: {cache_location()}")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="skyrecon-warmup-") as tmp:
        results = warm_groups(groups, Path(tmp), args.jobs)
    compiled = sum(len(r.compiled) for r in results)
    failed = [r for r in results if r.error]
    info(f"warmup: {len(results)} groups in {time.perf_counter() - t0:.1f} s, {compiled} kernels compiled")
    for r in failed:
        info(f"warning: warmup group {r.name} failed: {r.error}")
    mark_warm([r.name for r in results if not r.error], fingerprint)
    return 1 if failed else 0


def selected_groups(only: str | None) -> list[str]:
    """Group names to warm, in run order; ``render`` always first (it writes the others' inputs)."""
    if not only:
        return list(GROUPS)
    wanted = [w.strip() for w in only.split(",") if w.strip()]
    unknown = [w for w in wanted if w not in GROUPS]
    if unknown:
        raise InputError(f"--only: unknown group(s) {', '.join(unknown)}; choose from {', '.join(GROUPS)}")
    return ["render"] + [g for g in GROUPS if g in wanted and g != "render"]


def cache_location() -> str:
    """Where Numba writes the cache, in words."""
    return getattr(numba.config, "CACHE_DIR", "") or "beside the sources (__pycache__)"


def warm_groups(groups: list[str], work: Path, jobs: int) -> list[GroupResult]:
    """Run ``render`` here, then the other groups on ``jobs`` worker processes; one line per group."""
    results = [_report(warm_group("render", work))]
    if results[0].error:
        return results
    write_sfm_photos(work / "in" / "sfm")
    write_wall_map(work / "in" / "wall_map")
    rest = [g for g in groups if g != "render"]
    if jobs <= 1 or len(rest) <= 1:
        return results + [_report(warm_group(g, work)) for g in rest]
    ctx = multiprocessing.get_context("forkserver")  # like the executor: safe with Numba's threads
    with ProcessPoolExecutor(max_workers=min(jobs, len(rest)), mp_context=ctx) as pool:
        futures = [pool.submit(warm_group, g, work) for g in _longest_first(rest)]
        results += [_report(f.result()) for f in futures]
    return results


def warm_group(name: str, work: Path) -> GroupResult:
    """Run the commands of one group in this process, quietly, recording what was compiled."""
    set_compile_notice_enabled(False)
    words = {"{IN}": str(work / "in"), "{OUT}": str(work / "out" / name)}
    t0 = time.perf_counter()
    with CompileRecorder() as recorder:
        for warm in EXTRA_KERNELS.get(name, ()):
            warm()
        for line in GROUPS[name]:
            argv = _expand(line.split(), words, work / "in" / "sequence") + ["--quiet"]
            sink = io.StringIO()
            with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
                code = cli_main(argv)
            if code != 0:
                last = (sink.getvalue().strip().splitlines() or ["no message"])[-1]
                error = f"{argv[0]} exit {code}: {last}"
                return GroupResult(name, time.perf_counter() - t0, recorder.names, error)
    return GroupResult(name, time.perf_counter() - t0, recorder.names)


def _expand(argv: list[str], words: dict[str, str], sequence: Path) -> list[str]:
    """Fill in {IN}/{OUT} and, for ``plan``, {START}/{GOAL} (the first and last camera of the flight)."""
    out: list[str] = []
    for arg in argv:
        if arg in ("{START}", "{GOAL}"):
            poses = read_sequence(sequence).world_from_left
            if not poses:
                raise InputError("the rendered warmup flight has no poses", sequence)
            out += [str(v) for v in np.asarray(poses[0 if arg == "{START}" else -1].t, dtype=float)]
            continue
        for key, value in words.items():
            arg = arg.replace(key, value)
        out.append(arg)
    return out


def write_sfm_photos(out: Path, width: int = 256, height: int = 192) -> None:
    """8 views on a 100-degree arc around a monument (``out/images/*.png``, ``out/K.txt``): enough
    overlap that SfM registers them all, so its registration and bundle-adjustment kernels are
    compiled too (``render images`` orbits 360 degrees, too sparse for 8 views)."""
    intrinsics = Intrinsics.from_fov(width, height, 70)
    scene = generate_object_scene(1)
    views = orbit_views(scene, 8, intrinsics, seed=0, arc_deg=100)
    (out / "images").mkdir(parents=True, exist_ok=True)
    for view, rendered in zip(views, render_views(scene, views)):
        write_image(out / "images" / view.name, rendered.image)
    write_K_txt(out / "K.txt", intrinsics)


def write_wall_map(out: Path) -> None:
    """A known 24 x 24 x 12 m map (0.25 m voxels) with a wall across x = 0, |y| <= 4 m: a plan
    from x = -8 to x = 8 must search around it (the flight's own map gives a straight line)."""
    shape, voxel = (96, 96, 48), 0.25
    origin = np.array([-12.0, -12.0, 0.0])
    x = origin[0] + (np.arange(shape[0]) + 0.5) * voxel
    y = origin[1] + (np.arange(shape[1]) + 0.5) * voxel
    occupied = np.zeros(shape, bool)
    occupied[np.ix_(np.abs(x) < 0.25, np.abs(y) < 4.0, np.ones(shape[2], bool))] = True
    save_map(OccupancyMap.from_occupancy_grid(occupied, origin, voxel_size_m=voxel), out)


def _longest_first(groups: list[str]) -> list[str]:
    """Groups ordered by their cold compile time (longest first), so parallel workers finish together."""
    order = ["map", "sfm", "mvs", "stereo", "two-view"]
    return sorted(groups, key=lambda g: order.index(g) if g in order else len(order))


def _report(result: GroupResult) -> GroupResult:
    status = f"failed ({result.error})" if result.error else f"{len(result.compiled)} kernels compiled"
    info(f"  {result.name:<9} {result.seconds:6.1f} s  {status}")
    sys.stderr.flush()
    return result
