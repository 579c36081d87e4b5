"""Numba kernels for the hot loops of robust estimation (compiled on first use, cached on disk)."""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["msac_costs", "sampson_sq_many"]


@numba.njit(cache=True, inline="always")
def _sampson_sq(F: np.ndarray, u1: float, v1: float, u2: float, v2: float) -> float:
    """Squared Sampson error of one match (u1, v1) <-> (u2, v2) under ``x2^T F x1 = 0`` (inf if undefined)."""
    a0 = F[0, 0] * u1 + F[0, 1] * v1 + F[0, 2]
    a1 = F[1, 0] * u1 + F[1, 1] * v1 + F[1, 2]
    a2 = F[2, 0] * u1 + F[2, 1] * v1 + F[2, 2]
    b0 = F[0, 0] * u2 + F[1, 0] * v2 + F[2, 0]
    b1 = F[0, 1] * u2 + F[1, 1] * v2 + F[2, 1]
    num = u2 * a0 + v2 * a1 + a2
    den = a0 * a0 + a1 * a1 + b0 * b0 + b1 * b1
    return num * num / den if den > 0 else np.inf


@numba.njit(cache=True, fastmath=False)
def msac_costs(Fs: np.ndarray, x1: np.ndarray, x2: np.ndarray, thr2: float) -> tuple[np.ndarray, np.ndarray]:
    """MSAC cost and inlier count of K models on N matches.

    Args:
        Fs: (K, 3, 3) float64 models with ``x2^T F x1 = 0``.
        x1, x2: (N, 2) float64 points.
        thr2: squared threshold (units of x squared).
    Returns:
        ``(cost, count)``: (K,) float64 sum of ``min(sampson^2, thr2)`` and (K,) int64 inliers.
    """
    K = Fs.shape[0]
    N = x1.shape[0]
    cost = np.zeros(K)
    count = np.zeros(K, dtype=np.int64)
    for k in range(K):
        f = Fs[k]
        c = 0.0
        m = 0
        for i in range(N):
            e = _sampson_sq(f, x1[i, 0], x1[i, 1], x2[i, 0], x2[i, 1])
            if e < thr2:
                c += e
                m += 1
            else:
                c += thr2
        cost[k] = c
        count[k] = m
    return cost, count


@numba.njit(cache=True)
def sampson_sq_many(Fs: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """(K, N) squared Sampson errors of K models (K, 3, 3) on N matches (N, 2)."""
    K = Fs.shape[0]
    N = x1.shape[0]
    out = np.empty((K, N))
    for k in range(K):
        f = Fs[k]
        for i in range(N):
            out[k, i] = _sampson_sq(f, x1[i, 0], x1[i, 1], x2[i, 0], x2[i, 1])
    return out


@numba.njit(cache=True)
def msac_costs_pose(
    Rs: np.ndarray, ts: np.ndarray, x1: np.ndarray, x2: np.ndarray, thr2: float
) -> tuple[np.ndarray, np.ndarray]:
    """MSAC cost and inlier count of K poses on N normalised matches, with cheirality.

    A match is an inlier when its squared Sampson error under ``E = [t]x R`` is below thr2 and
    its mid-point triangulation lies in front of both cameras.

    Args:
        Rs: (K, 3, 3) rotations and ts: (K, 3) translations, cam2_from_cam1.
        x1, x2: (N, 2) normalised coordinates.
        thr2: squared threshold, normalised units.
    Returns:
        ``(cost, count)``: (K,) float64 and (K,) int64.
    """
    K = Rs.shape[0]
    N = x1.shape[0]
    cost = np.zeros(K)
    count = np.zeros(K, dtype=np.int64)
    E = np.empty((3, 3))
    for k in range(K):
        R = Rs[k]
        tx, ty, tz = ts[k, 0], ts[k, 1], ts[k, 2]
        # E = [t]x R
        E[0, 0] = -tz * R[1, 0] + ty * R[2, 0]
        E[0, 1] = -tz * R[1, 1] + ty * R[2, 1]
        E[0, 2] = -tz * R[1, 2] + ty * R[2, 2]
        E[1, 0] = tz * R[0, 0] - tx * R[2, 0]
        E[1, 1] = tz * R[0, 1] - tx * R[2, 1]
        E[1, 2] = tz * R[0, 2] - tx * R[2, 2]
        E[2, 0] = -ty * R[0, 0] + tx * R[1, 0]
        E[2, 1] = -ty * R[0, 1] + tx * R[1, 1]
        E[2, 2] = -ty * R[0, 2] + tx * R[1, 2]
        # camera-2 centre in camera-1 frame: c2 = -R^T t
        cx = -(R[0, 0] * tx + R[1, 0] * ty + R[2, 0] * tz)
        cy = -(R[0, 1] * tx + R[1, 1] * ty + R[2, 1] * tz)
        cz = -(R[0, 2] * tx + R[1, 2] * ty + R[2, 2] * tz)
        c = 0.0
        m = 0
        for i in range(N):
            u1 = x1[i, 0]
            v1 = x1[i, 1]
            u2 = x2[i, 0]
            v2 = x2[i, 1]
            err = _sampson_sq(E, u1, v1, u2, v2)
            if err < thr2:
                # g2 = R^T f2
                gx = R[0, 0] * u2 + R[1, 0] * v2 + R[2, 0]
                gy = R[0, 1] * u2 + R[1, 1] * v2 + R[2, 1]
                gz = R[0, 2] * u2 + R[1, 2] * v2 + R[2, 2]
                aa = u1 * u1 + v1 * v1 + 1.0
                bb = u1 * gx + v1 * gy + gz
                cc = gx * gx + gy * gy + gz * gz
                dd = u1 * cx + v1 * cy + cz
                ee = gx * cx + gy * cy + gz * cz
                dn = aa * cc - bb * bb
                l1 = (cc * dd - bb * ee) * dn
                l2 = (bb * dd - aa * ee) * dn
                if l1 > 0 and l2 > 0:
                    c += err
                    m += 1
                    continue
            c += thr2
        cost[k] = c
        count[k] = m
    return cost, count
