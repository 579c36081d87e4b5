"""The process-tree meter counts a command's worker processes, not just the command."""

from __future__ import annotations

import sys

import pytest

from skyrecon.eval.process_tree import run_measured, tree_usage

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

_BUSY = "import time\nt = time.process_time()\nwhile time.process_time() - t < {s}: pass\n"


def test_cpu_of_an_unwaited_worker_is_counted():
    """The parent starts a busy child and exits without waiting for it to be reaped by anyone
    who reports its CPU (as a process pool's workers are): the tree sampler still sees it."""
    child = _BUSY.format(s=0.5)
    code = (
        "import subprocess, sys, time\n"
        f"p = subprocess.Popen([sys.executable, '-c', {child!r}])\n"
        "time.sleep(2.0)\n"
        "import os; os._exit(0)\n"
    )
    m = run_measured([sys.executable, "-c", code], interval_s=0.1)
    assert m.returncode == 0
    assert m.cpu_s >= 0.3
    assert m.wall_s >= 1.9
    assert m.peak_gb > 0.0


def test_a_failing_command_reports_its_status_and_error():
    m = run_measured([sys.executable, "-c", "import sys; sys.stderr.write('boom'); sys.exit(3)"])
    assert m.returncode == 3 and m.stderr_tail.endswith("boom")


def test_tree_usage_of_this_process():
    rss, cpu = tree_usage(__import__("os").getpid())
    assert rss > 10_000_000 and cpu > 0.0
