"""Faults on the ground: kill each long command at 20 points, check what it left, resume it.

For ``map`` (a stereo sequence), ``mvs`` (a ring of views) and ``sfm`` (an orbit of photos), each on
inputs rendered here: one uninterrupted run gives the reference outputs and duration; then 20 runs
from an empty output folder are interrupted at 20 evenly spread moments (2.5 % to 97.5 % of the
reference duration), the signal rotating SIGKILL (the whole process group, as a power cut),
SIGINT (Ctrl-C) and SIGTERM. After each interruption the outputs are checked (every visible file
complete and identical to the reference's, or absent; checkpoints and cached results loadable),
then the same command is rerun and must give the reference outputs byte for byte (files carrying
timings: complete) and leave no temporary. Finally each command runs twice more with the same
arguments, serial (``--workers 1``) and with 2 worker processes, and every output must match.

Targets (issue "Faults in flight and on the ground"): 0 half-written files; resumed results
identical to uninterrupted ones; same arguments, byte-identical outputs across executors.

Usage:
  .venv/bin/python benchmarks/faults/kill_resume.py               # 20 points per command
  .venv/bin/python benchmarks/faults/kill_resume.py --points 5 --commands map

Writes ``benchmarks/faults/results_kill_resume.json`` (the commands run replace their entries).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from skyrecon.eval.interrupt import compare_outputs, kill_and_resume  # noqa: E402
from skyrecon.io.atomic import write_text_atomic  # noqa: E402

ENV = {"SKYRECON_PROGRESS": "0", "SKYRECON_CHECKPOINT_S": "1"}  # map: a checkpoint every second
SIGNALS = [signal.SIGKILL, signal.SIGINT, signal.SIGTERM]


def skyrecon(*argv: str) -> float:
    t0 = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "skyrecon", *argv], capture_output=True, text=True, env={**os.environ, **ENV}
    )
    if proc.returncode != 0:
        raise SystemExit(f"skyrecon {' '.join(argv)} failed: {proc.stderr.strip()}")
    return time.monotonic() - t0


def render_inputs(d: Path) -> None:
    if not (d / "flight" / "poses.txt").is_file():
        skyrecon("render", "sequence", "--frames", "40", "--seed", "3", "--out", str(d / "flight"), "--quiet")
    if not (d / "ring" / "sparse").is_dir():
        skyrecon("render", "ring", "--views", "10", "--width", "480", "--height", "360", "--seed", "5",
                 "--out", str(d / "ring"), "--quiet")  # fmt: skip
    if not (d / "photos" / "K.txt").is_file():
        skyrecon("render", "images", "--views", "16", "--width", "480", "--height", "360", "--seed", "7",
                 "--out", str(d / "photos"), "--quiet")  # fmt: skip


def argv_of(command: str, d: Path, out: Path, workers: int = 2) -> list[str]:
    if command == "map":
        return ["map", str(d / "flight"), "--out", str(out), "--quiet"]
    if command == "mvs":
        return ["mvs", str(d / "ring" / "images"), "--cameras", str(d / "ring" / "sparse"), "--out", str(out),
                "--workers", str(workers), "--quiet"]  # fmt: skip
    return ["sfm", str(d / "photos" / "images"), "--camera", str(d / "photos" / "K.txt"), "--out", str(out),
            "--workers", str(workers), "--quiet"]  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=20, help="interruptions per command (default 20)")
    ap.add_argument("--commands", nargs="+", default=["map", "mvs", "sfm"], choices=["map", "mvs", "sfm"])
    ap.add_argument("--work", default=str(ROOT / "benchmarks" / "faults" / "out_kill"))
    args = ap.parse_args()
    work = Path(args.work)
    inputs = work / "inputs"
    render_inputs(inputs)
    results: dict[str, dict] = {}
    for command in args.commands:
        reference = work / command / "reference"
        shutil.rmtree(work / command, ignore_errors=True)
        seconds = skyrecon(*argv_of(command, inputs, reference))
        trials = []
        for k in range(args.points):
            at = seconds * (k + 0.5) / args.points
            sig = SIGNALS[k % len(SIGNALS)]
            out = work / command / f"run{k:02d}"
            trial = kill_and_resume(argv_of(command, inputs, out), out, reference, at, sig, ENV)
            trials.append(trial)
            print(
                f"{command} {k + 1:2d}/{args.points}: {trial.signal_name:7s} at {at:5.1f} s -> exit "
                f"{trial.exit_code:4d}, broken {len(trial.broken)}, temporaries {trial.temporaries}, "
                f"resumed in {trial.resume_s:.1f} s ({trial.resume_s / seconds:.0%} of a full run), "
                f"differences {len(trial.differences)} {'ok' if trial.ok else 'FAIL'}",
                flush=True,
            )
            shutil.rmtree(out, ignore_errors=True)
        determinism: list[str] = []
        if command != "map":  # map has no worker processes
            a, b = work / command / "serial", work / command / "process"
            skyrecon(*argv_of(command, inputs, a, workers=1))
            skyrecon(*argv_of(command, inputs, b, workers=2))
            determinism = compare_outputs(a, b)
        results[command] = {
            "reference_s": round(seconds, 2),
            "points": args.points,
            "failed": sum(not t.ok for t in trials),
            "half_written_files": sum(len(t.broken) for t in trials),
            "resumed_differences": sum(len(t.differences) for t in trials),
            "temporaries_after_resume": sum(t.left_temporaries for t in trials),
            "resume_s_median": sorted(t.resume_s for t in trials)[len(trials) // 2],
            "serial_vs_process_differences": determinism,
            "trials": [asdict(t) for t in trials],
        }
        r = results[command]
        print(
            f"== {command}: {args.points - r['failed']}/{args.points} ok, half-written files {r['half_written_files']}, "
            f"resumed outputs differing {r['resumed_differences']}, serial vs process differences "
            f"{len(determinism)} (reference run {seconds:.1f} s)",
            flush=True,
        )
    out_json = ROOT / "benchmarks" / "faults" / "results_kill_resume.json"
    earlier = json.loads(out_json.read_text()) if out_json.is_file() else {}
    earlier.update(results)  # a run of some commands keeps the others' latest results
    write_text_atomic(out_json, json.dumps(earlier, indent=2) + "\n")
    print(f"wrote {out_json}")
    return (
        0 if all(r["failed"] == 0 and not r["serial_vs_process_differences"] for r in results.values()) else 1
    )


if __name__ == "__main__":
    sys.exit(main())
