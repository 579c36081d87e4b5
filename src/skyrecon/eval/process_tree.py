"""What a command costs: wall time, CPU seconds and peak memory of its whole process tree.

Used by the benchmarks that run ``skyrecon`` as a subprocess (``benchmarks/survey``,
``benchmarks/scale/sfm_flight.py``). Worker processes (the sfm pool, Dask workers) count:
``RUSAGE_CHILDREN`` alone misses workers that are not waited for, so the tree is also sampled
from ``/proc`` (Linux) every ``interval_s`` and the larger CPU figure is kept. CPU seconds do not
depend on what else runs on the machine: CPU / cores is the wall time the command would take on
that many otherwise idle cores (if it keeps them busy).
"""

from __future__ import annotations

import os
import resource
import subprocess
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["Measured", "tree_usage", "run_measured"]


def tree_usage(pid: int) -> tuple[int, float]:
    """(sum of RSS bytes, sum of CPU seconds including reaped children) of ``pid`` and all its
    descendants, from ``/proc`` (0, 0.0 where ``/proc`` is missing)."""
    children: dict[int, list[int]] = {}
    rss: dict[int, int] = {}
    cpu: dict[int, float] = {}
    tck = os.sysconf("SC_CLK_TCK")
    page = os.sysconf("SC_PAGE_SIZE")
    try:
        entries = os.listdir("/proc")
    except OSError:
        return 0, 0.0
    for d in entries:
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                parts = f.read().rsplit(")", 1)[1].split()
            children.setdefault(int(parts[1]), []).append(int(d))
            rss[int(d)] = int(parts[21]) * page
            cpu[int(d)] = sum(int(x) for x in parts[11:15]) / tck
        except (OSError, IndexError, ValueError):
            continue
    total, seconds, todo = 0, 0.0, [pid]
    while todo:
        p = todo.pop()
        total += rss.get(p, 0)
        seconds += cpu.get(p, 0.0)
        todo.extend(children.get(p, []))
    return total, seconds


@dataclass(frozen=True)
class Measured:
    """One command's cost. ``peak_gb``: the largest sum of RSS over the tree seen by the sampler
    (GB, 1e9 bytes); ``cpu_s``: CPU seconds of the tree; ``stderr_tail``: the last 2000
    characters of its standard error (empty when not captured)."""

    returncode: int
    wall_s: float
    peak_gb: float
    cpu_s: float
    stderr_tail: str


def run_measured(
    cmd: Sequence[str], env: dict[str, str] | None = None, capture: bool = True, interval_s: float = 0.5
) -> Measured:
    """Run ``cmd`` to completion while sampling its process tree; see :class:`Measured`."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    pipe = subprocess.PIPE if capture else None
    proc = subprocess.Popen(list(cmd), stdout=pipe, stderr=pipe, text=True, env=env)
    peak = [0, 0.0]

    def sample() -> None:
        while proc.poll() is None:
            rss, cpu = tree_usage(proc.pid)
            peak[0] = max(peak[0], rss)
            peak[1] = max(peak[1], cpu)
            time.sleep(interval_s)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    _, err = proc.communicate()
    th.join()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return Measured(
        proc.returncode, time.perf_counter() - t0, peak[0] / 1e9, max(cpu, peak[1]), (err or "")[-2000:]
    )
