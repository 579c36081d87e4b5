"""Robust fundamental-matrix estimation: 8-point, 7-point, RANSAC, LMedS and MAGSAC++.

Selectable like OpenCV's ``FM_8POINT / FM_7POINT / FM_RANSAC / FM_LMEDS`` (plus ``"magsac"``,
which delegates to OpenCV's USAC MAGSAC++). The RANSAC variant is our own, plugged into the
generic :func:`~skyrecon.geometry.sampling.lo_ransac`: batched 7-point minimal solutions (every
real root), MSAC scoring on the Sampson distance in pixels, local optimisation by iteratively
reweighted 8-point fits, adaptive stopping.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np

from skyrecon.errors import EstimationError, InputError
from skyrecon.geometry._kernels import msac_costs, sampson_sq_many
from skyrecon.geometry.epipolar import (
    as_points2,
    fundamental_7point,
    fundamental_8point,
    sampson_sq,
)
from skyrecon.geometry.sampling import (
    LocalOptimization,
    RansacOptions,
    as_generator,
    draw_samples,
    lo_ransac,
    required_iterations,
)

__all__ = [
    "FundamentalMethod",
    "FundamentalEstimate",
    "estimate_fundamental",
    "fundamental_7point_batch",
    "refine_fundamental_irls",
]

FundamentalMethod = Literal["8point", "7point", "ransac", "lmeds", "magsac"]
FUNDAMENTAL_METHODS: tuple[str, ...] = ("8point", "7point", "ransac", "lmeds", "magsac")

# Inverse Vandermonde matrix: cubic coefficients (a^3, a^2, a, 1) from values at a = -1, 0, 1, 2.
_SAMPLES = np.array([-1.0, 0.0, 1.0, 2.0])
_VINV = np.linalg.inv(np.vander(_SAMPLES, 4))


@dataclass
class FundamentalEstimate:
    """A fundamental matrix with its support.

    Attributes:
        F: (3, 3) rank-2, unit Frobenius norm, ``x2^T F x1 = 0`` for pixels.
        inliers: (N,) bool (all True for the 7- and 8-point methods).
        errors_px: (N,) Sampson distance of every match to F, pixels.
        method: the method used.
        iterations: minimal samples drawn (0 for direct methods).
        candidates: every solution of the 7-point method (1 or 3), else ``[F]``.
    """

    F: np.ndarray
    inliers: np.ndarray
    errors_px: np.ndarray
    method: str
    iterations: int = 0
    candidates: list[np.ndarray] = field(default_factory=list)

    @property
    def num_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))

    @property
    def inlier_ratio(self) -> float:
        return self.num_inliers / max(1, len(self.inliers))


def _normalize_batch(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hartley normalisation of each sample of a (B, m, 2) batch -> points and (B, 3, 3) T."""
    c = x.mean(axis=1, keepdims=True)
    d = np.sqrt(((x - c) ** 2).sum(axis=2)).mean(axis=1)
    s = np.sqrt(2.0) / np.maximum(d, 1e-300)
    B = x.shape[0]
    T = np.zeros((B, 3, 3))
    T[:, 0, 0] = s
    T[:, 1, 1] = s
    T[:, 0, 2] = -s * c[:, 0, 0]
    T[:, 1, 2] = -s * c[:, 0, 1]
    T[:, 2, 2] = 1.0
    return (x - c) * s[:, None, None], T


