"""Random minimal samples, robust scores and the adaptive RANSAC stopping rule."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyrecon.errors import InputError

__all__ = ["RansacOptions", "draw_samples", "required_iterations", "msac_scores", "as_generator"]


@dataclass(frozen=True)
class RansacOptions:
    """Options shared by the robust estimators.

    Attributes:
        threshold: inlier threshold on the Sampson (or transfer) distance, in the units of the
            points the estimator receives (pixels for F and H; the estimators of E take it in
            pixels and convert it with the focal length).
        confidence: probability of drawing at least one all-inlier sample (adaptive stopping).
        min_iterations: never stop before this many samples.
        max_iterations: never draw more samples than this.
        batch_size: samples solved together (vectorised) per round.
        local_optimization: run local optimisation (LO-RANSAC) on every new best model.
    """

    threshold: float = 1.0
    confidence: float = 0.9999
    min_iterations: int = 64
    max_iterations: int = 10000
    batch_size: int = 32
    local_optimization: bool = True

    def __post_init__(self) -> None:
        if not (self.threshold > 0 and math.isfinite(self.threshold)):
            raise InputError(f"the inlier threshold must be positive, got {self.threshold}")
        if not (0.0 < self.confidence < 1.0):
            raise InputError(f"the RANSAC confidence must be in (0, 1), got {self.confidence}")
        if self.max_iterations < 1 or self.min_iterations < 0 or self.batch_size < 1:
            raise InputError("RANSAC iteration counts and batch size must be positive")


def as_generator(seed: int | np.random.Generator | None) -> np.random.Generator:
    """A numpy Generator from a seed, a Generator (returned as is) or None (seed 0)."""
    if isinstance(seed, np.random.Generator):
        return seed
    return np.random.default_rng(0 if seed is None else seed)


def draw_samples(rng: np.random.Generator, n: int, k: int, count: int) -> np.ndarray:
    """(count, k) int indices, each row k distinct values in [0, n) (uniform without replacement).

    Raises:
        InputError: n < k.
    """
    if n < k:
        raise InputError(f"cannot draw samples of {k} from {n} items")
    if n <= 4 * k:  # small populations: permutation per sample
        return np.argsort(rng.random((count, n)), axis=1)[:, :k]
    out = np.empty((0, k), dtype=np.int64)
    while len(out) < count:
        cand = rng.integers(0, n, size=(max(2 * (count - len(out)), 8), k))
        s = np.sort(cand, axis=1)
        distinct = np.all(s[:, 1:] != s[:, :-1], axis=1)
        out = np.concatenate([out, cand[distinct]])
    return out[:count]


def required_iterations(inlier_ratio: float, sample_size: int, confidence: float, max_iterations: int) -> int:
    """Samples needed to draw one all-inlier sample with probability ``confidence``.

    ``k = log(1 - p) / log(1 - w^m)`` for inlier ratio w and sample size m, capped at max.
    """
    w = min(max(inlier_ratio, 0.0), 1.0)
    pw = w**sample_size
    if pw <= 0:
        return max_iterations
    if pw >= 1.0 - 1e-15:
        return 1
    k = math.log(1.0 - confidence) / math.log1p(-pw)
    return int(min(max_iterations, math.ceil(k)))


def msac_scores(err_sq: np.ndarray, threshold_sq: float) -> tuple[np.ndarray, np.ndarray]:
    """MSAC (truncated quadratic) costs and inlier counts.

    Args:
        err_sq: (K, N) squared errors of K models on N data.
        threshold_sq: squared threshold.
    Returns:
        ``(cost, count)``: (K,) sum of ``min(err_sq, threshold_sq)`` (lower is better) and
        (K,) number of errors below the threshold.
    """
    inl = err_sq < threshold_sq
    cost = np.where(inl, err_sq, threshold_sq).sum(axis=1)
    return cost, inl.sum(axis=1)
