"""The five-point essential-matrix solver (Stewenius, Engels and Nister 2006), batched.

Five correspondences in normalised coordinates give a 4-dimensional null space
``E = x X + y Y + z Z + W``. The cubic constraints ``det(E) = 0`` and
``2 E E^T E - trace(E E^T) E = 0`` are ten equations in the twenty monomials of degree <= 3
in ``(x, y, z)``; Gauss-Jordan elimination of the ten cubic monomials leaves a 10x10 action
matrix for multiplication by ``x`` whose real eigenvectors are the (up to ten) solutions.

Everything is vectorised over a batch of minimal samples (numpy batched SVD / solve / eig).
"""

from __future__ import annotations

import itertools

import numpy as np

from skyrecon.errors import EstimationError

__all__ = ["essential_5point", "essential_5point_batch"]

# Monomials as exponents of (x, y, z).
_LIN = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (0, 0, 0)]
_QUAD = [
    (2, 0, 0),
    (1, 1, 0),
    (0, 2, 0),
    (1, 0, 1),
    (0, 1, 1),
    (0, 0, 2),
    (1, 0, 0),
    (0, 1, 0),
    (0, 0, 1),
    (0, 0, 0),
]
_CUBIC = [
    (3, 0, 0),
    (2, 1, 0),
    (1, 2, 0),
    (0, 3, 0),
    (2, 0, 1),
    (1, 1, 1),
    (0, 2, 1),
    (1, 0, 2),
    (0, 1, 2),
    (0, 0, 3),
] + _QUAD  # the 10 cubic monomials first, then the 10 of degree <= 2 (the action-matrix basis)


def _product_tensor(a: list, b: list, c: list) -> np.ndarray:
    """T[i, j, k] = 1 when monomial a[i] * b[j] == c[k]."""
    index = {m: k for k, m in enumerate(c)}
    T = np.zeros((len(a), len(b), len(c)))
    for (i, ma), (j, mb) in itertools.product(enumerate(a), enumerate(b)):
        T[i, j, index[tuple(p + q for p, q in zip(ma, mb))]] = 1.0
    return T


_T_LL = _product_tensor(_LIN, _LIN, _QUAD)  # (4, 4, 10)
_T_QL = _product_tensor(_QUAD, _LIN, _CUBIC)  # (10, 4, 20)

# Action matrix of multiplication by x on the basis _QUAD = [xx, xy, yy, xz, yz, zz, x, y, z, 1]:
# x * (xx, xy, yy, xz, yz, zz) are the cubic monomials (xxx, xxy, xyy, xxz, xyz, xzz) = rows 0,1,2,4,5,7
# of the eliminated system; x * (x, y, z, 1) = (xx, xy, xz, x) are basis elements 0, 1, 3, 6.
_ACTION_ROWS = np.array([0, 1, 2, 4, 5, 7])
_UNIT_ROWS = [(6, 0), (7, 1), (8, 3), (9, 6)]


