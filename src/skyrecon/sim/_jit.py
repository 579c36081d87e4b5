"""How simulator kernels are compiled and run in parallel.

Every kernel is compiled with ``cache=True`` (CI pays the compile once per cache directory,
``$NUMBA_CACHE_DIR``), ``fastmath=False`` (reproducible results) and ``error_model="numpy"``
(a division by zero gives inf/NaN instead of raising, which the slab tests rely on).

Kernels are *serial* functions over an index range ``[start, stop)`` that release the GIL;
:func:`run_chunks` spreads a range over a small thread pool. This compiles much faster than
``parallel=True`` (no parfor lowering) and scales the same on a few cores.

Numba's cache does not notice when a helper in *another* file changes, so each kernel
module keeps its helpers in the same file.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numba

_pool: ThreadPoolExecutor | None = None
_pool_pid = -1
_lock = threading.Lock()


def jit():
    """Decorator: ``numba.njit`` with the simulator's settings (serial, GIL released)."""
    return numba.njit(cache=True, fastmath=False, parallel=False, error_model="numpy", nogil=True)


def num_threads() -> int:
    """Threads used by :func:`run_chunks` (Numba's thread count, itself the CPU count by default)."""
    # numba.config sets its options at import time from the environment; its stubs do not list them
    return max(1, int(numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]  # see above


def _get_pool(threads: int) -> ThreadPoolExecutor:
    global _pool, _pool_pid
    with _lock:
        if _pool is None or _pool_pid != os.getpid():  # a forked child cannot reuse the parent's threads
            _pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="skyrecon-sim")
            _pool_pid = os.getpid()
        return _pool


def run_chunks(kernel, n: int, *args, min_chunk: int = 2048) -> None:
    """Call ``kernel(start, stop, *args)`` over ``[0, n)`` split in chunks, on a thread pool."""
    threads = num_threads()
    if threads == 1 or n < 2 * min_chunk:
        kernel(0, n, *args)
        return
    chunks = max(2, min(threads * 6, n // min_chunk))
    bounds = [n * k // chunks for k in range(chunks + 1)]
    pool = _get_pool(threads)
    futures = [pool.submit(kernel, a, b, *args) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
    for f in futures:
        f.result()
