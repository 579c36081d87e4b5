"""Relative-pose error metrics: rotation error and translation-direction error, in degrees.

Both poses are ``cam2_from_cam1`` (``p_cam2 = R p_cam1 + t``). The translation of a two-view
estimate is known only up to a positive scale, so its error is the angle between directions
(a sign flip counts as 180 degrees: cheirality fixes the sign).
"""

from __future__ import annotations

import numpy as np

from skyrecon.core.rigid import Rigid3, rotation_angle_deg
from skyrecon.errors import InputError

__all__ = ["rotation_error_deg", "translation_direction_error_deg", "relative_pose_errors", "pose_auc"]


def rotation_error_deg(R_est: np.ndarray, R_gt: np.ndarray) -> float:
    """Angle of ``R_est^T R_gt`` in degrees (geodesic distance on SO(3)), for (3, 3) rotations."""
    R_est = np.asarray(R_est, np.float64)
    R_gt = np.asarray(R_gt, np.float64)
    if R_est.shape != (3, 3) or R_gt.shape != (3, 3):
        raise InputError(f"rotations must be 3x3, got {R_est.shape} and {R_gt.shape}")
    return rotation_angle_deg(R_est.T @ R_gt)


def translation_direction_error_deg(t_est: np.ndarray, t_gt: np.ndarray) -> float:
    """Angle in degrees between two (3,) translation vectors (scale ignored, sign kept).

    Raises:
        InputError: a zero vector (no direction).
    """
    a = np.asarray(t_est, np.float64).reshape(3)
    b = np.asarray(t_gt, np.float64).reshape(3)
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na == 0 or nb == 0:
        raise InputError("a translation direction error needs non-zero translations")
    a, b = a / na, b / nb
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b)))


def relative_pose_errors(est: Rigid3, gt: Rigid3) -> tuple[float, float]:
    """(rotation error, translation-direction error), degrees, of two ``cam2_from_cam1`` poses."""
    return rotation_error_deg(est.R, gt.R), translation_direction_error_deg(est.t, gt.t)


def pose_auc(errors_deg: np.ndarray, thresholds_deg: tuple[float, ...] = (5.0, 10.0, 20.0)) -> list[float]:
    """Area under the recall curve of max(rotation, translation) errors up to each threshold
    (the usual relative-pose benchmark summary), each in [0, 1]."""
    e = np.sort(np.asarray(errors_deg, np.float64))
    n = len(e)
    if n == 0:
        return [0.0 for _ in thresholds_deg]
    recall = np.arange(1, n + 1) / n
    e = np.concatenate([[0.0], e])
    recall = np.concatenate([[0.0], recall])
    out = []
    for th in thresholds_deg:
        k = int(np.searchsorted(e, th))
        x = np.concatenate([e[:k], [th]])
        y = np.concatenate([recall[:k], [recall[k - 1]]])
        out.append(float(np.trapezoid(y, x) / th))
    return out
