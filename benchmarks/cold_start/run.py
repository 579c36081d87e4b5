"""Cold start: what the first run of a command costs after installing, with and without ``skyrecon warmup``.

For ``stereo``, ``sfm``, ``map`` and ``plan`` on small synthetic inputs (rendered once, below), each
command runs as a subprocess (``python -m skyrecon``, this checkout) three ways:

  cold          an empty ``NUMBA_CACHE_DIR`` of its own: every kernel compiled (a fresh install)
  warm          the same command again, same cache: everything loaded from the cache
                (every run writes to a fresh --out: nothing but the cache is reused)
  after warmup  ``skyrecon warmup`` once into another empty cache dir, then the command's first run
                (what a user sees after ``make demo`` / ``make test``, which run the warmup)

Each command gets its own empty cache for the cold run, so shared kernels (map uses stereo's) do
not make a later command look warm. "compiled" counts the cache files (``*.nbc``, one per
compiled specialisation) that a run added: 0 after warmup means the warmup compiled everything
that command needed. Times are wall seconds, including Python start and imports, and CPU seconds
of the command process (steadier than wall time on a loaded machine; the CPU of forkserver
workers, e.g. SfM's feature workers or the warmup's groups, is not included). Warm is the best of
the reruns (``--repeat`` per cache dir).

Inputs: ``skyrecon render stereo`` (640x480), ``render sequence --frames 10`` (640x480, stereo
map and plan), and 8 photos on a 100-degree arc around a monument (640x480, SfM; ``render images``
orbits 360 degrees, too sparse for 8 views). ``plan`` plans along the flight's own map (a straight
line); ``plan-wall`` plans around a wall on a known 24 m map (the A* search and smoothing), with a
query other than the warmup's.

Usage:
  .venv/bin/python benchmarks/cold_start/run.py
  .venv/bin/python benchmarks/cold_start/run.py --repeat 2 --keep /tmp/cold
Writes benchmarks/cold_start/results.json.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from skyrecon.cli.warmup import write_sfm_photos, write_wall_map  # noqa: E402
from skyrecon.io import read_sequence  # noqa: E402


def skyrecon(argv: list[str], cache: Path, quiet: bool = True) -> tuple[float, float]:
    """Run ``python -m skyrecon ARGV`` with ``NUMBA_CACHE_DIR=cache``; (wall, CPU) seconds, the CPU
    time of the command and the worker processes it waited for. Fails loudly."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), SKYRECON_PROGRESS="0")
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    cpu0 = _children_cpu()
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "skyrecon", *argv, *(["--quiet"] if quiet else [])],
        env=env,
        capture_output=True,
        text=True,
    )
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"skyrecon {' '.join(argv)} exited {proc.returncode}:\n{proc.stderr}")
    return seconds, _children_cpu() - cpu0


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def compiled_files(cache: Path) -> int:
    """Number of compiled specialisations in a Numba cache directory."""
    return sum(1 for _ in cache.rglob("*.nbc")) if cache.exists() else 0


def make_inputs(work: Path) -> dict[str, list[str]]:
    """Render the inputs once; the command line of each benchmarked command (outputs under work/out)."""
    setup_cache = work / "cache-setup"
    skyrecon(["render", "stereo", "--seed", "1", "--out", str(work / "stereo")], setup_cache)
    skyrecon(["render", "sequence", "--frames", "10", "--seed", "3", "--out", str(work / "seq")], setup_cache)
    write_sfm_photos(work / "photos", 640, 480)
    write_wall_map(work / "wall_map")
    skyrecon(["map", str(work / "seq"), "--out", str(work / "plan_map")], setup_cache)
    track = np.array([p.t for p in read_sequence(work / "seq").world_from_left])
    start, goal = (list(map(str, track[i])) for i in (0, -1))
    s = str(work / "stereo")
    return {
        "stereo": ["stereo", f"{s}/left.png", f"{s}/right.png", "--calib", f"{s}/calib.txt"],
        "sfm": ["sfm", str(work / "photos" / "images"), "--camera", str(work / "photos" / "K.txt")],
        "map": ["map", str(work / "seq")],
        "plan": ["plan", str(work / "plan_map"), "--start", *start, "--goal", *goal, "--allow-unknown"],
        "plan-wall": ["plan", str(work / "wall_map"), "--start", "-9", "1", "6", "--goal", "9", "-1", "4"],
    }


_RUN_INDEX = itertools.count()


