"""One interface for fanning out per-item work (per image, per pair, per view).

Stages call ``executor.map(fn, items)`` and never care where the work runs.
``SerialExecutor`` runs in-process (debugging, tiny inputs); ``ProcessExecutor``
uses local worker processes; ``DaskExecutor`` (:mod:`skyrecon.executor_dask`, the ``dask``
extra) runs on a Dask cluster or a local one. Another cluster engine plugs in by implementing
:class:`Executor` (one method) and registering it with :func:`register_executor`.

``fn`` must be picklable (a module-level function or a ``functools.partial`` of
one) for process execution. Results come back in input order.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Protocol, TypeVar

from skyrecon.errors import InputError
from skyrecon.progress import progress

T = TypeVar("T")
R = TypeVar("R")


class Executor(Protocol):
    """Runs ``fn`` over items and returns the results in input order."""

    def map(self, fn: Callable[[T], R], items: Iterable[T], *, desc: str | None = None) -> list[R]: ...


class SerialExecutor:
    """Runs every item in this process, in order. Exceptions surface unchanged."""

    workers = 1

    def map(self, fn: Callable[[T], R], items: Iterable[T], *, desc: str | None = None) -> list[R]:
        items = list(items)
        return [fn(item) for item in progress(items, desc=desc, total=len(items))]


class ProcessExecutor:
    """Runs items on local worker processes (``forkserver`` start, safe with Numba threads).

    Args:
        workers: number of processes; default ``os.cpu_count()``.
        max_tasks_in_flight: bound on queued items so memory stays bounded
            when items are large (default ``4 * workers``).
    """

    def __init__(self, workers: int | None = None, max_tasks_in_flight: int | None = None):
        self.workers = max(1, workers or os.cpu_count() or 1)
        self.max_tasks_in_flight = max_tasks_in_flight or 4 * self.workers

    def map(self, fn: Callable[[T], R], items: Iterable[T], *, desc: str | None = None) -> list[R]:
        items = list(items)
        if self.workers == 1 or len(items) <= 1:
            return SerialExecutor().map(fn, items, desc=desc)
        ctx = multiprocessing.get_context("forkserver")
        results: list = [None] * len(items)
        children_before = set(multiprocessing.active_children())
        with ProcessPoolExecutor(
            max_workers=min(self.workers, len(items)), mp_context=ctx, initializer=_ignore_sigint
        ) as pool:
            pending: dict = {}
            next_index = 0
            bar = progress(total=len(items), desc=desc)
            try:
                while next_index < len(items) or pending:
                    while next_index < len(items) and len(pending) < self.max_tasks_in_flight:
                        pending[pool.submit(fn, items[next_index])] = next_index
                        next_index += 1
                    done = next(iter(_wait_first(pending)))
                    index = pending.pop(done)
                    results[index] = done.result()  # re-raises the worker's exception
                    bar.update(1)
            except BaseException as exc:
                if isinstance(exc, Exception):
                    for fut in pending:
                        fut.cancel()
                else:  # interrupted (Ctrl-C, SIGTERM): stop the workers now
                    _stop_workers(pool, children_before)
                raise
            finally:
                bar.close()
        return results


def _ignore_sigint() -> None:
    """Worker initializer: Ctrl-C reaches the whole process group; only the parent handles it
    (it stops the workers), so workers print no tracebacks of their own. A worker also ends itself
    once orphaned (:func:`exit_when_orphaned`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=exit_when_orphaned, name="skyrecon-orphan-watch", daemon=True).start()


#: how often a worker checks that the process that started it is still there, seconds
ORPHAN_POLL_S = 0.5


def exit_when_orphaned(
    poll_s: float = ORPHAN_POLL_S,
    parent_pid: Callable[[], int] = os.getppid,
    exit_now: Callable[[int], object] = os._exit,
    sleep: Callable[[float], object] = time.sleep,
) -> None:
    """Run in a worker's daemon thread: end the worker as soon as its parent is gone.

    A worker is forked by the forkserver, which ends when the program does. An interruption can
    reach the program while the pool is starting a worker (after the fork, before the pool records
    it); nothing then stops that worker, which waits on the pool's queue for ever, holding the
    program's stderr open (whoever waits for the program's output, a shell pipe or CI, waits with
    it: a 10 min hang seen in CI on an mvs run terminated at half time). When the parent changes
    (the worker was re-parented), the worker exits at once with status 1.
    """
    first = parent_pid()
    while True:
        sleep(poll_s)
        if parent_pid() != first:
            exit_now(1)
            return


def _stop_workers(pool: ProcessPoolExecutor, children_before: set) -> None:
    """Terminate a pool's workers at once instead of waiting for their running items.

    The queued items are cancelled by the pool's own manager thread (``cancel_futures``), never
    from here: on Python 3.11 a future cancelled from this thread can still be in the pool's
    pending table when the manager sees the terminated workers, and its ``set_exception`` on the
    cancelled future raises ``InvalidStateError`` in that thread (a traceback after the one-line
    interruption message, seen in CI on mvs).

    The workers are the children this process started since ``children_before`` (taken before
    the pool), not the pool's own table: an interruption between a worker's start and the pool
    recording it leaves a worker the table does not hold, and the interpreter's exit joins every
    child it started (a hang)."""
    workers = [p for p in multiprocessing.active_children() if p not in children_before]
    # items still queued for the killed workers must not hold the exit: the queue's feeder thread
    # blocks on a full pipe nobody reads, and interpreter exit joins it (a hang seen in CI on mvs)
    call_queue = getattr(pool, "_call_queue", None)
    if call_queue is not None:
        call_queue.cancel_join_thread()
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in workers:
        proc.terminate()


def _wait_first(pending: dict) -> set:
    done, _ = wait(list(pending), return_when=FIRST_COMPLETED)
    return done


def _dask_executor(workers: int | None) -> Executor:
    """The Dask executor (:mod:`skyrecon.executor_dask`), imported only when asked for: Dask is an
    optional extra and slow to import. The scheduler comes from ``$SKYRECON_SCHEDULER`` (else a
    ``LocalCluster`` of ``workers`` processes)."""
    from skyrecon.executor_dask import DaskExecutor

    return DaskExecutor(workers)


_REGISTRY: dict[str, Callable[[int | None], Executor]] = {
    "serial": lambda workers: SerialExecutor(),
    "process": lambda workers: ProcessExecutor(workers),
    "dask": _dask_executor,
}


def register_executor(name: str, factory: Callable[[int | None], Executor]) -> None:
    """Make ``get_executor(name)`` return ``factory(workers)`` (e.g. a cluster engine)."""
    _REGISTRY[name] = factory


def available_executors() -> Sequence[str]:
    return sorted(_REGISTRY)


def get_executor(kind: str | None = None, workers: int | None = None) -> Executor:
    """The executor named ``kind`` (``serial``, ``process``, ``dask`` or a registered one).

    ``None`` reads ``$SKYRECON_EXECUTOR`` and defaults to ``process``; ``workers``
    defaults to ``$SKYRECON_WORKERS`` or the CPU count.
    """
    kind = kind or os.environ.get("SKYRECON_EXECUTOR", "process")
    if workers is None and os.environ.get("SKYRECON_WORKERS"):
        try:
            workers = int(os.environ["SKYRECON_WORKERS"])
        except ValueError:
            raise InputError(
                f"SKYRECON_WORKERS must be an integer, got {os.environ['SKYRECON_WORKERS']!r}"
            ) from None
    if kind not in _REGISTRY:
        raise InputError(f"unknown executor {kind!r}; choose one of {', '.join(available_executors())}")
    return _REGISTRY[kind](workers)
