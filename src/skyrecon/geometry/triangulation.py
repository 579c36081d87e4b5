"""Two-view triangulation: linear DLT, the write-up's pseudo-inverse least squares, mid-point and
optimal (Lindstrom's niter2 correction, then exact intersection), plus the usual filters.

Frames: points are returned in camera 1's frame; ``(R, t) = cam2_from_cam1``. Projection
matrices ``P`` are (3, 4) and act on homogeneous points of the same frame, in the units of the
image points given with them (pixels with ``K [R | t]``, normalised coordinates with ``[R | t]``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from skyrecon.errors import InputError
from skyrecon.geometry.epipolar import essential_from_pose, homogeneous, ray_closest_points

__all__ = [
    "TriangulationMethod",
    "triangulate_dlt",
    "triangulate_pinv",
    "triangulate_midpoint",
    "correct_matches_optimal",
    "triangulate_optimal",
    "triangulate",
    "reprojection_errors",
    "parallax_angles_deg",
    "TriangulationFilter",
    "filter_points",
]

TriangulationMethod = Literal["dlt", "pinv", "midpoint", "optimal"]


def _check(x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x1 = np.asarray(x1, np.float64).reshape(-1, 2)
    x2 = np.asarray(x2, np.float64).reshape(-1, 2)
    if len(x1) != len(x2):
        raise InputError(f"{len(x1)} points in image 1 but {len(x2)} in image 2")
    return x1, x2


def _rows(P1: np.ndarray, P2: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """(N, 4, 4) linear equations ``A X = 0`` with rows scaled to unit norm."""
    A = np.stack(
        [
            x1[:, 0, None] * P1[2] - P1[0],
            x1[:, 1, None] * P1[2] - P1[1],
            x2[:, 0, None] * P2[2] - P2[0],
            x2[:, 1, None] * P2[2] - P2[1],
        ],
        axis=1,
    )
    return A / np.linalg.norm(A, axis=2, keepdims=True)


def triangulate_dlt(P1: np.ndarray, P2: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Linear (homogeneous DLT) triangulation, the smallest right singular vector of A.

    Args:
        P1, P2: (3, 4) projection matrices.
        x1, x2: (N, 2) image points in the units of P.
    Returns:
        (N, 3) float64 points; NaN for points at infinity.
    """
    x1, x2 = _check(x1, x2)
    A = _rows(np.asarray(P1, np.float64), np.asarray(P2, np.float64), x1, x2)
    _, _, Vt = np.linalg.svd(A)
    X = Vt[:, -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = X[:, :3] / X[:, 3:]
    out[np.abs(X[:, 3]) < 1e-14] = np.nan
    return out


def triangulate_pinv(P1: np.ndarray, P2: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """The write-up's inhomogeneous least squares: ``A[:, :3] X = -A[:, 3]`` by pseudo-inverse.

    Same arguments and result as :func:`triangulate_dlt`.
    """
    x1, x2 = _check(x1, x2)
    A = _rows(np.asarray(P1, np.float64), np.asarray(P2, np.float64), x1, x2)
    M = A[:, :, :3]
    b = -A[:, :, 3]
    return np.einsum("nij,nj->ni", np.linalg.pinv(M), b)


def triangulate_midpoint(R: np.ndarray, t: np.ndarray, x1n: np.ndarray, x2n: np.ndarray) -> np.ndarray:
    """Mid-point of the common perpendicular of the two rays.

    Args:
        R, t: cam2_from_cam1.
        x1n, x2n: (N, 2) normalised camera coordinates.
    Returns:
        (N, 3) points in camera 1's frame (NaN for parallel rays).
    """
    x1n, x2n = _check(x1n, x2n)
    R = np.asarray(R, np.float64)
    t = np.asarray(t, np.float64).reshape(3)
    l1, l2, f1, g2, c2, parallelism = ray_closest_points(R, t, x1n, x2n)
    X = 0.5 * (l1[:, None] * f1 + c2 + l2[:, None] * g2)
    X[parallelism < 1e-15] = np.nan
    return X


def correct_matches_optimal(E: np.ndarray, x1n: np.ndarray, x2n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lindstrom's niter2: the nearest pair of points satisfying ``x2^T E x1 = 0`` exactly.

    Minimises ``|x1 - x1'|^2 + |x2 - x2'|^2`` in the normalised plane (two Newton-like steps,
    optimal to machine precision in practice). Works for F and pixels just the same.

    Args:
        E: (3, 3) with ``x2^T E x1 = 0``; x1n, x2n: (N, 2).
    Returns:
        (N, 2), (N, 2) corrected points.
    """
    x1n, x2n = _check(x1n, x2n)
    Em = np.asarray(E, np.float64).T  # Lindstrom's form: x1^T Em x2 = 0
    h1 = homogeneous(x1n)
    h2 = homogeneous(x2n)
    Es = Em[:2, :2]
    n1 = (h2 @ Em.T)[:, :2]  # S Em x2
    n2 = (h1 @ Em)[:, :2]  # S Em^T x1
    a = np.einsum("ni,ij,nj->n", n1, Es, n2)
    b = 0.5 * (np.sum(n1 * n1, axis=1) + np.sum(n2 * n2, axis=1))
    c = np.einsum("ni,ij,nj->n", h1, Em, h2)
    d = np.sqrt(np.maximum(b * b - a * c, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = c / (b + d)
        n1, n2 = n1 - lam[:, None] * (n2 @ Es.T), n2 - lam[:, None] * (n1 @ Es)
        lam = lam * (2.0 * d) / (np.sum(n1 * n1, axis=1) + np.sum(n2 * n2, axis=1))
    lam = np.where(np.isfinite(lam), lam, 0.0)
    return x1n - lam[:, None] * n1, x2n - lam[:, None] * n2


def triangulate_optimal(R: np.ndarray, t: np.ndarray, x1n: np.ndarray, x2n: np.ndarray) -> np.ndarray:
    """Optimal two-view triangulation: correct the matches (niter2), then intersect the rays.

    Args/Returns as :func:`triangulate_midpoint`.
    """
    c1, c2 = correct_matches_optimal(essential_from_pose(R, t), x1n, x2n)
    return triangulate_midpoint(R, t, c1, c2)


def triangulate(
    R: np.ndarray,
    t: np.ndarray,
    x1n: np.ndarray,
    x2n: np.ndarray,
    method: TriangulationMethod = "optimal",
) -> np.ndarray:
    """Triangulate normalised matches with camera 1 = ``[I | 0]`` and camera 2 = ``[R | t]``.

    Returns:
        (N, 3) float64 points in camera 1's frame, in the units of t.
    """
    R = np.asarray(R, np.float64)
    t = np.asarray(t, np.float64).reshape(3)
    if method == "optimal":
        return triangulate_optimal(R, t, x1n, x2n)
    if method == "midpoint":
        return triangulate_midpoint(R, t, x1n, x2n)
    P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = np.hstack([R, t[:, None]])
    if method == "dlt":
        return triangulate_dlt(P1, P2, x1n, x2n)
    if method == "pinv":
        return triangulate_pinv(P1, P2, x1n, x2n)
    raise InputError(f"unknown triangulation method {method!r}; use optimal, midpoint, dlt or pinv")


def reprojection_errors(
    X: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    K1: np.ndarray,
    K2: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Pixel reprojection errors in both images (no lens distortion).

    Args:
        X: (N, 3) points in camera 1's frame; R, t: cam2_from_cam1; K1, K2: (3, 3).
        x1, x2: (N, 2) observed pixels.
    Returns:
        ``(e1, e2)``: (N,) distances in pixels (inf behind a camera or NaN points).
    """
    X = np.asarray(X, np.float64)
    out = []
    for K, P, x in ((K1, X, x1), (K2, X @ np.asarray(R).T + np.asarray(t).reshape(3), x2)):
        p = P @ np.asarray(K, np.float64).T
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = p[:, :2] / p[:, 2:]
            e = np.hypot(uv[:, 0] - x[:, 0], uv[:, 1] - x[:, 1])
        e[~(P[:, 2] > 0) | ~np.isfinite(e)] = np.inf
        out.append(e)
    return out[0], out[1]


def parallax_angles_deg(X: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N,) angle in degrees between the rays from the two camera centres to each point (N, 3)
    given in camera 1's frame (camera 2's centre is ``-R^T t``)."""
    X = np.asarray(X, np.float64)
    c2 = -np.asarray(R, np.float64).T @ np.asarray(t, np.float64).reshape(3)
    a = X
    b = X - c2
    with np.errstate(divide="ignore", invalid="ignore"):
        cos = np.sum(a * b, axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


@dataclass(frozen=True)
class TriangulationFilter:
    """Acceptance tests for triangulated points.

    Attributes:
        max_reprojection_px: largest reprojection error in either image, pixels.
        min_parallax_deg: smallest triangulation angle, degrees.
        max_depth_ratio: drop points farther than this many baselines (0 = no limit).
    """

    max_reprojection_px: float = 2.0
    min_parallax_deg: float = 0.5
    max_depth_ratio: float = 0.0


def filter_points(
    X: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    K1: np.ndarray,
    K2: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
    flt: TriangulationFilter = TriangulationFilter(),
) -> np.ndarray:
    """(N,) bool: finite, positive depth in both cameras, small reprojection error, enough parallax."""
    X = np.asarray(X, np.float64)
    ok = np.all(np.isfinite(X), axis=1)
    e1, e2 = reprojection_errors(X, R, t, K1, K2, x1, x2)
    ok &= (e1 <= flt.max_reprojection_px) & (e2 <= flt.max_reprojection_px)
    with np.errstate(invalid="ignore"):
        ok &= parallax_angles_deg(X, R, t) >= flt.min_parallax_deg
        if flt.max_depth_ratio > 0:
            ok &= np.linalg.norm(X, axis=1) <= flt.max_depth_ratio * np.linalg.norm(t)
    return ok
