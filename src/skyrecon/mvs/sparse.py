"""A rough sparse estimate of the scene from known cameras: SIFT matches checked against the
known epipolar geometry, triangulated, and the per-view depth ranges derived from them.

With known poses no robust estimation is needed: a putative match is kept when it lies within
a few pixels of its epipolar line, triangulates in front of both cameras with a small
reprojection error and a non-degenerate triangulation angle.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np

from skyrecon.mvs.frames import WorkingView

__all__ = ["SparseScene", "sparse_scene", "depth_range_from_points", "candidate_pairs"]


@dataclass
class SparseScene:
    """Triangulated matches of a view set.

    Attributes:
        points: (N, 3) float64 world points, metres.
        pair_index: (N, 2) int64 the two views each point was triangulated from.
        pair_counts: dict (i, j) -> number of points, i < j.
    """

    points: np.ndarray
    pair_index: np.ndarray
    pair_counts: dict[tuple[int, int], int] = field(default_factory=dict)


def _features(view: WorkingView, max_features: int) -> tuple[np.ndarray, np.ndarray | None]:
    sift = cv2.SIFT.create(nfeatures=max_features, contrastThreshold=0.02)
    grey = np.clip(view.grey + 0.5, 0, 255).astype(np.uint8)
    # stretch dark images (the rock set is grey levels 0..90): SIFT thresholds are absolute
    hi = float(np.percentile(grey[view.valid], 99.5)) if view.valid.any() else 255.0
    if 0 < hi < 200:
        grey = np.clip(grey.astype(np.float32) * (220.0 / hi), 0, 255).astype(np.uint8)
    mask = cv2.erode(view.valid.astype(np.uint8), np.ones((5, 5), np.uint8))
    kps, desc = sift.detectAndCompute(grey, mask)
    if desc is None or not kps:
        return np.zeros((0, 2)), None
    xy = np.array([k.pt for k in kps], np.float64)  # OpenCV keypoints: pixel centres at integers
    return xy, desc.astype(np.float32)


def candidate_pairs(
    views: list[WorkingView], max_axis_angle_deg: float = 100.0, max_per_view: int = 6
) -> list[tuple[int, int]]:
    """Pairs (i < j) worth matching: optical axes within ``max_axis_angle_deg`` and among each
    view's ``max_per_view`` nearest camera centres."""
    n = len(views)
    if n < 2:
        return []
    C = np.stack([v.center_world for v in views])
    Z = np.stack([v.cam_from_world.R[2] for v in views])  # optical axes in the world
    D = np.linalg.norm(C[:, None] - C[None], axis=2)
    np.fill_diagonal(D, np.inf)
    cos = np.clip(Z @ Z.T, -1, 1)
    keep = np.zeros((n, n), bool)
    order = np.argsort(D, axis=1)[:, :max_per_view]
    for i in range(n):
        keep[i, order[i]] = True
    keep = (keep | keep.T) & (cos >= np.cos(np.radians(max_axis_angle_deg)))
    return [(i, j) for i in range(n) for j in range(i + 1, n) if keep[i, j]]


def _match(fa: tuple, fb: tuple, ratio: float) -> np.ndarray:
    """(M, 2) index pairs passing Lowe's ratio test (exact nearest neighbours, deterministic)."""
    (xa, da), (xb, db) = fa, fb
    if da is None or db is None or len(xa) < 1 or len(xb) < 2:
        return np.zeros((0, 2), np.int64)
    d2 = (da * da).sum(1)[:, None] + (db * db).sum(1)[None, :] - 2.0 * (da @ db.T)
    two = np.argpartition(d2, 1, axis=1)[:, :2]
    rows = np.arange(len(da))
    a, b = d2[rows, two[:, 0]], d2[rows, two[:, 1]]
    best = np.where(a <= b, two[:, 0], two[:, 1])
    d1, d2nd = np.minimum(a, b), np.maximum(a, b)
    ok = np.sqrt(np.maximum(d1, 0)) < ratio * np.sqrt(np.maximum(d2nd, 0))
    return np.stack([rows[ok], best[ok]], axis=1).astype(np.int64)


def _fundamental(a: WorkingView, b: WorkingView) -> np.ndarray:
    rel = b.cam_from_world @ a.cam_from_world.inverse()
    t = rel.t
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return np.linalg.inv(b.intrinsics.K).T @ tx @ rel.R @ np.linalg.inv(a.intrinsics.K)


