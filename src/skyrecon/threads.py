"""Limit the threads of OpenBLAS, OpenCV and Numba's parallel kernels inside a block.

* :func:`limited_threads` (OpenBLAS and OpenCV): structure from motion fans work out over
  processes and runs many small dense solves; threaded BLAS then only oversubscribes the cores
  (and OpenBLAS threads spin badly on a busy machine: a 400 x 400 Cholesky factorisation can
  take a second instead of a millisecond). The OpenBLAS libraries loaded in the process (numpy's
  and scipy's) are found in ``/proc/self/maps`` and set through their ``*_set_num_threads``
  entry points; elsewhere this is a no-op.
* :func:`kernel_threads` (Numba): the delivery loop runs its parallel kernels (depth
  integration, the distance field) on one thread. Each of them does a millisecond or two of work
  per frame, and a parallel region waits for its slowest thread: on a 2-core machine a worker
  thread that is descheduled (another process, the simulator's renderer) stalls the region by a
  scheduler slice. Flown alone on dynamic seed 102 with 2 threads, depth integration took 1.1 ms
  at the median and 50-57 ms on 4 of 275 cycles (its block classification 0.1 -> 15.8 ms, its
  update 1.1 -> 32 ms), the loop p99 102 ms; on one thread the median loop is the same (18.9 ms)
  and its p99 33-35 ms.
* :func:`blas_threads` (OpenBLAS): the loop's matrix products (a frame's points into the world:
  (N, 3) @ (3, 3), N up to 77 000) go to a threaded OpenBLAS, whose calling thread spins until
  its workers are done. Two missions at a time on 2 cores, the mover detection of dynamic seed
  102 took 60-90 ms (40 ms of its own CPU) on 7 cycles where the camera looked down at more
  ground, against 10-13 ms alone; with one OpenBLAS thread, 11-25 ms under the same load.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
from collections.abc import Iterator

import cv2
import numba

__all__ = ["blas_threads", "kernel_threads", "limited_threads"]

_NAMES = (
    ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
    ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
    ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
    ("openblas_get_num_threads", "openblas_set_num_threads"),
)
_libs: list | None = None


def _openblas() -> list:
    global _libs
    if _libs is not None:
        return _libs
    found = []
    try:
        with open("/proc/self/maps", encoding="utf-8") as f:
            paths = sorted({ln.split()[-1] for ln in f if "openblas" in ln.lower() and ".so" in ln})
    except OSError:
        paths = []
    for p in paths:
        try:
            lib = ctypes.CDLL(p)
        except OSError:
            continue
        for get, put in _NAMES:
            if hasattr(lib, get) and hasattr(lib, put):
                g, s = getattr(lib, get), getattr(lib, put)
                g.restype = ctypes.c_int
                s.argtypes = [ctypes.c_int]
                found.append((g, s))
                break
    _libs = found
    return found


@contextlib.contextmanager
def blas_threads(n: int | None) -> Iterator[None]:
    """Run the block with at most ``n`` OpenBLAS threads (None or 0: as they are); restore them
    afterwards. OpenBLAS's count is the whole process's."""
    want = int(n or 0)
    libs = _openblas() if want else []
    before: list[int | None] = []
    for g, s in libs:
        try:
            before.append(int(g()))
            s(want)
        except Exception:  # pragma: no cover - exotic builds
            before.append(None)
    try:
        yield
    finally:
        for (_, s), b in zip(libs, before):
            if b is not None:
                try:
                    s(b)
                except Exception:  # pragma: no cover
                    pass


@contextlib.contextmanager
def limited_threads(n: int = 1) -> Iterator[None]:
    """Run the block with at most ``n`` OpenBLAS and OpenCV threads; restore them afterwards."""
    cv_before = cv2.getNumThreads()
    with blas_threads(n):
        cv2.setNumThreads(int(n))
        try:
            yield
        finally:
            cv2.setNumThreads(cv_before)


def available_cores() -> int:
    """Cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@contextlib.contextmanager
def kernel_threads(n: int | None) -> Iterator[None]:
    """Run the block's Numba parallel kernels on at most ``n`` threads (None or 0: all of
    Numba's threads); restore the count afterwards. Numba's count is per calling thread, so
    other threads' kernels are not affected."""
    before = numba.get_num_threads()
    most = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]  # set from the environment at import
    numba.set_num_threads(min(int(n), most) if n else most)
    try:
        yield
    finally:
        numba.set_num_threads(before)
