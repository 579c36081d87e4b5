"""Metrics of a reconstructed point cloud against a reference surface.

- **accuracy** (precision side): distance from each reconstructed point to the reference
  surface; reported as mean, median and the Middlebury "90 % accuracy" (the distance within
  which 90 % of the reconstruction lies);
- **completeness** (recall side): distance from each reference point to the reconstruction;
- at each threshold tau: precision = fraction of reconstructed points within tau, recall =
  fraction of reference points within tau, F-score = their harmonic mean (Tanks and Temples).

The reference is a point cloud (e.g. the rock's ``reference.ply``; distances to its nearest
point) or exact geometry (a callable giving the distance of points to the surface, e.g.
``abs(City.distance(...))``) plus a sampling of it for completeness
(:func:`reference_from_depth_maps`). A crop box restricts both sides to the evaluated region.

All points are (N, 3) world coordinates in metres.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from skyrecon.core import DepthMap
from skyrecon.errors import InputError

__all__ = [
    "CloudMetrics",
    "evaluate_cloud",
    "reference_from_depth_maps",
    "fraction_outside_box",
    "crop_mask",
    "voxel_subsample",
]


@dataclass
class CloudMetrics:
    """Accuracy / completeness of a reconstruction.

    Attributes:
        thresholds: distances tau, metres.
        precision, recall, fscore: per threshold, fractions in [0, 1].
        accuracy_mean, accuracy_median, accuracy_90: reconstruction -> reference distances, metres.
        completeness_mean, completeness_median: reference -> reconstruction distances, metres.
        num_reconstructed, num_reference: points evaluated on each side (after cropping and
            subsampling).
        num_cropped_out: reconstructed points outside the crop box (not evaluated).
    """

    thresholds: list[float]
    precision: list[float]
    recall: list[float]
    fscore: list[float]
    accuracy_mean: float
    accuracy_median: float
    accuracy_90: float
    completeness_mean: float
    completeness_median: float
    num_reconstructed: int
    num_reference: int
    num_cropped_out: int = 0
    extra: dict = field(default_factory=dict)

    def at(self, tau: float) -> tuple[float, float, float]:
        """(precision, recall, F-score) at the threshold closest to ``tau``."""
        i = int(np.argmin(np.abs(np.asarray(self.thresholds) - tau)))
        return self.precision[i], self.recall[i], self.fscore[i]


def _points(a: np.ndarray, what: str) -> np.ndarray:
    p = np.asarray(a, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"{what} must be an (N, 3) array of points, got shape {p.shape}")
    return p[np.all(np.isfinite(p), axis=1)]


def crop_mask(points: np.ndarray, box: tuple[ArrayLike, ArrayLike] | None) -> np.ndarray:
    """(N,) bool: points inside the axis-aligned box ``(lo (3,), hi (3,))`` (all True for None)."""
    p = np.asarray(points, np.float64)
    if box is None:
        return np.ones(len(p), bool)
    lo, hi = np.asarray(box[0], np.float64), np.asarray(box[1], np.float64)
    return np.all((p >= lo) & (p <= hi), axis=1)


def fraction_outside_box(
    points: np.ndarray, lo: Sequence[float], hi: Sequence[float], margin: float = 0.0
) -> float:
    """Fraction of points (N, 3) outside the box [lo - margin, hi + margin] (0 for no points)."""
    p = _points(points, "points")
    if len(p) == 0:
        return 0.0
    lo_ = np.asarray(lo, np.float64) - margin
    hi_ = np.asarray(hi, np.float64) + margin
    return float(1.0 - crop_mask(p, (lo_, hi_)).mean())


def voxel_subsample(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """One point (the first) per voxel of size ``voxel_m``: an even density sampling."""
    p = np.asarray(points, np.float64)
    if len(p) == 0:
        return p
    key = np.floor(p / voxel_m).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    return p[np.sort(first)]


def evaluate_cloud(
    reconstruction: np.ndarray,
    reference: np.ndarray,
    thresholds: Sequence[float],
    reference_distance: Callable[[np.ndarray], np.ndarray] | None = None,
    crop: tuple[Sequence[float], Sequence[float]] | None = None,
    max_points: int | None = 1_000_000,
    seed: int = 0,
) -> CloudMetrics:
    """Accuracy, completeness and F-scores of ``reconstruction`` against ``reference``.

    Args:
        reconstruction: (N, 3) reconstructed points, metres.
        reference: (M, 3) reference surface samples, metres (should be evenly spaced, finer
            than the smallest threshold).
        thresholds: distances tau, metres.
        reference_distance: optional exact distance-to-surface function ((K, 3) -> (K,) metres,
            non-negative); default: distance to the nearest reference point.
        crop: optional box (lo, hi): reconstructed and reference points outside are ignored.
        max_points: evaluate a random subset of at most this many reconstructed points
            (None: all); ``seed`` picks it.
    Returns:
        CloudMetrics. An empty reconstruction gives precision 0, recall 0 and infinite
        distances.
    Raises:
        InputError: malformed arrays, no thresholds, or an empty reference.
    """
    rec = _points(reconstruction, "the reconstruction")
    ref = _points(reference, "the reference")
    taus = [float(t) for t in thresholds]
    if not taus or min(taus) <= 0:
        raise InputError("give at least one positive threshold")
    inside = crop_mask(rec, crop)
    cropped_out = int((~inside).sum())
    rec = rec[inside]
    ref = ref[crop_mask(ref, crop)]
    if len(ref) == 0:
        raise InputError("the reference has no points (inside the crop box)")
    if max_points is not None and len(rec) > max_points:
        rng = np.random.default_rng(seed)
        rec = rec[rng.choice(len(rec), max_points, replace=False)]
    if len(rec) == 0:
        inf = float("inf")
        return CloudMetrics(
            taus,
            [0.0] * len(taus),
            [0.0] * len(taus),
            [0.0] * len(taus),
            inf,
            inf,
            inf,
            inf,
            inf,
            0,
            len(ref),
            cropped_out,
        )
    if reference_distance is not None:
        acc = np.abs(np.asarray(reference_distance(rec), np.float64).reshape(-1))
    else:
        acc = cKDTree(ref).query(rec, k=1, workers=-1)[0]
    comp = cKDTree(rec).query(ref, k=1, workers=-1)[0]
    prec = [float(np.mean(acc <= t)) for t in taus]
    rec_ = [float(np.mean(comp <= t)) for t in taus]
    f = [0.0 if p + r == 0 else 2 * p * r / (p + r) for p, r in zip(prec, rec_)]
    return CloudMetrics(
        taus,
        prec,
        rec_,
        f,
        float(acc.mean()),
        float(np.median(acc)),
        float(np.quantile(acc, 0.9)),
        float(comp.mean()),
        float(np.median(comp)),
        int(len(rec)),
        int(len(ref)),
        cropped_out,
    )


def reference_from_depth_maps(
    depth_maps: Sequence[DepthMap],
    min_views: int = 2,
    rel_tol: float = 0.01,
    voxel_m: float | None = None,
    crop: tuple[Sequence[float], Sequence[float]] | None = None,
) -> np.ndarray:
    """Sample a surface from exact (ground-truth) depth maps.

    Every valid pixel is back-projected; with ``min_views >= 2`` a point is kept only when at
    least ``min_views`` of the maps see it (its depth in that map matches within ``rel_tol``),
    i.e. the part of the surface that multi-view stereo can reconstruct.

    Args:
        depth_maps: exact depth maps with poses (``cam_from_world`` set).
        min_views: views that must see a point (1: keep all).
        rel_tol: relative depth tolerance of the visibility test.
        voxel_m: even out the density with one point per voxel of this size (None: keep all).
        crop: optional box (lo, hi) to keep.
    Returns:
        (M, 3) float64 world points, metres.
    """
    out = []
    for i, dm in enumerate(depth_maps):
        X = dm.to_points_world().points.astype(np.float64)
        X = X[crop_mask(X, crop)]
        if voxel_m:
            X = voxel_subsample(X, voxel_m / 2)
        if min_views > 1 and len(X):
            seen = np.ones(len(X), np.int32)
            for j, other in enumerate(depth_maps):
                if j == i:
                    continue
                if other.cam_from_world is None:
                    raise InputError(f"depth map {j} has no camera pose (cam_from_world)")
                pc = other.cam_from_world.apply(X)
                uv = other.intrinsics.project(pc)
                ok = other.intrinsics.in_image(uv) & (pc[:, 2] > 0)
                idx = np.nonzero(ok)[0]
                u = np.clip(np.rint(uv[idx, 0]).astype(np.int64), 0, other.intrinsics.width - 1)
                v = np.clip(np.rint(uv[idx, 1]).astype(np.int64), 0, other.intrinsics.height - 1)
                d = other.depth_m[v, u]
                with np.errstate(invalid="ignore"):
                    vis = np.abs(d - pc[idx, 2]) <= rel_tol * pc[idx, 2]
                seen[idx[vis]] += 1
            X = X[seen >= min_views]
        out.append(X)
    P = np.concatenate(out) if out else np.zeros((0, 3))
    return voxel_subsample(P, voxel_m) if voxel_m and len(P) else P
