"""Which views are matched with which: the write-up's named camera topologies and an automatic
per-view neighbour selection.

Named topologies (a camera ring in order, generalised from the write-up's 12 cameras to N)::

    360          (i, i+1 mod N) for every i            12 views: (0,1) (1,2) ... (11,0)
    overlapping  (i, i+1) for i < N-1                  12 views: (0,1) (1,2) ... (10,11)
    adjacent     (i, i+1) for i = 0, 2, 4, ...         12 views: (0,1) (2,3) ... (10,11)
    skipping_1   (i, i+1) for i = 0, 3, 6, ...         12 views: (0,1) (3,4) (6,7) (9,10)
    skipping_2   (i, i+1) for i = 0, 4, 8, ...         12 views: (0,1) (4,5) (8,9)

A pair (ref, src) means "the depth of view ref is computed against view src".

``auto`` chooses, for every reference view, the source views whose shared sparse points are seen
under a good triangulation angle (a score summed over points, COLMAP/MVSNet style), or when no
sparse points are available, points sampled in the reference frustum at its depth range.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from skyrecon.errors import InputError
from skyrecon.mvs.frames import WorkingView

__all__ = ["TOPOLOGIES", "topology_pairs", "neighbors_from_pairs", "select_neighbors", "angle_weight"]

TOPOLOGIES: tuple[str, ...] = ("auto", "360", "overlapping", "adjacent", "skipping_1", "skipping_2")

_BEST_ANGLES_DEG = (10.0, 30.0)
"""Triangulation angles (degrees) that score 1 in :func:`angle_weight`."""

_STEP = {"overlapping": 1, "adjacent": 2, "skipping_1": 3, "skipping_2": 4}


def topology_pairs(name: str, n_views: int) -> list[tuple[int, int]]:
    """The (reference, source) index pairs of a named topology for ``n_views`` views on a ring.

    Raises:
        InputError: unknown name (``auto`` is not a fixed list: use :func:`select_neighbors`) or
            fewer than 2 views.
    """
    if n_views < 2:
        raise InputError(f"a topology needs at least 2 views, got {n_views}")
    if name == "360":
        return [(i, (i + 1) % n_views) for i in range(n_views)] if n_views > 2 else [(0, 1)]
    if name in _STEP:
        return [(i, i + 1) for i in range(0, n_views - 1, _STEP[name])]
    choices = ", ".join(TOPOLOGIES)
    if name == "auto":
        raise InputError(
            "topology 'auto' has no fixed pair list; it is chosen from the cameras (select_neighbors)"
        )
    raise InputError(f"unknown topology {name!r}; choose one of {choices}")


def neighbors_from_pairs(
    pairs: list[tuple[int, int]], n_views: int, symmetric: bool = True
) -> list[list[int]]:
    """Per-view source lists from (ref, src) pairs; ``symmetric`` also uses each pair backwards."""
    out: list[list[int]] = [[] for _ in range(n_views)]
    for a, b in pairs:
        if b not in out[a]:
            out[a].append(b)
        if symmetric and a not in out[b]:
            out[b].append(a)
    return out


def angle_weight(
    theta_deg: np.ndarray, lo: float = 5.0, hi: float = 45.0, best: tuple[float, float] = _BEST_ANGLES_DEG
) -> np.ndarray:
    """Score of a triangulation angle: 1 in ``best``, falling off linearly to 0 at ``lo`` and ``hi``."""
    t = np.asarray(theta_deg, dtype=np.float64)
    w = np.ones_like(t)
    w = np.where(t < best[0], np.clip((t - lo) / (best[0] - lo), 0, 1), w)
    w = np.where(t > best[1], np.clip((hi - t) / (hi - best[1]), 0, 1), w)
    return w


def _frustum_samples(view: WorkingView, depth_range: tuple[float, float], n: int = 12) -> np.ndarray:
    """World points on a grid of the view's pixels at a few depths in its range."""
    intr = view.intrinsics
    u = np.linspace(0.1, 0.9, n) * (intr.width - 1)
    v = np.linspace(0.1, 0.9, n) * (intr.height - 1)
    uu, vv = np.meshgrid(u, v)
    pix = np.stack([uu.ravel(), vv.ravel()], axis=1)
    near, far = depth_range
    depths = 1.0 / np.linspace(1.0 / near, 1.0 / far, 5)[1:-1]
    pts = [intr.unproject(pix, d) for d in depths]
    return view.cam_from_world.inverse().apply(np.concatenate(pts))


@njit(cache=True, nogil=True)
def _pair_scores_kernel(
    P: np.ndarray,
    centers: np.ndarray,
    r: int,
    pts_of_r: np.ndarray,
    pt_ptr: np.ndarray,
    pt_views: np.ndarray,
    lo: float,
    hi: float,
    best_lo: float,
    best_hi: float,
    total: np.ndarray,
    counted: np.ndarray,
    shared: np.ndarray,
) -> None:
    """For every view s != r, over the points ``pts_of_r`` (indices into P (N, 3)) that r sees
    and s sees too (``pt_views[pt_ptr[p]:pt_ptr[p + 1]]``: the views seeing point p): ``shared[s]``
    += 1, ``total[s]`` += the :func:`angle_weight` of the triangulation angle, ``counted[s]`` +=
    1 when that weight is non-zero. ``total``, ``counted``, ``shared`` (n,) are zero on entry."""
    for p in pts_of_r:
        drx = P[p, 0] - centers[r, 0]
        dry = P[p, 1] - centers[r, 1]
        drz = P[p, 2] - centers[r, 2]
        nr = math.sqrt(drx * drx + dry * dry + drz * drz)
        drx /= nr
        dry /= nr
        drz /= nr
        for k in range(pt_ptr[p], pt_ptr[p + 1]):
            s = pt_views[k]
            if s == r:
                continue
            shared[s] += 1
            dsx = P[p, 0] - centers[s, 0]
            dsy = P[p, 1] - centers[s, 1]
            dsz = P[p, 2] - centers[s, 2]
            ns = math.sqrt(dsx * dsx + dsy * dsy + dsz * dsz)
            c = (drx * dsx + dry * dsy + drz * dsz) / ns
            c = min(1.0, max(-1.0, c))
            t = math.acos(c) * (180.0 / math.pi)
            w = 1.0
            if t < best_lo:
                w = min(1.0, max(0.0, (t - lo) / (best_lo - lo)))
            if t > best_hi:
                w = min(1.0, max(0.0, (hi - t) / (hi - best_hi)))
            total[s] += w
            if w > 0.0:
                counted[s] += 1


