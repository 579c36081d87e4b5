"""The depth step of MVS: per-view PatchMatch or per-pair rectified stereo, fanned out on an executor.

Each task is a module-level function of a picklable named tuple (process executors can run it)
and carries only the views it needs, without their colour images. Depth maps are (H, W)
float32 metres along the reference view's optical axis at the working resolution, NaN invalid.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np

from skyrecon.errors import InputError
from skyrecon.executor import Executor
from skyrecon.io.task_cache import map_cached, task_key
from skyrecon.mvs.frames import WorkingView
from skyrecon.mvs.pairwise import pairwise_depth
from skyrecon.mvs.patchmatch import PatchMatchSettings, patchmatch_depth
from skyrecon.mvs.planar_prior import FilledPlanes, PlanarPriorSettings, planar_prior_depth
from skyrecon.mvs.settings import MVSSettings

__all__ = ["DepthEstimates", "TaskTimings", "estimate_depths", "apply_planar_prior"]

#: Per task: milliseconds per step of the depth method, ``cpu`` (CPU milliseconds of the task),
#: ``pid`` (the process that ran it) and, for a pair that could not be matched, ``error`` (why).
TaskTimings = dict[str, Any]


class PatchMatchTask(NamedTuple):
    """One reference view's PatchMatch: its sources, depth range (near, far) metres, settings, seed."""

    ref: WorkingView
    sources: list[WorkingView]
    depth_range: tuple[float, float]
    settings: PatchMatchSettings
    seed: int


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
        costs: per view (H, W) float32 PatchMatch cost (1 - NCC, 2 where not estimated), or
            None (pairwise stereo, or no task).
    """

    depths: list[np.ndarray | None]
    pair_depths: list[tuple[int, np.ndarray]]
    task_timings: list[TaskTimings]
    costs: list[np.ndarray | None] = field(default_factory=list)


def _without_colour(view: WorkingView) -> WorkingView:
    """A copy without the colour image (tasks only need grey levels)."""
    return replace(view, rgb=np.zeros((0, 0, 3), np.uint8))


def _patchmatch_task(task: PatchMatchTask) -> tuple[np.ndarray, TaskTimings, np.ndarray]:
    c0 = time.process_time()
    res = patchmatch_depth(task.ref, task.sources, task.depth_range, task.settings, task.seed)
    tm = {**res.timings_ms, "cpu": (time.process_time() - c0) * 1e3, "pid": os.getpid()}
    return res.depth, tm, res.cost


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
    cache_dir: str | None = None,
) -> list[tuple[int, np.ndarray, TaskTimings, np.ndarray | None]]:
    """One PatchMatch task per view with sources and a depth range (results kept in ``cache_dir``)."""
    pm = settings.patchmatch
    if pm.threads == 1:
        pm = replace(pm, threads=_executor_threads(executor))
    slim = [_without_colour(v) for v in views]
    tasks: list[tuple[int, PatchMatchTask]] = []
    for r, nb in enumerate(neighbors):
        depth_range = ranges[r]
        if nb and depth_range is not None:
            sources = [slim[s] for s in nb]
            tasks.append(
                (r, PatchMatchTask(slim[r], sources, depth_range, pm, settings.seed * 1_000_003 + r))
            )
    # the thread count does not change a depth map: a rerun with other workers reuses the cache
    keys = [task_key(t._replace(settings=replace(t.settings, threads=1)), "patchmatch") for _, t in tasks]
    results, _ = map_cached(executor, _patchmatch_task, [t for _, t in tasks], keys, cache_dir, desc=desc)
    return [(r, d, tm, c) for (r, _), (d, tm, c) in zip(tasks, results)]


def _pairwise_depths(
    views: Sequence[WorkingView],
    settings: MVSSettings,
    pairs: Sequence[tuple[int, int]],
    ranges: Sequence[tuple[float, float] | None],
    executor: Executor,
    desc: str | None,
    points: np.ndarray | None,
    cache_dir: str | None = None,
) -> list[tuple[int, np.ndarray, TaskTimings, np.ndarray | None]]:
    """One rectified-stereo task per (reference, source) pair whose reference has a depth range
    (results kept in ``cache_dir``)."""
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
    keys = [task_key(t, "pairwise") for _, t in tasks]
    results, _ = map_cached(executor, _pairwise_task, [t for _, t in tasks], keys, cache_dir, desc=desc)
    return [(r, d, tm, None) for (r, _), (d, tm) in zip(tasks, results)]


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
    cache_dir: str | None = None,
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
        points: sparse world points (N, 3) metres that narrow the pairwise disparity search.
        cache_dir: keep each task's result here and reuse those already there (a resumed run;
            see :mod:`skyrecon.io.task_cache`); None: no cache.
    Returns:
        DepthEstimates. A pair that cannot be matched gives an all-NaN depth and an ``error``
        in its timings; it does not stop the others.
    """
    desc = "MVS depth" if progress else None
    if settings.depth_method == "patchmatch":
        results = _patchmatch_depths(views, settings, neighbors, ranges, executor, desc, cache_dir)
    else:
        results = _pairwise_depths(views, settings, pairs, ranges, executor, desc, points, cache_dir)
    depths: list[np.ndarray | None] = [None] * len(views)
    costs: list[np.ndarray | None] = [None] * len(views)
    for r, d, _, c in results:
        first = depths[r]
        # several pairs for one view: fill the holes of the first
        depths[r] = d if first is None else np.where(np.isfinite(first), first, d)
        costs[r] = c
    return DepthEstimates(depths, [(r, d) for r, d, _, _ in results], [tm for _, _, tm, _ in results], costs)


