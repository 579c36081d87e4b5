"""Robust relative pose of two calibrated cameras: LO-RANSAC around the five-point solver.

Pipeline: matches in pixels -> normalised coordinates (``K^-1``, lens distortion removed) ->
batched 5-point minimal solutions, each decomposed into the pose that puts its sample in front of
both cameras -> MSAC scoring on the Sampson distance with cheirality (matches behind a camera are
outliers) -> local optimisation (Levenberg-Marquardt on the inliers) of every so-far-the-best
sample model -> adaptive stopping -> final robust refinement of ``(R, t)`` on all inliers
(Cauchy loss in the normalised plane, optionally weighted by keypoint scale).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.errors import EstimationError, InputError
from skyrecon.geometry._kernels import msac_costs_pose
from skyrecon.geometry.epipolar import (
    as_points2,
    cheirality_depths,
    essential_from_pose,
    sampson_sq,
    select_pose,
)
from skyrecon.geometry.five_point import essential_5point_batch
from skyrecon.geometry.refine import Loss, refine_relative_pose
from skyrecon.geometry.sampling import (
    LocalOptimization,
    RansacOptions,
    as_generator,
    lo_ransac,
    local_optimize,
)

__all__ = [
    "RelativePose",
    "focal_scale",
    "normalize_points",
    "estimate_essential",
    "estimate_relative_pose",
    "pose_from_essential",
    "polish_pose",
    "finalize_pose",
]

_W = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class RelativePose:
    """A robustly estimated relative pose.

    Attributes:
        R: (3, 3) rotation, cam2_from_cam1 (``p_cam2 = R p_cam1 + t``).
        t: (3,) unit translation direction (scale unknown).
        E: (3, 3) essential matrix ``[t]x R`` (normalised coordinates).
        inliers: (N,) bool, Sampson distance below the threshold and in front of both cameras.
        errors_px: (N,) Sampson distance of every match, pixels (normalised distance x focal).
        threshold_px: the inlier threshold used, pixels.
        iterations: minimal samples drawn.
        local_optimizations: number of LO runs.
        refined: whether the final non-linear refinement ran.
    """

    R: np.ndarray
    t: np.ndarray
    E: np.ndarray
    inliers: np.ndarray
    errors_px: np.ndarray
    threshold_px: float
    iterations: int
    local_optimizations: int
    refined: bool

    @property
    def num_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))

    @property
    def inlier_ratio(self) -> float:
        return self.num_inliers / max(1, len(self.inliers))


def focal_scale(intr1: Intrinsics, intr2: Intrinsics) -> float:
    """Mean focal length of two cameras, pixels: converts normalised distances to pixels."""
    return float(np.mean([intr1.fx, intr1.fy, intr2.fx, intr2.fy]))


def normalize_points(x: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """Pixels (N, 2) -> undistorted normalised camera coordinates (N, 2) on the z = 1 plane."""
    return intr.normalized(np.asarray(x, dtype=np.float64))


def _poses_from_essentials(
    Es: np.ndarray, x1s: np.ndarray, x2s: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Decompose K essential matrices; keep the pose that puts all sample points in front.

    Args:
        Es: (K, 3, 3); x1s, x2s: (K, m, 2) normalised sample points.
    Returns:
        ``(R, t, ok)``: (K, 3, 3), (K, 3), (K,) bool (a pose passed the cheirality test).
    """
    U, _, Vt = np.linalg.svd(Es)
    U = U * np.sign(np.linalg.det(U))[:, None, None]
    Vt = Vt * np.sign(np.linalg.det(Vt))[:, None, None]
    Ra = U @ _W @ Vt
    Rb = U @ _W.T @ Vt
    t = U[:, :, 2]
    K, m = x1s.shape[:2]
    f1 = np.concatenate([x1s, np.ones((K, m, 1))], axis=2)
    f2 = np.concatenate([x2s, np.ones((K, m, 1))], axis=2)
    R_out = np.zeros((K, 3, 3))
    t_out = np.zeros((K, 3))
    ok = np.zeros(K, dtype=bool)
    for Rc in (Ra, Rb):
        g2 = np.einsum("kni,kij->knj", f2, Rc)  # R^T f2
        a = np.sum(f1 * f1, axis=2)
        b = np.sum(f1 * g2, axis=2)
        c = np.sum(g2 * g2, axis=2)
        den = a * c - b * b
        for sign in (1.0, -1.0):
            tc = sign * t
            c2 = -np.einsum("kji,kj->ki", Rc, tc)  # -R^T t
            d = np.einsum("kni,ki->kn", f1, c2)
            e = np.einsum("kni,ki->kn", g2, c2)
            with np.errstate(divide="ignore", invalid="ignore"):
                z1 = (c * d - b * e) / den
                z2 = (b * d - a * e) / den
            good = np.all((z1 > 0) & (z2 > 0), axis=1) & ~ok
            R_out[good] = Rc[good]
            t_out[good] = tc[good]
            ok |= good
    return R_out, t_out, ok


