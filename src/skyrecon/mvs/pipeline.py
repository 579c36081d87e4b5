"""The MVS stage: posed images in, per-view depth maps and one fused, coloured cloud out.

Steps (each timed in ``MVSResult.timings_s``):

1. ``load``: images resized to the working resolution (one full-size image in memory at a time);
2. ``sparse``: SIFT matches checked against the known epipolar geometry and triangulated, giving
   every view's depth range and the points the automatic view selection scores (or, when the
   caller gives them, known points such as the SfM model's: no matching);
3. ``select``: sources per reference view (``auto``) or the pairs of a named topology;
4. ``depth``: PatchMatch (or pairwise rectified stereo) per view, fanned out on the executor
   (each task carries only its reference and source views);
   ``prior``: plain (textureless) segments that PatchMatch left empty take the plane their
   surroundings support (:mod:`skyrecon.mvs.planar_prior`), per view on the executor; then
   the segments still empty try the planes their neighbours filled with (a second pass);
5. ``fusion``: geometric-consistency fusion (or plain concatenation);
6. ``cleanup``: statistical outlier removal, normals (PCA, oriented to the cameras), optional
   voxel averaging; optional ``mesh``.

Each step is a function that reads and fills one typed run state (``_MVSRun``); ``_STEPS``
lists them in order. World frame and metres throughout; depth maps are at the working
resolution, with the scaled intrinsics in each :class:`~skyrecon.core.DepthMap`.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np

from skyrecon import progress as _progress
from skyrecon.core import DepthMap, PointCloud, PosedView
from skyrecon.errors import InputError
from skyrecon.executor import Executor, get_executor
from skyrecon.memory import release_free_memory
from skyrecon.mvs.cleanup import clean_fused_cloud
from skyrecon.mvs.depth_tasks import TaskTimings, apply_planar_prior, estimate_depths
from skyrecon.mvs.frames import WorkingView
from skyrecon.mvs.fusion import FusedCloud, fuse_concat, fuse_consistent
from skyrecon.mvs.inputs import ImagesArg, load_working_views
from skyrecon.mvs.mesh import mesh_from_depth_maps
from skyrecon.mvs.planar_prior import FilledPlanes, dominant_planes, horizontal_planes
from skyrecon.mvs.settings import MVSSettings
from skyrecon.mvs.sparse import depth_range_from_points, sparse_scene
from skyrecon.mvs.topology import neighbors_from_pairs, select_neighbors, topology_pairs

__all__ = ["MVSResult", "run_mvs"]

#: vertices (V, 3) float32 world metres, faces (F, 3) int32, vertex colours (V, 3) uint8 RGB.
Mesh = tuple[np.ndarray, np.ndarray, np.ndarray]


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
    mesh: Mesh | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def _empty_fused() -> FusedCloud:
    empty = PointCloud(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8))
    return FusedCloud(empty, np.zeros(0, np.int32), np.zeros(0, np.int32))


@dataclass
class _MVSRun:
    """What the steps of one :func:`run_mvs` call share; each step fills in its part.

    View indices (in ``blank``, ``neighbors``, ``pairs``, ``depths``) refer to ``views``; the
    world frame and metres throughout.

    Attributes:
        inputs: the cameras given; images: their images (see :func:`run_mvs`).
        settings, executor, progress, workspace, known_points: as given to :func:`run_mvs`.
        views: ``load``: the working views (images at the working resolution, scaled intrinsics).
        blank: ``load``: views whose image has no texture (neither references nor sources).
        sparse_points: ``sparse``: (N, 3) triangulated feature points (or the known points),
            world metres.
        ranges: ``sparse``: per view the (near, far) depth range, metres, or None if unknown.
        neighbors: ``select``: per view the source views of its depth.
        pairs: ``select``: the (reference, source) pairs matched.
        depths: ``depth``: per view (H, W) float32 depth, metres, NaN invalid, or None
            (``prior``: with the plain segments filled).
        costs: ``depth``: per view the PatchMatch cost (H, W) float32, or None (emptied by ``fusion``).
        prior_filled: ``prior``: per view the (H, W) bool pixels whose depth a plane gave, or None
            (fusion asks fewer agreeing views of them, ``FusionSettings.min_consistent_prior``);
            empty when fusion would not read them (that count is not below ``min_consistent``).
        pair_depths: ``depth``: (reference, depth) per task, for ``concat`` fusion.
        fused: ``fusion``: the fused cloud before cleanup.
        cloud, support: ``cleanup``: the final cloud and per-point support.
        mesh: ``mesh``: the surface mesh, when asked for.
        timings, diagnostics, warnings: see :class:`MVSResult`.
    """

    inputs: list[PosedView]
    images: ImagesArg
    settings: MVSSettings
    executor: Executor
    progress: bool
    workspace: str | None = None
    known_points: np.ndarray | None = None
    views: list[WorkingView] = field(default_factory=list)
    blank: list[int] = field(default_factory=list)
    sparse_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    ranges: list[tuple[float, float] | None] = field(default_factory=list)
    neighbors: list[list[int]] = field(default_factory=list)
    pairs: list[tuple[int, int]] = field(default_factory=list)
    depths: list[np.ndarray | None] = field(default_factory=list)
    costs: list[np.ndarray | None] = field(default_factory=list)
    prior_filled: list[np.ndarray | None] = field(default_factory=list)
    pair_depths: list[tuple[int, np.ndarray]] = field(default_factory=list)
    fused: FusedCloud = field(default_factory=_empty_fused)
    cloud: PointCloud = field(default_factory=lambda: _empty_fused().cloud)
    support: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    mesh: Mesh | None = None
    timings: dict[str, float] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


# ------------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------------
def _names(views: Sequence[WorkingView], idx: Sequence[int]) -> str:
    names = [views[i].name for i in idx]
    return ", ".join(names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")


def _names_of(names: Sequence[str]) -> str:
    return ", ".join(names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")


def _all_names(views: Sequence[WorkingView]) -> str:
    return _names(views, range(len(views)))


def _check_view_names(views: Sequence[PosedView]) -> None:
    if len(views) < 2:
        raise InputError(f"MVS needs at least 2 views, got {len(views)}")
    seen: set[str] = set()
    for v in views:
        if v.name in seen:
            raise InputError(f"view name {v.name!r} appears twice; view names must be unique")
        seen.add(v.name)


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
        near, far = settings.depth_range
        return [(near, far)] * len(views)
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


# ------------------------------------------------------------------------------------------------
# the steps, in order (each reads and fills an _MVSRun)
# ------------------------------------------------------------------------------------------------
def _load(run: _MVSRun) -> None:
    """Images at the working resolution; blank images are left out (all blank: an error)."""
    run.views = load_working_views(run.inputs, run.images, run.settings.max_image_size)
    run.diagnostics["working_size"] = {v.stem: (v.shape[1], v.shape[0]) for v in run.views}
    run.blank = _blank_views(run.views)
    if len(run.blank) == len(run.views):
        raise InputError(
            f"every image is blank (no texture): {_names(run.views, run.blank)}; check the images"
        )
    if run.blank:
        run.warnings.append(f"blank images (no texture, no depth): {_names(run.views, run.blank)}")


#: at most this many known points (an SfM model's) are used; more add time, not information
MAX_KNOWN_POINTS = 200_000


def _sparse(run: _MVSRun) -> None:
    """Matched and triangulated features (or the known points given); each view's depth range from them."""
    known = np.zeros((0, 3))
    if run.known_points is not None:
        known = np.asarray(run.known_points, np.float64).reshape(-1, 3)
        known = known[np.isfinite(known).all(axis=1)]
    if len(known):
        step = -(-len(known) // MAX_KNOWN_POINTS)  # an even subsample: deterministic
        run.sparse_points = known[::step]
        run.diagnostics["sparse_points_source"] = "given"
    else:
        run.sparse_points = sparse_scene(run.views, max_features=run.settings.sparse_max_features).points
        run.diagnostics["sparse_points_source"] = "matched"
    run.diagnostics["sparse_points"] = len(run.sparse_points)
    run.ranges = _depth_ranges(run.views, run.settings, run.sparse_points, run.warnings)
    if all(r is None for r in run.ranges):
        raise InputError(
            f"no matched features between any two of the {len(run.views)} views ({_all_names(run.views)}): "
            "they see nothing in common (or the cameras do not belong to these images); pass depth_range if "
            "the scene is textureless"
        )


def _select(run: _MVSRun) -> None:
    """Sources per reference view and the pairs matched; blank views are neither."""
    neighbors, pairs = _choose_pairs(run.views, run.settings, run.sparse_points, run.ranges)
    blank = run.blank
    if blank:
        neighbors = [
            [] if r in blank else [s for s in nb if s not in blank] for r, nb in enumerate(neighbors)
        ]
        pairs = [(r, s) for r, s in pairs if r not in blank and s not in blank]
    isolated = [i for i, nb in enumerate(neighbors) if not nb and i not in blank]
    if len(isolated) + len(blank) >= len(run.views) or not pairs:
        raise InputError(f"no two views see enough in common to match: {_all_names(run.views)}")
    if isolated:
        run.warnings.append(
            f"views sharing too little with any other view (no depth): {_names(run.views, isolated)}"
        )
    run.neighbors, run.pairs = neighbors, pairs


def _depth(run: _MVSRun) -> None:
    """Per-view depth maps, fanned out on the executor."""
    est = estimate_depths(
        run.views,
        run.settings,
        run.neighbors,
        run.pairs,
        run.ranges,
        run.executor,
        progress=run.progress,
        points=run.sparse_points,
        cache_dir=None if run.workspace is None else os.path.join(run.workspace, "depth_tasks"),
    )
    run.depths = est.depths
    # each task's own depth is read only by ``concat`` fusion; kept otherwise, the planar prior's
    # replaced depths would stay resident beside the new ones (1.2 MB a view at 640 px)
    run.pair_depths = est.pair_depths if run.settings.fusion == "concat" else []
    run.diagnostics["depth_task_ms"] = est.task_timings
    run.costs = est.costs
    empty = [i for i, d in enumerate(run.depths) if d is not None and not np.isfinite(d).any()]
    if empty:
        run.warnings.append(f"no depth could be estimated for {_names(run.views, empty)}")


def _fusion_neighbors(run: _MVSRun) -> list[list[int]]:
    checked = [(r, s) for r, nb in enumerate(run.neighbors) for s in nb]
    return neighbors_from_pairs(checked, len(run.views))


def _filled_by_prior(
    before: list[np.ndarray | None], after: list[np.ndarray | None]
) -> list[np.ndarray | None]:
    """Per view the (H, W) bool pixels without a depth ``before`` that have one ``after``."""
    return [
        None if a is None or b is None else (np.isfinite(b) & ~np.isfinite(a)) for a, b in zip(before, after)
    ]


def _shared_planes_pass(
    run: _MVSRun,
    linked: list[list[int]],
    before: list[np.ndarray | None],
    filled: dict[int, FilledPlanes],
    cache_dir: str | None,
) -> dict[int, dict[str, Any]]:
    """The planar prior's second pass: each view's segments still empty try the planes its
    fusion neighbours (``linked``, :func:`_fusion_neighbors`) filled with (``filled``, per view
    index); ``run.depths`` are updated. The pixels the first pass filled are no support (their
    cost is PatchMatch's), and the see-through test reads the PatchMatch depths (``before``).
    Returns the reports per view."""
    offered = [
        FilledPlanes.concat([filled[q] for q in linked[r] if q in filled]) for r in range(len(run.views))
    ]
    costs = [
        None if c is None or m is None else np.where(m, np.inf, c)
        for c, m in zip(run.costs, _filled_by_prior(before, run.depths))
    ]
    run.depths, reports, _ = apply_planar_prior(
        run.views,
        run.settings,
        run.neighbors,
        run.ranges,
        run.depths,
        costs,
        np.zeros((0, 4)),  # the candidates are the offered planes only
        run.executor,
        progress=run.progress,
        points=run.sparse_points,
        cache_dir=cache_dir,
        offered=offered,
        source_depths=before,
    )
    return reports


def _prior(run: _MVSRun) -> None:
    """Plain segments without depth take the plane their surroundings support: the dominant planes
    of the multi-view consistent PatchMatch points (and sparse points), or a triangle or
    Manhattan plane of the view's own support; then (``propagate``) the segments still empty
    try the planes the view's fusion neighbours filled with (diagnostics: ``shared_planes`` per
    view). Views where it fails keep their depth (see diagnostics)."""
    s = run.settings
    linked = _fusion_neighbors(run)
    pre = fuse_consistent(run.views, run.depths, linked, s.fusion_settings)
    pts = np.concatenate([pre.cloud.points.astype(np.float64), run.sparse_points.reshape(-1, 3)])
    planes = np.concatenate(
        [dominant_planes(pts, s.planar_prior, seed=s.seed), horizontal_planes(pts, s.planar_prior)]
    )
    before = run.depths
    cache_dir = None if run.workspace is None else os.path.join(run.workspace, "prior_tasks")
    run.depths, reports, filled = apply_planar_prior(
        run.views,
        s,
        run.neighbors,
        run.ranges,
        run.depths,
        run.costs,
        planes,
        run.executor,
        progress=run.progress,
        points=run.sparse_points,
        cache_dir=cache_dir,
    )
    if s.planar_prior.propagate and any(len(f.planes) for f in filled.values()):
        for r, rep in _shared_planes_pass(run, linked, before, filled, cache_dir).items():
            reports.setdefault(r, {})["shared_planes"] = rep
    fs = s.fusion_settings
    if s.fusion == "consistency" and fs.checks_prior_apart:  # else unread
        run.prior_filled = _filled_by_prior(before, run.depths)
    prior = {run.views[r].stem: rep for r, rep in reports.items()}
    run.diagnostics["planar_prior"] = {
        "dominant_planes": np.round(planes, 4).tolist(),
        "views": prior,
    }
    for second, kept in ((False, "PatchMatch depth kept"), (True, "first pass kept")):
        why = {
            n: str((p.get("shared_planes", {}) if second else p).get("fallback", ""))
            for n, p in prior.items()
        }
        failed = [n for n, w in why.items() if w.startswith("planar prior failed")]
        if failed:
            which = "planar prior's second pass" if second else "planar prior"
            run.warnings.append(f"{which} failed ({kept}) in {_names_of(failed)}: {why[failed[0]]}")


def _fuse(run: _MVSRun) -> None:
    """One cloud: depths that agree across views, or every pair's cloud concatenated. The
    PatchMatch costs are released first (nothing after the prior reads them; 1.2 MB a view)."""
    run.costs = []
    if run.settings.fusion == "concat":
        run.fused = fuse_concat(run.views, run.pair_depths)
    else:
        run.fused = fuse_consistent(
            run.views,
            run.depths,
            _fusion_neighbors(run),
            run.settings.fusion_settings,
            run.prior_filled or None,
        )
    if not run.settings.mesh:
        _release_pixels(run)


def _release_pixels(run: _MVSRun) -> None:
    """Drop the working images (2.4 MB a view at 640 px) once nothing reads them: after fusion
    only the cameras are used (normals' orientation, the result), unless a mesh is coloured from
    them (their sizes are in the diagnostics since loading)."""
    rgb, grey, valid = np.zeros((0, 0, 3), np.uint8), np.zeros((0, 0), np.float32), np.zeros((0, 0), bool)
    run.views = [replace(v, rgb=rgb, grey=grey, valid=valid) for v in run.views]


def _cleanup(run: _MVSRun) -> None:
    """Outliers and floaters removed, normals, optional voxel averaging."""
    clean = clean_fused_cloud(run.fused, run.views, run.settings)
    run.cloud, run.support = clean.cloud, clean.support
    run.diagnostics.update(clean.counts)
    if len(run.cloud) == 0:
        run.warnings.append(
            "the fused cloud is empty: no depth was consistent across views (check that the cameras belong "
            "to the images, or lower fusion_settings.min_consistent)"
        )


def _mesh(run: _MVSRun) -> None:
    """A surface mesh from the depth maps (TSDF fusion + marching cubes)."""
    run.mesh = mesh_from_depth_maps(run.views, run.depths, run.cloud, run.settings.mesh_voxel_m)


class _Step(NamedTuple):
    name: str  # the key in MVSResult.timings_s
    run: Callable[[_MVSRun], None]
    wanted: Callable[[_MVSRun], bool] = lambda run: True


_STEPS: tuple[_Step, ...] = (
    _Step("load", _load),
    _Step("sparse", _sparse),
    _Step("select", _select),
    _Step("depth", _depth),
    _Step(
        "prior",
        _prior,
        wanted=lambda run: run.settings.depth_method == "patchmatch" and run.settings.planar_prior.enabled,
    ),
    _Step("fusion", _fuse),
    _Step("cleanup", _cleanup),
    _Step("mesh", _mesh, wanted=lambda run: run.settings.mesh and len(run.cloud) > 0),
)


def _result(run: _MVSRun, t_start: float, cpu_start: float) -> MVSResult:
    """The MVSResult of a finished run, with totals (wall clock, and CPU including worker processes)."""
    views, depths, diag = run.views, run.depths, run.diagnostics
    depth_maps = {
        v.stem: DepthMap(d, v.intrinsics, v.cam_from_world) for v, d in zip(views, depths) if d is not None
    }
    diag["valid_fraction"] = {
        v.stem: float(np.isfinite(d).mean()) for v, d in zip(views, depths) if d is not None
    }
    run.timings["total"] = time.perf_counter() - t_start
    # CPU seconds: this process (all its threads) plus the tasks that ran in worker processes
    task_timings: list[TaskTimings] = diag.get("depth_task_ms", [])
    worker_cpu = sum(tm["cpu"] for tm in task_timings if tm.get("pid") != os.getpid()) / 1e3
    diag["cpu_s"] = time.process_time() - cpu_start + worker_cpu
    return MVSResult(
        cloud=run.cloud,
        depth_maps=depth_maps,
        neighbors={views[r].name: [views[s].name for s in nb] for r, nb in enumerate(run.neighbors)},
        pairs=run.pairs,
        view_names=[v.name for v in views],
        depth_ranges={v.name: r for v, r in zip(views, run.ranges) if r is not None},
        support=run.support,
        mesh=run.mesh,
        timings_s=run.timings,
        diagnostics=diag,
        warnings=run.warnings,
    )


@contextmanager
def _progress_bars(enabled: bool) -> Iterator[None]:
    """Progress bars off inside the block unless ``enabled`` (the global setting is restored after)."""
    previous = _progress._enabled
    if not enabled:
        _progress.set_progress_enabled(False)
    try:
        yield
    finally:
        _progress._enabled = previous


# ------------------------------------------------------------------------------------------------
# the stage
# ------------------------------------------------------------------------------------------------
def run_mvs(
    views: Sequence[PosedView],
    images: ImagesArg = None,
    settings: MVSSettings = MVSSettings(),
    executor: Executor | None = None,
    progress: bool = True,
    workspace: str | os.PathLike | None = None,
    known_points: np.ndarray | None = None,
) -> MVSResult:
    """Dense multi-view stereo: per-view depth maps and one fused coloured cloud.

    Runs the steps of the module docstring in order, each timed in ``timings_s``.

    Args:
        views: the cameras (intrinsics without distortion, ``cam_from_world`` poses, metres),
            at least 2, names unique.
        images: None (read each ``view.image_path``), one entry per view (an (H, W) grey or
            (H, W, 3) RGB uint8 array, an ``(image, alpha)`` tuple with alpha 0 = no data, or a
            path), or a callable ``f(index)`` returning one of those.
        settings: see :class:`MVSSettings`.
        executor: where per-view work runs (default :func:`skyrecon.executor.get_executor`).
        progress: show progress bars (subject to the global progress setting).
        workspace: a folder where each view's depth is kept as soon as it is computed
            (``depth_tasks/<hash>.pkl``, and its planar prior in ``prior_tasks/``); a rerun with
            the same views, images and settings (a killed run resumed, or another fusion)
            reuses them. None: nothing kept.
        known_points: (N, 3) world points (metres) on the scene's surfaces, such as the points
            of the SfM model the cameras come from: the ``sparse`` step then takes them (an
            even subsample of at most :data:`MAX_KNOWN_POINTS`) for the depth ranges and the
            choice of sources instead of matching features again. None or empty: matched.
    Returns:
        MVSResult (world frame). Problems that leave some views out are listed in
        ``warnings`` with the view names.
    Raises:
        InputError: fewer than 2 views, duplicate names, images that do not match their
            cameras, every image blank, or no two views that see anything in common.
    """
    t_start = time.perf_counter()
    cpu_start = time.process_time()
    inputs = list(views)
    _check_view_names(inputs)
    with _progress_bars(progress):
        ws = None if workspace is None else os.fspath(workspace)
        run = _MVSRun(inputs, images, settings, executor or get_executor(), progress, ws, known_points)
        for step in _STEPS:
            if step.wanted(run):
                t = time.perf_counter()
                step.run(run)
                release_free_memory()  # what the step freed leaves the resident size
                run.timings[step.name] = time.perf_counter() - t
    return _result(run, t_start, cpu_start)
