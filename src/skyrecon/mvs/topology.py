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

import numpy as np

from skyrecon.errors import InputError
from skyrecon.mvs.frames import WorkingView

__all__ = ["TOPOLOGIES", "topology_pairs", "neighbors_from_pairs", "select_neighbors", "angle_weight"]

TOPOLOGIES: tuple[str, ...] = ("auto", "360", "overlapping", "adjacent", "skipping_1", "skipping_2")

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
    theta_deg: np.ndarray, lo: float = 5.0, hi: float = 45.0, best: tuple[float, float] = (10.0, 30.0)
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
    for r in range(n):
        X = P[vis_sparse[r]] if len(P) else P
        vis = vis_sparse[:, vis_sparse[r]] if len(P) else vis_sparse
        frustum_range = None if depth_ranges is None else depth_ranges[r]
        if len(X) < min_shared and frustum_range is not None:
            X = _frustum_samples(views[r], frustum_range)
            vis = np.stack([visible(v, X) for v in views])
        cand: list[tuple[float, int]] = []
        if len(X):
            dr = X - centers[r]
            dr /= np.linalg.norm(dr, axis=1, keepdims=True)
            for s in range(n):
                if s == r:
                    continue
                m = vis[s]
                if m.sum() < min_shared:
                    continue
                ds = X[m] - centers[s]
                ds /= np.linalg.norm(ds, axis=1, keepdims=True)
                theta = np.degrees(np.arccos(np.clip(np.sum(dr[m] * ds, axis=1), -1, 1)))
                w = angle_weight(theta, min_angle_deg, max_angle_deg)
                if np.count_nonzero(w) < min_shared:
                    continue
                cand.append((float(w.sum()), s))
        cand.sort(key=lambda t: (-t[0], t[1]))
        neighbors.append([s for _, s in cand[:num_sources]])
        scores.append([sc for sc, _ in cand[:num_sources]])
    return neighbors, scores
