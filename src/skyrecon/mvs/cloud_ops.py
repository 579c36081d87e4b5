"""Point-cloud clean-up: normals by PCA, statistical outlier removal, voxel down-sampling.

All clouds are (N, 3) float32 world points in metres; neighbour queries use ``scipy``'s cKDTree
and run in chunks so that memory stays bounded for millions of points.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

__all__ = [
    "knn_mean_distance_and_normals",
    "statistical_outlier_mask",
    "voxel_downsample_indices",
    "orient_normals",
]

_CHUNK = 100_000


def knn_mean_distance_and_normals(
    points: np.ndarray, k: int = 16, workers: int = -1
) -> tuple[np.ndarray, np.ndarray]:
    """Mean distance to the ``k`` nearest neighbours and the PCA normal of every point.

    Args:
        points: (N, 3) metres.
        k: neighbours (the point itself excluded).
        workers: threads for the KD-tree queries (-1: all cores).
    Returns:
        (mean_dist (N,) float64 metres, normals (N, 3) float32 unit, unoriented; the direction
        of least variance of the point and its neighbours).
    """
    P = np.asarray(points, np.float64)
    n = len(P)
    if n == 0:
        return np.zeros(0), np.zeros((0, 3), np.float32)
    kk = min(k + 1, n)
    tree = cKDTree(P)
    mean_d = np.zeros(n)
    normals = np.zeros((n, 3), np.float32)
    for a in range(0, n, _CHUNK):
        b = min(n, a + _CHUNK)
        dist, idx = tree.query(P[a:b], k=kk, workers=workers)
        dist = dist.reshape(b - a, kk)
        idx = idx.reshape(b - a, kk)
        mean_d[a:b] = dist[:, 1:].mean(axis=1) if kk > 1 else 0.0
        nb = P[idx]  # (m, kk, 3)
        c = nb - nb.mean(axis=1, keepdims=True)
        cov = np.einsum("mki,mkj->mij", c, c)
        _, vec = np.linalg.eigh(cov)
        normals[a:b] = vec[:, :, 0]
    return mean_d, normals


def orient_normals(
    points: np.ndarray,
    normals: np.ndarray,
    viewpoints: np.ndarray,
    viewpoint_index: np.ndarray | None = None,
) -> np.ndarray:
    """Flip normals (N, 3) to face their viewpoints, world frame.

    ``viewpoints`` is (N, 3) (one per point), or (V, 3) with ``viewpoint_index`` (N,) giving each
    point's row (e.g. the camera centres and the view that emitted each point). Works in
    chunks: no (N, 3) float64 temporaries. Returns float32 (N, 3).
    """
    out = np.array(normals, np.float32, copy=True)
    for a in range(0, len(out), _CHUNK):
        b = min(len(out), a + _CHUNK)
        vp = viewpoints[a:b] if viewpoint_index is None else viewpoints[viewpoint_index[a:b]]
        to_cam = np.asarray(vp, np.float64) - np.asarray(points[a:b], np.float64)
        flip = np.sum(to_cam * normals[a:b], axis=1) < 0
        out[a:b][flip] *= -1
    return out


def statistical_outlier_mask(mean_dist: np.ndarray, std_ratio: float = 2.0) -> np.ndarray:
    """(N,) bool inliers: mean k-NN distance at most ``mean + std_ratio * std`` of all points."""
    if len(mean_dist) == 0:
        return np.zeros(0, bool)
    mu = float(np.mean(mean_dist))
    sd = float(np.std(mean_dist))
    return mean_dist <= mu + std_ratio * sd


def voxel_downsample_indices(points: np.ndarray, voxel_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Group points by voxel of size ``voxel_m`` metres.

    Returns:
        (inverse (N,) int64 voxel id of every point, counts (M,) int64 points per voxel); use
        ``np.add.at`` or ``np.bincount`` with ``inverse`` to average attributes.
    """
    key = np.floor(np.asarray(points, np.float64) / voxel_m).astype(np.int64)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return inverse.reshape(-1), counts


@njit(cache=True, nogil=True, boundscheck=False)
def _find(parent: np.ndarray, i: int) -> int:  # pragma: no cover - jit
    """The root of ``i`` in a union-find forest, halving the path on the way."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True, nogil=True, boundscheck=False)
def _union(parent: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:  # pragma: no cover - jit
    """Join the trees of every pair (a[e], b[e]) in the forest ``parent`` (N,) int64 (in place)."""
    for e in range(len(a)):
        ra = _find(parent, a[e])
        rb = _find(parent, b[e])
        if ra != rb:
            if ra < rb:
                parent[rb] = ra
            else:
                parent[ra] = rb


@njit(cache=True, nogil=True, boundscheck=False)
def _roots(parent: np.ndarray) -> np.ndarray:  # pragma: no cover - jit
    """(N,) int64: each element's root (its component's smallest index)."""
    out = np.empty(len(parent), np.int64)
    for i in range(len(parent)):
        out[i] = _find(parent, i)
    return out


def small_component_mask(
    points: np.ndarray, radius_m: float, min_fraction: float = 0.01, k: int = 8, workers: int = -1
) -> np.ndarray:
    """(N,) bool: points in connected components holding at least ``min_fraction`` of all points.

    Two points are linked when one is among the other's ``k`` nearest neighbours and they are
    closer than ``radius_m`` metres: detached clusters (floaters, background fragments) fall
    into small components and are dropped.
    """
    P = np.asarray(points, np.float64)
    n = len(P)
    if n == 0:
        return np.zeros(0, bool)
    kk = min(k + 1, n)
    tree = cKDTree(P)
    # the links are found in chunks and merged at once into a union-find forest: memory stays at a
    # few arrays of N, never the N * k links (a 24-million-point survey cloud needs no more)
    parent = np.arange(n, dtype=np.int64)
    for a in range(0, n, _CHUNK):
        b = min(n, a + _CHUNK)
        dist, idx = tree.query(P[a:b], k=kk, workers=workers)
        dist = dist.reshape(b - a, kk)[:, 1:]
        idx = idx.reshape(b - a, kk)[:, 1:]
        rows = np.broadcast_to(np.arange(a, b)[:, None], idx.shape)
        ok = dist <= radius_m
        _union(parent, rows[ok], idx[ok].astype(np.int64, copy=False))
    labels = _roots(parent)
    sizes = np.bincount(labels)
    return sizes[labels] >= max(1, int(np.ceil(min_fraction * n)))
