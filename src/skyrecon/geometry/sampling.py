"""One LO-RANSAC loop for every robust estimator, with its sampling, scoring and stopping rules.

The loop (:func:`lo_ransac`) follows COLMAP's LO-RANSAC template (``optim/loransac.h``): draw
batches of minimal samples from a seeded ``numpy.random.Generator``, keep the cheapest minimal model
of each batch (MSAC cost), locally optimise every model that beats the best so far by refitting on
its inliers (:func:`local_optimize`), and stop adaptively once enough samples were drawn to have
met an all-inlier sample with the requested confidence. An estimator plugs in through the small
:class:`RansacProblem` interface: its minimal solver with batch scoring, the score of one model
(cost and inliers) and its non-minimal refit on inliers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

import numpy as np

from skyrecon.errors import EstimationError, InputError

__all__ = [
    "RansacOptions",
    "LocalOptimization",
    "RansacProblem",
    "RansacResult",
    "lo_ransac",
    "local_optimize",
    "draw_samples",
    "required_iterations",
    "msac_scores",
    "as_generator",
]

ModelT = TypeVar("ModelT")


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


@dataclass(frozen=True)
class LocalOptimization:
    """How :func:`local_optimize` polishes a model (the estimator's choice, not the user's).

    Attributes:
        max_steps: refits per local optimisation.
        min_inliers: stop when the current model has fewer inliers than this (the refit's minimum).
        min_relative_gain: accept a refit only when its cost is below ``cost * (1 - gain)``
            (0: any decrease).
    """

    max_steps: int = 3
    min_inliers: int = 8
    min_relative_gain: float = 0.0


class RansacProblem(Protocol[ModelT]):
    """What an estimator provides to :func:`lo_ransac` (models of type ``ModelT``).

    Costs are MSAC costs (sum over the data of ``min(err^2, threshold^2)``, lower is better);
    the estimator owns its residual, threshold and any batched (Numba) scoring kernel.
    """

    @property
    def model_name(self) -> str:
        """What is estimated, for the failure message (e.g. ``"homography"``)."""
        ...

    @property
    def num_data(self) -> int:
        """N, the number of data (matches) samples are drawn from."""
        ...

    @property
    def sample_size(self) -> int:
        """m, the data in one minimal sample."""
        ...

    def best_minimal_model(self, samples: np.ndarray) -> tuple[ModelT, float] | None:
        """Solve every (B, m) sample of data indices with the minimal solver, score all solutions
        and return the cheapest with its cost, or None when no sample gave a valid model."""
        ...

    def score(self, model: ModelT) -> tuple[float, np.ndarray]:
        """``(cost, inliers)``: the MSAC cost of one model and its (N,) bool inlier mask."""
        ...

    def refit(self, model: ModelT, inliers: np.ndarray) -> ModelT:
        """The non-minimal estimate on the (N,) bool inliers (may start from ``model``)."""
        ...


@dataclass
class RansacResult(Generic[ModelT]):
    """The best model of :func:`lo_ransac`.

    Attributes:
        model: the best model found.
        cost: its MSAC cost.
        inliers: (N,) bool inliers of the model.
        iterations: minimal samples drawn.
        local_optimizations: local optimisations run.
    """

    model: ModelT
    cost: float
    inliers: np.ndarray
    iterations: int
    local_optimizations: int


def local_optimize(
    problem: RansacProblem[ModelT],
    model: ModelT,
    cost: float,
    inliers: np.ndarray,
    settings: LocalOptimization,
) -> tuple[ModelT, float, np.ndarray]:
    """Refit on the inliers, re-select the inliers, repeat while the cost drops enough.

    Args:
        problem: the estimator.
        model, cost, inliers: a model with its MSAC cost and (N,) bool inliers.
        settings: steps, minimum inliers and minimum relative gain.
    Returns:
        ``(model, cost, inliers)``, the last accepted refit (or the input).
    """
    for _ in range(settings.max_steps):
        if np.count_nonzero(inliers) < settings.min_inliers:
            break
        candidate = problem.refit(model, inliers)
        candidate_cost, candidate_inliers = problem.score(candidate)
        if candidate_cost >= cost * (1.0 - settings.min_relative_gain):
            break
        model, cost, inliers = candidate, candidate_cost, candidate_inliers
    return model, cost, inliers


def lo_ransac(
    problem: RansacProblem[ModelT],
    options: RansacOptions,
    rng: np.random.Generator,
    local: LocalOptimization = LocalOptimization(),
    polish_every_best_sample: bool = False,
) -> RansacResult[ModelT]:
    """LO-RANSAC with MSAC scoring and adaptive stopping.

    Each round draws ``options.batch_size`` minimal samples and takes the cheapest minimal model.
    A model that beats the best so far is locally optimised (when ``options.local_optimization``)
    and becomes the best; the number of samples still needed is then recomputed from its inlier
    ratio (``options.confidence``), within ``[options.min_iterations, options.max_iterations]``.

    Args:
        problem: the estimator (minimal solver, scoring, refit).
        options: confidence, iteration limits, batch size, local optimisation on/off (the
            threshold is the problem's business).
        rng: the random generator of the samples.
        local: how to locally optimise.
        polish_every_best_sample: compare minimal models with the best *minimal* cost so far
            instead of the best (polished) cost, so every so-far-the-best sample is polished even
            when an earlier polished model scores lower; the best stays the cheapest polished model.
    Returns:
        RansacResult.
    Raises:
        EstimationError: no sample gave a valid model.
    """
    n, m = problem.num_data, problem.sample_size
    best: ModelT | None = None
    best_cost = best_sample_cost = math.inf
    best_inliers = np.zeros(n, dtype=bool)
    iterations = local_optimizations = 0
    required = options.max_iterations
    while iterations < max(required, options.min_iterations) and iterations < options.max_iterations:
        count = min(options.batch_size, options.max_iterations - iterations)
        samples = draw_samples(rng, n, m, count)
        iterations += count
        hypothesis = problem.best_minimal_model(samples)
        if hypothesis is None:
            continue
        model, sample_cost = hypothesis
        if sample_cost >= (best_sample_cost if polish_every_best_sample else best_cost):
            continue
        best_sample_cost = sample_cost
        cost, inliers = problem.score(model)
        if options.local_optimization:
            model, cost, inliers = local_optimize(problem, model, cost, inliers, local)
            local_optimizations += 1
        if cost < best_cost:
            best, best_cost, best_inliers = model, cost, inliers
            ratio = np.count_nonzero(inliers) / n
            required = required_iterations(ratio, m, options.confidence, options.max_iterations)
    if best is None:
        raise EstimationError(f"no {problem.model_name} found in {iterations} samples of {n} matches")
    return RansacResult(best, best_cost, best_inliers, iterations, local_optimizations)