def _fresh_out(work: Path, name: str) -> list[str]:
    """``--out`` to a directory no earlier run wrote: every run starts from nothing but the Numba
    cache. (``sfm`` keeps its features and pair matches in ``OUT/workspace`` and reuses them; a
    warm run into the cold run's directory skipped that work and looked 1.2 s faster.)"""
    return ["--out", str(work / "out" / f"{name}-{next(_RUN_INDEX)}")]


def measure(work: Path, commands: dict[str, list[str]], repeat: int, jobs: int) -> dict:
    """Cold, warm and after-warmup seconds (wall and CPU) per command, and the warmup's own seconds.

    Warm is the best of the runs after the cold one (same cache) and after the first run after
    warmup (the installed cache), so that a burst of load on the shared machine does not count.
    """
    rows: dict[str, dict] = {}
    warm_runs: dict[str, list[tuple[float, float]]] = {}
    for name, argv in commands.items():
        cache = work / f"cache-cold-{name}"
        cold, cold_cpu = skyrecon(argv + _fresh_out(work, name), cache)
        rows[name] = {"cold_s": cold, "cold_cpu_s": cold_cpu, "cold_compiled": compiled_files(cache)}
        warm_runs[name] = [skyrecon(argv + _fresh_out(work, name), cache) for _ in range(repeat)]
        print(
            f"  {name}: cold {cold:.1f} s ({rows[name]['cold_compiled']} kernels), warm", end="", flush=True
        )
        print(f" {min(w for w, _ in warm_runs[name]):.1f} s", flush=True)
    installed = work / "cache-installed"
    warmup_s, warmup_cpu = skyrecon(["warmup", "--jobs", str(jobs)], installed, quiet=False)
    print(f"  warmup --jobs {jobs}: {warmup_s:.1f} s ({compiled_files(installed)} kernels)", flush=True)
    again_s, _ = skyrecon(["warmup", "--jobs", str(jobs)], installed, quiet=False)
    print(f"  second warmup: {again_s:.1f} s", flush=True)
    for name, argv in commands.items():
        before = compiled_files(installed)
        first, first_cpu = skyrecon(argv + _fresh_out(work, name), installed)
        compiled = compiled_files(installed) - before
        warm_runs[name] += [skyrecon(argv + _fresh_out(work, name), installed) for _ in range(repeat)]
        warm, warm_cpu = min(w for w, _ in warm_runs[name]), min(c for _, c in warm_runs[name])
        rows[name].update(
            after_warmup_s=first,
            after_warmup_cpu_s=first_cpu,
            after_warmup_compiled=compiled,
            warm_s=warm,
            warm_cpu_s=warm_cpu,
            after_warmup_minus_warm_s=first - warm,
            after_warmup_minus_warm_cpu_s=first_cpu - warm_cpu,
        )
    return {
        "commands": rows,
        "warmup_s": warmup_s,
        "warmup_cpu_s": warmup_cpu,
        "second_warmup_s": again_s,
        "warmup_jobs": jobs,
    }


def print_table(results: dict) -> None:
    print()
    print(
        "| command | cold s | after warmup s | warm s | after warmup - warm | same, CPU s | compiled after warmup |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name, r in results["commands"].items():
        print(
            f"| {name} | {r['cold_s']:.1f} | {r['after_warmup_s']:.1f} | {r['warm_s']:.1f} "
            f"| {r['after_warmup_minus_warm_s']:+.1f} | {r['after_warmup_minus_warm_cpu_s']:+.1f} "
            f"| {r['after_warmup_compiled']} |"
        )
    print(
        f"\nskyrecon warmup --jobs {results['warmup_jobs']}: {results['warmup_s']:.1f} s once after installing "
        f"({results['second_warmup_s']:.1f} s when already warm)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=1, help="warm runs per command, best kept (default 1)")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="skyrecon warmup --jobs")
    parser.add_argument("--keep", help="work directory to keep (default: a temporary one, removed)")
    parser.add_argument("--out", default=str(Path(__file__).with_name("results.json")))
    args = parser.parse_args()
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="skyrecon-cold-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        print(f"rendering inputs in {work}", flush=True)
        commands = make_inputs(work)
        results = measure(work, commands, args.repeat, args.jobs)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    results["cpu_count"] = os.cpu_count()
    results["argv"] = {k: " ".join(v).replace(str(work), "WORK") for k, v in commands.items()}
    print_table(results)
    Path(args.out).write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
