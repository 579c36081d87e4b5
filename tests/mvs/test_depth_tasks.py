"""The depth step's bookkeeping: which tasks run, and how several pairs of one view are merged."""

from __future__ import annotations

from typing import Any

import numpy as np

from skyrecon.mvs.depth_tasks import PairwiseTask, PatchMatchTask, estimate_depths
from skyrecon.mvs.settings import MVSSettings
from tests.mvs.test_fusion import H, W, plane_views


class CannedExecutor:
    """Answers every task with the next canned depth, and records the tasks."""

    workers = 2

    def __init__(self, depths: list[np.ndarray]) -> None:
        self.depths = depths
        self.tasks: list[Any] = []

    def map(self, fn, items, *, desc=None):
        self.tasks = list(items)
        if fn.__name__ == "_patchmatch_task":  # PatchMatch tasks also answer their cost
            return [(d, {"cpu": 1.0, "pid": 0}, np.zeros_like(d)) for d in self.depths[: len(self.tasks)]]
        return [(d, {"cpu": 1.0, "pid": 0}) for d in self.depths[: len(self.tasks)]]


def test_pairwise_fills_the_holes_of_the_first_pair_from_the_next() -> None:
    views, _ = plane_views(3)
    first = np.full((H, W), np.nan, np.float32)
    first[:, : W // 2] = 5.0
    second = np.full((H, W), 6.0, np.float32)
    other = np.full((H, W), 7.0, np.float32)
    executor = CannedExecutor([first, second, other])
    settings = MVSSettings(depth_method="pairwise", matcher_settings={"block_size": 5})
    ranges = [(1.0, 10.0), (1.0, 10.0), None]
    est = estimate_depths(
        views, settings, [[], [], []], [(0, 1), (0, 2), (1, 0), (2, 0)], ranges, executor, progress=False
    )
    assert [type(t) for t in executor.tasks] == [PairwiseTask] * 3  # view 2 has no depth range
    assert all(t.rgb.size == 0 for task in executor.tasks for t in (task.ref, task.src))  # no colour sent
    assert executor.tasks[0].matcher_settings == {"block_size": 5} and executor.tasks[0].points is None
    d0 = est.depths[0]
    assert d0 is not None and np.all(d0[:, : W // 2] == 5.0) and np.all(d0[:, W // 2 :] == 6.0)
    assert np.isnan(first).any()  # the pair's own depth is left as it was
    assert est.depths[2] is None and est.depths[1] is not None and np.all(est.depths[1] == 7.0)
    assert [r for r, _ in est.pair_depths] == [0, 0, 1] and est.pair_depths[0][1] is first
    assert len(est.task_timings) == 3


def test_patchmatch_runs_one_task_per_view_with_sources_and_range() -> None:
    views, _ = plane_views(3)
    depth = np.full((H, W), 5.0, np.float32)
    executor = CannedExecutor([depth, depth])
    settings = MVSSettings(seed=3)
    ranges = [(1.0, 10.0), (1.0, 10.0), (1.0, 10.0)]
    est = estimate_depths(views, settings, [[1, 2], [], [0]], [], ranges, executor, progress=False)
    tasks = executor.tasks
    assert [type(t) for t in tasks] == [PatchMatchTask] * 2
    assert [len(t.sources) for t in tasks] == [2, 1]
    assert [t.seed for t in tasks] == [3 * 1_000_003 + 0, 3 * 1_000_003 + 2]
    assert tasks[0].settings.threads >= 1
    assert est.depths[1] is None and est.depths[0] is depth and est.depths[2] is depth
