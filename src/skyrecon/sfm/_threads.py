"""Limit the threads of OpenBLAS and OpenCV inside a block.

Structure from motion fans work out over processes and runs many small dense solves; threaded
BLAS then only oversubscribes the cores (and OpenBLAS threads spin badly on a busy machine:
a 400 x 400 Cholesky factorisation can take a second instead of a millisecond). The OpenBLAS
libraries loaded in the process (numpy's and scipy's) are found in ``/proc/self/maps`` and set
through their ``*_set_num_threads`` entry points; elsewhere this is a no-op.
"""

from __future__ import annotations

import contextlib
import ctypes
from collections.abc import Iterator

import cv2

__all__ = ["limited_threads"]

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
def limited_threads(n: int = 1) -> Iterator[None]:
    """Run the block with at most ``n`` OpenBLAS and OpenCV threads; restore them afterwards."""
    libs = _openblas()
    before: list[int | None] = []
    for g, s in libs:
        try:
            before.append(int(g()))
            s(int(n))
        except Exception:  # pragma: no cover - exotic builds
            before.append(None)
    cv_before = cv2.getNumThreads()
    cv2.setNumThreads(int(n))
    try:
        yield
    finally:
        cv2.setNumThreads(cv_before)
        for (_, s), b in zip(libs, before):
            if b is not None:
                try:
                    s(b)
                except Exception:  # pragma: no cover
                    pass
