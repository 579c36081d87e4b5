"""The depth step of MVS: per-view PatchMatch or per-pair rectified stereo, fanned out on an executor.

Each task is a module-level function of a picklable named tuple (process executors can run it)
and carries only the views it needs, without their colour images. Depth maps are (H, W)
float32 metres along the reference view's optical axis at the working resolution, NaN invalid.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np

from skyrecon.errors import InputError
from skyrecon.executor import Executor
from skyrecon.mvs.frames import WorkingView
from skyrecon.mvs.pairwise import pairwise_depth
from skyrecon.mvs.patchmatch import PatchMatchSettings, patchmatch_depth
from skyrecon.mvs.planar_prior import dominant_planes
from skyrecon.mvs.settings import MVSSettings

__all__ = ["DepthEstimates", "TaskTimings", "estimate_depths"]

#: Per task: milliseconds per step of the depth method, ``cpu`` (CPU milliseconds of the task),
#: ``pid`` (the process that ran it) and, for a pair that could not be matched, ``error`` (why).
TaskTimings = dict[str, Any]


class PatchMatchTask(NamedTuple):
    """One reference view's PatchMatch: its sources, depth range (near, far) metres, settings, seed,
    and the planar prior's sparse world points (N, 3) metres seen by the view and dominant world
    planes (P, 4) (or None)."""

    ref: WorkingView
    sources: list[WorkingView]
    depth_range: tuple[float, float]
    settings: PatchMatchSettings
    seed: int
    points: np.ndarray | None = None
    planes: np.ndarray | None = None


class PairwiseTask(NamedTuple):
    """One (reference, source) pair of rectified stereo.

    ``points`` are the sparse world points (N, 3) metres both views see (or None), used to
    narrow the disparity search.
    """

    ref: WorkingView
    src: WorkingView
    depth_range: tuple[float, float]
    matcher: str
    matcher_settings: dict[str, Any]
    points: np.ndarray | None


@dataclass
class DepthEstimates:
    """What :func:`estimate_depths` returns.

    Attributes:
        depths: per view (H, W) float32 depth in metres, NaN invalid; None for views without a
            task. With several pairs per reference view, the holes of the first pair's depth are
            filled from the next ones, in order.
        pair_depths: (reference index, depth) per task, in task order.
        task_timings: per task, see :data:`TaskTimings`.
    """

    depths: list[np.ndarray | None]
    pair_depths: list[tuple[int, np.ndarray]]
    task_timings: list[TaskTimings]


def _without_colour(view: WorkingView) -> WorkingView:
    """A copy without the colour image (tasks only need grey levels)."""
    return replace(view, rgb=np.zeros((0, 0, 3), np.uint8))


def _patchmatch_task(task: PatchMatchTask) -> tuple[np.ndarray, TaskTimings]:
    c0 = time.process_time()
    res = patchmatch_depth(
        task.ref, task.sources, task.depth_range, task.settings, task.seed, task.points, task.planes
    )
    tm: TaskTimings = {**res.timings_ms, "cpu": (time.process_time() - c0) * 1e3, "pid": os.getpid()}
    if res.prior:
        tm["planar_prior"] = res.prior
    return res.depth, tm


def _pairwise_task(task: PairwiseTask) -> tuple[np.ndarray, TaskTimings]:
    c0 = time.process_time()
    try:
        res = pairwise_depth(
            task.ref,
            task.src,
            task.depth_range,
            task.matcher,
            task.matcher_settings,
            points_world=task.points,
        )
    except InputError as exc:  # one unusable pair must not stop the others
        return np.full(task.ref.shape, np.nan, np.float32), {
            "cpu": (time.process_time() - c0) * 1e3,
            "error": str(exc),
            "pid": os.getpid(),
        }
    return res.depth, {**res.timings_ms, "cpu": (time.process_time() - c0) * 1e3, "pid": os.getpid()}


def _executor_threads(executor: Executor) -> int:
    """Threads per task so that the executor's workers together use every core."""
    workers = int(getattr(executor, "workers", 1) or 1)
    return max(1, (os.cpu_count() or 1) // workers)


def _points_in_view(points: np.ndarray | None, view: WorkingView) -> np.ndarray | None:
    """The world points (M, 3) metres in front of and inside ``view``, or None without points."""
    if points is None or len(points) == 0:
        return None
    uv, z = view.posed().project(points)
    return points[view.intrinsics.in_image(uv) & (z > 0)]


def _points_seen_by_both(points: np.ndarray | None, ref: WorkingView, src: WorkingView) -> np.ndarray | None:
    """The world points (M, 3) metres in front of and inside both views, or None without points."""
    if points is None or len(points) == 0:
        return None
    ok = np.ones(len(points), bool)
    for v in (ref, src):
        uv, z = v.posed().project(points)
        ok &= v.intrinsics.in_image(uv) & (z > 0)
    return points[ok]


def _patchmatch_depths(
    views: Sequence[WorkingView],
    settings: MVSSettings,
    neighbors: Sequence[Sequence[int]],
    ranges: Sequence[tuple[float, float] | None],
    executor: Executor,
    desc: str | None,
    points: np.ndarray | None,
) -> list[tuple[int, np.ndarray, TaskTimings]]:
    """One PatchMatch task per view with sources and a depth range."""
    pm = settings.patchmatch
    if pm.threads == 1:
        pm = replace(pm, threads=_executor_threads(executor))
    slim = [_without_colour(v) for v in views]
    planes = None
    if pm.prior.enabled and points is not None and len(points):
        planes = dominant_planes(points, pm.prior, seed=settings.seed)
    tasks: list[tuple[int, PatchMatchTask]] = []
    for r, nb in enumerate(neighbors):
        depth_range = ranges[r]
        if nb and depth_range is not None:
            sources = [slim[s] for s in nb]
            seen = _points_in_view(points, views[r]) if pm.prior.enabled else None
            seed = settings.seed * 1_000_003 + r
            tasks.append((r, PatchMatchTask(slim[r], sources, depth_range, pm, seed, seen, planes)))
    results = executor.map(_patchmatch_task, [t for _, t in tasks], desc=desc)
    return [(r, d, tm) for (r, _), (d, tm) in zip(tasks, results)]


def _pairwise_depths(
    views: Sequence[WorkingView],
    settings: MVSSettings,
    pairs: Sequence[tuple[int, int]],
    ranges: Sequence[tuple[float, float] | None],
    executor: Executor,
    desc: str | None,
    points: np.ndarray | None,
) -> list[tuple[int, np.ndarray, TaskTimings]]:
    """One rectified-stereo task per (reference, source) pair whose reference has a depth range."""
    slim = [_without_colour(v) for v in views]
    tasks: list[tuple[int, PairwiseTask]] = []
    for r, s in pairs:
        depth_range = ranges[r]
        if depth_range is not None:
            shared = _points_seen_by_both(points, views[r], views[s])
            matcher_settings = dict(settings.matcher_settings)
            tasks.append(
                (r, PairwiseTask(slim[r], slim[s], depth_range, settings.matcher, matcher_settings, shared))
            )
    results = executor.map(_pairwise_task, [t for _, t in tasks], desc=desc)
    return [(r, d, tm) for (r, _), (d, tm) in zip(tasks, results)]


def estimate_depths(
    views: Sequence[WorkingView],
    settings: MVSSettings,
    neighbors: Sequence[Sequence[int]],
    pairs: Sequence[tuple[int, int]],
    ranges: Sequence[tuple[float, float] | None],
    executor: Executor,
    *,
    progress: bool = True,
    points: np.ndarray | None = None,
) -> DepthEstimates:
    """Depth maps of the views by ``settings.depth_method``.

    Args:
        views: the working views (world frame, metres).
        settings: the MVS settings (depth method, PatchMatch and matcher settings, seed).
        neighbors: per view the source view indices (PatchMatch); empty: no depth for that view.
        pairs: the (reference, source) view-index pairs (pairwise stereo).
        ranges: per view the (near, far) depth range searched, metres, or None (no depth).
        executor: where the tasks run.
        progress: show a progress bar.
        points: sparse world points (N, 3) metres that narrow the pairwise disparity search and
            support PatchMatch's planar prior.
    Returns:
        DepthEstimates. A pair that cannot be matched gives an all-NaN depth and an ``error``
        in its timings; it does not stop the others.
    """
    desc = "MVS depth" if progress else None
    if settings.depth_method == "patchmatch":
        results = _patchmatch_depths(views, settings, neighbors, ranges, executor, desc, points)
    else:
        results = _pairwise_depths(views, settings, pairs, ranges, executor, desc, points)
    depths: list[np.ndarray | None] = [None] * len(views)
    for r, d, _ in results:
        first = depths[r]
        # several pairs for one view: fill the holes of the first
        depths[r] = d if first is None else np.where(np.isfinite(first), first, d)
    return DepthEstimates(depths, [(r, d) for r, d, _ in results], [tm for _, _, tm in results])
