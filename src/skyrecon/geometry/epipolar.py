"""Epipolar geometry: linear F solvers, E <-> F, Sampson error, decomposition of E, cheirality.

Conventions (DESIGN.md): pixels ``(u, v)`` with the centre of the top-left pixel at (0, 0);
``x2^T F x1 = 0`` for matching pixels ``x1`` in image 1 and ``x2`` in image 2;
``E = [t]x R`` with ``(R, t) = cam2_from_cam1`` (``p_cam2 = R p_cam1 + t``) and
``x2n^T E x1n = 0`` for normalised camera coordinates (the z = 1 plane). All math in float64.
"""

from __future__ import annotations

import numpy as np

from skyrecon.errors import EstimationError, InputError

__all__ = [
    "skew",
    "homogeneous",
    "as_points2",
    "hartley_normalization",
    "null_vector",
    "fundamental_8point",
    "fundamental_7point",
    "essential_8point",
    "essential_from_fundamental",
    "fundamental_from_essential",
    "essential_from_pose",
    "project_to_essential",
    "enforce_rank2",
    "sampson_sq",
    "sampson_distance",
    "sampson_sq_batch",
    "epipolar_lines",
    "decompose_essential",
    "pose_candidates",
    "cheirality_depths",
    "select_pose",
]


def skew(v: np.ndarray) -> np.ndarray:
    """(3, 3) cross-product matrix ``[v]x`` of a (3,) vector: ``skew(v) @ w == cross(v, w)``."""
    x, y, z = np.asarray(v, dtype=np.float64).reshape(3)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def as_points2(x: np.ndarray, what: str = "points") -> np.ndarray:
    """Validate and convert to a contiguous (N, 2) float64 array (raises InputError otherwise)."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 2:
        raise InputError(f"{what} must have shape (N, 2), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{what} contain NaN or infinite values")
    return np.ascontiguousarray(a)


def homogeneous(x: np.ndarray) -> np.ndarray:
    """(N, 2) -> (N, 3) by appending ones."""
    x = np.asarray(x, dtype=np.float64)
    return np.concatenate([x, np.ones((x.shape[0], 1))], axis=1)


def hartley_normalization(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hartley's isotropic normalisation: centroid to 0, mean distance to sqrt(2).

    Args:
        x: (N, 2) points (pixels).
    Returns:
        ``(xn, T)``: (N, 2) normalised points and the (3, 3) similarity with ``xn_h = T @ x_h``.
    """
    c = x.mean(axis=0)
    d = np.sqrt(((x - c) ** 2).sum(axis=1)).mean()
    s = np.sqrt(2.0) / d if d > 1e-300 else 1.0
    T = np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])
    return (x - c) * s, T


