"""Sparse voxel storage: cubic blocks of voxels in an open-addressing hash table.

The world is cut into voxels of edge ``voxel_size`` metres anchored at the world origin: voxel
index ``i = floor(p / voxel_size)`` (per axis, world frame), voxel centre ``(i + 0.5) * voxel_size``.
Voxels are grouped into blocks of ``B x B x B`` voxels: block coordinate ``b = floor(i / B)``,
local index ``l = i - b * B`` and flat index ``(lx * B + ly) * B + lz`` inside the block's row.

:class:`BlockGrid` keeps the blocks in a pool (``data[k]`` is block ``k``, ``coords[k]`` its
block coordinate) and finds a block from its coordinate with a hash table held in plain numpy
arrays, so that Numba kernels can look blocks up (and the Python side can grow the table).
Only blocks that were touched exist; memory grows with the observed space, not with the city.
"""

from __future__ import annotations

import numpy as np
from numba import njit

EMPTY = np.int32(np.iinfo(np.int32).min)  # marks an empty hash slot in the key table
_MAX_LOAD = 0.5  # hash table load factor limit


@njit(cache=True, nogil=True)
def _slot(x, y, z, mask):
    h = (
        (np.int64(x) * np.int64(73856093))
        ^ (np.int64(y) * np.int64(19349663))
        ^ (np.int64(z) * np.int64(83492791))
    )
    return h & mask


@njit(cache=True, nogil=True)
def table_find(tkeys, tvals, x, y, z):
    """Pool index of block (x, y, z), or -1 when absent. ``tkeys`` (C, 3) int32, ``tvals`` (C,) int32."""
    mask = tkeys.shape[0] - 1
    h = _slot(x, y, z, mask)
    while True:
        kx = tkeys[h, 0]
        if kx == EMPTY:
            return -1
        if kx == x and tkeys[h, 1] == y and tkeys[h, 2] == z:
            return tvals[h]
        h = (h + 1) & mask


@njit(cache=True, nogil=True)
def _table_put(tkeys, tvals, x, y, z, value):
    mask = tkeys.shape[0] - 1
    h = _slot(x, y, z, mask)
    while tkeys[h, 0] != EMPTY:
        h = (h + 1) & mask
    tkeys[h, 0] = x
    tkeys[h, 1] = y
    tkeys[h, 2] = z
    tvals[h] = value


@njit(cache=True, nogil=True)
def find_many(tkeys, tvals, queries):
    """(M,) int32 pool indices of the (M, 3) int32 block coordinates ``queries`` (-1: absent)."""
    out = np.empty(queries.shape[0], np.int32)
    for i in range(queries.shape[0]):
        out[i] = table_find(tkeys, tvals, queries[i, 0], queries[i, 1], queries[i, 2])
    return out


@njit(cache=True, nogil=True)
def insert_many(tkeys, tvals, coords, count, limit, queries, out, start):
    """Find or insert blocks ``queries[start:]`` (M, 3) int32, writing pool indices to ``out``.

    New blocks get pool index ``count, count + 1, ...`` and their coordinates are written to
    ``coords``. Stops before inserting a block that would make ``count`` exceed ``limit``.

    Returns:
        (next query to process, new count). The caller grows the storage and calls again
        when the first value is less than M.
    """
    lx = EMPTY
    ly = EMPTY
    lz = EMPTY
    last = -1
    for i in range(start, queries.shape[0]):
        x = queries[i, 0]
        y = queries[i, 1]
        z = queries[i, 2]
        if x == lx and y == ly and z == lz:
            out[i] = last
            continue
        k = table_find(tkeys, tvals, x, y, z)
        if k < 0:
            if count >= limit:
                return i, count
            k = count
            _table_put(tkeys, tvals, x, y, z, k)
            coords[k, 0] = x
            coords[k, 1] = y
            coords[k, 2] = z
            count += 1
        out[i] = k
        lx = x
        ly = y
        lz = z
        last = k
    return queries.shape[0], count


@njit(cache=True, nogil=True)
def _rehash(coords, count, capacity):
    tkeys = np.full((capacity, 3), EMPTY, np.int32)
    tvals = np.full(capacity, -1, np.int32)
    for k in range(count):
        _table_put(tkeys, tvals, coords[k, 0], coords[k, 1], coords[k, 2], k)
    return tkeys, tvals


