"""The odometry's per-frame absolute pose: a lighter variant of
:func:`skyrecon.sfm.pnp.estimate_absolute_pose` for the real-time path.

Same RANSAC (OpenCV's AP3P in ``cv2.solvePnPRansac``, seeded), then Levenberg-Marquardt on the
inliers with OpenCV's ``solvePnPRefineLM`` (plain least squares: RANSAC has already removed the
outliers at a 2 px threshold) instead of the robust Cauchy refinement through the bundle adjuster,
which costs a few milliseconds more a frame. Measured on two synthetic 190 m flights (640x480) the
robust refinement gives a third less error per frame (1.0 vs 1.3 cm, 20 vs 27 millidegrees) and the
same or lower drift, so the engine uses it by default (``OdometrySettings.pnp_refinement``).
"""

from __future__ import annotations

import cv2
import numpy as np

from skyrecon.errors import EstimationError
from skyrecon.sfm.pnp import AbsolutePose, reprojection_errors_px

__all__ = ["fast_absolute_pose"]


def _errors_px(rvec: np.ndarray, tvec: np.ndarray, xn: np.ndarray, X: np.ndarray, focal: float) -> np.ndarray:
    return reprojection_errors_px(cv2.Rodrigues(rvec)[0], tvec.reshape(3), xn, X, focal)


def fast_absolute_pose(
    xn: np.ndarray,
    X: np.ndarray,
    focal_px: float,
    threshold_px: float = 2.0,
    seed: int = 0,
    max_iterations: int = 300,
    confidence: float = 0.999,
    min_inliers: int = 15,
) -> AbsolutePose:
    """Pose ``cam_from_world`` of a calibrated camera from 2D-3D matches, RANSAC + LM.

    Args:
        xn: (N, 2) normalised image coordinates (z = 1 plane) of the observations.
        X: (N, 3) world points, metres.
        focal_px: focal length, pixels (converts the pixel threshold).
        threshold_px: RANSAC and final inlier threshold on the reprojection error, pixels.
        seed: seeds OpenCV's random generator (deterministic for a given seed).
        max_iterations, confidence: RANSAC stopping.
        min_inliers: fewer final inliers raise ``EstimationError``.
    Returns:
        :class:`skyrecon.sfm.pnp.AbsolutePose` (``R``, ``t`` cam_from_world, inliers, errors).
    Raises:
        EstimationError: too few matches, no RANSAC consensus or too few inliers.
    """
    xn = np.ascontiguousarray(xn, np.float64).reshape(-1, 2)
    X = np.ascontiguousarray(X, np.float64).reshape(-1, 3)
    n = len(xn)
    if n < max(4, min_inliers):
        raise EstimationError(f"only {n} 2D-3D correspondences (at least {max(4, min_inliers)} needed)")
    cv2.setRNGSeed(int(seed) & 0x7FFFFFFF)
    K = np.eye(3)
    try:
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            X,
            xn,
            K,
            None,
            iterationsCount=int(max_iterations),
            reprojectionError=float(threshold_px) / float(focal_px),
            confidence=float(confidence),
            flags=cv2.SOLVEPNP_AP3P,
        )
    except cv2.error as exc:  # degenerate configurations
        raise EstimationError(f"PnP RANSAC failed: {exc.err}") from None
    if not ok or inl is None or len(inl) < 4:
        raise EstimationError(f"PnP RANSAC found no pose consistent with {n} correspondences")
    inliers = np.zeros(n, bool)
    inliers[inl.reshape(-1)] = True
    for _ in range(2):
        rvec, tvec = cv2.solvePnPRefineLM(X[inliers], xn[inliers], K, None, rvec, tvec)
        err = _errors_px(rvec, tvec, xn, X, focal_px)
        new = err < threshold_px
        if np.array_equal(new, inliers) or np.count_nonzero(new) < 4:
            break
        inliers = new
    err = _errors_px(rvec, tvec, xn, X, focal_px)
    inliers = err < threshold_px
    if np.count_nonzero(inliers) < min_inliers:
        raise EstimationError(
            f"only {int(np.count_nonzero(inliers))} of {n} 2D-3D correspondences agree on a pose "
            f"(at least {min_inliers} needed)"
        )
    return AbsolutePose(cv2.Rodrigues(rvec)[0], tvec.reshape(3).astype(np.float64), inliers, err, n)
