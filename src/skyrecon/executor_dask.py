"""A Dask executor: per-item work on a Dask cluster, or on a ``LocalCluster`` started for the run.

``DaskExecutor(workers, scheduler)`` implements :class:`skyrecon.executor.Executor` (results in
input order, at most ``max_tasks_in_flight`` tasks submitted at a time, a progress bar) and is
registered as ``"dask"`` by :mod:`skyrecon.executor` without importing Dask at skyrecon import
time. Dask is an optional extra: ``pip install 'skyrecon[dask]'``.

* ``scheduler=None`` (and no ``$SKYRECON_SCHEDULER``): a ``LocalCluster`` of ``workers`` single-threaded
  worker processes (dashboard on a free port), each with this process's ``NUMBA_CACHE_DIR`` so that they load the
  kernels compiled once (``skyrecon warmup``) instead of compiling them again. :meth:`close` (or
  leaving the ``with`` block, or Ctrl-C during :meth:`map`) tears it down.
* ``scheduler="tcp://host:8786"``: joins that running cluster (short connect timeout,
  ``$SKYRECON_SCHEDULER_TIMEOUT`` seconds, default 5). An unreachable scheduler, or workers that run
  another skyrecon, is an :class:`~skyrecon.errors.InputError` naming the address and what to do.
  The run's workspace (``--workspace``, ``--out``) must then be on a filesystem the workers share:
  they read their inputs there and write their large results there.

Large results: :func:`skyrecon.io.task_cache.map_cached` sees ``results_via_files`` and has each
worker leave its result in the workspace file it already writes for resume, returning only
the path (so depth maps do not travel as pickled task results). Items over ``scatter_bytes`` are
scattered to the cluster rather than embedded in the task graph (and sent again if the worker
holding one dies).

Lost workers: a task whose worker dies is run again elsewhere by the scheduler (up to Dask's
``distributed.scheduler.allowed-failures`` times, then a :class:`~skyrecon.errors.SkyreconError`
that says so); a task that raises is retried ``retries`` times (Dask ``retries=``) before its
exception surfaces. Tasks are pure functions of their item, so a rerun gives the same bytes.
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
import os
import pickle
import time
import uuid
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar

from skyrecon.errors import InputError, SkyreconError
from skyrecon.progress import progress

__all__ = ["DaskExecutor", "DaskUnavailable", "INSTALL_HINT", "code_fingerprint"]

T = TypeVar("T")
R = TypeVar("R")

INSTALL_HINT = "pip install 'skyrecon[dask]'"
SCHEDULER_ENV = "SKYRECON_SCHEDULER"
TIMEOUT_ENV = "SKYRECON_SCHEDULER_TIMEOUT"
DEFAULT_CONNECT_TIMEOUT_S = 5.0


class DaskUnavailable(InputError):
    """``--executor dask`` without Dask installed."""


def _require_distributed() -> None:
    if importlib.util.find_spec("distributed") is None or importlib.util.find_spec("dask") is None:
        raise DaskUnavailable(f"the dask executor needs Dask's distributed scheduler: {INSTALL_HINT}")


def _connect_timeout() -> float:
    text = os.environ.get(TIMEOUT_ENV)
    if not text:
        return DEFAULT_CONNECT_TIMEOUT_S
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"{TIMEOUT_ENV} must be a number of seconds, got {text!r}") from None
    if not value > 0:
        raise InputError(f"{TIMEOUT_ENV} must be a positive number of seconds, got {text!r}")
    return value


def code_fingerprint() -> str:
    """skyrecon's version and a hash (12 hex digits) of its Python sources: two processes with the
    same fingerprint run the same code."""
    import skyrecon

    root = Path(skyrecon.__file__).resolve().parent
    h = hashlib.sha1()
    for path in sorted(root.rglob("*.py")):
        h.update(path.relative_to(root).as_posix().encode())
        h.update(path.read_bytes())
    return f"{skyrecon.__version__}+{h.hexdigest()[:12]}"


def _scatter(client: Any, item: Any, attempts: int = 6) -> Any:
    """``client.scatter(item)``, tried again when the worker it went to has just died (its
    connection closes under the scatter: OSError/CommClosedError); the cluster replaces the worker."""
    for attempt in range(attempts):
        try:
            return client.scatter(item, hash=False)
        except OSError:
            if attempt == attempts - 1:
                raise SkyreconError(
                    f"could not send a work item to the cluster's workers ({attempts} tries): are they alive?"
                ) from None
            time.sleep(0.25 * (attempt + 1))
    raise AssertionError("unreachable")


class DaskExecutor:
    """Runs items as Dask tasks; see the module docstring.

    Args:
        workers: worker processes of the ``LocalCluster`` (default ``os.cpu_count()``); ignored
            with a scheduler (the cluster's worker threads are counted instead).
        scheduler: address of a running scheduler (``tcp://host:8786``); default
            ``$SKYRECON_SCHEDULER``, else a ``LocalCluster``.
        max_tasks_in_flight: bound on submitted, unfinished tasks (default ``4 * workers``).
        retries: extra attempts of a task that raised (Dask ``retries=``).
        scatter_bytes: items whose pickle is larger are scattered to the cluster first.
        connect_timeout_s: seconds to reach the scheduler (default ``$SKYRECON_SCHEDULER_TIMEOUT`` or 5).
    Raises:
        InputError: Dask is not installed (the message says how to install it), the scheduler
            cannot be reached, or its workers run another skyrecon.
    """

    #: map_cached: workers leave large results in the workspace and return their path
    results_via_files = True

    def __init__(
        self,
        workers: int | None = None,
        scheduler: str | None = None,
        *,
        max_tasks_in_flight: int | None = None,
        retries: int = 1,
        scatter_bytes: int = 1 << 20,
        connect_timeout_s: float | None = None,
    ) -> None:
        _require_distributed()
        self.scheduler = scheduler or os.environ.get(SCHEDULER_ENV) or None
        self.retries = max(0, int(retries))
        self.scatter_bytes = int(scatter_bytes)
        self._cluster: Any = None
        self._client: Any = None
        timeout = connect_timeout_s if connect_timeout_s is not None else _connect_timeout()
        if self.scheduler:
            self._client = _connect(self.scheduler, timeout)
            self.workers = max(1, sum(self._client.nthreads().values()))
        else:
            self.workers = max(1, workers or os.cpu_count() or 1)
            self._cluster, self._client = _local_cluster(self.workers)
        self.max_tasks_in_flight = max_tasks_in_flight or 4 * self.workers

    @property
    def client(self) -> Any:
        """The ``distributed.Client`` (raises once closed)."""
        if self._client is None:
            raise SkyreconError("this Dask executor is closed")
        return self._client

    @property
    def address(self) -> str:
        """The scheduler's address (the LocalCluster's own when none was given)."""
        return str(self.client.scheduler.address)

    def map(self, fn: Callable[[T], R], items: Iterable[T], *, desc: str | None = None) -> list[R]:
        """``[fn(item) for item in items]`` on the cluster, in input order. A task's exception is
        re-raised here (after ``retries``); Ctrl-C cancels the submitted tasks and closes a
        LocalCluster this executor started."""
        from distributed import as_completed

        items = list(items)
        if not items:
            return []
        client = self.client
        name = getattr(fn, "__name__", None) or getattr(getattr(fn, "func", None), "__name__", "task")
        run_id = uuid.uuid4().hex[:12]
        results: list[Any] = [None] * len(items)
        index: dict[Any, int] = {}
        ready = as_completed(loop=client.loop)
        bar = progress(total=len(items), desc=desc)
        nxt = 0

        resubmitted = [0] * len(items)

        def submit(i: int) -> None:
            item: Any = items[i]
            if _pickled_size(item) > self.scatter_bytes:
                item = _scatter(client, item)
            key = f"{name}-{run_id}-{i}-{resubmitted[i]}"
            fut = client.submit(fn, item, key=key, pure=False, retries=self.retries)
            index[fut] = i
            ready.add(fut)

        try:
            while nxt < len(items) and nxt < self.max_tasks_in_flight:
                submit(nxt)
                nxt += 1
            for fut in ready:
                i = index.pop(fut)
                value = _result(fut, self.address, resubmittable=resubmitted[i] < _RESUBMITS)
                if value is _LOST:
                    # its scattered item was lost with a worker (the scheduler cannot recompute
                    # scattered data): send the item again
                    resubmitted[i] += 1
                    submit(i)
                    continue
                results[i] = value
                fut.release()
                bar.update(1)
                if nxt < len(items):
                    submit(nxt)
                    nxt += 1
        except BaseException as exc:
            pending = list(index)
            if pending:
                try:
                    client.cancel(pending, force=True)
                except Exception:  # noqa: BLE001 - the scheduler may be gone already
                    pass
            if not isinstance(exc, Exception):  # Ctrl-C, SIGTERM: stop the local workers now
                self._close(restore_logging=False)
            raise
        finally:
            bar.close()
        return results

    def close(self) -> None:
        """Disconnect; shut down the LocalCluster this executor started (idempotent)."""
        self._close(restore_logging=True)

    def _close(self, restore_logging: bool) -> None:
        client, cluster = self._client, self._cluster
        self._client = self._cluster = None
        if client is None and cluster is None:
            return
        # the workers' goodbyes (and, after Ctrl-C, the scheduler's complaints about the tasks it
        # was handling, logged later too) are no news to the user: the command says what happened
        loggers = [logging.getLogger(name) for name in ("distributed", "asyncio")]
        levels = [lg.level for lg in loggers]
        for lg in loggers:
            lg.setLevel(logging.CRITICAL)
        try:
            for thing in (client, cluster):
                if thing is not None:
                    try:
                        thing.close()
                    except Exception:  # noqa: BLE001 - closing after a lost connection
                        pass
        finally:
            if restore_logging:
                for lg, level in zip(loggers, levels):
                    lg.setLevel(level)

    def __enter__(self) -> DaskExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover - a forgotten close at interpreter exit
        try:
            self.close()
        except Exception:  # noqa: BLE001
            pass


#: times an item is sent again after its scattered copy was lost with a worker
_RESUBMITS = 3


def _pickled_size(item: Any) -> int:
    """Bytes of ``item`` pickled (0 when the standard pickle cannot: Dask's cloudpickle will)."""
    try:
        return len(pickle.dumps(item, protocol=5))
    except Exception:  # noqa: BLE001 - lambdas and the like
        return 0


_LOST = object()


def _result(fut: Any, address: str, resubmittable: bool) -> Any:
    """The future's value, or ``_LOST`` when the scheduler cancelled it (its scattered input lost
    with a worker) and it may be sent again; a task that killed its workers too often, or
    cancelled too often, becomes a SkyreconError."""
    from distributed import KilledWorker
    from distributed.client import FutureCancelledError

    try:
        return fut.result()
    except FutureCancelledError as exc:
        if resubmittable:
            return _LOST
        raise SkyreconError(
            f"the Dask scheduler {address} cancelled a task again and again ({exc}): were its workers "
            "restarted? run the command again"
        ) from None
    except KilledWorker as exc:
        raise SkyreconError(
            f"a task was lost with its Dask worker again and again ({exc}); the workers of {address} may "
            "be running out of memory: give them more, or use fewer per machine"
        ) from None
    except (OSError, TimeoutError) as exc:
        if type(exc).__module__.startswith("distributed"):  # CommClosedError and friends
            raise SkyreconError(f"lost the connection to the Dask scheduler {address}: {exc}") from None
        raise


def _connect(address: str, timeout: float) -> Any:
    from distributed import Client

    what_to_do = (
        "start one there ('dask scheduler' and 'dask worker ADDRESS'), check the address and the "
        f"firewall, or drop --scheduler/${SCHEDULER_ENV} to run a local cluster"
    )
    try:
        client = Client(address, timeout=timeout, set_as_default=False)
    except Exception as exc:  # noqa: BLE001 - OSError, TimeoutError, ValueError for a bad address
        raise InputError(
            f"cannot reach the Dask scheduler at {address} within {timeout:g} s "
            f"({' '.join(str(exc).split())[:120] or type(exc).__name__}); {what_to_do}"
        ) from None
    try:
        _check_workers(client, address)
    except BaseException:
        client.close()
        raise
    return client


def _worker_fingerprint() -> str:
    try:
        return code_fingerprint()
    except ImportError as exc:
        return f"cannot import skyrecon ({exc})"


def _check_workers(client: Any, address: str) -> None:
    """Every worker must run this very skyrecon code, or its results could silently differ."""
    mine = code_fingerprint()
    theirs = client.run(_worker_fingerprint)
    other = {w: fp for w, fp in theirs.items() if fp != mine}
    if other:
        worker, fp = sorted(other.items())[0]
        raise InputError(
            f"the Dask workers of {address} run another skyrecon ({len(other)} of {len(theirs)}, e.g. "
            f"{worker}: {fp}; this command: {mine}); install this skyrecon on every worker and restart them"
        )


def _local_cluster(workers: int) -> tuple[Any, Any]:
    from distributed import Client, LocalCluster

    env = {k: os.environ[k] for k in ("NUMBA_CACHE_DIR", "PYTHONPATH") if os.environ.get(k)}
    cluster = LocalCluster(
        n_workers=workers,
        threads_per_worker=1,
        processes=True,
        dashboard_address=":0",  # any free port: no clash with another cluster on this machine
        silence_logs=logging.CRITICAL,  # what goes wrong reaches the client, which says it once
        env=env,
    )
    try:
        from skyrecon.executor_dask_plugin import QuietWorker

        client = Client(cluster, set_as_default=False)
        client.register_plugin(QuietWorker())
    except BaseException:
        cluster.close()
        raise
    return cluster, client
