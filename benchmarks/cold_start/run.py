"""Cold start: what the first run of a command costs after installing, with and without ``skyrecon warmup``.

For ``stereo``, ``sfm``, ``map`` and ``plan`` on small synthetic inputs (rendered once, below), each
command runs as a subprocess (``python -m skyrecon``, this checkout) three ways:

  cold          an empty ``NUMBA_CACHE_DIR`` of its own: every kernel compiled (a fresh install)
  warm          the same command again, same cache: everything loaded from the cache
  after warmup  ``skyrecon warmup`` once into another empty cache dir, then the command's first run
                (what a user sees after ``make demo`` / ``make test``, which run the warmup)

Each command gets its own empty cache for the cold run, so shared kernels (map uses stereo's) do
not make a later command look warm. "compiled" counts the cache files (``*.nbc``, one per
compiled specialisation) that a run added: 0 after warmup means the warmup compiled everything
that command needed. Times are wall seconds, including Python start and imports; the machine is
shared, so expect +-0.3 s noise (``--repeat`` takes the best of several warm runs).

Inputs: ``skyrecon render stereo`` (640x480), ``render sequence --frames 10`` (640x480, stereo
map and plan), and 8 photos on a 100-degree arc around a monument (640x480, SfM; ``render images``
orbits 360 degrees, too sparse for 8 views).

Usage:
  .venv/bin/python benchmarks/cold_start/run.py
  .venv/bin/python benchmarks/cold_start/run.py --repeat 2 --keep /tmp/cold
Writes benchmarks/cold_start/results.json.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from skyrecon.cli.warmup import write_sfm_photos  # noqa: E402
from skyrecon.io import read_sequence  # noqa: E402

COMMANDS = ["stereo", "sfm", "map", "plan"]


def skyrecon(argv: list[str], cache: Path, quiet: bool = True) -> float:
    """Run ``python -m skyrecon ARGV`` with ``NUMBA_CACHE_DIR=cache``; wall seconds. Fails loudly."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), SKYRECON_PROGRESS="0")
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
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
    return seconds


def compiled_files(cache: Path) -> int:
    """Number of compiled specialisations in a Numba cache directory."""
    return sum(1 for _ in cache.rglob("*.nbc")) if cache.exists() else 0


def make_inputs(work: Path) -> dict[str, list[str]]:
    """Render the inputs once; the command line of each benchmarked command (outputs under work/out)."""
    setup_cache = work / "cache-setup"
    skyrecon(["render", "stereo", "--seed", "1", "--out", str(work / "stereo")], setup_cache)
    skyrecon(["render", "sequence", "--frames", "10", "--seed", "3", "--out", str(work / "seq")], setup_cache)
    write_sfm_photos(work / "photos", 640, 480)
    skyrecon(["map", str(work / "seq"), "--out", str(work / "plan_map")], setup_cache)
    track = np.array([p.t for p in read_sequence(work / "seq").world_from_left])
    start, goal = (list(map(str, track[i])) for i in (0, -1))
    s = str(work / "stereo")
    return {
        "stereo": ["stereo", f"{s}/left.png", f"{s}/right.png", "--calib", f"{s}/calib.txt"],
        "sfm": ["sfm", str(work / "photos" / "images"), "--camera", str(work / "photos" / "K.txt")],
        "map": ["map", str(work / "seq")],
        "plan": ["plan", str(work / "plan_map"), "--start", *start, "--goal", *goal, "--allow-unknown"],
    }


def measure(work: Path, commands: dict[str, list[str]], repeat: int, jobs: int) -> dict:
    """Cold, warm and after-warmup seconds per command, and the warmup's own seconds."""
    rows: dict[str, dict] = {}
    for name, argv in commands.items():
        cache = work / f"cache-cold-{name}"
        out = ["--out", str(work / "out" / name)]
        cold = skyrecon(argv + out, cache)
        cold_compiled = compiled_files(cache)
        warm = min(skyrecon(argv + out, cache) for _ in range(repeat))
        rows[name] = {"cold_s": cold, "warm_s": warm, "cold_compiled": cold_compiled}
        print(f"  {name}: cold {cold:.1f} s ({cold_compiled} kernels), warm {warm:.1f} s", flush=True)
    installed = work / "cache-installed"
    warmup_s = skyrecon(["warmup", "--jobs", str(jobs)], installed, quiet=False)
    print(f"  warmup --jobs {jobs}: {warmup_s:.1f} s ({compiled_files(installed)} kernels)", flush=True)
    again_s = skyrecon(["warmup", "--jobs", str(jobs)], installed, quiet=False)
    print(f"  second warmup: {again_s:.1f} s", flush=True)
    for name, argv in commands.items():
        before = compiled_files(installed)
        first = skyrecon(argv + ["--out", str(work / "out" / f"{name}-installed")], installed)
        rows[name]["after_warmup_s"] = first
        rows[name]["after_warmup_compiled"] = compiled_files(installed) - before
        rows[name]["after_warmup_minus_warm_s"] = first - rows[name]["warm_s"]
    return {"commands": rows, "warmup_s": warmup_s, "second_warmup_s": again_s, "warmup_jobs": jobs}


def print_table(results: dict) -> None:
    print()
    print("| command | cold s | after warmup s | warm s | after warmup - warm | compiled after warmup |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for name, r in results["commands"].items():
        print(
            f"| {name} | {r['cold_s']:.1f} | {r['after_warmup_s']:.1f} | {r['warm_s']:.1f} "
            f"| {r['after_warmup_minus_warm_s']:+.1f} | {r['after_warmup_compiled']} |"
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
    results["argv"] = {k: " ".join(v[:1]) for k, v in commands.items()}
    print_table(results)
    Path(args.out).write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
