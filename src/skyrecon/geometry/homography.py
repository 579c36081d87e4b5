"""Homographies (normalised DLT, batched 4-point RANSAC) and the H-versus-E degeneracy test.

``x2 ~ H x1`` for pixels. A homography explains a match set when the scene is a plane or the
camera only rotated; the degeneracy test compares how well H and the epipolar model explain the
same matches and measures the parallax left after removing the rotation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skyrecon.errors import EstimationError, InputError
from skyrecon.geometry.epipolar import (
    as_points2,
    cheirality_depths,
    hartley_normalization,
    homogeneous,
    null_vector,
)
from skyrecon.geometry.sampling import LocalOptimization, RansacOptions, as_generator, lo_ransac

__all__ = [
    "homography_dlt",
    "homography_transfer_sq",
    "HomographyEstimate",
    "estimate_homography",
    "decompose_homography",
]


def _dlt_rows(n1: np.ndarray, n2: np.ndarray) -> np.ndarray:
    """(..., 2m, 9) DLT rows for points (..., m, 2)."""
    u1, v1 = n1[..., 0], n1[..., 1]
    u2, v2 = n2[..., 0], n2[..., 1]
    z = np.zeros_like(u1)
    o = np.ones_like(u1)
    r1 = np.stack([-u1, -v1, -o, z, z, z, u2 * u1, u2 * v1, u2], axis=-1)
    r2 = np.stack([z, z, z, -u1, -v1, -o, v2 * u1, v2 * v1, v2], axis=-1)
    return np.concatenate([r1, r2], axis=-2)


def homography_dlt(x1: np.ndarray, x2: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Normalised DLT homography ``x2 ~ H x1`` from N >= 4 pixel matches (N, 2).

    Returns:
        (3, 3) H with ``H[2, 2] = 1`` when possible (else unit Frobenius norm).
    """
    x1 = np.asarray(x1, np.float64)
    x2 = np.asarray(x2, np.float64)
    if len(x1) < 4:
        raise EstimationError(f"a homography needs at least 4 matches, got {len(x1)}")
    n1, T1 = hartley_normalization(x1)
    n2, T2 = hartley_normalization(x2)
    A = _dlt_rows(n1, n2)
    if weights is not None:
        w = np.asarray(weights, np.float64)
        A = A * np.concatenate([w, w])[:, None]
    Hn = null_vector(A).reshape(3, 3)
    H = np.linalg.inv(T2) @ Hn @ T1
    return H / H[2, 2] if abs(H[2, 2]) > 1e-12 * np.abs(H).max() else H / np.linalg.norm(H)


