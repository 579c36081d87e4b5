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
        _mean_distance_and_normals(
            P,
            dist.reshape(b - a, kk),
            idx.reshape(b - a, kk).astype(np.int64, copy=False),
            mean_d[a:b],
            normals[a:b],
        )
    return mean_d, normals


@njit(cache=True, nogil=True, boundscheck=False)
def _smallest_eigenvector(c: np.ndarray) -> tuple[float, float, float]:  # pragma: no cover - jit
    """Unit eigenvector of the smallest eigenvalue of the symmetric 3x3 ``c`` (float64).

    Eigenvalues in closed form (the trigonometric solution of the characteristic cubic), the
    eigenvector as the longest cross product of two rows of ``c - lambda I``. Where the two
    smallest eigenvalues coincide (points on a line), any unit vector across the largest
    eigenvector; where all three do (a single point), +z.
    """
    scale = 0.0
    for i in range(3):
        for j in range(3):
            scale = max(scale, abs(c[i, j]))
    if scale == 0.0:
        return 0.0, 0.0, 1.0
    a00, a01, a02 = c[0, 0] / scale, c[0, 1] / scale, c[0, 2] / scale
    a11, a12, a22 = c[1, 1] / scale, c[1, 2] / scale, c[2, 2] / scale
    q = (a00 + a11 + a22) / 3.0
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    p2 = (a00 - q) ** 2 + (a11 - q) ** 2 + (a22 - q) ** 2 + 2.0 * p1
    p = np.sqrt(p2 / 6.0)
    if p < 1e-12:
        return 0.0, 0.0, 1.0
    b00, b11, b22 = (a00 - q) / p, (a11 - q) / p, (a22 - q) / p
    b01, b02, b12 = a01 / p, a02 / p, a12 / p
    r = (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02)) / 2.0
    r = min(1.0, max(-1.0, r))
    phi = np.arccos(r) / 3.0
    lam_max = q + 2.0 * p * np.cos(phi)
    lam_min = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    best = (0.0, 0.0, 0.0)
    best_n2 = -1.0
    for lam in (lam_min, lam_max):
        r0 = (a00 - lam, a01, a02)
        r1 = (a01, a11 - lam, a12)
        r2 = (a02, a12, a22 - lam)
        best = (0.0, 0.0, 0.0)
        best_n2 = -1.0
        for u, v in ((r0, r1), (r0, r2), (r1, r2)):
            x = u[1] * v[2] - u[2] * v[1]
            y = u[2] * v[0] - u[0] * v[2]
            z = u[0] * v[1] - u[1] * v[0]
            n2 = x * x + y * y + z * z
            if n2 > best_n2:
                best, best_n2 = (x, y, z), n2
        if best_n2 > 1e-20:
            if lam == lam_min:
                nrm = np.sqrt(best_n2)
                return best[0] / nrm, best[1] / nrm, best[2] / nrm
            break
    if best_n2 <= 1e-20:
        return 0.0, 0.0, 1.0
    # the two smallest coincide: across the largest eigenvector ``best``
    nrm = np.sqrt(best_n2)
    ex, ey, ez = best[0] / nrm, best[1] / nrm, best[2] / nrm
    if abs(ex) < 0.9:
        x, y, z = 0.0, ez, -ey  # e x (1, 0, 0)
    else:
        x, y, z = -ez, 0.0, ex  # e x (0, 1, 0)
    nrm = np.sqrt(x * x + y * y + z * z)
    return x / nrm, y / nrm, z / nrm


@njit(cache=True, nogil=True, boundscheck=False)
def _mean_distance_and_normals(
    P: np.ndarray, dist: np.ndarray, idx: np.ndarray, mean_d: np.ndarray, normals: np.ndarray
) -> None:  # pragma: no cover - jit
    """Per query row: the mean of ``dist[:, 1:]`` into ``mean_d`` and the PCA normal of the
    points ``P[idx[row]]`` into ``normals`` (both written in place)."""
    m, kk = idx.shape
    c = np.empty((3, 3))
    for i in range(m):
        s = 0.0
        for j in range(1, kk):
            s += dist[i, j]
        mean_d[i] = s / (kk - 1) if kk > 1 else 0.0
        mx = my = mz = 0.0
        for j in range(kk):
            q = idx[i, j]
            mx += P[q, 0]
            my += P[q, 1]
            mz += P[q, 2]
        mx /= kk
        my /= kk
        mz /= kk
        c[:] = 0.0
        for j in range(kk):
            q = idx[i, j]
            dx, dy, dz = P[q, 0] - mx, P[q, 1] - my, P[q, 2] - mz
            c[0, 0] += dx * dx
            c[0, 1] += dx * dy
            c[0, 2] += dx * dz
            c[1, 1] += dy * dy
            c[1, 2] += dy * dz
            c[2, 2] += dz * dz
        c[1, 0], c[2, 0], c[2, 1] = c[0, 1], c[0, 2], c[1, 2]
        x, y, z = _smallest_eigenvector(c)
        normals[i, 0], normals[i, 1], normals[i, 2] = x, y, z


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
    bound = float(np.nextafter(radius_m, np.inf))
    for a in range(0, n, _CHUNK):
        b = min(n, a + _CHUNK)
        # neighbours past the radius are no links: the bound prunes the search (they come back
        # as inf, index n)
        dist, idx = tree.query(P[a:b], k=kk, workers=workers, distance_upper_bound=bound)
        dist = dist.reshape(b - a, kk)[:, 1:]
        idx = idx.reshape(b - a, kk)[:, 1:]
        rows = np.broadcast_to(np.arange(a, b)[:, None], idx.shape)
        ok = dist <= radius_m
        _union(parent, rows[ok], idx[ok].astype(np.int64, copy=False))
    labels = _roots(parent)
    sizes = np.bincount(labels)
    return sizes[labels] >= max(1, int(np.ceil(min_fraction * n)))
