"""A local process pool kept alive for the whole run (features, then matching).

:class:`skyrecon.executor.ProcessExecutor` starts a fresh pool for every ``map`` call; on a busy
two-core machine each start (forkserver + imports in every worker) costs seconds. When the
caller did not choose an executor and the configured one is the local process executor,
``run_sfm`` uses this pool instead: the same interface (``map(fn, items, desc=...)``, results in
input order, worker exceptions re-raised), the same worker count, started once, with the SfM
modules preloaded in the fork server.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any

from skyrecon.executor import ProcessExecutor
from skyrecon.progress import progress

__all__ = ["PersistentProcessExecutor", "run_scoped_executor"]

_PRELOAD = ["numpy", "cv2", "skyrecon.sfm.extract", "skyrecon.sfm.matching"]


class PersistentProcessExecutor:
    """Local worker processes reused across ``map`` calls until :meth:`close`.

    Args:
        workers: number of processes.
        max_tasks_in_flight: bound on queued items (default ``4 * workers``).
    """

    def __init__(self, workers: int, max_tasks_in_flight: int | None = None) -> None:
        self.workers = max(1, int(workers))
        self.max_tasks_in_flight = max_tasks_in_flight or 4 * self.workers
        self._pool: ProcessPoolExecutor | None = None

    def _get(self) -> ProcessPoolExecutor:
        if self._pool is None:
            ctx = multiprocessing.get_context("forkserver")
            try:
                ctx.set_forkserver_preload(_PRELOAD)
            except Exception:  # pragma: no cover - platforms without forkserver settings
                pass
            self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=ctx)
        return self._pool

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any], *, desc: str | None = None) -> list[Any]:
        items = list(items)
        if len(items) == 0:
            return []
        pool = self._get()
        results: list = [None] * len(items)
        pending: dict = {}
        nxt = 0
        bar = progress(total=len(items), desc=desc)
        try:
            while nxt < len(items) or pending:
                while nxt < len(items) and len(pending) < self.max_tasks_in_flight:
                    pending[pool.submit(fn, items[nxt])] = nxt
                    nxt += 1
                done, _ = wait(list(pending), return_when=FIRST_COMPLETED)
                for f in done:
                    results[pending.pop(f)] = f.result()
                    bar.update(1)
        except BaseException:
            for f in pending:
                f.cancel()
            raise
        finally:
            bar.close()
        return results

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def __enter__(self) -> PersistentProcessExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def run_scoped_executor(executor: Any) -> tuple[Any, Callable[[], None]]:
    """The executor to use for one run and how to release it: a plain local
    :class:`ProcessExecutor` with several workers is replaced by a persistent pool of the same
    size; anything else (serial, registered cluster engines) is used as it is."""
    if type(executor) is ProcessExecutor and executor.workers > 1:
        pool = PersistentProcessExecutor(executor.workers, executor.max_tasks_in_flight)
        return pool, pool.close
    return executor, lambda: None
