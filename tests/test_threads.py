"""Thread limits: Numba's per-thread count is set inside the block and restored after it."""

import threading

import numba
import numpy as np
from numba import njit, prange

from skyrecon.threads import kernel_threads, limited_threads


@njit(parallel=True, cache=False)
def _threads_used(n: int) -> np.ndarray:
    out = np.zeros(n, np.int64)
    for i in prange(n):
        out[i] = numba.get_thread_id()
    return out


def test_kernel_threads_sets_and_restores_the_count():
    before = numba.get_num_threads()
    with kernel_threads(1):
        assert numba.get_num_threads() == 1
        assert set(_threads_used(64).tolist()) == {0}  # the kernel really ran on one thread
    assert numba.get_num_threads() == before
    with kernel_threads(0):  # 0: all of Numba's threads
        assert numba.get_num_threads() == numba.config.NUMBA_NUM_THREADS
    with kernel_threads(10_000):  # never more than Numba has
        assert numba.get_num_threads() == numba.config.NUMBA_NUM_THREADS
    assert numba.get_num_threads() == before


def test_kernel_threads_restores_after_an_error():
    before = numba.get_num_threads()
    try:
        with kernel_threads(1):
            raise RuntimeError("boom")
    except RuntimeError:
        pass
    assert numba.get_num_threads() == before


def test_kernel_threads_leaves_other_threads_alone():
    seen = []
    with kernel_threads(1):
        t = threading.Thread(target=lambda: seen.append(numba.get_num_threads()))
        t.start()
        t.join()
    assert seen == [numba.config.NUMBA_NUM_THREADS]


def test_limited_threads_restores_opencv():
    import cv2

    before = cv2.getNumThreads()
    with limited_threads(1):
        assert cv2.getNumThreads() == 1
    assert cv2.getNumThreads() == before


def test_blas_threads_sets_and_restores_openblas():
    from skyrecon.threads import _openblas, blas_threads

    libs = _openblas()
    if not libs:
        import pytest

        pytest.skip("no OpenBLAS loaded in this process (numpy built against another BLAS)")
    before = [g() for g, _ in libs]
    with blas_threads(1):
        assert all(g() == 1 for g, _ in libs)
    assert [g() for g, _ in libs] == before
    with blas_threads(0):  # 0: as they are
        assert [g() for g, _ in libs] == before