def _triangulate(Pa: np.ndarray, Pb: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """Linear triangulation (DLT) of (M, 2) pixel pairs -> (M, 3)."""
    A = np.stack(
        [
            xa[:, 0:1] * Pa[2] - Pa[0],
            xa[:, 1:2] * Pa[2] - Pa[1],
            xb[:, 0:1] * Pb[2] - Pb[0],
            xb[:, 1:2] * Pb[2] - Pb[1],
        ],
        axis=1,
    )
    _, _, Vt = np.linalg.svd(A)
    X = Vt[:, -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        return X[:, :3] / X[:, 3:4]


def sparse_scene(
    views: list[WorkingView],
    pairs: list[tuple[int, int]] | None = None,
    max_features: int = 1500,
    ratio: float = 0.85,
    max_epipolar_px: float = 2.0,
    max_reproj_px: float = 2.0,
    min_angle_deg: float = 1.0,
) -> SparseScene:
    """Match SIFT features between view pairs and triangulate them with the known cameras.

    Args:
        views: working views (their intrinsics and poses are trusted).
        pairs: pairs (i, j) to match; default :func:`candidate_pairs`.
        max_features: features per image.
        ratio: Lowe's ratio test.
        max_epipolar_px: largest distance of a match to its epipolar line, pixels.
        max_reproj_px: largest reprojection error of a triangulated point, pixels.
        min_angle_deg: smallest triangulation angle.
    Returns:
        SparseScene (possibly empty).
    """
    pairs = candidate_pairs(views) if pairs is None else pairs
    threads = max(1, min(4, os.cpu_count() or 1))
    with ThreadPoolExecutor(threads) as pool:  # OpenCV releases the GIL
        feats = list(pool.map(lambda v: _features(v, max_features), views))
        raw = list(pool.map(lambda ij: _match(feats[ij[0]], feats[ij[1]], ratio), pairs))
    pts, idx = [], []
    counts: dict[tuple[int, int], int] = {}
    for (i, j), m in zip(pairs, raw):
        (xa, _), (xb, _) = feats[i], feats[j]
        if len(m) == 0:
            counts[(i, j)] = 0
            continue
        a, b = xa[m[:, 0]], xb[m[:, 1]]
        F = _fundamental(views[i], views[j])
        ha = np.c_[a, np.ones(len(a))]
        hb = np.c_[b, np.ones(len(b))]
        l2 = ha @ F.T
        dist = np.abs(np.sum(l2 * hb, axis=1)) / np.maximum(np.hypot(l2[:, 0], l2[:, 1]), 1e-12)
        ok = dist < max_epipolar_px
        a, b = a[ok], b[ok]
        if len(a) == 0:
            counts[(i, j)] = 0
            continue
        va, vb = views[i].posed(), views[j].posed()
        X = _triangulate(va.P, vb.P, a, b)
        good = np.all(np.isfinite(X), axis=1)
        pa, za = va.project(X)
        pb, zb = vb.project(X)
        with np.errstate(invalid="ignore"):
            good &= (za > 0) & (zb > 0)
            good &= np.linalg.norm(pa - a, axis=1) < max_reproj_px
            good &= np.linalg.norm(pb - b, axis=1) < max_reproj_px
        ra = X - va.center_world
        rb = X - vb.center_world
        cosang = np.sum(ra * rb, axis=1) / np.maximum(
            np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1), 1e-300
        )
        with np.errstate(invalid="ignore"):
            good &= cosang < np.cos(np.radians(min_angle_deg))
        X = X[good]
        counts[(i, j)] = int(len(X))
        pts.append(X)
        idx.append(np.tile([i, j], (len(X), 1)))
    if pts:
        P = np.concatenate(pts)
        I = np.concatenate(idx).astype(np.int64)
    else:
        P = np.zeros((0, 3))
        I = np.zeros((0, 2), np.int64)
    return SparseScene(P, I, counts)


def depth_range_from_points(
    view: WorkingView,
    points_world: np.ndarray,
    margin: float = 0.25,
    quantiles: tuple[float, float] = (0.01, 0.99),
    min_points: int = 20,
) -> tuple[float, float] | None:
    """(near, far) depth range of ``view`` from the sparse points that project into it.

    The quantiles of the visible points' depths are widened by ``margin`` (near / (1 + margin),
    far * (1 + margin)). None when fewer than ``min_points`` project into the view.
    """
    if len(points_world) == 0:
        return None
    uv, z = view.posed().project(points_world)
    inside = view.intrinsics.in_image(uv) & (z > 0)
    if inside.sum() < min_points:
        return None
    q = np.quantile(z[inside], quantiles)
    near, far = float(q[0]) / (1.0 + margin), float(q[1]) * (1.0 + margin)
    return (near, far) if 0 < near < far else None
