"""Kill-safety checks: interrupt a command at a chosen moment, inspect what it left, resume it.

Used by the kill tests and ``benchmarks/faults/kill_resume.py``. A command's output folder after
an interruption must hold, for every visible file, either the complete file of an uninterrupted
run or nothing; hidden temporaries (``.name.<pid>.<random>.tmp``) are allowed until the next run
sweeps them. Files whose bytes legitimately differ between runs (they carry timings) are checked
for completeness instead: JSON must parse, HTML must end with ``</html>``. Workspace files
(checkpoints, cached task results: pickles, ``.npz``) must load.
"""

from __future__ import annotations

import json
import os
import pickle
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = [
    "InterruptOutcome",
    "KillTrial",
    "check_partial",
    "compare_outputs",
    "interrupt_command",
    "kill_and_resume",
    "output_files",
]

#: Files whose content carries timings (or run facts such as resumed-from): complete, not identical.
TIMED_NAMES = frozenset({"map_summary.json", "mvs.json", "sfm.json", "summary.json", "report.html"})


def _timed(rel: str) -> bool:
    return Path(rel).name in TIMED_NAMES


@dataclass
class InterruptOutcome:
    """What one interrupted run did.

    Attributes:
        returncode: the process's exit status (negative: killed by that signal; 0: it finished
            before the signal).
        signal_name: the signal sent; at_s: seconds after the start it was sent.
        stderr: what the command printed on stderr.
    """

    returncode: int
    signal_name: str
    at_s: float
    stderr: str


@dataclass
class PartialCheck:
    """Files found after an interruption (paths relative to the output folder)."""

    complete: list[str] = field(default_factory=list)
    broken: list[str] = field(default_factory=list)  # half-written or unreadable: must stay empty
    temporaries: list[str] = field(default_factory=list)  # hidden, swept by the next run


def interrupt_command(
    argv: Sequence[str],
    at_s: float,
    sig: int = signal.SIGKILL,
    env: dict | None = None,
    timeout_s: float = 600,
) -> InterruptOutcome:
    """Run ``python -m skyrecon ARGV``, send ``sig`` after ``at_s`` seconds, wait for it to end."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "skyrecon", *argv],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, **(env or {})},
        start_new_session=True,  # its workers form their own group: killed together below
        preexec_fn=_default_sigint,
    )
    t0 = time.monotonic()
    try:
        proc.wait(timeout=at_s)
    except subprocess.TimeoutExpired:
        proc.send_signal(sig)
        if sig == signal.SIGKILL:
            # a SIGKILL'd parent leaves its workers orphaned: a power cut takes them too
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
    _, err = proc.communicate(timeout=timeout_s)
    name = signal.Signals(sig).name
    return InterruptOutcome(proc.returncode, name, time.monotonic() - t0 if proc.returncode else at_s, err)


def _default_sigint() -> None:
    """In the child before exec: a shell starts background jobs with SIGINT ignored, and Python
    keeps an ignored SIGINT ignored; restore the default so that Ctrl-C is what it is for a user."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def output_files(folder: str | Path) -> list[str]:
    """Every file under ``folder``, relative, sorted (hidden ones included)."""
    root = Path(folder)
    if not root.is_dir():
        return []
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())


def _hidden(rel: str) -> bool:
    return any(part.startswith(".") for part in Path(rel).parts)


def _loads(path: Path) -> bool:
    try:
        if path.suffix == ".pkl":
            with open(path, "rb") as f:
                pickle.load(f)
        elif path.suffix == ".npz":
            with np.load(path) as z:
                for k in z.files:
                    z[k]
        elif path.suffix == ".json" or path.suffix == ".geojson":
            json.loads(path.read_text())
        elif path.suffix == ".html":
            return path.read_text().rstrip().endswith("</html>")
        else:
            return path.stat().st_size > 0
    except Exception:  # noqa: BLE001 - unreadable is the finding
        return False
    return True


