"""Non-linear refinement of a relative pose on the Sampson error (Levenberg-Marquardt).

The pose ``(R, t) = cam2_from_cam1`` lives on SO(3) x S^2 (5 degrees of freedom): updates are
``R <- exp([w]x) R`` and ``t <- normalise(t + B d)`` with ``B`` (3, 2) an orthonormal basis of
the tangent plane of the unit sphere at ``t``. The residual of a match is its signed Sampson
distance in the normalised image plane; a robust loss is minimised by iteratively reweighted
normal equations.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from skyrecon.core.rigid import rotvec_to_matrix
from skyrecon.errors import InputError
from skyrecon.geometry.epipolar import skew

__all__ = [
    "Loss",
    "robust_loss",
    "RefineResult",
    "refine_relative_pose",
    "sampson_residuals",
    "tangent_basis",
]

Loss = Literal["trivial", "huber", "cauchy", "truncated"]


def robust_loss(s: np.ndarray, loss: Loss) -> tuple[np.ndarray, np.ndarray]:
    """Robust loss ``rho(s)`` and weight ``rho'(s)`` of squared, scaled residuals ``s = (r / scale)^2``.

    Returns:
        ``(rho, weight)``, each shaped like s.
    """
    if loss == "trivial":
        return s, np.ones_like(s)
    if loss == "cauchy":
        return np.log1p(s), 1.0 / (1.0 + s)
    if loss == "huber":
        inner = s <= 1.0
        r = np.sqrt(np.maximum(s, 1e-300))
        return np.where(inner, s, 2.0 * r - 1.0), np.where(inner, 1.0, 1.0 / r)
    if loss == "truncated":
        inner = s <= 1.0
        return np.where(inner, s, 1.0), inner.astype(np.float64)
    raise InputError(f"unknown robust loss {loss!r}; use trivial, huber, cauchy or truncated")


def tangent_basis(t: np.ndarray) -> np.ndarray:
    """(3, 2) orthonormal basis of the plane orthogonal to the unit vector t."""
    t = t / np.sqrt(t @ t)
    a = (1.0, 0.0, 0.0) if abs(t[0]) < 0.9 else (0.0, 1.0, 0.0)
    b1 = np.array([t[1] * a[2] - t[2] * a[1], t[2] * a[0] - t[0] * a[2], t[0] * a[1] - t[1] * a[0]])
    b1 /= np.sqrt(b1 @ b1)
    b2 = np.array([t[1] * b1[2] - t[2] * b1[1], t[2] * b1[0] - t[0] * b1[2], t[0] * b1[1] - t[1] * b1[0]])
    return np.stack([b1, b2], axis=1)


def sampson_residuals(E: np.ndarray, h1: np.ndarray, h2: np.ndarray) -> np.ndarray:
    """(N,) signed Sampson distances for homogeneous normalised points h1, h2 (N, 3)."""
    Ex1 = h1 @ E.T
    Etx2 = h2 @ E
    C = np.sum(h2 * Ex1, axis=1)
    D = Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2
    return C / np.sqrt(np.maximum(D, 1e-300))


_GEN = np.stack([skew(e) for e in np.eye(3)])  # generators of so(3)


def _residuals_and_jacobian(
    R: np.ndarray, t: np.ndarray, B: np.ndarray, h1: np.ndarray, h2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    E = skew(t) @ R
    Ex1 = h1 @ E.T
    Etx2 = h2 @ E
    C = np.sum(h2 * Ex1, axis=1)
    D = np.maximum(Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2, 1e-300)
    sD = np.sqrt(D)
    r = C / sD
    tx = skew(t)
    dE = np.stack(
        [tx @ _GEN[0] @ R, tx @ _GEN[1] @ R, tx @ _GEN[2] @ R, skew(B[:, 0]) @ R, skew(B[:, 1]) @ R]
    )
    dEx1 = np.matmul(h1, dE.transpose(0, 2, 1))  # (5, N, 3)
    dEtx2 = np.matmul(h2, dE)  # (5, N, 3)
    dC = np.sum(h2 * dEx1, axis=2)  # (5, N)
    dD = 2.0 * (
        Ex1[:, 0] * dEx1[:, :, 0]
        + Ex1[:, 1] * dEx1[:, :, 1]
        + Etx2[:, 0] * dEtx2[:, :, 0]
        + Etx2[:, 1] * dEtx2[:, :, 1]
    )
    J = (dC / sD - 0.5 * C * dD / (D * sD)).T
    return r, J


@dataclass(frozen=True)
class RefineResult:
    """Result of :func:`refine_relative_pose`.

    Attributes:
        R: (3, 3) refined rotation, cam2_from_cam1.
        t: (3,) refined unit translation direction.
        initial_cost, final_cost: robust cost before and after (normalised units squared).
        iterations: LM iterations run.
        converged: the step or the relative cost change fell below tolerance.
    """

    R: np.ndarray
    t: np.ndarray
    initial_cost: float
    final_cost: float
    iterations: int
    converged: bool


def refine_relative_pose(
    R: np.ndarray,
    t: np.ndarray,
    x1n: np.ndarray,
    x2n: np.ndarray,
    loss: Loss = "cauchy",
    loss_scale: float = 1e-3,
    max_iterations: int = 50,
    tolerance: float = 1e-10,
    sigmas: np.ndarray | None = None,
) -> RefineResult:
    """Levenberg-Marquardt refinement of (R, t) on the robust Sampson error.

    Args:
        R: (3, 3) initial rotation, cam2_from_cam1.
        t: (3,) initial translation direction (normalised to unit length).
        x1n, x2n: (N, 2) matches in normalised camera coordinates (z = 1 plane), N >= 5.
        loss: robust loss of the scaled squared residual.
        loss_scale: residual scale in normalised units (a pixel threshold divided by the focal
            length); the loss is ``scale^2 * rho((r / scale)^2)``.
        max_iterations: LM iteration cap.
        tolerance: stop when the relative cost decrease or step norm falls below it.
        sigmas: optional (N,) relative noise level of each match (e.g. from keypoint scales,
            median ~1): residuals are divided by it before the loss.
    Returns:
        RefineResult with the refined pose (|t| = 1).
    """
    R = np.asarray(R, dtype=np.float64).copy()
    t = np.asarray(t, dtype=np.float64).reshape(3)
    t = t / np.linalg.norm(t)
    x1n = np.asarray(x1n, dtype=np.float64)
    x2n = np.asarray(x2n, dtype=np.float64)
    if len(x1n) < 5:
        return RefineResult(R, t, np.nan, np.nan, 0, False)
    h1 = np.concatenate([x1n, np.ones((len(x1n), 1))], axis=1)
    h2 = np.concatenate([x2n, np.ones((len(x2n), 1))], axis=1)
    s2 = float(loss_scale) ** 2
    inv_sigma = None if sigmas is None else 1.0 / np.asarray(sigmas, dtype=np.float64)

    def cost_of(r: np.ndarray) -> float:
        rho, _ = robust_loss(r * r / s2, loss)
        return float(s2 * rho.sum())

    def evaluate(R_: np.ndarray, t_: np.ndarray, B_: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r_, J_ = _residuals_and_jacobian(R_, t_, B_, h1, h2)
        if inv_sigma is not None:
            r_, J_ = r_ * inv_sigma, J_ * inv_sigma[:, None]
        return r_, J_

    B = tangent_basis(t)
    r, J = evaluate(R, t, B)
    cost = cost_of(r)
    initial = cost
    lam = 1e-4
    converged = False
    it = 0
    for it in range(1, max_iterations + 1):  # noqa: B007  (the count is returned)
        _, w = robust_loss(r * r / s2, loss)
        Jw = J * w[:, None]
        H = Jw.T @ J
        g = Jw.T @ r
        improved = False
        for _ in range(10):
            Hd = H + lam * np.diag(np.maximum(np.diag(H), 1e-12))
            try:
                step = -np.linalg.solve(Hd, g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            R_new = rotvec_to_matrix(step[:3]) @ R
            t_new = t + B @ step[3:]
            t_new /= np.linalg.norm(t_new)
            B_new = tangent_basis(t_new)
            r_new, J_new = evaluate(R_new, t_new, B_new)
            new_cost = cost_of(r_new)
            if new_cost < cost:
                rel = (cost - new_cost) / max(cost, 1e-300)
                R, t, B, r, J = R_new, t_new, B_new, r_new, J_new
                cost = new_cost
                lam = max(lam / 10.0, 1e-12)
                improved = True
                if rel < tolerance or np.linalg.norm(step) < tolerance:
                    converged = True
                break
            lam *= 10.0
        if not improved:
            converged = True
            break
        if converged:
            break
    U, _, Vt = np.linalg.svd(R)
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return RefineResult(R, t, initial, cost, it, converged)
