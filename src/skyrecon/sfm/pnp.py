"""Absolute pose of one camera from 2D-3D correspondences: RANSAC around a minimal P3P solver
(OpenCV's AP3P inside ``cv2.solvePnPRansac``), then robust non-linear refinement (our bundle
adjuster with the points held fixed) and a final inlier selection.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from skyrecon.errors import EstimationError, InputError
from skyrecon.sfm.bundle import BundleProblem, BundleSolverOptions, bundle_adjust

__all__ = ["AbsolutePose", "estimate_absolute_pose", "refine_absolute_pose"]


@dataclass
class AbsolutePose:
    """A robustly estimated camera pose.

    Attributes:
        R: (3, 3) rotation ``cam_from_world``.
        t: (3,) translation ``cam_from_world`` (world units).
        inliers: (N,) bool per correspondence.
        errors_px: (N,) reprojection error of every correspondence, pixels (inf behind).
        num_correspondences: N.
    """

    R: np.ndarray
    t: np.ndarray
    inliers: np.ndarray
    errors_px: np.ndarray
    num_correspondences: int

    @property
    def num_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))

    @property
    def inlier_ratio(self) -> float:
        return self.num_inliers / max(1, self.num_correspondences)


def reprojection_errors_px(
    R: np.ndarray, t: np.ndarray, xn: np.ndarray, X: np.ndarray, focal: float
) -> np.ndarray:
    """(N,) reprojection errors, pixels, of world points X (N, 3) seen at normalised coordinates
    xn (N, 2) by the camera ``cam_from_world = (R, t)``; inf behind the camera or not finite."""
    P = X @ R.T + t
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.hypot(P[:, 0] / P[:, 2] - xn[:, 0], P[:, 1] / P[:, 2] - xn[:, 1]) * focal
    e[~(P[:, 2] > 0) | ~np.isfinite(e)] = np.inf
    return e


def refine_absolute_pose(
    R: np.ndarray,
    t: np.ndarray,
    xn: np.ndarray,
    X: np.ndarray,
    focal_px: float,
    loss_scale_px: float = 1.0,
    sigmas_px: np.ndarray | None = None,
    max_iterations: int = 30,
) -> tuple[np.ndarray, np.ndarray]:
    """Robust (Cauchy) Levenberg-Marquardt refinement of a pose with fixed points.

    Args:
        R, t: initial ``cam_from_world``.
        xn: (N, 2) undistorted normalised observations; X: (N, 3) world points.
        focal_px: focal length converting normalised errors to pixels.
        loss_scale_px: Cauchy scale, pixels.
        sigmas_px: optional (N,) localisation error of each observation, pixels.
    Returns:
        Refined ``(R, t)``.
    """
    n = len(xn)
    sig = np.ones(n) if sigmas_px is None else np.asarray(sigmas_px, np.float64)
    prob = BundleProblem(
        R[None].copy(),
        t[None].copy(),
        X,
        np.array([[1.0, 1.0, 0.0, 0.0, 0.0, 0.0]]),
        np.zeros(1, np.int64),
        np.zeros(n, np.int64),
        np.arange(n),
        xn,
        sig / focal_px,
        constant_points=np.ones(n, bool),
    )
    bundle_adjust(
        prob, BundleSolverOptions(loss="cauchy", loss_scale=loss_scale_px, max_iterations=max_iterations)
    )
    return prob.R[0], prob.t[0]


def estimate_absolute_pose(
    xn: np.ndarray,
    X: np.ndarray,
    focal_px: float,
    threshold_px: float = 4.0,
    seed: int = 0,
    max_iterations: int = 10000,
    confidence: float = 0.9999,
    min_inliers: int = 15,
    refine_loss_scale_px: float = 1.0,
    sigmas_px: np.ndarray | None = None,
) -> AbsolutePose:
    """Robust pose of a calibrated camera from 2D-3D correspondences.

    Args:
        xn: (N, 2) undistorted normalised image coordinates (z = 1 plane).
        X: (N, 3) world points, same order.
        focal_px: focal length, pixels (thresholds are given in pixels).
        threshold_px: RANSAC and final inlier threshold on the reprojection error, pixels.
        seed: seeds OpenCV's random generator (deterministic for a given seed).
        max_iterations, confidence: RANSAC stopping.
        min_inliers: fewer RANSAC inliers raise ``EstimationError``.
        refine_loss_scale_px: Cauchy scale of the refinement, pixels.
        sigmas_px: optional (N,) localisation error of each observation, pixels.
    Returns:
        AbsolutePose.
    Raises:
        EstimationError: too few correspondences, RANSAC found no pose, or too few inliers.
        InputError: mismatched arrays.
    """
    xn = np.ascontiguousarray(xn, np.float64).reshape(-1, 2)
    X = np.ascontiguousarray(X, np.float64).reshape(-1, 3)
    if len(xn) != len(X):
        raise InputError(f"{len(xn)} image points but {len(X)} world points")
    n = len(xn)
    if n < max(4, min_inliers):
        raise EstimationError(f"only {n} 2D-3D correspondences (at least {max(4, min_inliers)} needed)")
    cv2.setRNGSeed(int(seed) & 0x7FFFFFFF)
    thr_n = float(threshold_px) / float(focal_px)
    try:
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            X,
            xn,
            np.eye(3),
            None,
            iterationsCount=int(max_iterations),
            reprojectionError=thr_n,
            confidence=float(confidence),
            flags=cv2.SOLVEPNP_AP3P,
        )
    except cv2.error as exc:  # degenerate configurations
        raise EstimationError(f"PnP RANSAC failed: {exc.err}") from None
    if not ok or inl is None or len(inl) < 4:
        raise EstimationError(f"PnP RANSAC found no pose consistent with {n} correspondences")
    R = cv2.Rodrigues(rvec)[0]
    t = tvec.reshape(3).astype(np.float64)
    inliers = np.zeros(n, bool)
    inliers[inl.reshape(-1)] = True
    for _ in range(2):
        if np.count_nonzero(inliers) < 4:
            break
        R, t = refine_absolute_pose(
            R,
            t,
            xn[inliers],
            X[inliers],
            focal_px,
            refine_loss_scale_px,
            None if sigmas_px is None else np.asarray(sigmas_px)[inliers],
        )
        new = reprojection_errors_px(R, t, xn, X, focal_px) < threshold_px
        if np.array_equal(new, inliers):
            break
        inliers = new
    err = reprojection_errors_px(R, t, xn, X, focal_px)
    inliers = err < threshold_px
    if np.count_nonzero(inliers) < min_inliers:
        raise EstimationError(
            f"only {int(np.count_nonzero(inliers))} of {n} 2D-3D correspondences agree on a pose "
            f"(at least {min_inliers} needed)"
        )
    return AbsolutePose(R, t, inliers, err, n)
