"""SE(3) pose-graph optimisation over the odometry's keyframes (the back end of loop closure).

Nodes are keyframe poses ``world_from_kf`` (4x4, metres). Edges are relative-pose measurements
``i_from_j`` (``Z_ij``, 4x4): odometry edges between consecutive keyframes and loop edges found by
place recognition. The residual of an edge is ``log(Z_ij^-1 @ T_i^-1 @ T_j)``, the rotation part
(rotation vector, radians) divided by the edge's rotation sigma and the translation part (metres)
by its translation sigma. Loop edges go through a Cauchy loss (per edge, on the norm of its
whitened 6-vector), so one wrong loop cannot bend the whole trajectory; odometry edges are plain
least squares. The first node is held fixed (the gauge).

Solved with :func:`scipy.optimize.least_squares` (trust region, a sparse Jacobian pattern so the
finite differences cost a handful of residual evaluations) over a left perturbation of each free
node, ``R_i = exp(w_i) R_i0``, ``t_i = t_i0 + v_i``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix, diags
from scipy.sparse.linalg import spsolve
from scipy.spatial.transform import Rotation

__all__ = ["PoseEdge", "PoseGraphResult", "optimize_pose_graph", "edge_errors"]


@dataclass(frozen=True)
class PoseEdge:
    """A relative-pose measurement between nodes ``i`` and ``j``.

    Attributes:
        i, j: node indices.
        i_from_j: (4, 4) measured ``T_i^-1 @ T_j`` (metres).
        sigma_t_m: translation 1-sigma, metres.
        sigma_r_rad: rotation 1-sigma, radians.
        robust: put the edge through the Cauchy loss (loop edges).
    """

    i: int
    j: int
    i_from_j: np.ndarray
    sigma_t_m: float
    sigma_r_rad: float
    robust: bool = False


@dataclass
class PoseGraphResult:
    """The optimised graph.

    Attributes:
        poses: (N, 4, 4) optimised ``world_from_kf``.
        cost_before, cost_after: half the sum of squared (robustified) whitened residuals.
        iterations: Levenberg-Marquardt iterations run.
        success: the solver converged (or stopped on its tolerances).
    """

    poses: np.ndarray
    cost_before: float
    cost_after: float
    iterations: int
    success: bool


def _edge_arrays(edges: list[PoseEdge]) -> tuple[np.ndarray, ...]:
    ii = np.array([e.i for e in edges], np.int64)
    jj = np.array([e.j for e in edges], np.int64)
    Z = np.stack([e.i_from_j for e in edges]) if edges else np.zeros((0, 4, 4))
    st = np.array([e.sigma_t_m for e in edges], np.float64)
    sr = np.array([e.sigma_r_rad for e in edges], np.float64)
    rob = np.array([e.robust for e in edges], bool)
    return ii, jj, Z, st, sr, rob


def edge_errors(poses: np.ndarray, edges: list[PoseEdge]) -> tuple[np.ndarray, np.ndarray]:
    """Per edge: translation error (metres) and rotation error (degrees) of ``poses`` (N, 4, 4)
    against the measurements. Returns two (E,) arrays."""
    if not edges:
        return np.zeros(0), np.zeros(0)
    ii, jj, Z, _, _, _ = _edge_arrays(edges)
    R, t = poses[:, :3, :3], poses[:, :3, 3]
    r = _whitened(R[ii], t[ii], R[jj], t[jj], Z, np.ones(len(edges)), np.ones(len(edges)))
    return np.linalg.norm(r[:, 3:], axis=1), np.degrees(np.linalg.norm(r[:, :3], axis=1))


def _log_rotations(R: np.ndarray) -> np.ndarray:
    """(E, 3) rotation vectors (radians) of (E, 3, 3) rotations smaller than about 170 degrees
    (edge errors; faster than scipy's general conversion)."""
    cos = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    sin = np.sin(theta)
    k = np.where(theta < 1e-6, 0.5 + theta**2 / 12.0, theta / (2.0 * np.maximum(sin, 1e-12)))
    v = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    return v * k[:, None]


def _whitened(
    Ri: np.ndarray,
    ti: np.ndarray,
    Rj: np.ndarray,
    tj: np.ndarray,
    Z: np.ndarray,
    st: np.ndarray,
    sr: np.ndarray,
) -> np.ndarray:
    """(E, 6) whitened residuals ``[rotvec / sigma_r, translation / sigma_t]`` of edges whose end
    poses are given per edge."""
    RiT, RzT = Ri.transpose(0, 2, 1), Z[:, :3, :3].transpose(0, 2, 1)
    R_err = RzT @ (RiT @ Rj)
    t_err = (RzT @ (RiT @ (tj - ti)[:, :, None] - Z[:, :3, 3:]))[:, :, 0]
    r_err = _log_rotations(R_err)
    return np.hstack([r_err / sr[:, None], t_err / st[:, None]])


def _perturbed(R: np.ndarray, t: np.ndarray, d: int, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """The poses moved by ``eps`` along left-perturbation direction ``d`` (0-2 rotation, 3-5 translation)."""
    if d < 3:
        w = np.zeros(3)
        w[d] = eps
        return np.einsum("ij,njk->nik", Rotation.from_rotvec(w).as_matrix(), R), t
    t2 = t.copy()
    t2[:, d - 3] += eps
    return R, t2


def optimize_pose_graph(
    poses: np.ndarray,
    edges: list[PoseEdge],
    fixed: int = 0,
    loss_scale: float = 3.0,
    max_iterations: int = 20,
) -> PoseGraphResult:
    """Optimise the node poses to agree with the edges (Levenberg-Marquardt, sparse normal equations,
    the Cauchy loss of robust edges by iterative re-weighting).

    Args:
        poses: (N, 4, 4) initial ``world_from_node``, metres.
        edges: the measurements (indices into ``poses``).
        fixed: the node held fixed (gauge).
        loss_scale: Cauchy scale of the robust edges, in sigmas (whitened units).
        max_iterations: cap on the iterations (each one a sparse solve).
    Returns:
        :class:`PoseGraphResult` (the initial poses when nothing is free or there are no edges).
    """
    poses = np.asarray(poses, np.float64)
    N = len(poses)
    R, t = poses[:, :3, :3].copy(), poses[:, :3, 3].copy()
    ii, jj, Z, st, sr, rob = _edge_arrays(edges)
    E = len(edges)
    col = np.arange(N) - (np.arange(N) > fixed)  # block column of each node (the fixed one: dropped)
    col[fixed] = -1
    F = N - 1
    c2 = float(loss_scale) ** 2

    def cost_and_weights(R: np.ndarray, t: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        r = _whitened(R[ii], t[ii], R[jj], t[jj], Z, st, sr)
        n2 = np.sum(r**2, axis=1)
        rho = n2.copy()
        w = np.ones(E)
        rho[rob] = c2 * np.log1p(n2[rob] / c2)
        w[rob] = 1.0 / (1.0 + n2[rob] / c2)
        return 0.5 * float(rho.sum()), w, r

    if E == 0 or F == 0:
        c = cost_and_weights(R, t)[0] if E else 0.0
        return PoseGraphResult(poses.copy(), c, c, 0, True)
    cost0, w, r = cost_and_weights(R, t)
    cost = cost0
    lam = 1e-4
    eps = 1e-6
    it = 0
    converged = False
    # sparse pattern of the normal equations: blocks (a, b) for a, b in {col[i], col[j]} of each edge
    blocks_a, blocks_b = [], []
    for a_nodes, b_nodes in ((ii, ii), (ii, jj), (jj, ii), (jj, jj)):
        blocks_a.append(col[a_nodes])
        blocks_b.append(col[b_nodes])
    ba, bb = np.concatenate(blocks_a), np.concatenate(blocks_b)
    keep = (ba >= 0) & (bb >= 0)
    rows = (6 * ba[:, None, None] + np.arange(6)[None, :, None]).repeat(6, axis=2)
    cols = (6 * bb[:, None, None] + np.arange(6)[None, None, :]).repeat(6, axis=1)
    for _ in range(max_iterations):
        it += 1
        # Jacobians of each edge's residual with respect to its two nodes (central differences)
        Ji = np.zeros((E, 6, 6))
        Jj = np.zeros((E, 6, 6))
        Ri, ti, Rj, tj = R[ii], t[ii], R[jj], t[jj]
        for d in range(6):
            Rp, tp = _perturbed(Ri, ti, d, eps)
            Rm, tm = _perturbed(Ri, ti, d, -eps)
            Ji[:, :, d] = (_whitened(Rp, tp, Rj, tj, Z, st, sr) - _whitened(Rm, tm, Rj, tj, Z, st, sr)) / (
                2 * eps
            )
            Rp, tp = _perturbed(Rj, tj, d, eps)
            Rm, tm = _perturbed(Rj, tj, d, -eps)
            Jj[:, :, d] = (_whitened(Ri, ti, Rp, tp, Z, st, sr) - _whitened(Ri, ti, Rm, tm, Z, st, sr)) / (
                2 * eps
            )
        wJi, wJj = Ji * w[:, None, None], Jj * w[:, None, None]
        H_blocks = np.concatenate(
            [
                np.einsum("eki,ekj->eij", wJi, Ji),
                np.einsum("eki,ekj->eij", wJi, Jj),
                np.einsum("eki,ekj->eij", wJj, Ji),
                np.einsum("eki,ekj->eij", wJj, Jj),
            ]
        )
        H = coo_matrix(
            (H_blocks[keep].ravel(), (rows[keep].ravel(), cols[keep].ravel())), shape=(6 * F, 6 * F)
        ).tocsc()
        g = np.zeros(6 * F)
        for nodes, J in ((ii, wJi), (jj, wJj)):
            c = col[nodes]
            m = c >= 0
            np.add.at(g, (6 * c[m, None] + np.arange(6)[None, :]), np.einsum("eki,ek->ei", J[m], r[m]))
        diag = H.diagonal()
        improved = False
        for _ in range(8):
            A = H + diags(lam * np.maximum(diag, 1e-9) + 1e-12)
            try:
                step = -spsolve(A.tocsc(), g)
            except RuntimeError:
                lam *= 10
                continue
            if not np.all(np.isfinite(step)):
                lam *= 10
                continue
            p = step.reshape(-1, 6)
            R2, t2 = R.copy(), t.copy()
            free = col >= 0
            R2[free] = np.einsum("nij,njk->nik", Rotation.from_rotvec(p[col[free], :3]).as_matrix(), R[free])
            t2[free] = t[free] + p[col[free], 3:]
            cost2, w2, r2 = cost_and_weights(R2, t2)
            if cost2 < cost:
                rel = (cost - cost2) / max(cost, 1e-12)
                R, t, cost, w, r = R2, t2, cost2, w2, r2
                lam = max(lam / 10, 1e-9)
                improved = True
                converged = rel < 1e-6 or float(np.abs(step).max()) < 1e-9
                break
            lam *= 10
        if not improved or converged:
            converged = True
            break
    out = np.tile(np.eye(4), (N, 1, 1))
    out[:, :3, :3], out[:, :3, 3] = R, t
    return PoseGraphResult(out, cost0, cost, it, converged)