def _design_matrix(x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """(N, 9) rows of ``x2^T F x1 = 0`` for row-major vec(F)."""
    u1, v1 = x1[:, 0], x1[:, 1]
    u2, v2 = x2[:, 0], x2[:, 1]
    one = np.ones_like(u1)
    return np.stack([u2 * u1, u2 * v1, u2, v2 * u1, v2 * v1, v2, u1, v1, one], axis=1)


def null_vector(A: np.ndarray) -> np.ndarray:
    """Right singular vector of the smallest singular value of a tall (N, 9) matrix.

    A QR factorisation first reduces it to 9 x 9 (cheap, and as accurate as the SVD of A).
    """
    if len(A) > 9:
        # numpy's stub types every mode as QRResult; mode="r" returns the R factor alone
        A = np.linalg.qr(A, mode="r")  # type: ignore[assignment]
    _, _, Vt = np.linalg.svd(A, full_matrices=True)
    return Vt[-1]


def enforce_rank2(F: np.ndarray) -> np.ndarray:
    """Nearest rank-2 matrix (Frobenius norm) by zeroing the smallest singular value."""
    U, S, Vt = np.linalg.svd(F)
    S[2] = 0.0
    return U @ np.diag(S) @ Vt


def _unit_frobenius(M: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(M)
    return M / n if n > 0 else M


def fundamental_8point(x1: np.ndarray, x2: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Normalised 8-point algorithm (Hartley 1997) with rank-2 enforcement.

    Args:
        x1, x2: (N, 2) matching pixels in image 1 and image 2, N >= 8.
        weights: optional (N,) non-negative weights of the algebraic equations.
    Returns:
        (3, 3) fundamental matrix, rank 2, unit Frobenius norm, ``x2^T F x1 ~ 0``.
    Raises:
        EstimationError: fewer than 8 points.
    """
    x1 = np.asarray(x1, dtype=np.float64)
    x2 = np.asarray(x2, dtype=np.float64)
    if len(x1) < 8:
        raise EstimationError(f"the 8-point algorithm needs at least 8 matches, got {len(x1)}")
    n1, T1 = hartley_normalization(x1)
    n2, T2 = hartley_normalization(x2)
    A = _design_matrix(n1, n2)
    if weights is not None:
        A = A * np.asarray(weights, dtype=np.float64)[:, None]
    F = enforce_rank2(null_vector(A).reshape(3, 3))
    return _unit_frobenius(T2.T @ F @ T1)


def _cubic_real_roots(c: np.ndarray) -> np.ndarray:
    """Real roots of ``c[0] a^3 + c[1] a^2 + c[2] a + c[3]`` (degree may drop)."""
    c = np.asarray(c, dtype=np.float64)
    scale = np.abs(c).max()
    if scale == 0:
        return np.zeros(0)
    c = c / scale
    while len(c) > 1 and abs(c[0]) < 1e-12:
        c = c[1:]
    if len(c) == 1:
        return np.zeros(0)
    r = np.roots(c)
    # polish each root with Newton steps on the original cubic (np.roots works via eigenvalues)
    real = r[np.abs(r.imag) <= 1e-8 * np.maximum(1.0, np.abs(r))].real
    p = np.poly1d(c)
    dp = p.deriv()
    out = []
    for a in real:
        for _ in range(3):
            d = dp(a)
            if d == 0:
                break
            a = a - p(a) / d
        out.append(a)
    return np.array(out)


def fundamental_7point(x1: np.ndarray, x2: np.ndarray) -> list[np.ndarray]:
    """The 7-point algorithm: every real root of ``det(a F1 + (1 - a) F2) = 0``.

    Args:
        x1, x2: (7, 2) matching pixels (more rows are accepted; the null space is then
            the two smallest right singular vectors).
    Returns:
        List of 1 or 3 (3, 3) fundamental matrices, each rank 2 and unit Frobenius norm.
    Raises:
        EstimationError: fewer than 7 points.
    """
    x1 = np.asarray(x1, dtype=np.float64)
    x2 = np.asarray(x2, dtype=np.float64)
    if len(x1) < 7:
        raise EstimationError(f"the 7-point algorithm needs 7 matches, got {len(x1)}")
    n1, T1 = hartley_normalization(x1)
    n2, T2 = hartley_normalization(x2)
    A = _design_matrix(n1, n2)
    _, _, Vt = np.linalg.svd(A, full_matrices=len(A) < 9)
    F1 = Vt[-1].reshape(3, 3)
    F2 = Vt[-2].reshape(3, 3)
    # det(a F1 + (1-a) F2) = det(F2 + a D), D = F1 - F2: a cubic in a, from 4 samples (exact).
    D = F1 - F2
    samples = np.array([-1.0, 0.0, 1.0, 2.0])
    dets = np.array([np.linalg.det(F2 + a * D) for a in samples])
    coeffs = np.polyfit(samples, dets, 3)
    out = []
    for a in _cubic_real_roots(coeffs):
        F = a * F1 + (1.0 - a) * F2
        F = T2.T @ F @ T1
        out.append(_unit_frobenius(F))
    return out


def essential_from_fundamental(F: np.ndarray, K1: np.ndarray, K2: np.ndarray) -> np.ndarray:
    """``E = K2^T F K1`` (not projected onto the essential manifold; see :func:`project_to_essential`)."""
    return np.asarray(K2, np.float64).T @ np.asarray(F, np.float64) @ np.asarray(K1, np.float64)


def fundamental_from_essential(E: np.ndarray, K1: np.ndarray, K2: np.ndarray) -> np.ndarray:
    """``F = K2^-T E K1^-1``, unit Frobenius norm (pixels of image 1 and image 2)."""
    F = (
        np.linalg.inv(np.asarray(K2, np.float64)).T
        @ np.asarray(E, np.float64)
        @ np.linalg.inv(np.asarray(K1, np.float64))
    )
    return _unit_frobenius(F)


def essential_from_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``E = [t]x R`` for ``(R, t) = cam2_from_cam1``."""
    return skew(t) @ np.asarray(R, dtype=np.float64)


def project_to_essential(E: np.ndarray) -> np.ndarray:
    """Nearest essential matrix (singular values (1, 1, 0)) to a 3x3 matrix."""
    U, _, Vt = np.linalg.svd(E)
    return U @ np.diag([1.0, 1.0, 0.0]) @ Vt


def essential_8point(x1n: np.ndarray, x2n: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Linear 8-point estimate of E from normalised coordinates, projected onto the manifold.

    Args:
        x1n, x2n: (N, 2) normalised camera coordinates (z = 1 plane), N >= 8.
        weights: optional (N,) weights.
    Returns:
        (3, 3) essential matrix with singular values (1, 1, 0).
    """
    F = fundamental_8point(x1n, x2n, weights)
    return project_to_essential(F)


def sampson_sq(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """(N,) squared Sampson error of ``x2^T F x1 = 0`` in the units of x1, x2 squared.

    Args:
        F: (3, 3) fundamental (pixels) or essential (normalised coordinates) matrix.
        x1, x2: (N, 2) matching points.
    """
    x1 = np.asarray(x1, dtype=np.float64)
    x2 = np.asarray(x2, dtype=np.float64)
    Fx1 = x1 @ F[:, :2].T + F[:, 2]  # (N, 3)
    Ftx2 = x2 @ F[:2, :] + F[2, :]  # (N, 3)
    num = np.sum(x2 * Fx1[:, :2], axis=1) + Fx1[:, 2]
    den = Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        out = num * num / den
    out[~np.isfinite(out)] = np.inf
    return out


def sampson_distance(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """(N,) Sampson distance (first-order geometric error), in the units of x1 and x2."""
    return np.sqrt(sampson_sq(F, x1, x2))


def sampson_sq_batch(Fs: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Squared Sampson errors of K models on N matches.

    Args:
        Fs: (K, 3, 3) models.
        x1, x2: (N, 2) matching points.
    Returns:
        (K, N) squared errors (inf where undefined).
    """
    K = Fs.shape[0]
    h1 = homogeneous(x1).T  # (3, N)
    h2 = homogeneous(x2).T
    Fx1 = (Fs.reshape(3 * K, 3) @ h1).reshape(K, 3, -1)  # (K, 3, N)
    Ftx2 = (np.ascontiguousarray(Fs.transpose(0, 2, 1)).reshape(3 * K, 3) @ h2).reshape(K, 3, -1)
    num = h2[0] * Fx1[:, 0] + h2[1] * Fx1[:, 1] + Fx1[:, 2]
    den = Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        out = num * num / den
    out[~np.isfinite(out)] = np.inf
    return out


def epipolar_lines(F: np.ndarray, x: np.ndarray, which: int = 2) -> np.ndarray:
    """Epipolar lines ``a u + b v + c = 0`` with ``a^2 + b^2 = 1``.

    Args:
        F: (3, 3) with ``x2^T F x1 = 0``.
        x: (N, 2) pixels in image 1 (``which=2``: lines in image 2) or image 2 (``which=1``).
    Returns:
        (N, 3) normalised line coefficients.
    """
    h = homogeneous(np.asarray(x, dtype=np.float64))
    lines = h @ F.T if which == 2 else h @ F
    n = np.hypot(lines[:, 0], lines[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        return lines / n[:, None]


def decompose_essential(E: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """SVD decomposition of E into two rotations and a unit translation direction.

    ``E = U diag(1, 1, 0) V^T``; ``R1 = U W V^T``, ``R2 = U W^T V^T``, ``t = U[:, 2]``; the four
    candidate poses are ``(R1, t), (R1, -t), (R2, t), (R2, -t)``.

    Returns:
        ``(R1, R2, t)``: two (3, 3) rotations (det +1) and a (3,) unit vector.
    """
    U, _, Vt = np.linalg.svd(np.asarray(E, dtype=np.float64))
    if np.linalg.det(U) < 0:
        U = -U
    if np.linalg.det(Vt) < 0:
        Vt = -Vt
    W = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    R1 = U @ W @ Vt
    R2 = U @ W.T @ Vt
    t = U[:, 2] / np.linalg.norm(U[:, 2])
    return R1, R2, t


def pose_candidates(E: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The four ``(R, t)`` (cam2_from_cam1, |t| = 1) consistent with E."""
    R1, R2, t = decompose_essential(E)
    return [(R1, t), (R1, -t), (R2, t), (R2, -t)]


def ray_closest_points(
    R: np.ndarray, t: np.ndarray, x1n: np.ndarray, x2n: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where the rays of each match come closest to each other (camera 1's frame).

    Solves ``l1 * f1 - l2 * R^T f2 = -R^T t`` in the least-squares sense: the closest points are
    ``l1 * f1`` on ray 1 and ``c2 + l2 * g2`` on ray 2.

    Args:
        R, t: cam2_from_cam1.
        x1n, x2n: (N, 2) normalised coordinates.
    Returns:
        ``(l1, l2, f1, g2, c2, parallelism)``: (N,) ray parameters (= depths, since the ray
        directions have z = 1 in their own camera), (N, 3) ray directions ``f1`` and ``g2 = R^T f2``
        in camera 1's frame, camera 2's centre ``c2`` (3,), and (N,) ``|det| / (|f1|^2 |g2|^2)``,
        which is 0 for parallel rays (their parameters are then meaningless).
    """
    f1 = homogeneous(x1n)
    g2 = homogeneous(x2n) @ R  # rows: R^T f2
    c2 = -R.T @ t
    a = np.sum(f1 * f1, axis=1)
    b = np.sum(f1 * g2, axis=1)
    c = np.sum(g2 * g2, axis=1)
    d = f1 @ c2
    e = g2 @ c2
    den = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        l1 = (c * d - b * e) / den
        l2 = (b * d - a * e) / den
    return l1, l2, f1, g2, c2, np.abs(den) / (a * c)


def cheirality_depths(
    R: np.ndarray, t: np.ndarray, x1n: np.ndarray, x2n: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Depths of the mid-point triangulation of each match in both cameras.

    Args:
        R, t: cam2_from_cam1.
        x1n, x2n: (N, 2) normalised coordinates.
    Returns:
        ``(z1, z2)``: (N,) depth along each optical axis (units of t); NaN for parallel rays.
    """
    z1, z2, _, _, _, parallelism = ray_closest_points(R, t, x1n, x2n)  # f1, f2 have z = 1
    bad = parallelism < 1e-14
    return np.where(bad, np.nan, z1), np.where(bad, np.nan, z2)


def select_pose(
    E: np.ndarray, x1n: np.ndarray, x2n: np.ndarray, mask: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pick the one of four poses that puts most matches in front of both cameras.

    Args:
        E: (3, 3) essential matrix.
        x1n, x2n: (N, 2) normalised coordinates.
        mask: optional (N,) bool, the matches to vote with (e.g. inliers).
    Returns:
        ``(R, t, in_front)``: cam2_from_cam1 with |t| = 1, and (N,) bool mask of matches
        with positive depth in both cameras under that pose.
    Raises:
        EstimationError: no pose puts any match in front of both cameras.
    """
    best = None
    for R, t in pose_candidates(E):
        z1, z2 = cheirality_depths(R, t, x1n, x2n)
        with np.errstate(invalid="ignore"):
            front = (z1 > 0) & (z2 > 0)
        score = int(np.count_nonzero(front if mask is None else front & mask))
        if best is None or score > best[0]:
            best = (score, R, t, front)
    assert best is not None
    if best[0] == 0:
        raise EstimationError("no relative pose puts the matches in front of both cameras")
    return best[1], best[2], best[3]