def check_partial(folder: str | Path, reference: str | Path) -> PartialCheck:
    """Sort the files an interrupted run left in ``folder`` against an uninterrupted run's
    ``reference`` folder (see the module)."""
    folder, reference = Path(folder), Path(reference)
    found = PartialCheck()
    for rel in output_files(folder):
        path = folder / rel
        if _hidden(rel):
            found.temporaries.append(rel)
        elif rel.startswith("workspace/") or _timed(rel):
            (found.complete if _loads(path) else found.broken).append(rel)
        else:
            ref = reference / rel
            same = ref.is_file() and ref.read_bytes() == path.read_bytes()
            (found.complete if same else found.broken).append(rel)
    return found


def compare_outputs(folder: str | Path, reference: str | Path) -> list[str]:
    """Visible non-workspace files that differ between two complete runs (timed files are only
    required to exist in both), or exist in only one of them."""
    folder, reference = Path(folder), Path(reference)

    def visible(root: Path) -> set[str]:
        return {r for r in output_files(root) if not _hidden(r) and not r.startswith("workspace/")}

    a, b = visible(folder), visible(reference)
    diffs = sorted(a ^ b)
    for rel in sorted(a & b):
        if _timed(rel):
            continue
        if (folder / rel).read_bytes() != (reference / rel).read_bytes():
            diffs.append(rel)
    return diffs


@dataclass
class KillTrial:
    """One interruption and its resumption.

    Attributes:
        signal_name, at_s: what was sent, when (seconds after the start).
        exit_code: the interrupted run's exit status (0: it had finished already).
        exit_ok: the status is what the signal calls for (130 SIGINT, 143 SIGTERM, -9 SIGKILL) or 0.
        one_line: SIGINT/SIGTERM printed exactly one ``error:`` line (True for SIGKILL).
        broken: half-written or unreadable visible files found after the interruption.
        temporaries: hidden temporaries left (swept by the resumed run).
        resumed_code: exit status of the rerun with the same arguments.
        differences: files of the resumed outputs that differ from the uninterrupted run's.
        left_temporaries: hidden temporaries still there after the resumed run.
        resume_s: wall time of the resumed run.
        stderr: what the interrupted run printed on stderr (the last 600 characters), to tell
            what an extra line was.
    """

    signal_name: str
    at_s: float
    exit_code: int
    exit_ok: bool
    one_line: bool
    broken: list[str]
    temporaries: int
    resumed_code: int
    differences: list[str]
    left_temporaries: int
    resume_s: float
    stderr: str = ""

    @property
    def ok(self) -> bool:
        return (
            self.exit_ok
            and self.one_line
            and not self.broken
            and self.resumed_code == 0
            and not self.differences
            and self.left_temporaries == 0
        )


_EXPECTED = {"SIGINT": 130, "SIGTERM": 143, "SIGKILL": -9}


def kill_and_resume(
    argv: Sequence[str],
    out: str | Path,
    reference: str | Path,
    at_s: float,
    sig: int,
    env: dict | None = None,
) -> KillTrial:
    """Start ``skyrecon ARGV`` (writing to ``out``, which should not exist yet), interrupt it with
    ``sig`` after ``at_s`` s, check what it left against ``reference`` (the outputs of an
    uninterrupted run with the same arguments), rerun it to completion and compare."""
    got = interrupt_command(argv, at_s, sig, env)
    name = got.signal_name
    exit_ok = got.returncode in (0, _EXPECTED[name])
    lines = [ln for ln in got.stderr.strip().splitlines() if ln.strip()]
    one_line = (
        name == "SIGKILL" or got.returncode == 0 or (len(lines) == 1 and lines[0].startswith("error: "))
    )
    partial = check_partial(out, reference)
    t0 = time.monotonic()
    rerun = subprocess.run(
        [sys.executable, "-m", "skyrecon", *argv],
        capture_output=True,
        text=True,
        env={**os.environ, **(env or {})},
    )
    resume_s = time.monotonic() - t0
    left = [r for r in output_files(out) if _hidden(r)]
    return KillTrial(
        name,
        round(got.at_s, 2),
        got.returncode,
        exit_ok,
        one_line,
        partial.broken,
        len(partial.temporaries),
        rerun.returncode,
        compare_outputs(out, reference)
        if rerun.returncode == 0
        else ["(rerun failed) " + rerun.stderr[-300:]],
        len(left),
        round(resume_s, 2),
        got.stderr[-600:],
    )
