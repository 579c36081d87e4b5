"""Rotation consistency of the view graph: reject verified pairs whose relative rotation
disagrees with the rotations chained along the strongest pairs.

Repeated structure (identical facades, tiled plazas) produces image pairs that pass geometric
verification with many inliers but the wrong relative pose. Such a pair closes a cycle whose
rotations do not compose to the identity. The absolute rotations are propagated along a
maximum spanning tree of the view graph (edge weight: inlier count), so they come from the
most reliable pairs, and every pair is compared with them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree

from skyrecon.core.rigid import rotation_angle_deg
from skyrecon.sfm.matching import PairGeometry

__all__ = ["chained_rotations", "rotation_inconsistent_pairs"]


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
        trusted: optional (len(pairs),) bool: build the spanning tree from these pairs only
            (e.g. the pairs of neighbouring frames of a flight, which repeated structure far
            away in the sequence cannot fool); all pairs are checked.
    """
    tree_pairs = pairs if trusted is None else [p for p, ok in zip(pairs, trusted) if ok]
    R, label = chained_rotations(tree_pairs, n_images)
    err = np.full(len(pairs), np.nan)
    bad = []
    for k, p in enumerate(pairs):
        if p.R is None or label[p.i] != label[p.j]:
            continue
        err[k] = rotation_angle_deg(p.R.T @ R[p.j] @ R[p.i].T)
        if err[k] > max_error_deg:
            bad.append(k)
    return bad, err