def _views_per_point(vis: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """From (n, M) bool visibility: (view_ptr (n + 1,), point_of (K,): the points each view sees,
    view-major; pt_ptr (M + 1,), pt_views (K,) int64: the views that see each point)."""
    n, m = vis.shape
    view_of, point_of = np.nonzero(vis)
    view_ptr = np.searchsorted(view_of, np.arange(n + 1))
    by_point = np.argsort(point_of, kind="stable")
    pt_ptr = np.searchsorted(point_of[by_point], np.arange(m + 1))
    return view_ptr, point_of.astype(np.int64), pt_ptr, view_of[by_point].astype(np.int64)


def _scored_sources(
    X: np.ndarray,
    centers: np.ndarray,
    r: int,
    pts_of_r: np.ndarray,
    pt_ptr: np.ndarray,
    pt_views: np.ndarray,
    min_angle_deg: float,
    max_angle_deg: float,
    min_shared: int,
) -> list[tuple[float, int]]:
    """(score, source) of every view other than ``r`` sharing at least ``min_shared`` of the
    points ``pts_of_r`` (indices into X (N, 3)) with it, as many with a non-zero weight (see
    :func:`_pair_scores_kernel`)."""
    n = len(centers)
    total, counted, shared = np.zeros(n), np.zeros(n, np.int64), np.zeros(n, np.int64)
    _pair_scores_kernel(
        X,
        centers,
        r,
        pts_of_r,
        pt_ptr,
        pt_views,
        min_angle_deg,
        max_angle_deg,
        *_BEST_ANGLES_DEG,
        total,
        counted,
        shared,
    )
    ok = np.nonzero((shared >= min_shared) & (counted >= min_shared))[0]
    return [(float(total[s]), int(s)) for s in ok if s != r]


def select_neighbors(
    views: list[WorkingView],
    num_sources: int = 4,
    points_world: np.ndarray | None = None,
    depth_ranges: list[tuple[float, float] | None] | None = None,
    min_angle_deg: float = 5.0,
    max_angle_deg: float = 45.0,
    min_shared: int = 10,
) -> tuple[list[list[int]], list[list[float]]]:
    """Choose up to ``num_sources`` source views for every reference view.

    For reference r and candidate s, every sparse point that projects inside both images (in
    front of both cameras) contributes :func:`angle_weight` of its triangulation angle; a
    candidate needs at least ``min_shared`` such points with a non-zero weight. Without sparse
    points (or too few for a view), points sampled in the reference frustum within its depth
    range stand in for them.

    Args:
        views: working views.
        num_sources: most sources per reference.
        points_world: (N, 3) sparse world points, metres (or None).
        depth_ranges: per view (near, far) for the frustum fallback (None entries skip it).
        min_angle_deg, max_angle_deg: triangulation angles outside this range do not count.
        min_shared: points needed to accept a source.
    Returns:
        (neighbors, scores): per view the chosen source indices, best first, and their scores.
    """
    n = len(views)
    P = np.zeros((0, 3)) if points_world is None else np.asarray(points_world, np.float64).reshape(-1, 3)
    centers = np.stack([v.center_world for v in views])
    neighbors: list[list[int]] = []
    scores: list[list[float]] = []

    def visible(view: WorkingView, X: np.ndarray) -> np.ndarray:
        uv, z = view.posed().project(X)
        with np.errstate(invalid="ignore"):
            return view.intrinsics.in_image(uv) & (z > 0)

    vis_sparse = np.stack([visible(v, P) for v in views]) if len(P) else np.zeros((n, 0), bool)
    view_ptr, point_of, pt_ptr, pt_views = _views_per_point(vis_sparse)
    angles = (min_angle_deg, max_angle_deg, min_shared)
    for r in range(n):
        frustum_range = None if depth_ranges is None else depth_ranges[r]
        pts_of_r = point_of[view_ptr[r] : view_ptr[r + 1]]
        if len(pts_of_r) < min_shared and frustum_range is not None:
            X = _frustum_samples(views[r], frustum_range)
            _, _, x_ptr, x_views = _views_per_point(np.stack([visible(v, X) for v in views]))
            all_x = np.arange(len(X), dtype=np.int64)
            cand = _scored_sources(X, centers, r, all_x, x_ptr, x_views, *angles)
        else:
            cand = _scored_sources(P, centers, r, pts_of_r, pt_ptr, pt_views, *angles)
        cand.sort(key=lambda t: (-t[0], t[1]))
        neighbors.append([s for _, s in cand[:num_sources]])
        scores.append([sc for sc, _ in cand[:num_sources]])
    return neighbors, scores
