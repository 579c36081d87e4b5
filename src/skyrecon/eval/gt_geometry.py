"""Two-view reference geometry from ground-truth cameras.

Used to score estimated relative poses, fundamental matrices and matches against known
cameras (Middlebury, Strecha, HALCON sets read by :mod:`skyrecon.io.multiview`).

Conventions: pixels ``(u, v)`` with the centre of the top-left pixel at (0, 0); poses
``cam_from_world``; ``cam2_from_cam1 = cam2_from_world @ world_from_cam1``. Lens distortion is
ignored: these matrices relate *undistorted* pixels (all supported ground-truth sets are
undistorted).
"""

from __future__ import annotations

import numpy as np

from skyrecon.core.rigid import Rigid3
from skyrecon.core.view import PosedView
from skyrecon.geometry.epipolar import skew as skew_matrix  # (3, 3) [v]x, public name kept

__all__ = [
    "relative_pose",
    "skew_matrix",
    "essential_from_views",
    "fundamental_from_views",
    "epipolar_distances",
    "symmetric_epipolar_distance",
]


def relative_pose(view1: PosedView, view2: PosedView) -> Rigid3:
    """``cam2_from_cam1``: maps points from camera 1's frame to camera 2's, metres."""
    return view2.cam_from_world @ view1.cam_from_world.inverse()


def essential_from_views(view1: PosedView, view2: PosedView) -> np.ndarray:
    """(3, 3) essential matrix ``E = [t]x R`` with ``(R, t) = cam2_from_cam1``.

    Satisfies ``x2^T E x1 = 0`` for normalised camera coordinates (z = 1) of one world point.
    Scaled so that ``|t| = 1`` (E has singular values 1, 1, 0); zero if the centres coincide.
    """
    rel = relative_pose(view1, view2)
    n = np.linalg.norm(rel.t)
    t = rel.t / n if n > 0 else rel.t
    return skew_matrix(t) @ rel.R


def fundamental_from_views(view1: PosedView, view2: PosedView) -> np.ndarray:
    """(3, 3) fundamental matrix from two ground-truth views.

    ``F = K2^-T [t]x R K1^-1`` with ``(R, t) = cam2_from_cam1``, so that
    ``[u2, v2, 1] F [u1, v1, 1]^T = 0`` for the pixels (skyrecon convention) of one world point
    in view 1 and view 2. ``F @ x1`` is the epipolar line in image 2; ``F.T @ x2`` the line in
    image 1. Normalised to unit Frobenius norm.
    """
    E = essential_from_views(view1, view2)
    K1inv = np.linalg.inv(view1.intrinsics.K)
    K2inv = np.linalg.inv(view2.intrinsics.K)
    F = K2inv.T @ E @ K1inv
    n = np.linalg.norm(F)
    return F / n if n > 0 else F


def epipolar_distances(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Point-to-epipolar-line distances, pixels.

    Args:
        F: (3, 3) with ``x2^T F x1 = 0``.
        x1, x2: (N, 2) matching pixels in image 1 and image 2.
    Returns:
        ``(d1, d2)``, each (N,): distance of ``x1`` to the line ``F^T x2`` in image 1 and of
        ``x2`` to the line ``F x1`` in image 2.
    """
    x1 = np.asarray(x1, dtype=np.float64).reshape(-1, 2)
    x2 = np.asarray(x2, dtype=np.float64).reshape(-1, 2)
    h1 = np.concatenate([x1, np.ones((len(x1), 1))], axis=1)
    h2 = np.concatenate([x2, np.ones((len(x2), 1))], axis=1)
    l2 = h1 @ F.T  # lines in image 2, (N, 3)
    l1 = h2 @ F  # lines in image 1, (N, 3)
    alg = np.abs(np.sum(h2 * l2, axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        d2 = alg / np.hypot(l2[:, 0], l2[:, 1])
        d1 = alg / np.hypot(l1[:, 0], l1[:, 1])
    return d1, d2


def symmetric_epipolar_distance(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """(N,) symmetric epipolar distance, pixels: the mean of the two point-to-line distances.

    ``(d(x1, F^T x2) + d(x2, F x1)) / 2`` for (N, 2) pixel arrays ``x1``, ``x2``.
    """
    d1, d2 = epipolar_distances(F, x1, x2)
    return 0.5 * (d1 + d2)