def fundamental_7point_batch(x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """7-point solutions for a batch of samples.

    Args:
        x1, x2: (B, 7, 2) pixel samples.
    Returns:
        ``(Fs, sample)``: (M, 3, 3) fundamental matrices (unit Frobenius norm) and the (M,)
        index of the sample each came from; 1 or 3 per non-degenerate sample.
    """
    n1, T1 = _normalize_batch(np.asarray(x1, np.float64))
    n2, T2 = _normalize_batch(np.asarray(x2, np.float64))
    B = n1.shape[0]
    A = np.empty((B, 7, 9))
    u1, v1, u2, v2 = n1[..., 0], n1[..., 1], n2[..., 0], n2[..., 1]
    A[..., 0], A[..., 1], A[..., 2] = u2 * u1, u2 * v1, u2
    A[..., 3], A[..., 4], A[..., 5] = v2 * u1, v2 * v1, v2
    A[..., 6], A[..., 7], A[..., 8] = u1, v1, 1.0
    _, _, Vt = np.linalg.svd(A, full_matrices=True)
    F1 = Vt[:, -1].reshape(B, 3, 3)
    F2 = Vt[:, -2].reshape(B, 3, 3)
    D = F1 - F2
    dets = np.linalg.det(F2[:, None] + _SAMPLES[None, :, None, None] * D[:, None])  # (B, 4)
    coef = dets @ _VINV.T  # (B, 4): a^3, a^2, a, 1
    lead = coef[:, 0]
    ok = np.abs(lead) > 1e-12 * np.abs(coef).max(axis=1)
    comp = np.zeros((B, 3, 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        comp[:, 0, :] = -coef[:, 1:] / lead[:, None]
    comp[:, 1, 0] = 1.0
    comp[:, 2, 1] = 1.0
    comp[~ok] = 0.0
    roots = np.linalg.eigvals(comp)  # (B, 3)
    real = (np.abs(roots.imag) <= 1e-8 * np.maximum(1.0, np.abs(roots.real))) & ok[:, None]
    bi, ki = np.nonzero(real)
    a = roots.real[bi, ki]
    # Newton polish on the cubic
    c = coef[bi]
    for _ in range(2):
        p = ((c[:, 0] * a + c[:, 1]) * a + c[:, 2]) * a + c[:, 3]
        dp = (3 * c[:, 0] * a + 2 * c[:, 1]) * a + c[:, 2]
        step = np.where(np.abs(dp) > 1e-300, p / np.where(dp == 0, 1.0, dp), 0.0)
        a = a - step
    Fn = a[:, None, None] * F1[bi] + (1.0 - a)[:, None, None] * F2[bi]
    Fs = np.transpose(T2[bi], (0, 2, 1)) @ Fn @ T1[bi]
    Fs /= np.linalg.norm(Fs, axis=(1, 2), keepdims=True)
    return Fs, bi


def refine_fundamental_irls(F: np.ndarray, x1: np.ndarray, x2: np.ndarray, iterations: int = 5) -> np.ndarray:
    """Minimise the Sampson error of F on the given (inlier) matches by reweighted 8-point fits.

    Each iteration solves the weighted algebraic problem with weights ``1 / sqrt(den)`` of the
    previous F's Sampson denominator (the classic Sampson/IRLS scheme).
    """
    for _ in range(iterations):
        h1 = np.concatenate([x1, np.ones((len(x1), 1))], axis=1)
        h2 = np.concatenate([x2, np.ones((len(x2), 1))], axis=1)
        Fx1 = h1 @ F.T
        Ftx2 = h2 @ F
        den = Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2
        w = 1.0 / np.sqrt(np.maximum(den, 1e-300))
        F_new = fundamental_8point(x1, x2, w / w.max())
        if np.sum(sampson_sq(F_new, x1, x2)) > np.sum(sampson_sq(F, x1, x2)):
            break
        F = F_new
    return F


class _FundamentalProblem:
    """F for :func:`lo_ransac`: 7-point minimal solver, MSAC on the Sampson distance (pixels),
    refit by the 8-point method and a few reweighted (Sampson) iterations on the inliers."""

    model_name = "fundamental matrix"
    sample_size = 7

    def __init__(self, x1: np.ndarray, x2: np.ndarray, threshold: float) -> None:
        self.x1, self.x2 = x1, x2
        self.thr2 = threshold**2
        self.num_data = len(x1)

    def best_minimal_model(self, samples: np.ndarray) -> tuple[np.ndarray, float] | None:
        Fs, _ = fundamental_7point_batch(self.x1[samples], self.x2[samples])
        if len(Fs) == 0:
            return None
        costs, _ = msac_costs(np.ascontiguousarray(Fs), self.x1, self.x2, self.thr2)
        k = int(np.argmin(costs))
        return Fs[k], float(costs[k])

    def score(self, F: np.ndarray) -> tuple[float, np.ndarray]:
        cost = float(msac_costs(np.ascontiguousarray(F[None]), self.x1, self.x2, self.thr2)[0][0])
        return cost, sampson_sq(F, self.x1, self.x2) < self.thr2

    def refit(self, F: np.ndarray, inliers: np.ndarray) -> np.ndarray:
        x1, x2 = self.x1[inliers], self.x2[inliers]
        return refine_fundamental_irls(fundamental_8point(x1, x2), x1, x2, 3)


_LOCAL = LocalOptimization(max_steps=3, min_inliers=9)


def _lmeds(
    x1: np.ndarray, x2: np.ndarray, options: RansacOptions, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, int]:
    n = len(x1)
    iters = required_iterations(0.5, 7, options.confidence, options.max_iterations)
    iters = max(iters, options.min_iterations)
    best_med, best_F = np.inf, None
    done = 0
    while done < iters:
        b = min(options.batch_size * 4, iters - done)
        idx = draw_samples(rng, n, 7, b)
        done += b
        Fs, _ = fundamental_7point_batch(x1[idx], x2[idx])
        if len(Fs) == 0:
            continue
        med = np.median(sampson_sq_many(np.ascontiguousarray(Fs), x1, x2), axis=1)
        k = int(np.argmin(med))
        if med[k] < best_med:
            best_med, best_F = float(med[k]), Fs[k]
    if best_F is None:
        raise EstimationError(f"LMedS found no fundamental matrix in {done} samples")
    sigma = 1.4826 * (1.0 + 5.0 / max(n - 7, 1)) * np.sqrt(best_med)
    inl = sampson_sq(best_F, x1, x2) < (2.5 * sigma) ** 2
    F = best_F
    if np.count_nonzero(inl) >= 8:
        F = refine_fundamental_irls(fundamental_8point(x1[inl], x2[inl]), x1[inl], x2[inl])
    return F, inl, done


def _magsac(x1: np.ndarray, x2: np.ndarray, options: RansacOptions, seed: int) -> np.ndarray:
    params = cv2.UsacParams()
    params.confidence = options.confidence
    params.maxIterations = options.max_iterations
    params.threshold = options.threshold
    params.randomGeneratorState = int(seed) & 0x7FFFFFFF
    params.sampler = cv2.SAMPLING_UNIFORM
    params.score = cv2.SCORE_METHOD_MAGSAC
    params.loMethod = cv2.LOCAL_OPTIM_SIGMA
    params.loIterations = 10
    params.loSampleSize = 50
    params.final_polisher = cv2.MAGSAC
    params.final_polisher_iterations = 10
    params.isParallel = False
    F, _ = cv2.findFundamentalMat(x1, x2, params)
    if F is None or F.shape != (3, 3):
        raise EstimationError("MAGSAC++ found no fundamental matrix")
    return F / np.linalg.norm(F)


def estimate_fundamental(
    x1: np.ndarray,
    x2: np.ndarray,
    method: FundamentalMethod = "ransac",
    options: RansacOptions = RansacOptions(),
    seed: int | np.random.Generator | None = 0,
) -> FundamentalEstimate:
    """Estimate F from pixel matches.

    Args:
        x1, x2: (N, 2) matching pixels in image 1 and 2.
        method: ``"8point"`` (all matches, N >= 8), ``"7point"`` (exactly the first 7 matches:
            every real root in ``candidates``), ``"ransac"`` (ours, LO-MSAC), ``"lmeds"`` (ours),
            ``"magsac"`` (OpenCV USAC MAGSAC++).
        options: threshold (pixels, Sampson distance), confidence and iteration limits.
        seed: seed or Generator for the samples.
    Returns:
        FundamentalEstimate; inliers have Sampson distance below ``options.threshold``
        (LMedS: below its own robust scale estimate).
    Raises:
        InputError: unknown method, mismatched or invalid points.
        EstimationError: too few matches or no solution.
    """
    x1 = as_points2(x1, "x1")
    x2 = as_points2(x2, "x2")
    if len(x1) != len(x2):
        raise InputError(f"{len(x1)} points in image 1 but {len(x2)} in image 2")
    if method not in FUNDAMENTAL_METHODS:
        raise InputError(
            f"unknown fundamental-matrix method {method!r}; use one of {', '.join(FUNDAMENTAL_METHODS)}"
        )
    n = len(x1)
    need = 7 if method == "7point" else 8
    if n < need:
        raise EstimationError(
            f"the {method} fundamental-matrix method needs at least {need} matches, got {n}"
        )
    rng = as_generator(seed)
    thr2 = options.threshold**2
    iterations = 0
    candidates: list[np.ndarray] = []
    if method == "8point":
        F = fundamental_8point(x1, x2)
        inl = np.ones(n, dtype=bool)
    elif method == "7point":
        candidates = fundamental_7point(x1[:7], x2[:7])
        if not candidates:
            raise EstimationError("the 7-point algorithm found no real solution")
        errs = [float(np.sum(sampson_sq(Fc, x1, x2))) for Fc in candidates]
        F = candidates[int(np.argmin(errs))]
        inl = np.ones(n, dtype=bool)
    elif method == "lmeds":
        F, inl, iterations = _lmeds(x1, x2, options, rng)
    else:
        if method == "ransac":
            found = lo_ransac(_FundamentalProblem(x1, x2, options.threshold), options, rng, _LOCAL)
            F, iterations = found.model, found.iterations
        else:
            F = _magsac(x1, x2, options, int(rng.integers(0, 2**31 - 1)))
        inl = sampson_sq(F, x1, x2) < thr2
        if method == "ransac" and np.count_nonzero(inl) >= 8:
            F_fin = refine_fundamental_irls(fundamental_8point(x1[inl], x2[inl]), x1[inl], x2[inl])
            inl_fin = sampson_sq(F_fin, x1, x2) < thr2
            if np.count_nonzero(inl_fin) >= np.count_nonzero(inl) * 0.98:
                F, inl = F_fin, inl_fin
    F = F / np.linalg.norm(F)
    errors = np.sqrt(sampson_sq(F, x1, x2))
    return FundamentalEstimate(F, inl, errors, method, iterations, candidates or [F])