@njit(cache=True, nogil=True)
def gather_dense(tkeys, tvals, data, B, lo, shape, fill):
    """Copy voxels of the box ``[lo, lo + shape)`` (voxel indices) into a dense (X, Y, Z) float32 array.

    Voxels in absent blocks get ``fill``.
    """
    out = np.full((shape[0], shape[1], shape[2]), fill, np.float32)
    b0x = lo[0] // B
    b0y = lo[1] // B
    b0z = lo[2] // B
    b1x = (lo[0] + shape[0] - 1) // B
    b1y = (lo[1] + shape[1] - 1) // B
    b1z = (lo[2] + shape[2] - 1) // B
    nbx = b1x - b0x + 1
    nby = b1y - b0y + 1
    nbz = b1z - b0z + 1
    for flat in range(nbx * nby * nbz):
        bx = b0x + flat // (nby * nbz)
        by = b0y + (flat // nbz) % nby
        bz = b0z + flat % nbz
        k = table_find(tkeys, tvals, bx, by, bz)
        if k < 0:
            continue
        for lx in range(B):
            gx = bx * B + lx - lo[0]
            if gx < 0 or gx >= shape[0]:
                continue
            for ly in range(B):
                gy = by * B + ly - lo[1]
                if gy < 0 or gy >= shape[1]:
                    continue
                base = (lx * B + ly) * B
                for lz in range(B):
                    gz = bz * B + lz - lo[2]
                    if gz < 0 or gz >= shape[2]:
                        continue
                    out[gx, gy, gz] = data[k, base + lz]
    return out


@njit(cache=True, nogil=True)
def scatter_dense(ids, coords, data, B, lo, dense):
    """Write the dense (X, Y, Z) box starting at voxel ``lo`` into the blocks ``ids`` (pool indices).

    Only the voxels of each block that fall inside the box are written.
    """
    for j in range(ids.shape[0]):
        k = ids[j]
        for lx in range(B):
            gx = coords[k, 0] * B + lx - lo[0]
            if gx < 0 or gx >= dense.shape[0]:
                continue
            for ly in range(B):
                gy = coords[k, 1] * B + ly - lo[1]
                if gy < 0 or gy >= dense.shape[1]:
                    continue
                base = (lx * B + ly) * B
                for lz in range(B):
                    gz = coords[k, 2] * B + lz - lo[2]
                    if gz < 0 or gz >= dense.shape[2]:
                        continue
                    data[k, base + lz] = dense[gx, gy, gz]


@njit(cache=True, nogil=True)
def _lookup_one(tkeys, tvals, data, B, vx, vy, vz, fill):
    bx = vx // B
    by = vy // B
    bz = vz // B
    k = table_find(tkeys, tvals, bx, by, bz)
    if k < 0:
        return fill
    return data[k, ((vx - bx * B) * B + (vy - by * B)) * B + (vz - bz * B)]


@njit(cache=True, nogil=True)
def lookup_voxels(tkeys, tvals, data, B, voxels, fill):
    """Values (N,) float32 of the voxels with indices ``voxels`` (N, 3) int64; ``fill`` where absent."""
    out = np.empty(voxels.shape[0], np.float32)
    for i in range(voxels.shape[0]):
        out[i] = _lookup_one(tkeys, tvals, data, B, voxels[i, 0], voxels[i, 1], voxels[i, 2], fill)
    return out


def _resize_rows(owner: object, name: str, rows: int, keep: int, fill: float | np.floating) -> None:
    """Give the array ``owner.<name>`` ``rows`` rows: its first ``keep`` rows kept, the rest ``fill``.

    Resized in place when nothing else refers to the array (numpy's refcheck; the attribute is
    detached meanwhile so that it is the only reference): a C realloc remaps a large array's pages
    instead of copying them, so the old and the new voxel pool (gigabytes in a city-scale map)
    are never resident together. A live view of it elsewhere makes it a copy instead.
    """
    a = getattr(owner, name)
    setattr(owner, name, None)
    try:
        try:
            a.resize((rows,) + a.shape[1:], refcheck=True)
        except ValueError:
            b = np.empty((rows,) + a.shape[1:], a.dtype)
            b[:keep] = a[:keep]
            a = b
        a[keep:] = fill
    finally:
        setattr(owner, name, a)


class BlockGrid:
    """A sparse grid of float32 voxel blocks.

    Attributes:
        block_size: B, voxels per block edge.
        fill: value of every voxel of a new block (and of voxels in absent blocks).
        count: number of blocks in use.
    The arrays ``coords[:count]`` (int32 block coordinates) and ``data[:count]`` ((count, B^3)
    float32 voxel values, flat index ``(lx * B + ly) * B + lz``) are the blocks.
    """

    def __init__(self, block_size: int, fill: float, capacity: int = 1024):
        self.block_size = int(block_size)
        self.fill = np.float32(fill)
        self.count = 0
        cap = 1 << max(4, int(np.ceil(np.log2(max(capacity, 16) / _MAX_LOAD))))
        self.tkeys = np.full((cap, 3), EMPTY, np.int32)
        self.tvals = np.full(cap, -1, np.int32)
        self.coords = np.zeros((max(capacity, 16), 3), np.int32)
        self.data = np.full((max(capacity, 16), self.block_size**3), self.fill, np.float32)

    # ----- growth ----------------------------------------------------------------------
    def _limit(self) -> int:
        return min(self.coords.shape[0], int(self.tkeys.shape[0] * _MAX_LOAD))

    def reserve(self, n_blocks: int) -> None:
        """Make room for ``n_blocks`` blocks in total without further reallocation."""
        if n_blocks > self.coords.shape[0]:
            new = max(n_blocks, int(self.coords.shape[0] * 1.5) + 16)
            _resize_rows(self, "data", new, self.count, self.fill)
            _resize_rows(self, "coords", new, self.count, 0)
        if n_blocks > int(self.tkeys.shape[0] * _MAX_LOAD):
            cap = self.tkeys.shape[0]
            while n_blocks > int(cap * _MAX_LOAD):
                cap *= 2
            self.tkeys, self.tvals = _rehash(self.coords, self.count, cap)

    def shrink_to_fit(self) -> None:
        """Give back the pool's spare rows (up to a third of it after a growth): a finished map
        keeps only its blocks. In place (realloc) when nothing else refers to the arrays, like
        :meth:`reserve`; a later :meth:`ensure` grows it again."""
        n = max(self.count, 16)
        if n < self.coords.shape[0]:
            _resize_rows(self, "data", n, n, self.fill)
            _resize_rows(self, "coords", n, n, 0)

    # ----- access ----------------------------------------------------------------------
    def find(self, block_coords: np.ndarray) -> np.ndarray:
        """(M,) int32 pool indices of (M, 3) block coordinates, -1 where absent."""
        q = np.ascontiguousarray(np.asarray(block_coords, dtype=np.int32).reshape(-1, 3))
        return find_many(self.tkeys, self.tvals, q)

    def ensure(self, block_coords: np.ndarray) -> np.ndarray:
        """(M,) int32 pool indices of (M, 3) block coordinates, creating absent blocks (filled)."""
        q = np.ascontiguousarray(np.asarray(block_coords, dtype=np.int32).reshape(-1, 3))
        out = np.empty(len(q), np.int32)
        start = 0
        while start < len(q):
            start, self.count = insert_many(
                self.tkeys, self.tvals, self.coords, self.count, self._limit(), q, out, start
            )
            if start < len(q):
                self.reserve(max(self.count + 1, int(self.count * 1.6) + 64))
        return out

    def gather(
        self, lo_voxel: np.ndarray, shape: tuple[int, int, int], fill: float | None = None
    ) -> np.ndarray:
        """Dense (X, Y, Z) float32 copy of the voxel box ``[lo, lo + shape)``; absent blocks read ``fill``."""
        lo = np.asarray(lo_voxel, dtype=np.int64).reshape(3)
        shp = np.asarray(shape, dtype=np.int64).reshape(3)
        f = self.fill if fill is None else np.float32(fill)
        return gather_dense(self.tkeys, self.tvals, self.data, self.block_size, lo, shp, f)

    def scatter(self, ids: np.ndarray, lo_voxel: np.ndarray, dense: np.ndarray) -> None:
        """Write the dense box starting at voxel ``lo_voxel`` into existing blocks ``ids``."""
        scatter_dense(
            np.ascontiguousarray(ids, dtype=np.int32),
            self.coords,
            self.data,
            self.block_size,
            np.asarray(lo_voxel, dtype=np.int64).reshape(3),
            np.ascontiguousarray(dense, dtype=np.float32),
        )

    def lookup(self, voxels: np.ndarray, fill: float | None = None) -> np.ndarray:
        """(N,) float32 values of voxels with integer indices (N, 3); ``fill`` in absent blocks."""
        v = np.ascontiguousarray(np.asarray(voxels, dtype=np.int64).reshape(-1, 3))
        f = self.fill if fill is None else np.float32(fill)
        return lookup_voxels(self.tkeys, self.tvals, self.data, self.block_size, v, f)

    @property
    def block_coords(self) -> np.ndarray:
        """(count, 3) int32 block coordinates in use (a view)."""
        return self.coords[: self.count]

    @property
    def blocks(self) -> np.ndarray:
        """(count, B^3) float32 voxel values of the blocks in use (a view)."""
        return self.data[: self.count]

    def nbytes(self) -> int:
        """Bytes held by this grid (pool and hash table, including spare capacity)."""
        return int(self.tkeys.nbytes + self.tvals.nbytes + self.coords.nbytes + self.data.nbytes)

    def copy(self) -> BlockGrid:
        g = BlockGrid.__new__(BlockGrid)
        g.block_size, g.fill, g.count = self.block_size, self.fill, self.count
        g.tkeys, g.tvals = self.tkeys.copy(), self.tvals.copy()
        g.coords, g.data = self.coords.copy(), self.data.copy()
        return g

    @classmethod
    def from_blocks(cls, block_size: int, fill: float, coords: np.ndarray, data: np.ndarray) -> BlockGrid:
        """Rebuild a grid from (M, 3) int32 block coordinates and (M, B^3) float32 block values."""
        coords = np.ascontiguousarray(coords, dtype=np.int32).reshape(-1, 3)
        g = cls(block_size, fill, capacity=max(len(coords), 16))
        ids = g.ensure(coords)
        if len(np.unique(ids)) != len(ids):
            raise ValueError("duplicate block coordinates")
        g.data[ids] = np.asarray(data, dtype=np.float32).reshape(len(coords), -1)
        return g


def warm_kernels() -> None:
    """Compile (or load) the table growth kernel (``skyrecon warmup``): a map that outgrows its
    block table rehashes it (loading a map of a wider flight), which the warmup's tiny maps
    never do."""
    grid = BlockGrid(2, 0.0, capacity=16)
    grid.reserve(4 * grid.tkeys.shape[0])