def _msac(
    R: np.ndarray, t: np.ndarray, x1n: np.ndarray, x2n: np.ndarray, thr2: float
) -> tuple[float, np.ndarray]:
    """MSAC cost of a pose: truncated squared Sampson error, and matches triangulating behind
    either camera count as outliers (this separates the planar twin solutions, which fit the
    epipolar constraint equally well but put part of the scene behind the cameras)."""
    e2 = sampson_sq(essential_from_pose(R, t), x1n, x2n)
    z1, z2 = cheirality_depths(R, t, x1n, x2n)
    with np.errstate(invalid="ignore"):
        inl = (e2 < thr2) & (z1 > 0) & (z2 > 0)
    return float(np.where(inl, e2, thr2).sum()), inl


PoseHypothesis = tuple[np.ndarray, np.ndarray]  # (R (3, 3), t (3,)), cam2_from_cam1


class _RelativePoseProblem:
    """(R, t) for :func:`lo_ransac`: batched 5-point solutions decomposed into the pose that puts
    its sample in front of both cameras, MSAC on the Sampson distance with cheirality (normalised
    units), refit by robust (Cauchy) Levenberg-Marquardt on the inliers."""

    model_name = "valid relative pose"
    sample_size = 5

    def __init__(self, x1n: np.ndarray, x2n: np.ndarray, thr2: float) -> None:
        self.x1n, self.x2n, self.thr2 = x1n, x2n, thr2
        self.num_data = len(x1n)

    def best_minimal_model(self, samples: np.ndarray) -> tuple[PoseHypothesis, float] | None:
        x1n, x2n = self.x1n, self.x2n
        Es, si = essential_5point_batch(x1n[samples], x2n[samples])
        if len(Es) == 0:
            return None
        Rs, ts, ok = _poses_from_essentials(Es, x1n[samples[si]], x2n[samples[si]])
        if not np.any(ok):
            return None
        Rs, ts = Rs[ok], ts[ok]
        costs, _ = msac_costs_pose(np.ascontiguousarray(Rs), np.ascontiguousarray(ts), x1n, x2n, self.thr2)
        k = int(np.argmin(costs))
        return (Rs[k], ts[k]), float(costs[k])

    def score(self, pose: PoseHypothesis) -> tuple[float, np.ndarray]:
        return _msac(pose[0], pose[1], self.x1n, self.x2n, self.thr2)

    def refit(self, pose: PoseHypothesis, inliers: np.ndarray) -> PoseHypothesis:
        res = refine_relative_pose(
            pose[0],
            pose[1],
            self.x1n[inliers],
            self.x2n[inliers],
            loss="cauchy",
            loss_scale=np.sqrt(self.thr2),
            max_iterations=8,
        )
        return res.R, res.t


_LOCAL = LocalOptimization(max_steps=4, min_inliers=6, min_relative_gain=1e-6)


def estimate_essential(
    x1n: np.ndarray,
    x2n: np.ndarray,
    threshold: float,
    options: RansacOptions = RansacOptions(),
    seed: int | np.random.Generator | None = 0,
    refine: bool = True,
    final_loss: Loss = "cauchy",
    final_loss_scale: float | None = None,
    pixel_scale: float = 1.0,
    sigmas: np.ndarray | None = None,
) -> RelativePose:
    """LO-RANSAC relative pose from normalised correspondences.

    Args:
        x1n, x2n: (N, 2) normalised camera coordinates of matches in camera 1 and 2, N >= 5.
        threshold: inlier threshold on the Sampson distance, normalised units
            (``options.threshold`` is ignored here).
        options: sampling options (confidence, iteration limits, batch size, LO on/off).
        seed: seed or Generator for the samples.
        refine: run the final robust LM refinement on the inliers.
        final_loss, final_loss_scale: loss of the final refinement and its scale in normalised
            units (default: half the threshold).
        pixel_scale: focal length used to report ``errors_px`` and ``threshold_px``.
        sigmas: optional (N,) relative localisation noise of each match (e.g. from keypoint
            scales; median ~1). The final refinement divides residuals by it, so precise
            (fine-scale) matches weigh more. Inlier tests are unaffected.
    Returns:
        RelativePose (inliers: Sampson distance < threshold and positive depths).
    Raises:
        EstimationError: fewer than 5 matches, or no sample gave a valid pose.
    """
    x1n = as_points2(x1n, "x1n")
    x2n = as_points2(x2n, "x2n")
    if len(x1n) != len(x2n):
        raise InputError(f"{len(x1n)} points in image 1 but {len(x2n)} in image 2")
    n = len(x1n)
    if n < 5:
        raise EstimationError(f"relative pose needs at least 5 matches, got {n}")
    # LO runs on every so-far-the-best *sample* model (compared with raw sample costs, so a
    # better hypothesis is polished even when an earlier polished model scores lower)
    problem = _RelativePoseProblem(x1n, x2n, float(threshold) ** 2)
    found = lo_ransac(problem, options, as_generator(seed), _LOCAL, polish_every_best_sample=True)
    R, t = found.model
    best_inl = found.inliers
    out = finalize_pose(
        R,
        t,
        x1n,
        x2n,
        threshold,
        best_inl if refine else None,
        final_loss,
        final_loss_scale,
        sigmas,
        pixel_scale,
    )
    out.iterations, out.local_optimizations = found.iterations, found.local_optimizations
    return out


