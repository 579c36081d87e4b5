"""The MVS stage: posed images in, per-view depth maps and one fused, coloured cloud out.

Steps (each timed in ``MVSResult.timings_s``):

1. ``load``: images resized to the working resolution (one full-size image in memory at a time);
2. ``sparse``: SIFT matches checked against the known epipolar geometry and triangulated, giving
   every view's depth range and the points the automatic view selection scores;
3. ``select``: sources per reference view (``auto``) or the pairs of a named topology;
4. ``depth``: PatchMatch (or pairwise rectified stereo) per view, fanned out on the executor
   (each task carries only its reference and source views);
5. ``fusion``: geometric-consistency fusion (or plain concatenation);
6. ``cleanup``: statistical outlier removal, normals (PCA, oriented to the cameras), optional
   voxel averaging; optional ``mesh``.

World frame and metres throughout; depth maps are at the working resolution, with the scaled
intrinsics in each :class:`~skyrecon.core.DepthMap`.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from skyrecon import progress as _progress
from skyrecon.core import DepthMap, PointCloud, PosedView
from skyrecon.errors import InputError
from skyrecon.executor import Executor, get_executor
from skyrecon.mvs.cloud_ops import (
    knn_mean_distance_and_normals,
    orient_normals,
    small_component_mask,
    statistical_outlier_mask,
    voxel_downsample_indices,
)
from skyrecon.mvs.frames import WorkingView
from skyrecon.mvs.fusion import FusedCloud, fuse_concat, fuse_consistent
from skyrecon.mvs.inputs import ImagesArg, load_working_views
from skyrecon.mvs.pairwise import pairwise_depth
from skyrecon.mvs.patchmatch import patchmatch_depth
from skyrecon.mvs.settings import MVSSettings
from skyrecon.mvs.sparse import depth_range_from_points, sparse_scene
from skyrecon.mvs.topology import neighbors_from_pairs, select_neighbors, topology_pairs

__all__ = ["MVSResult", "run_mvs"]


@dataclass
class MVSResult:
    """What :func:`run_mvs` returns.

    Attributes:
        cloud: the fused cloud, world frame: points (N, 3) float32 metres, colours (N, 3) uint8
            RGB, normals (N, 3) float32 unit (facing the cameras that saw them).
        depth_maps: per view (keyed by image stem) the depth at the working resolution,
            (H, W) float32 metres along the optical axis, NaN invalid, with the working
            intrinsics and ``cam_from_world``.
        neighbors: per view name, the source view names used for its depth.
        pairs: the (reference, source) view-index pairs matched.
        view_names: input view names, in order (indices in ``pairs`` refer to it).
        depth_ranges: per view name, the (near, far) depth range searched, metres.
        support: (N,) int32 views that agreed on each point (1 for ``concat``).
        mesh: (vertices (V, 3) float32 world metres, faces (F, 3) int32, vertex colours (V, 3)
            uint8) when requested (``settings.mesh``), else None.
        timings_s: wall-clock seconds per step and ``total``.
        diagnostics: numbers describing the run (points before/after each filter, sparse
            points, per-view valid fractions, per-task timings, ``cpu_s``: CPU seconds of this
            process and of the depth tasks run in worker processes).
        warnings: human-readable problems naming the views concerned.
    """

    cloud: PointCloud
    depth_maps: dict[str, DepthMap]
    neighbors: dict[str, list[str]]
    pairs: list[tuple[int, int]]
    view_names: list[str]
    depth_ranges: dict[str, tuple[float, float]]
    support: np.ndarray
    mesh: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


# ------------------------------------------------------------------------------------------------
# per-view tasks (module level: picklable for process executors)
# ------------------------------------------------------------------------------------------------
def _slim(v: WorkingView) -> WorkingView:
    """A copy without the colour image (tasks only need grey levels)."""
    return replace(v, rgb=np.zeros((0, 0, 3), np.uint8))


def _patchmatch_task(task: tuple) -> tuple[np.ndarray, dict[str, float]]:
    ref, sources, depth_range, pm_settings, seed = task
    c0 = time.process_time()
    res = patchmatch_depth(ref, sources, depth_range, pm_settings, seed)
    return res.depth, {**res.timings_ms, "cpu": (time.process_time() - c0) * 1e3, "pid": os.getpid()}


def _pairwise_task(task: tuple) -> tuple[np.ndarray, dict[str, float]]:
    ref, src, depth_range, matcher, matcher_settings, points = task
    c0 = time.process_time()
    try:
        res = pairwise_depth(ref, src, depth_range, matcher, matcher_settings, points_world=points)
    except InputError as exc:  # one unusable pair must not stop the others
        return np.full(ref.shape, np.nan, np.float32), {
            "cpu": (time.process_time() - c0) * 1e3,
            "error": str(exc),
            "pid": os.getpid(),
        }
    return res.depth, {**res.timings_ms, "cpu": (time.process_time() - c0) * 1e3, "pid": os.getpid()}


# ------------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------------
def _names(views: Sequence[WorkingView], idx: Sequence[int]) -> str:
    names = [views[i].name for i in idx]
    return ", ".join(names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")


def _blank_views(views: list[WorkingView]) -> list[int]:
    out = []
    for i, v in enumerate(views):
        g = v.grey[v.valid]
        if g.size == 0 or float(g.std()) < 1.0:
            out.append(i)
    return out


def _depth_ranges(
    views: list[WorkingView], settings: MVSSettings, points: np.ndarray, warnings: list[str]
) -> list[tuple[float, float] | None]:
    if settings.depth_range is not None:
        return [tuple(settings.depth_range)] * len(views)  # type: ignore[list-item]
    ranges = [depth_range_from_points(v, points) for v in views]
    known = [r for r in ranges if r is not None]
    if not known:
        return ranges
    missing = [i for i, r in enumerate(ranges) if r is None]
    if missing:
        fallback = (min(r[0] for r in known), max(r[1] for r in known))
        warnings.append(
            f"too few matched features to estimate the depth range of {_names(views, missing)}; "
            f"using the range of the other views ({fallback[0]:.3g}-{fallback[1]:.3g} m)"
        )
        ranges = [fallback if r is None else r for r in ranges]
    return ranges


def _choose_pairs(
    views: list[WorkingView],
    settings: MVSSettings,
    points: np.ndarray,
    ranges: list[tuple[float, float] | None],
) -> tuple[list[list[int]], list[tuple[int, int]]]:
    """Per-view source lists and the (ref, src) pairs of the depth step."""
    n = len(views)
    if settings.topology == "auto":
        neighbors, _ = select_neighbors(
            views, settings.num_sources, points, ranges, settings.min_angle_deg, settings.max_angle_deg
        )
        if settings.depth_method == "pairwise":
            pairs = [(r, nb[0]) for r, nb in enumerate(neighbors) if nb]
        else:
            pairs = [(r, s) for r, nb in enumerate(neighbors) for s in nb]
        return neighbors, pairs
    pairs = topology_pairs(settings.topology, n)
    if settings.depth_method == "pairwise":
        return neighbors_from_pairs(pairs, n, symmetric=False), pairs
    neighbors = neighbors_from_pairs(pairs, n, symmetric=True)
    return neighbors, [(r, s) for r, nb in enumerate(neighbors) for s in nb]


def _executor_threads(executor: Executor) -> int:
    workers = int(getattr(executor, "workers", 1) or 1)
    return max(1, (os.cpu_count() or 1) // workers)


def _cleanup(
    fused: FusedCloud, views: list[WorkingView], settings: MVSSettings, diag: dict[str, Any]
) -> tuple[PointCloud, np.ndarray]:
    cloud, vid, support = fused.cloud, fused.view_index, fused.support
    diag["points_fused"] = len(cloud)
    if len(cloud) == 0:
        return PointCloud(cloud.points, cloud.colors, np.zeros((0, 3), np.float32)), support
    mean_d, normals = knn_mean_distance_and_normals(cloud.points, settings.outlier_k)
    if settings.outlier_std > 0 and len(cloud) > settings.outlier_k:
        keep = statistical_outlier_mask(mean_d, settings.outlier_std)
        cloud, vid, support, normals = cloud.select(keep), vid[keep], support[keep], normals[keep]
    diag["points_after_outlier_removal"] = len(cloud)
    if settings.component_min_fraction > 0 and len(cloud) > settings.outlier_k:
        radius = settings.component_radius_factor * float(np.median(mean_d))
        keep = small_component_mask(cloud.points, radius, settings.component_min_fraction, settings.outlier_k)
        cloud, vid, support, normals = cloud.select(keep), vid[keep], support[keep], normals[keep]
        diag["points_after_component_filter"] = len(cloud)
    centers = np.stack([v.center_world for v in views])
    normals = orient_normals(cloud.points, normals, centers[vid])
    if settings.voxel_size_m:
        inv, counts = voxel_downsample_indices(cloud.points, settings.voxel_size_m)
        m = len(counts)
        w = 1.0 / counts[:, None]

        def avg(a: np.ndarray) -> np.ndarray:
            out = np.zeros((m, a.shape[1]))
            np.add.at(out, inv, a.astype(np.float64))
            return out * w

        nrm = avg(normals)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
        sup = np.zeros(m, np.int64)
        np.maximum.at(sup, inv, support)
        cloud = PointCloud(
            avg(cloud.points).astype(np.float32), avg(cloud.colors.astype(np.float64)), nrm.astype(np.float32)
        )
        support = sup.astype(np.int32)
        diag["points_after_voxel"] = len(cloud)
        return cloud, support
    return PointCloud(cloud.points, cloud.colors, normals), support


# ------------------------------------------------------------------------------------------------
# the stage
# ------------------------------------------------------------------------------------------------
def run_mvs(
    views: Sequence[PosedView],
    images: ImagesArg = None,
    settings: MVSSettings = MVSSettings(),
    executor: Executor | None = None,
    progress: bool = True,
) -> MVSResult:
    """Dense multi-view stereo: per-view depth maps and one fused coloured cloud.

    Args:
        views: the cameras (intrinsics without distortion, ``cam_from_world`` poses, metres),
            at least 2, names unique.
        images: None (read each ``view.image_path``), one entry per view (an (H, W) grey or
            (H, W, 3) RGB uint8 array, an ``(image, alpha)`` tuple with alpha 0 = no data, or a
            path), or a callable ``f(index)`` returning one of those.
        settings: see :class:`MVSSettings`.
        executor: where per-view work runs (default :func:`skyrecon.executor.get_executor`).
        progress: show progress bars (subject to the global progress setting).
    Returns:
        MVSResult (world frame). Problems that leave some views out are listed in
        ``warnings`` with the view names.
    Raises:
        InputError: fewer than 2 views, duplicate names, images that do not match their
            cameras, every image blank, or no two views that see anything in common.
    """
    t_start = time.perf_counter()
    cpu_start = time.process_time()
    timings: dict[str, float] = {}
    warnings: list[str] = []
    diag: dict[str, Any] = {}
    views = list(views)
    if len(views) < 2:
        raise InputError(f"MVS needs at least 2 views, got {len(views)}")
    seen: set[str] = set()
    for v in views:
        if v.name in seen:
            raise InputError(f"view name {v.name!r} appears twice; view names must be unique")
        seen.add(v.name)
    previous_progress = _progress._enabled
    if not progress:
        _progress.set_progress_enabled(False)
    try:
        executor = executor or get_executor()

        t = time.perf_counter()
        wviews = load_working_views(views, images, settings.max_image_size)
        timings["load"] = time.perf_counter() - t
        blank = _blank_views(wviews)
        if len(blank) == len(wviews):
            raise InputError(f"every image is blank (no texture): {_names(wviews, blank)}; check the images")
        if blank:
            warnings.append(f"blank images (no texture, no depth): {_names(wviews, blank)}")

        t = time.perf_counter()
        sparse = sparse_scene(wviews, max_features=settings.sparse_max_features)
        diag["sparse_points"] = len(sparse.points)
        ranges = _depth_ranges(wviews, settings, sparse.points, warnings)
        timings["sparse"] = time.perf_counter() - t
        if all(r is None for r in ranges):
            raise InputError(
                f"no matched features between any two of the {len(wviews)} views ({_names(wviews, range(len(wviews)))}): "
                "they see nothing in common (or the cameras do not belong to these images); pass depth_range if "
                "the scene is textureless"
            )

        t = time.perf_counter()
        neighbors, pairs = _choose_pairs(wviews, settings, sparse.points, ranges)
        if blank:  # blank views are neither references nor sources
            neighbors = [
                [] if r in blank else [s for s in nb if s not in blank] for r, nb in enumerate(neighbors)
            ]
            pairs = [(r, s) for r, s in pairs if r not in blank and s not in blank]
        isolated = [i for i, nb in enumerate(neighbors) if not nb and i not in blank]
        if len(isolated) + len(blank) >= len(wviews) or not pairs:
            raise InputError(
                f"no two views see enough in common to match: {_names(wviews, range(len(wviews)))}"
            )
        if isolated:
            warnings.append(
                f"views sharing too little with any other view (no depth): {_names(wviews, isolated)}"
            )
        timings["select"] = time.perf_counter() - t

        t = time.perf_counter()
        depths, pair_depths, dtimes = _depth_step(
            wviews, settings, neighbors, pairs, ranges, blank, executor, progress, sparse.points
        )
        timings["depth"] = time.perf_counter() - t
        diag["depth_task_ms"] = dtimes
        warnings.extend(tm["error"] for tm in dtimes if "error" in tm)
        empty = [i for i, d in enumerate(depths) if d is not None and not np.isfinite(d).any()]
        if empty:
            warnings.append(f"no depth could be estimated for {_names(wviews, empty)}")

        t = time.perf_counter()
        if settings.fusion == "concat":
            fused = fuse_concat(wviews, pair_depths)
        else:
            fusion_nb = neighbors_from_pairs(
                [(r, s) for r, nb in enumerate(neighbors) for s in nb], len(wviews)
            )
            fused = fuse_consistent(wviews, depths, fusion_nb, settings.fusion_settings)
        timings["fusion"] = time.perf_counter() - t

        t = time.perf_counter()
        cloud, support = _cleanup(fused, wviews, settings, diag)
        timings["cleanup"] = time.perf_counter() - t
        if len(cloud) == 0:
            warnings.append(
                "the fused cloud is empty: no depth was consistent across views (check that the cameras belong "
                "to the images, or lower fusion_settings.min_consistent)"
            )

        mesh = None
        if settings.mesh and len(cloud):
            from skyrecon.mvs.mesh import mesh_from_depth_maps

            t = time.perf_counter()
            mesh = mesh_from_depth_maps(wviews, depths, cloud, settings.mesh_voxel_m)
            timings["mesh"] = time.perf_counter() - t
    finally:
        _progress._enabled = previous_progress

    depth_maps = {
        v.stem: DepthMap(d, v.intrinsics, v.cam_from_world) for v, d in zip(wviews, depths) if d is not None
    }
    diag["valid_fraction"] = {
        v.stem: float(np.isfinite(d).mean()) for v, d in zip(wviews, depths) if d is not None
    }
    diag["working_size"] = {v.stem: (v.shape[1], v.shape[0]) for v in wviews}
    timings["total"] = time.perf_counter() - t_start
    # CPU seconds: this process (all its threads) plus the tasks that ran in worker processes
    worker_cpu = sum(tm["cpu"] for tm in diag.get("depth_task_ms", []) if tm.get("pid") != os.getpid()) / 1e3
    diag["cpu_s"] = time.process_time() - cpu_start + worker_cpu
    return MVSResult(
        cloud=cloud,
        depth_maps=depth_maps,
        neighbors={wviews[r].name: [wviews[s].name for s in nb] for r, nb in enumerate(neighbors)},
        pairs=pairs,
        view_names=[v.name for v in wviews],
        depth_ranges={v.name: r for v, r in zip(wviews, ranges) if r is not None},
        support=support,
        mesh=mesh,
        timings_s=timings,
        diagnostics=diag,
        warnings=warnings,
    )


def _depth_step(
    wviews: list[WorkingView],
    settings: MVSSettings,
    neighbors: list[list[int]],
    pairs: list[tuple[int, int]],
    ranges: list,
    blank: list[int],
    executor: Executor,
    progress: bool,
    points: np.ndarray | None = None,
) -> tuple[list[np.ndarray | None], list[tuple[int, np.ndarray]], list[dict[str, float]]]:
    """Run the per-view (or per-pair) depth tasks; returns per-view depths and per-pair depths."""
    n = len(wviews)
    depths: list[np.ndarray | None] = [None] * n
    pair_depths: list[tuple[int, np.ndarray]] = []
    slim = [_slim(v) for v in wviews]
    desc = "MVS depth" if progress else None
    if settings.depth_method == "patchmatch":
        pm = (
            replace(settings.patchmatch, threads=_executor_threads(executor))
            if settings.patchmatch.threads == 1
            else settings.patchmatch
        )
        refs = [r for r in range(n) if neighbors[r] and r not in blank and ranges[r] is not None]
        tasks = [
            (slim[r], [slim[s] for s in neighbors[r]], ranges[r], pm, settings.seed * 1_000_003 + r)
            for r in refs
        ]
        results = executor.map(_patchmatch_task, tasks, desc=desc)
        for r, (d, _) in zip(refs, results):
            depths[r] = d
            pair_depths.append((r, d))
        return depths, pair_depths, [tm for _, tm in results]
    todo = [(r, s) for r, s in pairs if r not in blank and s not in blank and ranges[r] is not None]

    def shared(r: int, s: int) -> np.ndarray | None:
        if points is None or len(points) == 0:
            return None
        ok = np.ones(len(points), bool)
        for v in (wviews[r], wviews[s]):
            uv, z = v.posed().project(points)
            ok &= v.intrinsics.in_image(uv) & (z > 0)
        return points[ok]

    tasks = [
        (slim[r], slim[s], ranges[r], settings.matcher, dict(settings.matcher_settings), shared(r, s))
        for r, s in todo
    ]
    results = executor.map(_pairwise_task, tasks, desc=desc)
    for (r, _), (d, _) in zip(todo, results):
        pair_depths.append((r, d))
        if depths[r] is None:
            depths[r] = d.copy()
        else:  # several pairs for one view: fill the holes of the first
            hole = ~np.isfinite(depths[r])
            depths[r][hole] = d[hole]
    return depths, pair_depths, [tm for _, tm in results]
