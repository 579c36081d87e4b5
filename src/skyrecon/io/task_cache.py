"""Per-task results kept in a run's workspace, so that a killed run resumes without redoing them.

:func:`map_cached` is ``executor.map`` whose every finished result is stored at once, by the
worker that computed it, as ``<cache_dir>/<key>.pkl`` (written atomically: a kill leaves the
whole file or none). A rerun finds the results already there and runs only the missing tasks.
The key of a task is the hash of the task itself (its pickled bytes, with the fields that do not
change the result replaced by the caller) and of the package version, so any change in its input,
or another version of skyrecon, gives a new key.

Results must be picklable; the files are the run's own, read back only by later runs. An
executor with ``results_via_files = True`` (the Dask one) gets only the file's path back from
its workers and reads the result from the file: large arrays then move through the workspace
(which its workers must share), not through pickled task results.
"""

from __future__ import annotations

import functools
import hashlib
import io
import pickle
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

from skyrecon import __version__
from skyrecon.errors import SkyreconError
from skyrecon.executor import Executor
from skyrecon.io.atomic import write_bytes_atomic

__all__ = ["map_cached", "task_key"]

T = TypeVar("T")
R = TypeVar("R")

FORMAT = "skyrecon.task-result.v1"


def task_key(task: Any, salt: str = "") -> str:
    """A hash (32 hex digits) of a picklable task, ``salt`` (e.g. the function's name) and the
    package version: a workspace left by another version is recomputed, never reused.

    The task is pickled without the pickle memo (``Pickler.fast``): a plain pickle also encodes
    which of its parts are the same object (two fields holding one array, arrays sharing a
    dtype), and that differs between arrays just computed and arrays read back from a
    workspace, so a resumed run would miss its kept results. Tasks must not refer to themselves.
    """
    h = hashlib.sha256(f"{__version__}\0{salt}".encode())
    buf = io.BytesIO()
    pickler = pickle.Pickler(buf, protocol=pickle.HIGHEST_PROTOCOL)
    pickler.fast = True  # no memo: the bytes depend on the values only
    pickler.dump(task)
    h.update(buf.getbuffer())
    return h.hexdigest()[:32]


def _load(path: Path) -> tuple[bool, Any]:
    try:
        with open(path, "rb") as f:
            doc = pickle.load(f)
    except Exception:  # noqa: BLE001 - a missing or damaged file only means running the task again
        return False, None
    if not isinstance(doc, tuple) or len(doc) != 2 or doc[0] != FORMAT:
        return False, None
    return True, doc[1]


def _run_and_store(fn: Callable[[T], R], path: str, item: T) -> R:
    """Worker side: compute, then store the result atomically before returning it."""
    result = fn(item)
    write_bytes_atomic(path, pickle.dumps((FORMAT, result), protocol=pickle.HIGHEST_PROTOCOL))
    return result


def _run_and_store_path(fn: Callable[[T], R], path: str, item: T) -> str:
    """Worker side, results through files: compute and store the result; return only its path."""
    _run_and_store(fn, path, item)
    return path


def map_cached(
    executor: Executor,
    fn: Callable[[T], R],
    items: Sequence[T],
    keys: Sequence[str],
    cache_dir: str | Path | None,
    *,
    desc: str | None = None,
) -> tuple[list[R], int]:
    """``executor.map(fn, items)`` with each result kept under ``cache_dir`` (see the module).

    Args:
        executor: where the missing tasks run.
        fn: a picklable (module-level) function of one item.
        items: the tasks.
        keys: one key per item (see :func:`task_key`).
        cache_dir: the cache folder (created when needed); None: no cache, plain ``executor.map``.
        desc: progress-bar label.
    Returns:
        (results in item order, how many came from the cache).
    """
    if cache_dir is None:
        return executor.map(fn, items, desc=desc), 0
    folder = Path(cache_dir)
    folder.mkdir(parents=True, exist_ok=True)
    results: list[Any] = [None] * len(items)
    missing: list[int] = []
    for i, key in enumerate(keys):
        ok, result = _load(folder / f"{key}.pkl")
        if ok:
            results[i] = result
        else:
            missing.append(i)
    if missing:
        # one partial per distinct path, so each task carries its own destination
        via_files = bool(getattr(executor, "results_via_files", False))
        store = _run_and_store_path if via_files else _run_and_store
        jobs = [functools.partial(store, fn, str(folder / f"{keys[i]}.pkl")) for i in missing]
        computed = executor.map(_call, list(zip(jobs, [items[i] for i in missing])), desc=desc)
        for i, r in zip(missing, computed):
            results[i] = _read_stored(r) if via_files else r
    return results, len(items) - len(missing)


def _read_stored(path: str) -> Any:
    ok, result = _load(Path(path))
    if not ok:
        raise SkyreconError(
            f"a worker stored its result in {path} but this process cannot read it; with a remote "
            "cluster, put --workspace on a filesystem shared by the workers and this machine"
        )
    return result


def _call(job: tuple[Callable[[Any], Any], Any]) -> Any:
    fn, item = job
    return fn(item)
