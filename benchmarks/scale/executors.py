"""Executors side by side: SfM feature extraction and MVS per-view depth, serial vs process vs Dask.

Renders a synthetic set once (``skyrecon render images`` for SfM, ``render ring`` for MVS, both
``--views N`` at ``--size`` px wide, 4:3), then times one stage on each executor:

  serial     this process
  process 2  two local worker processes (the persistent pool ``skyrecon sfm`` uses)
  dask 1     a LocalCluster with one single-threaded worker process
  dask 2     a LocalCluster with two

Every executor is started and warmed (modules imported, Numba kernels loaded from the cache) on
two items before its timed run, so the figures are the stage's, not the start-up's (reported
apart). Each timed run uses a fresh workspace (no cached result is reused).

``sfm features``: ``extract_one`` per image (SIFT at the input size, single-threaded).
``mvs depth``: the pipeline's ``depth`` step (PatchMatch per view at the working size
``--size``), after load/sparse/select ran once in this process. The pipeline gives each
PatchMatch task ``cpu_count // workers`` threads; ``--threads-per-task 1`` (the default here)
pins it to one so that the comparison measures the executors, ``auto`` keeps the policy.

Printed per stage and executor: wall seconds, speedup over serial (and dask 2 over dask 1), the
tasks' CPU seconds (sum and per item, measured inside the workers), and a CPU-time-based
speedup: serial CPU / the busiest worker's CPU (what the split achieves with a core per
worker; on a shared, loaded machine the wall figures are not). ``identical`` says whether every
executor gave the same bytes (feature arrays, depth maps) as serial.

Usage:
  .venv/bin/python benchmarks/scale/executors.py                    # 1024 px, 16 views
  .venv/bin/python benchmarks/scale/executors.py --size 512 --views 8 --keep /tmp/scale
Writes benchmarks/scale/results.json (``--results`` to change).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import hashlib
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1].parent
sys.path.insert(0, str(ROOT / "src"))

from skyrecon.executor import SerialExecutor  # noqa: E402


# ------------------------------------------------------------------------------------------------
# inputs
# ------------------------------------------------------------------------------------------------
def render(kind: str, views: int, size: int, out: Path) -> None:
    """``skyrecon render KIND`` into ``out`` (skipped when already there)."""
    if (out / "images").is_dir():
        return
    argv = ["render", kind, "--views", str(views), "--width", str(size), "--height", str(size * 3 // 4)]
    env = dict(os.environ, SKYRECON_PROGRESS="0", PYTHONPATH=str(ROOT / "src"))
    subprocess.run(
        [sys.executable, "-m", "skyrecon", *argv, "--out", str(out), "--quiet"], check=True, env=env
    )


# ------------------------------------------------------------------------------------------------
# executors
# ------------------------------------------------------------------------------------------------
def timed_call(fn: Callable[[Any], Any], item: Any) -> tuple[Any, float, int]:
    """Worker side: (fn(item), CPU seconds of the call, the worker's pid)."""
    c0 = time.process_time()
    result = fn(item)
    return result, time.process_time() - c0, os.getpid()


def make_executors(names: Sequence[str]) -> dict[str, tuple[Any, float]]:
    """(executor, start-up seconds) per name."""
    from skyrecon.sfm._pool import PersistentProcessExecutor

    out: dict[str, tuple[Any, float]] = {}
    for name in names:
        t0 = time.perf_counter()
        if name == "serial":
            ex: Any = SerialExecutor()
        elif name.startswith("process"):
            ex = PersistentProcessExecutor(int(name.split()[1]))
        else:
            from skyrecon.executor_dask import DaskExecutor

            ex = DaskExecutor(int(name.split()[1]))
        out[name] = (ex, time.perf_counter() - t0)
    return out


def close(ex: Any) -> None:
    if hasattr(ex, "close"):
        ex.close()


def cpu_figures(cpu: Sequence[float], pids: Sequence[int], serial_cpu: float | None) -> dict[str, Any]:
    per_worker: dict[int, float] = {}
    for c, p in zip(cpu, pids):
        per_worker[p] = per_worker.get(p, 0.0) + c
    busiest = max(per_worker.values()) if per_worker else 0.0
    return {
        "cpu_s": round(sum(cpu), 3),
        "cpu_per_item_s": round(sum(cpu) / max(1, len(cpu)), 3),
        "workers_used": len(per_worker),
        "busiest_worker_cpu_s": round(busiest, 3),
        "cpu_speedup": None if not serial_cpu or not busiest else round(serial_cpu / busiest, 2),
    }


def digest(arrays: Sequence[np.ndarray | None]) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(b"none" if a is None else np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


# ------------------------------------------------------------------------------------------------
# the stages
# ------------------------------------------------------------------------------------------------
def sfm_features(photos: Path, executors: dict[str, tuple[Any, float]], scratch: Path) -> dict[str, Any]:
    from skyrecon.sfm.extract import ExtractTask, extract_one
    from skyrecon.sfm.settings import SfMSettings

    settings = SfMSettings()
    paths = sorted((photos / "images").glob("*.png"))

    def tasks(cache: Path, subset: slice = slice(None)) -> list:
        cache.mkdir(parents=True, exist_ok=True)
        return [
            ExtractTask(k, str(p), p.name, settings.feature_settings, str(cache), settings.target_features)
            for k, p in list(enumerate(paths))[subset]
        ]

    rows: dict[str, Any] = {}
    serial_cpu = None
    for name, (ex, _) in executors.items():
        ex.map(extract_one, tasks(scratch / f"warm_{name}", slice(0, 2)))
        cache = scratch / f"sfm_{name.replace(' ', '')}"
        t0 = time.perf_counter()
        res = ex.map(functools.partial(timed_call, extract_one), tasks(cache), desc=f"features {name}")
        wall = time.perf_counter() - t0
        files = [r[0].cache_path for r in res]
        arrays = []
        for f in files:
            with np.load(f) as z:
                arrays += [z[k] for k in sorted(z.files)]
        cpu, pids = [r[1] for r in res], [r[2] for r in res]
        if name == "serial":
            serial_cpu = sum(cpu)
        rows[name] = {
            "wall_s": round(wall, 3),
            "items": len(res),
            "digest": digest(arrays),
            **cpu_figures(cpu, pids, serial_cpu),
        }
        print(f"  sfm features, {name}: {wall:.1f} s", flush=True)
    return rows


def mvs_depth(
    ring: Path, executors: dict[str, tuple[Any, float]], scratch: Path, size: int, threads: str
) -> dict[str, Any]:
    from skyrecon.mvs import depth_tasks
    from skyrecon.mvs.inputs import load_views_and_images
    from skyrecon.mvs.pipeline import _STEPS, _depth, _MVSRun
    from skyrecon.mvs.settings import MVSSettings

    if threads != "auto":
        depth_tasks._executor_threads = lambda executor: int(threads)  # type: ignore[assignment]
    views, _ = load_views_and_images(ring / "images", ring / "sparse")
    settings = MVSSettings(max_image_size=size)
    base = _MVSRun(list(views), None, settings, SerialExecutor(), False)
    for step in _STEPS:
        if step.name == "depth":
            break
        step.run(base)
    rows: dict[str, Any] = {}
    serial_cpu = None
    for name, (ex, _) in executors.items():
        warm_nb = [nb if k < 2 else [] for k, nb in enumerate(base.neighbors)]
        _depth(
            dataclasses.replace(base, executor=ex, neighbors=warm_nb, workspace=str(scratch / f"warm_{name}"))
        )
        run = dataclasses.replace(base, executor=ex, workspace=str(scratch / f"mvs_{name.replace(' ', '')}"))
        run.diagnostics, run.warnings = {}, []
        t0 = time.perf_counter()
        _depth(run)
        wall = time.perf_counter() - t0
        tm = run.diagnostics["depth_task_ms"]
        cpu, pids = [t["cpu"] / 1e3 for t in tm], [t["pid"] for t in tm]
        if name == "serial":
            serial_cpu = sum(cpu)
        rows[name] = {
            "wall_s": round(wall, 3),
            "items": len(tm),
            "digest": digest(run.depths),
            **cpu_figures(cpu, pids, serial_cpu),
        }
        print(f"  mvs depth, {name}: {wall:.1f} s", flush=True)
    return rows


# ------------------------------------------------------------------------------------------------
def summarize(rows: dict[str, Any]) -> dict[str, Any]:
    serial = rows.get("serial") or next(iter(rows.values()))  # speedups relative to the first when no serial
    for r in rows.values():
        r["speedup_vs_serial"] = round(serial["wall_s"] / r["wall_s"], 2)
    out: dict[str, Any] = {"identical": all(r["digest"] == serial["digest"] for r in rows.values())}
    if "dask 1" in rows and "dask 2" in rows:
        d1, d2 = rows["dask 1"], rows["dask 2"]
        out["dask2_over_dask1_wall"] = round(d1["wall_s"] / d2["wall_s"], 2)
        out["dask2_over_dask1_cpu"] = round(d1["busiest_worker_cpu_s"] / d2["busiest_worker_cpu_s"], 2)
    return out


def table(stage: str, rows: dict[str, Any], summary: dict[str, Any]) -> str:
    lines = [
        f"{stage}: identical outputs on every executor: {'yes' if summary['identical'] else 'NO'}",
        f"  {'executor':<10} {'wall s':>8} {'speedup':>8} {'task CPU s':>11} {'CPU/item s':>11} {'busiest s':>10} {'CPU speedup':>12}",
    ]
    for name, r in rows.items():
        lines.append(
            f"  {name:<10} {r['wall_s']:>8.2f} {r['speedup_vs_serial']:>8.2f} {r['cpu_s']:>11.2f} "
            f"{r['cpu_per_item_s']:>11.3f} {r['busiest_worker_cpu_s']:>10.2f} {r['cpu_speedup'] or 0:>12.2f}"
        )
    if "dask2_over_dask1_wall" in summary:
        lines.append(
            f"  dask 2 over dask 1: {summary['dask2_over_dask1_wall']:.2f}x wall, "
            f"{summary['dask2_over_dask1_cpu']:.2f}x by the busiest worker's CPU (target 1.7x)"
        )
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=1024, help="image width, pixels (default 1024; 4:3)")
    ap.add_argument("--views", type=int, default=16, help="images per set (default 16)")
    ap.add_argument("--stages", default="sfm,mvs", help="comma-separated: sfm, mvs (default both)")
    ap.add_argument("--executors", default="serial,process 2,dask 1,dask 2", help="comma-separated")
    ap.add_argument("--threads-per-task", default="1", help="PatchMatch threads per task: N or auto")
    ap.add_argument("--keep", type=Path, help="keep the inputs and workspaces here (reused on a rerun)")
    ap.add_argument("--results", type=Path, default=Path(__file__).with_name("results.json"))
    args = ap.parse_args()
    os.environ.setdefault("SKYRECON_PROGRESS", "0")
    work = args.keep or Path(tempfile.mkdtemp(prefix="skyrecon-scale-"))
    inputs = work / f"inputs_{args.size}_{args.views}"
    stages = args.stages.split(",")
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    if "sfm" in stages:
        render("images", args.views, args.size, inputs / "photos")
    if "mvs" in stages:
        render("ring", args.views, args.size, inputs / "ring")
    print(f"inputs ready in {time.perf_counter() - t0:.0f} s ({inputs})", flush=True)
    executors = make_executors(args.executors.split(","))
    startup = {name: round(s, 2) for name, (_, s) in executors.items()}
    doc: dict[str, Any] = {
        "benchmark": "executors",
        "size_px": [args.size, args.size * 3 // 4],
        "views": args.views,
        "threads_per_task": args.threads_per_task,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "loadavg_before": load0},
        "startup_s": startup,
    }
    scratch = work / f"runs_{int(time.time())}"
    try:
        if "sfm" in stages:
            rows = sfm_features(inputs / "photos", executors, scratch)
            doc["sfm_features"] = {"executors": rows, **summarize(rows)}
        if "mvs" in stages:
            rows = mvs_depth(inputs / "ring", executors, scratch, args.size, args.threads_per_task)
            doc["mvs_depth"] = {"executors": rows, **summarize(rows)}
    finally:
        for ex, _ in executors.values():
            close(ex)
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)
        else:
            shutil.rmtree(scratch, ignore_errors=True)
    doc["machine"]["loadavg_after"] = os.getloadavg()
    print(f"\n{args.views} views at {args.size}x{args.size * 3 // 4}, {os.cpu_count()} CPUs, load average "
          f"{load0[0]:.1f} before / {doc['machine']['loadavg_after'][0]:.1f} after; start-up s: {startup}")  # fmt: skip
    for key, stage in (("sfm_features", "sfm feature extraction"), ("mvs_depth", "mvs per-view depth")):
        if key in doc:
            print(table(stage, doc[key]["executors"], doc[key]))
    args.results.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"wrote {args.results}")
    ok = all(doc[k]["identical"] for k in ("sfm_features", "mvs_depth") if k in doc)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