def polish_pose(
    R: np.ndarray, t: np.ndarray, x1n: np.ndarray, x2n: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Local optimisation of a pose hypothesis (as inside LO-RANSAC).

    Args:
        R, t: cam2_from_cam1 hypothesis; x1n, x2n: (N, 2) normalised matches;
        threshold: Sampson threshold, normalised units.
    Returns:
        ``(R, t, cost, inliers)`` with the MSAC cost (normalised units squared) and (N,) bool.
    """
    problem = _RelativePoseProblem(x1n, x2n, float(threshold) ** 2)
    pose = (np.asarray(R, np.float64), np.asarray(t, np.float64))
    cost, inl = problem.score(pose)
    (R, t), cost, inl = local_optimize(problem, pose, cost, inl, _LOCAL)
    return R, t, cost, inl


def finalize_pose(
    R: np.ndarray,
    t: np.ndarray,
    x1n: np.ndarray,
    x2n: np.ndarray,
    threshold: float,
    inliers: np.ndarray | None,
    loss: Loss = "cauchy",
    loss_scale: float | None = None,
    sigmas: np.ndarray | None = None,
    pixel_scale: float = 1.0,
) -> RelativePose:
    """Final robust refinement of a pose on its inliers and the resulting inlier set.

    Args:
        R, t: cam2_from_cam1 estimate; x1n, x2n: (N, 2) normalised matches.
        threshold: Sampson inlier threshold, normalised units.
        inliers: (N,) bool to refine on, or None to skip the refinement.
        loss, loss_scale: robust loss and its scale (normalised units; default half the threshold).
        sigmas: optional (N,) relative noise of each match (weights of the refinement).
        pixel_scale: focal length for reporting pixel errors.
    Returns:
        RelativePose (iterations and LO count zero).
    """
    thr2 = float(threshold) ** 2
    R = np.asarray(R, np.float64)
    t = np.asarray(t, np.float64)
    refined = False
    if inliers is not None and np.count_nonzero(inliers) >= 6:
        inl = inliers
        scale = 0.5 * float(threshold) if loss_scale is None else float(loss_scale)
        for _ in range(2):
            sig = None if sigmas is None else sigmas[inl]
            res = refine_relative_pose(
                R, t, x1n[inl], x2n[inl], loss=loss, loss_scale=scale, max_iterations=50, sigmas=sig
            )
            R, t = res.R, res.t
            _, new_inl = _msac(R, t, x1n, x2n, thr2)
            if np.array_equal(new_inl, inl):
                break
            inl = new_inl
        refined = True
    t = t / np.linalg.norm(t)
    E = essential_from_pose(R, t)
    z1, z2 = cheirality_depths(R, t, x1n, x2n)
    with np.errstate(invalid="ignore"):
        front = (z1 > 0) & (z2 > 0)
    e = np.sqrt(sampson_sq(E, x1n, x2n))
    return RelativePose(
        R=R,
        t=t,
        E=E,
        inliers=(e * e < thr2) & front,
        errors_px=e * pixel_scale,
        threshold_px=float(threshold) * pixel_scale,
        iterations=0,
        local_optimizations=0,
        refined=refined,
    )


def estimate_relative_pose(
    x1: np.ndarray,
    x2: np.ndarray,
    intr1: Intrinsics,
    intr2: Intrinsics,
    options: RansacOptions = RansacOptions(),
    seed: int | np.random.Generator | None = 0,
    refine: bool = True,
    final_loss: Loss = "cauchy",
    final_loss_scale_px: float | None = None,
    sigmas: np.ndarray | None = None,
) -> RelativePose:
    """Relative pose of camera 2 w.r.t. camera 1 from pixel matches (5-point LO-RANSAC).

    Args:
        x1, x2: (N, 2) matching pixels in image 1 and image 2 (pixel-centre convention).
        intr1, intr2: the cameras' intrinsics (distortion is removed before estimation).
        options: ``options.threshold`` is the inlier threshold on the Sampson distance in pixels.
        seed: seed or Generator for the samples.
        refine: final robust refinement on all inliers.
        final_loss, final_loss_scale_px: loss of the final refinement and its scale in pixels
            (default half the threshold).
        sigmas: optional (N,) relative noise of each match for the final refinement.
    Returns:
        RelativePose with ``(R, t) = cam2_from_cam1``, |t| = 1.
    """
    x1 = as_points2(x1, "x1")
    x2 = as_points2(x2, "x2")
    f = focal_scale(intr1, intr2)
    return estimate_essential(
        normalize_points(x1, intr1),
        normalize_points(x2, intr2),
        options.threshold / f,
        options,
        seed,
        refine,
        final_loss,
        None if final_loss_scale_px is None else final_loss_scale_px / f,
        f,
        sigmas,
    )


def pose_from_essential(E: np.ndarray, x1n: np.ndarray, x2n: np.ndarray, mask: np.ndarray | None = None):
    """(R, t, in_front) from an essential matrix by the cheirality vote (see ``select_pose``)."""
    return select_pose(E, x1n, x2n, mask)