def homography_transfer_sq(Hs: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Symmetric squared transfer error ``(|x2 - H x1|^2 + |x1 - H^-1 x2|^2) / 2``.

    Args:
        Hs: (K, 3, 3) or (3, 3) homographies.
        x1, x2: (N, 2) pixels.
    Returns:
        (K, N) or (N,) squared errors, pixels^2 (inf for points mapped to infinity).
    """
    single = Hs.ndim == 2
    Hs = Hs[None] if single else Hs
    h1 = homogeneous(x1).T
    h2 = homogeneous(x2).T
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # adjugate (a scaled inverse that exists for singular H too): columns r2xr3, r3xr1, r1xr2
        r1, r2, r3 = Hs[:, 0], Hs[:, 1], Hs[:, 2]
        Hinv = np.stack([np.cross(r2, r3), np.cross(r3, r1), np.cross(r1, r2)], axis=-1)
        p2 = Hs @ h1  # (K, 3, N)
        p1 = Hinv @ h2
        e2 = (p2[:, 0] / p2[:, 2] - x2[:, 0]) ** 2 + (p2[:, 1] / p2[:, 2] - x2[:, 1]) ** 2
        e1 = (p1[:, 0] / p1[:, 2] - x1[:, 0]) ** 2 + (p1[:, 1] / p1[:, 2] - x1[:, 1]) ** 2
        e = 0.5 * (e1 + e2)
    e[~np.isfinite(e)] = np.inf
    return e[0] if single else e


@dataclass
class HomographyEstimate:
    """A robust homography ``x2 ~ H x1`` (pixels).

    Attributes:
        H: (3, 3). inliers: (N,) bool. errors_px: (N,) symmetric transfer distance, pixels.
        iterations: samples drawn.
    """

    H: np.ndarray
    inliers: np.ndarray
    errors_px: np.ndarray
    iterations: int

    @property
    def num_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))


def _batch_4point(n1: np.ndarray, n2: np.ndarray) -> np.ndarray:
    """(B, 3, 3) homographies through (B, 4, 2) normalised samples (may be degenerate)."""
    A = _dlt_rows(n1, n2)  # (B, 8, 9)
    _, _, Vt = np.linalg.svd(A, full_matrices=True)
    return Vt[:, -1].reshape(-1, 3, 3)


class _HomographyProblem:
    """H for :func:`lo_ransac`: batched 4-point DLT on Hartley-normalised samples, MSAC on the
    symmetric transfer error (pixels^2), refit by the normalised DLT on the inliers."""

    model_name = "homography"
    sample_size = 4

    def __init__(self, x1: np.ndarray, x2: np.ndarray, thr2: float) -> None:
        self.x1, self.x2, self.thr2 = x1, x2, thr2
        self.num_data = len(x1)
        self.n1, self.T1 = hartley_normalization(x1)
        self.n2, T2 = hartley_normalization(x2)
        self.T2inv = np.linalg.inv(T2)

    def best_minimal_model(self, samples: np.ndarray) -> tuple[np.ndarray, float] | None:
        Hs = self.T2inv @ _batch_4point(self.n1[samples], self.n2[samples]) @ self.T1
        costs = np.minimum(homography_transfer_sq(Hs, self.x1, self.x2), self.thr2).sum(axis=1)
        k = int(np.argmin(costs))
        return Hs[k], float(costs[k])

    def score(self, H: np.ndarray) -> tuple[float, np.ndarray]:
        e2 = homography_transfer_sq(H, self.x1, self.x2)
        return float(np.minimum(e2, self.thr2).sum()), e2 < self.thr2

    def refit(self, H: np.ndarray, inliers: np.ndarray) -> np.ndarray:
        return homography_dlt(self.x1[inliers], self.x2[inliers])


_LOCAL = LocalOptimization(max_steps=3, min_inliers=5)


def estimate_homography(
    x1: np.ndarray,
    x2: np.ndarray,
    options: RansacOptions = RansacOptions(threshold=2.0),
    seed: int | np.random.Generator | None = 0,
) -> HomographyEstimate:
    """LO-RANSAC homography with MSAC scoring on the symmetric transfer error.

    Args:
        x1, x2: (N, 2) pixels, N >= 4.
        options: ``threshold`` in pixels (symmetric transfer distance).
        seed: seed or Generator.
    """
    x1 = as_points2(x1, "x1")
    x2 = as_points2(x2, "x2")
    n = len(x1)
    if n != len(x2):
        raise InputError(f"{n} points in image 1 but {len(x2)} in image 2")
    if n < 4:
        raise EstimationError(f"a homography needs at least 4 matches, got {n}")
    thr2 = options.threshold**2
    found = lo_ransac(_HomographyProblem(x1, x2, thr2), options, as_generator(seed), _LOCAL)
    best_H = found.model
    H = best_H / best_H[2, 2] if abs(best_H[2, 2]) > 1e-12 else best_H
    e2 = homography_transfer_sq(H, x1, x2)
    return HomographyEstimate(H, e2 < thr2, np.sqrt(e2), found.iterations)


def decompose_homography(
    H: np.ndarray,
    K1: np.ndarray,
    K2: np.ndarray,
    x1n: np.ndarray | None = None,
    x2n: np.ndarray | None = None,
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Motions compatible with a plane-induced homography (Ma, Soatto, Kosecka, Sastry, sec. 5.3).

    ``K2^-1 H K1 ~ R + t n^T / d`` for cam2_from_cam1 ``(R, t)`` and the plane ``n^T X = d`` in
    camera 1's frame. Up to four solutions; with the matches given, only those that put the
    plane in front of camera 1 and the matches in front of both cameras are kept (usually two:
    the planar two-fold ambiguity).

    Args:
        H: (3, 3) pixel homography ``x2 ~ H x1``.
        K1, K2: (3, 3) intrinsics.
        x1n, x2n: optional (N, 2) normalised coordinates of the homography's inliers.
    Returns:
        List of ``(R, t, n)``: rotation, unit translation direction (zero for a pure rotation)
        and unit plane normal (camera-1 frame).
    """
    Hn = np.linalg.inv(K2) @ np.asarray(H, np.float64) @ K1
    s = np.linalg.svd(Hn, compute_uv=False)
    Hn = Hn / s[1]
    if x1n is not None and x2n is not None and len(x1n):
        h1 = homogeneous(x1n)
        h2 = homogeneous(x2n)
        if np.median(np.sum(h2 * (h1 @ Hn.T), axis=1)) < 0:
            Hn = -Hn
    elif np.linalg.det(Hn) < 0:
        Hn = -Hn
    _, S2, Vt = np.linalg.svd(Hn.T @ Hn)
    V = Vt.T
    if np.linalg.det(V) < 0:
        V = -V
    s1, s3 = S2[0], S2[2]
    if s1 - s3 < 1e-10:  # pure rotation: H is a rotation
        U, _, Wt = np.linalg.svd(Hn)
        R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Wt)]) @ Wt
        return [(R, np.zeros(3), np.array([0.0, 0.0, 1.0]))]
    v1, v2, v3 = V[:, 0], V[:, 1], V[:, 2]
    a = np.sqrt(max(1.0 - s3, 0.0))
    b = np.sqrt(max(s1 - 1.0, 0.0))
    den = np.sqrt(s1 - s3)
    out = []
    for u in ((a * v1 + b * v3) / den, (a * v1 - b * v3) / den):
        U_ = np.stack([v2, u, np.cross(v2, u)], axis=1)
        W_ = np.stack([Hn @ v2, Hn @ u, np.cross(Hn @ v2, Hn @ u)], axis=1)
        R = W_ @ U_.T
        n = np.cross(v2, u)
        T = (Hn - R) @ n
        for sign in (1.0, -1.0):
            nn, TT = sign * n, sign * T
            if nn[2] <= 0:  # the plane must be in front of camera 1
                continue
            norm = np.linalg.norm(TT)
            out.append((R, TT / norm if norm > 0 else TT, nn / np.linalg.norm(nn)))
    if x1n is not None and x2n is not None and len(x1n):
        kept = []
        for R, t, n in out:
            z1, z2 = cheirality_depths(R, t, x1n, x2n)
            with np.errstate(invalid="ignore"):
                if np.mean((z1 > 0) & (z2 > 0)) > 0.5:
                    kept.append((R, t, n))
        out = kept or out
    return out