def _null_spaces(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """(B, 4, 9) null-space bases of the (B, 5, 9) epipolar design matrices (rows of E row-major)."""
    A = np.einsum("bni,bnj->bnij", q2, q1).reshape(q1.shape[0], q1.shape[1], 9)
    _, _, Vt = np.linalg.svd(A, full_matrices=True)
    return Vt[:, -4:, :]


def _constraint_matrix(N: np.ndarray) -> np.ndarray:
    """(B, 10, 20) coefficients of the ten cubic constraints for null spaces N (B, 4, 9)."""
    B = N.shape[0]
    # E[b, i, j, :] = coefficients of E_ij on (x, y, z, 1)
    E = np.transpose(N, (0, 2, 1)).reshape(B, 3, 3, 4)
    EEt = np.einsum("bikp,bjkq,pqr->bijr", E, E, _T_LL)  # (B, 3, 3, 10)
    EEtE = np.einsum("bikr,bkjq,rqs->bijs", EEt, E, _T_QL)  # (B, 3, 3, 20)
    tr = EEt[:, 0, 0] + EEt[:, 1, 1] + EEt[:, 2, 2]  # (B, 10)
    trE = np.einsum("br,bijq,rqs->bijs", tr, E, _T_QL)
    C = (2.0 * EEtE - trE).reshape(B, 9, 20)
    # det(E) = E0 . (E1 x E2)
    E0, E1, E2 = E[:, 0], E[:, 1], E[:, 2]
    cross = np.stack(
        [
            np.einsum("bp,bq,pqr->br", E1[:, 1], E2[:, 2], _T_LL)
            - np.einsum("bp,bq,pqr->br", E1[:, 2], E2[:, 1], _T_LL),
            np.einsum("bp,bq,pqr->br", E1[:, 2], E2[:, 0], _T_LL)
            - np.einsum("bp,bq,pqr->br", E1[:, 0], E2[:, 2], _T_LL),
            np.einsum("bp,bq,pqr->br", E1[:, 0], E2[:, 1], _T_LL)
            - np.einsum("bp,bq,pqr->br", E1[:, 1], E2[:, 0], _T_LL),
        ],
        axis=1,
    )  # (B, 3, 10)
    det = np.einsum("bkr,bkq,rqs->bs", cross, E0, _T_QL)  # (B, 20)
    return np.concatenate([C, det[:, None, :]], axis=1)


def _eliminate(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solve ``M[:, :, :10] G = M[:, :, 10:]`` per sample; returns (G, ok) with ok (B,) bool."""
    A, Bm = M[:, :, :10], M[:, :, 10:]
    ok = np.ones(M.shape[0], dtype=bool)
    try:
        G = np.linalg.solve(A, Bm)
    except np.linalg.LinAlgError:
        G = np.zeros_like(Bm)
        for i in range(M.shape[0]):
            try:
                G[i] = np.linalg.solve(A[i], Bm[i])
            except np.linalg.LinAlgError:
                ok[i] = False
    ok &= np.all(np.isfinite(G), axis=(1, 2))
    return G, ok


def essential_5point_batch(x1n: np.ndarray, x2n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Five-point solutions for a batch of minimal samples.

    Args:
        x1n, x2n: (B, 5, 2) normalised camera coordinates (z = 1 plane) of B samples
            of 5 matches (more than 5 per sample also works: least-squares null space).
    Returns:
        ``(Es, sample)``: (M, 3, 3) essential matrices (unit Frobenius norm, singular values
        (s, s, 0)) and (M,) int index of the sample each came from. Up to 10 per sample.
    """
    x1n = np.asarray(x1n, dtype=np.float64)
    x2n = np.asarray(x2n, dtype=np.float64)
    B, n = x1n.shape[:2]
    one = np.ones((B, n, 1))
    q1 = np.concatenate([x1n, one], axis=2)
    q2 = np.concatenate([x2n, one], axis=2)
    N = _null_spaces(q1, q2)  # (B, 4, 9)
    M = _constraint_matrix(N)
    G, ok = _eliminate(M)
    A = np.zeros((B, 10, 10))
    A[:, :6, :] = -G[:, _ACTION_ROWS, :]
    for r, c in _UNIT_ROWS:
        A[:, r, c] = 1.0
    A[~ok] = 0.0
    w, V = np.linalg.eig(A)  # V[:, :, k]: eigenvector k
    real = (np.abs(w.imag) <= 1e-9 * np.maximum(1.0, np.abs(w.real))) & ok[:, None]
    V = V.real
    # basis order: xx xy yy xz yz zz x y z 1 -> (x, y, z) = V[6:9] / V[9]
    den = V[:, 9, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = V[:, 6, :] / den
        ys = V[:, 7, :] / den
        zs = V[:, 8, :] / den
    real &= np.abs(den) > 1e-12 * np.abs(V).max(axis=1)
    real &= np.isfinite(xs) & np.isfinite(ys) & np.isfinite(zs)
    bi, ki = np.nonzero(real)
    if len(bi) == 0:
        return np.zeros((0, 3, 3)), np.zeros(0, dtype=np.int64)
    coef = np.stack([xs[bi, ki], ys[bi, ki], zs[bi, ki], np.ones(len(bi))], axis=1)  # (M, 4)
    Es = np.einsum("mk,mkj->mj", coef, N[bi]).reshape(-1, 3, 3)
    Es /= np.linalg.norm(Es, axis=(1, 2), keepdims=True)
    return Es, bi


def essential_5point(x1n: np.ndarray, x2n: np.ndarray) -> list[np.ndarray]:
    """Every real essential matrix through five correspondences.

    Args:
        x1n, x2n: (5, 2) normalised camera coordinates of the matches in image 1 and 2.
    Returns:
        List of up to 10 (3, 3) essential matrices (unit Frobenius norm).
    Raises:
        EstimationError: fewer than 5 matches.
    """
    x1n = np.asarray(x1n, dtype=np.float64)
    x2n = np.asarray(x2n, dtype=np.float64)
    if x1n.shape[0] < 5:
        raise EstimationError(f"the five-point solver needs 5 matches, got {x1n.shape[0]}")
    Es, _ = essential_5point_batch(x1n[None], x2n[None])
    return list(Es)
