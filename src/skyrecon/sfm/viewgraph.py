"""Rotation consistency of the view graph: reject verified pairs whose relative rotation
disagrees with the rotations chained along the strongest pairs.

Repeated structure (identical facades, tiled plazas) produces image pairs that pass geometric
verification with many inliers but the wrong relative pose. Such a pair closes a cycle whose
rotations do not compose to the identity. The absolute rotations are propagated along a
maximum spanning tree of the view graph (edge weight: inlier count), so they come from the
most reliable pairs, and every pair is compared with them.

A flight's neighbouring frames are trusted instead (repeated structure far away in the sequence
cannot fool them). Chained along a spanning tree of a thousand frames, a few wrong neighbour
pairs (a small baseline's rotation-translation ambiguity) add up to tens of degrees, and every
true loop would look inconsistent; so there the absolute rotations are averaged over all the
trusted pairs (robust chordal averaging), which outvotes the wrong ones.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.sparse import coo_matrix, identity
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree
from scipy.sparse.linalg import splu

from skyrecon.core.rigid import rotation_angles_deg
from skyrecon.sfm.matching import PairGeometry

__all__ = ["averaged_rotations", "chained_rotations", "rotation_inconsistent_pairs"]


def chained_rotations(pairs: Sequence[PairGeometry], n_images: int) -> tuple[np.ndarray, np.ndarray]:
    """Absolute rotations ``cam_from_world`` (world = the root camera of each connected
    component) chained along a maximum spanning tree of the pairs with a rotation.

    Returns:
        ``(R (n, 3, 3), component (n,))``: identity for images without pairs; component label
        per image.
    """
    usable = [p for p in pairs if p.R is not None]
    R = np.tile(np.eye(3), (n_images, 1, 1))
    if not usable:
        return R, np.arange(n_images)
    i = np.array([p.i for p in usable])
    j = np.array([p.j for p in usable])
    w = np.array([float(p.num_inliers) for p in usable])
    # maximum spanning tree = minimum spanning tree of (max + 1 - w) (all weights positive)
    cost = (w.max() + 1.0) - w
    G = coo_matrix((cost, (i, j)), shape=(n_images, n_images)).tocsr()
    T = minimum_spanning_tree(G)
    T = T + T.T
    n_comp, label = connected_components(T, directed=False)
    rel = {(p.i, p.j): p.R for p in usable if p.R is not None}
    for c in range(n_comp):
        members = np.nonzero(label == c)[0]
        root = int(members[0])
        order, pred = breadth_first_order(T, root, directed=False, return_predecessors=True)
        for node in order[1:]:
            par = int(pred[node])
            if (par, node) in rel:  # R_node = R_par_node R_par
                R[node] = rel[(par, node)] @ R[par]
            else:
                R[node] = rel[(node, par)].T @ R[par]
    return R, label


def _disagreement_deg(R_rel: np.ndarray, R_i: np.ndarray, R_j: np.ndarray) -> np.ndarray:
    """(E,) angle between each pair's relative rotation and the absolute ones, degrees: the
    angle of ``R_rel^T R_j R_i^T`` (all (E, 3, 3))."""
    return rotation_angles_deg(np.transpose(R_rel, (0, 2, 1)) @ R_j @ np.transpose(R_i, (0, 2, 1)))


def averaged_rotations(
    pairs: Sequence[PairGeometry],
    n_images: int,
    iterations: int = 6,
    scale_deg: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Absolute rotations ``cam_from_world`` that agree best with the relative rotations of all
    the pairs: chordal averaging (``R_j ~ R_ij R_i`` in least squares over the 3x3 entries, then
    the nearest rotation), reweighted ``iterations`` times with Cauchy weights of scale
    ``scale_deg`` on each pair's disagreement so that a minority of wrong pairs is outvoted.

    The rotations are anchored (with a negligible weight) to :func:`chained_rotations`, which
    also gives each connected component its own world.

    Returns:
        ``(R (n, 3, 3), component (n,))`` as :func:`chained_rotations`.
    """
    R0, label = chained_rotations(pairs, n_images)
    usable = [(p.i, p.j, p.R) for p in pairs if p.R is not None]
    if not usable:
        return R0, label
    i = np.array([u[0] for u in usable])
    j = np.array([u[1] for u in usable])
    R_rel = np.stack([u[2] for u in usable])
    n_e = len(usable)
    # unknowns: the 3 rows of each R, one column of R at a time: x_j - R_ij x_i = 0 (3 rows per pair)
    rows3 = np.arange(3 * n_e).reshape(n_e, 3)
    rows = np.concatenate([rows3.ravel(), np.repeat(rows3, 3, axis=1).ravel()])
    cols = np.concatenate(
        [(3 * j[:, None] + np.arange(3)).ravel(), np.tile(3 * i[:, None] + np.arange(3), (1, 3)).ravel()]
    )
    vals = np.concatenate([np.ones(3 * n_e), -R_rel.ravel()])
    eps = 1e-6
    prior = eps * R0.reshape(3 * n_images, 3)
    weights = np.ones(n_e)
    R = R0
    for _ in range(iterations):
        sw = np.repeat(np.sqrt(weights), 3)
        A = coo_matrix(
            (vals * np.concatenate([sw, np.repeat(sw, 3)]), (rows, cols)), shape=(3 * n_e, 3 * n_images)
        ).tocsc()
        X = splu((A.T @ A + eps * identity(3 * n_images)).tocsc()).solve(prior).reshape(n_images, 3, 3)
        U, _, Vt = np.linalg.svd(X)
        flip = np.ones((n_images, 3))
        flip[:, 2] = np.sign(np.linalg.det(U @ Vt))
        R = U @ (flip[:, :, None] * Vt)
        weights = 1.0 / (1.0 + (_disagreement_deg(R_rel, R[i], R[j]) / scale_deg) ** 2)
    return R, label


def rotation_inconsistent_pairs(
    pairs: Sequence[PairGeometry],
    n_images: int,
    max_error_deg: float = 5.0,
    trusted: np.ndarray | None = None,
) -> tuple[list[int], np.ndarray]:
    """Indices (into ``pairs``) of the pairs whose rotation disagrees with the chained rotations
    by more than ``max_error_deg``, and the (len(pairs),) disagreement in degrees (NaN for pairs
    without a rotation).

    Args:
        trusted: optional (len(pairs),) bool: the pairs the rotations come from (e.g. the
            pairs of neighbouring frames of a flight, which repeated structure far away in the
            sequence cannot fool), averaged over all of them (:func:`averaged_rotations`);
            without it, chained along the strongest pairs. All pairs are checked.
    """
    if trusted is None:
        R, label = chained_rotations(pairs, n_images)
    else:
        R, label = averaged_rotations([p for p, ok in zip(pairs, trusted) if ok], n_images)
    err = np.full(len(pairs), np.nan)
    checked = [
        (k, p.i, p.j, p.R) for k, p in enumerate(pairs) if p.R is not None and label[p.i] == label[p.j]
    ]
    if checked:
        k, i, j = (np.array([c[m] for c in checked]) for m in range(3))
        err[k] = _disagreement_deg(np.stack([c[3] for c in checked]), R[i], R[j])
    bad = [int(c[0]) for c in checked if err[c[0]] > max_error_deg]
    return bad, err
