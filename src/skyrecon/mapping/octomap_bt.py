"""Export to OctoMap's binary tree format (``.bt``), readable by ``octovis`` and ``OcTree::readBinary``.

Format (OctoMap 1.x ``AbstractOcTree::writeBinary``): an ASCII header ::

    # Octomap OcTree binary file
    # (feel free to add / change comments, but leave the first line as it is!)
    #
    id OcTree
    size <number of nodes>
    res <voxel size in metres>
    data

followed by the tree in depth-first pre-order: for every inner node, two bytes describing its
8 children (child ``i`` holds keys with bit ``x | y << 1 | z << 2`` at that level), two bits per
child, children 0-3 in the first byte and 4-7 in the second, child ``i % 4`` at bits
``2 (i % 4)`` (low) and ``2 (i % 4) + 1`` (high): ``00`` unknown (absent), ``01`` (low bit) free
leaf, ``10`` (high bit) occupied leaf, ``11`` inner node (its own two bytes follow later, in
child order). Keys are ``floor(p / res) + 32768`` on 16 levels, so the grid is anchored at the
world origin exactly like skyrecon's. The binary format stores occupancy only (no
probabilities): OctoMap reads free leaves at the lower clamping bound and occupied leaves at the
upper one. Groups of 8 equal known leaves are merged (pruned) as OctoMap does.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skyrecon.errors import InputError
from skyrecon.io.atomic import write_bytes_atomic

_HEADER = (
    "# Octomap OcTree binary file\n"
    "# (feel free to add / change comments, but leave the first line as it is!)\n#\n"
)
DEPTH = 16
KEY_OFFSET = 1 << (DEPTH - 1)


def _morton(keys: np.ndarray) -> np.ndarray:
    """(M,) uint64 interleaved bits (x low, then y, then z per level) of (M, 3) 16-bit keys."""
    out = np.zeros(len(keys), np.uint64)
    k = keys.astype(np.uint64)
    for b in range(DEPTH):
        for a in range(3):
            out |= ((k[:, a] >> np.uint64(b)) & np.uint64(1)) << np.uint64(3 * b + a)
    return out


def octree_bytes(voxels: np.ndarray, occupied: np.ndarray, resolution: float) -> bytes:
    """The ``.bt`` file content for known voxels.

    Args:
        voxels: (N, 3) int voxel indices (``floor(p / resolution)``), unique.
        occupied: (N,) bool, True occupied, False free.
        resolution: voxel size, metres.
    """
    v = np.asarray(voxels, dtype=np.int64).reshape(-1, 3)
    keys = v + KEY_OFFSET
    if len(keys) and (keys.min() < 0 or keys.max() >= 2 * KEY_OFFSET):
        raise InputError(
            f"the map reaches beyond OctoMap's key range (+-{KEY_OFFSET} voxels from the origin)"
        )
    code = np.where(np.asarray(occupied, dtype=bool), 2, 1).astype(np.uint8)  # 1 free, 2 occupied, 3 inner
    inner_keys, inner_depth, inner_bytes = [], [], []
    n_nodes = 1 if len(keys) else 0
    for d in range(DEPTH, 0, -1):  # nodes at depth d -> parents at depth d - 1
        if len(keys) == 0:
            break
        parent = keys >> 1
        child = (keys[:, 0] & 1) | ((keys[:, 1] & 1) << 1) | ((keys[:, 2] & 1) << 2)
        pk = (parent[:, 0] << 32) | (parent[:, 1] << 16) | parent[:, 2]
        order = np.argsort(pk, kind="stable")
        pk, parent, child, code = pk[order], parent[order], child[order], code[order]
        first = np.concatenate([[True], pk[1:] != pk[:-1]])
        group = np.cumsum(first) - 1
        ng = int(group[-1]) + 1
        slots = np.zeros((ng, 8), np.uint8)
        slots[group, child] = code
        n_nodes += len(code)
        counts = np.bincount(group, minlength=ng)
        same = (counts == 8) & np.all(slots == slots[:, :1], axis=1) & (slots[:, 0] != 3)
        pkeys = parent[first]
        pcode = np.where(same, slots[:, 0], 3).astype(np.uint8)
        n_nodes -= 8 * int(same.sum())  # pruned children are not written
        inner = ~same
        b1 = (slots[inner, :4].astype(np.uint16) << np.array([0, 2, 4, 6], np.uint16)).sum(axis=1)
        b2 = (slots[inner, 4:].astype(np.uint16) << np.array([0, 2, 4, 6], np.uint16)).sum(axis=1)
        inner_keys.append(pkeys[inner] << (DEPTH - (d - 1)))
        inner_depth.append(np.full(int(inner.sum()), d - 1, np.int64))
        inner_bytes.append(np.stack([b1, b2], axis=1).astype(np.uint8))
        keys, code = pkeys, pcode
    if len(keys) and code[0] != 3:  # everything merged into the root: not representable, keep one level
        raise InputError("the map is a single uniform cube; nothing to export")
    if inner_keys:
        K = np.concatenate(inner_keys)
        D = np.concatenate(inner_depth)
        Bt = np.concatenate(inner_bytes)
        order = np.lexsort((D, _morton(K & (2 * KEY_OFFSET - 1))))
        data = Bt[order].tobytes()
    else:
        data = b""
    header = f"{_HEADER}id OcTree\nsize {n_nodes}\nres {resolution:.10g}\ndata\n"
    return header.encode("ascii") + data


def write_octomap_bt(occ_map, path: str | Path) -> int:
    """Write the known voxels of an :class:`OccupancyMap` as an OctoMap ``.bt`` file (atomically).

    Returns the number of tree nodes written.
    """
    B = occ_map.block_size
    blocks = occ_map.grid.blocks
    thr = occ_map.config.log_odds[4]
    k, q = np.nonzero(np.isfinite(blocks))
    local = np.stack([q // (B * B), (q // B) % B, q % B], axis=1)
    vox = occ_map.grid.block_coords[k].astype(np.int64) * B + local
    occ = blocks[k, q] >= thr
    data = octree_bytes(vox, occ, occ_map.voxel_size)
    write_bytes_atomic(path, data)
    size_line = data.split(b"\nsize ", 1)[1].split(b"\n", 1)[0]
    return int(size_line)
