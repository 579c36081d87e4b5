"""Kill-safety of the long commands (map, mvs, sfm), through the real command line in a subprocess.

Each command is run once uninterrupted, then interrupted (SIGKILL of the whole process group,
SIGINT, SIGTERM) at fractions of that run's duration: what it left must be complete files or none,
and rerunning the same command must resume and give the uninterrupted run's outputs, byte for
byte (files that carry timings are only required to be complete). Any interruption point must
pass, so the timing of the signal does not make the test flaky. ``benchmarks/faults/kill_resume.py``
does the same at 20 points per command.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from skyrecon.eval.interrupt import compare_outputs, kill_and_resume

ENV = {"SKYRECON_PROGRESS": "0", "SKYRECON_CHECKPOINT_S": "0"}  # checkpoint after every frame


def _skyrecon(*argv: str) -> float:
    """Run to completion; returns the wall time (s)."""
    t0 = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "skyrecon", *argv], capture_output=True, text=True, env={**os.environ, **ENV}
    )
    assert proc.returncode == 0, proc.stderr
    return time.monotonic() - t0


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("kill_inputs")
    common = ["--width", "320", "--height", "240", "--quiet"]
    _skyrecon("render", "sequence", "--frames", "20", "--out", str(d / "flight"), "--quiet")
    _skyrecon("render", "ring", "--views", "6", "--out", str(d / "ring"), *common)
    _skyrecon(
        "render",
        "images",
        "--views",
        "12",
        "--width",
        "480",
        "--height",
        "360",
        "--out",
        str(d / "photos"),
        "--quiet",
    )
    return d


def _argv(command: str, d: Path, out: Path) -> list[str]:
    if command == "map":
        return ["map", str(d / "flight"), "--out", str(out), "--quiet"]
    if command == "mvs":
        return ["mvs", str(d / "ring" / "images"), "--cameras", str(d / "ring" / "sparse"), "--out", str(out)]
    return ["sfm", str(d / "photos" / "images"), "--camera", str(d / "photos" / "K.txt"), "--out", str(out)]


@pytest.mark.parametrize("command", ["map", "mvs", "sfm"])
def test_interrupted_runs_leave_complete_files_and_resume_identically(inputs, tmp_path, command):
    reference = tmp_path / "reference"
    argv_ref = _argv(command, inputs, reference) + ["--quiet", "--workers", "2"] * (command != "map")
    seconds = _skyrecon(*argv_ref)
    plan = [(0.4, signal.SIGKILL), (0.7, signal.SIGINT)] + (
        [(0.5, signal.SIGTERM)] if command == "mvs" else []
    )
    for k, (fraction, sig) in enumerate(plan):
        out = tmp_path / f"run{k}"
        argv = _argv(command, inputs, out) + ["--quiet", "--workers", "2"] * (command != "map")
        trial = kill_and_resume(argv, out, reference, fraction * seconds, sig, ENV)
        assert trial.exit_ok, trial
        assert trial.one_line, trial
        assert trial.broken == [], trial
        assert trial.resumed_code == 0 and trial.differences == [], trial
        assert trial.left_temporaries == 0, trial


def test_same_arguments_same_bytes_serial_and_process(inputs, tmp_path):
    """Determinism: mvs and sfm with one worker (serial) and with two worker processes."""
    for command in ("mvs", "sfm"):
        a, b = tmp_path / f"{command}_serial", tmp_path / f"{command}_process"
        _skyrecon(*_argv(command, inputs, a), "--quiet", "--workers", "1")
        _skyrecon(*_argv(command, inputs, b), "--quiet", "--workers", "2")
        assert compare_outputs(a, b) == [], command
