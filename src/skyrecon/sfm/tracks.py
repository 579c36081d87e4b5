"""Feature tracks: union-find over verified pairwise matches.

Every keypoint of every image is a node; each verified match joins two nodes. A connected
component is a track: the observations of one 3D point. A component holding two different
keypoints of the same image is inconsistent (a wrong match chained two scene points together)
and is dropped.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numba as nb
import numpy as np

from skyrecon.errors import InputError

__all__ = ["Tracks", "UnionFind", "build_tracks"]


@nb.njit(cache=True)
def _find(parent: np.ndarray, a: int) -> int:
    root = a
    while parent[root] != root:
        root = parent[root]
    while parent[a] != root:  # path compression
        nxt = parent[a]
        parent[a] = root
        a = nxt
    return root


@nb.njit(cache=True)
def _union_many(parent: np.ndarray, size: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
    for k in range(a.shape[0]):
        ra = _find(parent, a[k])
        rb = _find(parent, b[k])
        if ra == rb:
            continue
        if size[ra] < size[rb]:
            ra, rb = rb, ra
        parent[rb] = ra
        size[ra] += size[rb]


@nb.njit(cache=True)
def _union_consistent(parent, size, nxt, tail, node_img, a, b, mark) -> int:
    """Union the pairs (a[k], b[k]) in order, refusing any union that would put two nodes of
    the same image into one set. Members of each set are kept as a linked list (``nxt``,
    ``tail`` of the root). Returns the number of refused unions."""
    refused = 0
    stamp = 0
    for k in range(a.shape[0]):
        ra = _find(parent, a[k])
        rb = _find(parent, b[k])
        if ra == rb:
            continue
        if size[ra] < size[rb]:
            ra, rb = rb, ra
        stamp += 1
        m = ra
        while m >= 0:
            mark[node_img[m]] = stamp
            m = nxt[m]
        conflict = False
        m = rb
        while m >= 0:
            if mark[node_img[m]] == stamp:
                conflict = True
                break
            m = nxt[m]
        if conflict:
            refused += 1
            continue
        parent[rb] = ra
        size[ra] += size[rb]
        nxt[tail[ra]] = rb
        tail[ra] = tail[rb]
    return refused


@nb.njit(cache=True)
def _find_many(parent: np.ndarray, nodes: np.ndarray, out: np.ndarray) -> None:
    for k in range(nodes.shape[0]):
        out[k] = _find(parent, nodes[k])


class UnionFind:
    """Disjoint sets over ``n`` integer nodes (union by size, path compression)."""

    def __init__(self, n: int) -> None:
        self.parent = np.arange(n, dtype=np.int64)
        self.size = np.ones(n, dtype=np.int64)

    def union(self, a: np.ndarray | int, b: np.ndarray | int) -> None:
        """Join the sets of ``a[k]`` and ``b[k]`` for every k (scalars or (K,) arrays)."""
        a = np.atleast_1d(np.asarray(a, np.int64))
        b = np.atleast_1d(np.asarray(b, np.int64))
        if a.shape != b.shape:
            raise InputError(f"union needs arrays of the same shape, got {a.shape} and {b.shape}")
        n = len(self.parent)
        if len(a) and (min(a.min(), b.min()) < 0 or max(a.max(), b.max()) >= n):
            raise InputError(f"union-find node out of range [0, {n})")
        _union_many(self.parent, self.size, a, b)

    def union_consistent(self, a: np.ndarray, b: np.ndarray, node_image: np.ndarray) -> int:
        """Like :meth:`union`, but refuse a union that would put two nodes with the same
        ``node_image`` label into one set (pairs are applied in order). Returns the number of
        refused unions. Keep using one kind of union on a given instance."""
        a = np.atleast_1d(np.asarray(a, np.int64))
        b = np.atleast_1d(np.asarray(b, np.int64))
        n = len(self.parent)
        if not hasattr(self, "_next"):
            self._next = np.full(n, -1, np.int64)
            self._tail = np.arange(n, dtype=np.int64)
        node_image = np.asarray(node_image, np.int64)
        mark = np.zeros(int(node_image.max()) + 1 if len(node_image) else 1, np.int64)
        return int(_union_consistent(self.parent, self.size, self._next, self._tail, node_image, a, b, mark))

    def find(self, nodes: np.ndarray | int) -> np.ndarray:
        """(K,) root of each node."""
        nodes = np.atleast_1d(np.asarray(nodes, np.int64))
        out = np.empty(len(nodes), np.int64)
        _find_many(self.parent, nodes, out)
        return out


@dataclass
class Tracks:
    """Tracks in CSR form, observations sorted by track then image.

    Attributes:
        ptr: (n_tracks + 1,) int64 offsets into the observation arrays.
        obs_image: (n_obs,) int64 image index of each observation.
        obs_kp: (n_obs,) int64 keypoint index within its image.
        kp_track: per image, (n_keypoints,) int64 track of each keypoint or -1.
        kp_obs: per image, (n_keypoints,) int64 observation index of each keypoint or -1.
        num_inconsistent: components dropped because they held two keypoints of one image
            (``conflicts="drop"``), or matches refused because they would have (``"split"``).
        num_inconsistent_observations: keypoints in the dropped components (``"drop"``).
    """

    ptr: np.ndarray
    obs_image: np.ndarray
    obs_kp: np.ndarray
    kp_track: list[np.ndarray]
    kp_obs: list[np.ndarray]
    num_inconsistent: int = 0
    num_inconsistent_observations: int = 0

    @property
    def num_tracks(self) -> int:
        return len(self.ptr) - 1

    @property
    def num_observations(self) -> int:
        return len(self.obs_image)

    @property
    def lengths(self) -> np.ndarray:
        """(n_tracks,) number of observations of each track."""
        return np.diff(self.ptr)

    @property
    def obs_track(self) -> np.ndarray:
        """(n_obs,) track of each observation."""
        return np.repeat(np.arange(self.num_tracks), self.lengths)

    def track(self, k: int) -> np.ndarray:
        """(L, 2) rows ``(image, keypoint)`` of track k."""
        s = slice(self.ptr[k], self.ptr[k + 1])
        return np.stack([self.obs_image[s], self.obs_kp[s]], axis=1)


def build_tracks(
    num_keypoints: Sequence[int],
    pair_matches: Sequence[tuple[int, int, np.ndarray]],
    keypoints: Sequence[np.ndarray] | None = None,
    merge_radius_px: float = 1.0,
    conflicts: str = "split",
) -> Tracks:
    """Chain pairwise matches into tracks.

    Args:
        num_keypoints: keypoints of each image (n_images entries).
        pair_matches: ``(i, j, matches)`` with (K, 2) int keypoint indices ``[kp in i, kp in j]``
            (the geometrically verified inliers of the pair).
        keypoints: optional per-image (N_i, 2) keypoint positions, pixels. When given, a track
            whose keypoints in one image all lie within ``merge_radius_px`` of each other (the
            same image point detected twice, e.g. SIFT's multiple orientations) keeps the first
            of them instead of being dropped.
        merge_radius_px: see ``keypoints``.
        conflicts: ``"split"`` (default): matches are added pair by pair, the pairs with most
            matches first, and a match that would put two keypoints of one image into one track
            is refused, so wrong matches cannot chain tracks together; ``"drop"``: plain
            union-find, then every track holding two keypoints of one image is dropped.
    Returns:
        Tracks with at least two observations each, at most one per image.
    """
    n_kp = np.asarray(num_keypoints, np.int64)
    n_img = len(n_kp)
    offsets = np.concatenate([[0], np.cumsum(n_kp)]).astype(np.int64)
    total = int(offsets[-1])
    if conflicts not in ("split", "drop"):
        raise InputError(f"conflicts must be 'split' or 'drop', got {conflicts!r}")
    uf = UnionFind(total)
    used = np.zeros(total, bool)
    edges_a, edges_b = [], []
    for i, j, m in sorted(pair_matches, key=lambda x: -len(x[2])):
        m = np.asarray(m, np.int64).reshape(-1, 2)
        if not (0 <= i < n_img and 0 <= j < n_img) or i == j:
            raise InputError(f"pair ({i}, {j}) refers to images outside 0..{n_img - 1} or to one image twice")
        if len(m) == 0:
            continue
        if m[:, 0].min() < 0 or m[:, 0].max() >= n_kp[i] or m[:, 1].min() < 0 or m[:, 1].max() >= n_kp[j]:
            raise InputError(f"pair ({i}, {j}): keypoint index out of range")
        a = offsets[i] + m[:, 0]
        b = offsets[j] + m[:, 1]
        edges_a.append(a)
        edges_b.append(b)
        used[a] = True
        used[b] = True
    ea = np.concatenate(edges_a) if edges_a else np.zeros(0, np.int64)
    eb = np.concatenate(edges_b) if edges_b else np.zeros(0, np.int64)
    refused = 0
    if conflicts == "split":
        node_image = np.repeat(np.arange(n_img), n_kp)
        refused = uf.union_consistent(ea, eb, node_image)
    else:
        uf.union(ea, eb)
    nodes = np.nonzero(used)[0]
    roots = uf.find(nodes)
    img = np.searchsorted(offsets, nodes, side="right") - 1
    kp = nodes - offsets[img]
    order = np.lexsort((img, roots))
    roots, img, kp = roots[order], img[order], kp[order]
    new = np.ones(len(roots), bool)
    new[1:] = roots[1:] != roots[:-1]
    tid = np.cumsum(new) - 1
    # inconsistent components: the same image twice in one track
    dup = np.zeros(len(roots), bool)
    dup[1:] = (tid[1:] == tid[:-1]) & (img[1:] == img[:-1])
    n_tracks0 = int(tid[-1]) + 1 if len(tid) else 0
    keep = np.ones(len(tid), bool)
    if keypoints is not None and np.any(dup):
        # co-located duplicates: keep the first keypoint of each (track, image) run, drop the others
        all_xy = np.concatenate([np.asarray(k, np.float64).reshape(-1, 2) for k in keypoints])
        xy = all_xy[offsets[img] + kp]
        first = np.maximum.accumulate(np.where(dup, 0, np.arange(len(tid))))
        far = np.zeros(len(tid), bool)
        far[dup] = np.hypot(*(xy[dup] - xy[first[dup]]).T) > merge_radius_px
        keep[dup] = False
        dup = far
    bad = np.zeros(n_tracks0, bool)
    bad[tid[dup]] = True
    keep &= ~bad[tid]
    num_bad = int(bad.sum()) + refused
    num_bad_obs = int((~keep).sum())
    tid, img, kp = tid[keep], img[keep], kp[keep]
    # renumber
    uniq, tid = np.unique(tid, return_inverse=True)
    counts = np.bincount(tid, minlength=len(uniq))
    ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    kp_track = [np.full(int(n), -1, np.int64) for n in n_kp]
    kp_obs = [np.full(int(n), -1, np.int64) for n in n_kp]
    by_img = np.argsort(img, kind="stable")
    bounds = np.searchsorted(img[by_img], np.arange(n_img + 1))
    for i in range(n_img):
        sel = by_img[bounds[i] : bounds[i + 1]]
        kp_track[i][kp[sel]] = tid[sel]
        kp_obs[i][kp[sel]] = sel
    return Tracks(ptr, img.astype(np.int64), kp.astype(np.int64), kp_track, kp_obs, num_bad, num_bad_obs)
