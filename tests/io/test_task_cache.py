"""Per-task results kept in a workspace: reused by a rerun, recomputed for another version."""

from __future__ import annotations

from skyrecon.executor import SerialExecutor
from skyrecon.io import task_cache
from skyrecon.io.task_cache import map_cached, task_key


def _square(x: int) -> int:
    _square.calls += 1  # type: ignore[attr-defined]
    return x * x


_square.calls = 0  # type: ignore[attr-defined]


def test_a_rerun_reuses_results_and_another_version_recomputes_them(tmp_path, monkeypatch) -> None:
    items = [1, 2, 3]
    keys = [task_key(i, "square") for i in items]
    assert len(set(keys)) == 3 and keys[0] != task_key(1, "cube")
    _square.calls = 0
    out, cached = map_cached(SerialExecutor(), _square, items, keys, tmp_path)
    assert (out, cached, _square.calls) == ([1, 4, 9], 0, 3)
    out, cached = map_cached(SerialExecutor(), _square, items, keys, tmp_path)
    assert (out, cached, _square.calls) == ([1, 4, 9], 3, 3)
    # a damaged file is computed again
    (tmp_path / f"{keys[1]}.pkl").write_bytes(b"not a pickle")
    out, cached = map_cached(SerialExecutor(), _square, items, keys, tmp_path)
    assert (out, cached, _square.calls) == ([1, 4, 9], 2, 4)
    # the same workspace under another version of skyrecon: other keys, nothing reused
    monkeypatch.setattr(task_cache, "__version__", "99.0")
    new_keys = [task_key(i, "square") for i in items]
    assert not set(new_keys) & set(keys)
    out, cached = map_cached(SerialExecutor(), _square, items, new_keys, tmp_path)
    assert (out, cached, _square.calls) == ([1, 4, 9], 0, 7)