class PriorTask(NamedTuple):
    """One view's planar prior (:func:`skyrecon.mvs.planar_prior.fill_plain_segments`): the view
    and its sources with colour, its PatchMatch depth (H, W) metres and cost, depth range (near,
    far) metres, settings, the sparse world points (N, 3) it sees, the dominant world planes
    (P, 4), the sources' PatchMatch depths (H, W) metres (for the see-through test) and, in the
    second pass, the planes its neighbours filled with (``offered``)."""

    ref: WorkingView
    sources: list[WorkingView]
    depth: np.ndarray
    cost: np.ndarray
    depth_range: tuple[float, float]
    settings: PlanarPriorSettings
    cos_max_incidence: float
    points: np.ndarray | None
    planes: np.ndarray
    source_depths: list[np.ndarray | None] | None = None
    offered: FilledPlanes | None = None


def _prior_task(task: PriorTask) -> tuple[np.ndarray, dict[str, Any], FilledPlanes]:
    c0 = time.process_time()
    depth, rep, planes = planar_prior_depth(
        task.ref,
        task.sources,
        task.depth,
        task.cost,
        task.depth_range,
        task.cos_max_incidence,
        task.settings,
        task.points,
        task.planes,
        task.source_depths,
        task.offered,
    )
    report: dict[str, Any] = {**rep, "cpu_ms": round((time.process_time() - c0) * 1e3, 1)}
    return depth, report, planes


def apply_planar_prior(
    views: Sequence[WorkingView],
    settings: MVSSettings,
    neighbors: Sequence[Sequence[int]],
    ranges: Sequence[tuple[float, float] | None],
    depths: list[np.ndarray | None],
    costs: list[np.ndarray | None],
    planes: np.ndarray,
    executor: Executor,
    *,
    progress: bool = True,
    points: np.ndarray | None = None,
    cache_dir: str | None = None,
    offered: Sequence[FilledPlanes | None] | None = None,
    source_depths: Sequence[np.ndarray | None] | None = None,
) -> tuple[list[np.ndarray | None], dict[int, dict[str, Any]], dict[int, FilledPlanes]]:
    """The planar prior of every view with a PatchMatch depth, fanned out on the executor.

    Args:
        views, neighbors, ranges: as for :func:`estimate_depths`.
        settings: ``planar_prior`` and ``patchmatch.max_incidence_deg``.
        depths, costs: per view the PatchMatch depth (H, W) metres (NaN invalid) and cost.
        planes: (P, 4) dominant world planes (n, c), n . X = c.
        executor: where the tasks run.
        progress: show a progress bar.
        points: sparse world points (N, 3) metres.
        cache_dir: keep each view's result here and reuse those already there (a resumed run,
            as for :func:`estimate_depths`); None: no cache.
        offered: the second pass: per view the planes its neighbours filled with (a view with
            None or none is skipped); None: the first pass.
        source_depths: per view the depth the see-through test reads (default ``depths``).
    Returns:
        (per view the depth with plain segments filled (unchanged where the prior fell back),
        per view index the prior's report (``fallback`` says why it was not applied) and the
        planes it filled with).
    """
    cos_max = float(np.cos(np.radians(settings.patchmatch.max_incidence_deg)))
    tasks: list[tuple[int, PriorTask]] = []
    for r, nb in enumerate(neighbors):
        d, c, rng = depths[r], costs[r], ranges[r]
        if d is None or c is None or rng is None or not nb:
            continue
        offer = None if offered is None else offered[r]
        if offered is not None and (offer is None or len(offer.planes) == 0):
            continue
        seen = _points_in_view(points, views[r])
        task = PriorTask(
            views[r],
            [views[s] for s in nb],
            d,
            c,
            rng,
            settings.planar_prior,
            cos_max,
            seen,
            planes,
            [(depths if source_depths is None else source_depths)[s] for s in nb],
            offer,
        )
        tasks.append((r, task))
    keys = [task_key(t, "planar_prior") for _, t in tasks]
    desc = (
        ("MVS planar prior" if offered is None else "MVS planar prior, shared planes") if progress else None
    )
    results, _ = map_cached(executor, _prior_task, [t for _, t in tasks], keys, cache_dir, desc=desc)
    out = list(depths)
    reports: dict[int, dict[str, Any]] = {}
    filled: dict[int, FilledPlanes] = {}
    for (r, _), (d, rep, fp) in zip(tasks, results):
        out[r] = d
        reports[r] = rep
        filled[r] = fp
    return out, reports, filled


def _points_in_view(points: np.ndarray | None, view: WorkingView) -> np.ndarray | None:
    """The world points (M, 3) metres in front of and inside ``view``, or None without points."""
    if points is None or len(points) == 0:
        return None
    uv, z = view.posed().project(points)
    return points[view.intrinsics.in_image(uv) & (z > 0)]
