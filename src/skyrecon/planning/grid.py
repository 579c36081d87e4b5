"""A dense planning view of a distance field: distances, flyable voxels, safe cells, levels."""

from __future__ import annotations

import numpy as np

from skyrecon.planning import _geom
from skyrecon.planning._los import lattice, safe_cells


class PlanningGrid:
    """Distances and flyable cells over the voxel box ``[lo, lo + shape)`` of a distance field.

    Args:
        df: a :class:`~skyrecon.mapping.distance.DistanceField`.
        lo: (3,) int64 first voxel index of the box; shape: (3,) number of voxels.
        threshold: a point is clear when its interpolated distance is at least this, metres
            (clearance plus margin).
        zmin, zmax: altitude band, world z metres.
        step: sampling step of the sampled segment checks, metres.
    Attributes:
        dist: (NX, NY, NZ) float32 distances at voxel centres, metres.
        flyable: (NX, NY, NZ) uint8, 1 where the voxel centre is clear and inside the band.
        safe: (NX-1, NY-1, NZ-1) uint8 dual cells whose 8 corner centres are flyable
            (see :mod:`skyrecon.planning._los`).
        origin: (3,) float64 world position of the box's lower corner.
    Search levels: level f is the lattice of every f-th safe cell (:meth:`level`); node ``I`` of
    level f sits at world ``origin + (f I + 1) * voxel``.
    """

    def __init__(
        self, df, lo: np.ndarray, shape: np.ndarray, threshold: float, zmin: float, zmax: float, step: float
    ):
        self.voxel = float(df.voxel_size)
        self.inv_v = 1.0 / self.voxel
        self.lo = np.asarray(lo, dtype=np.int64)
        self.shape = tuple(int(s) for s in shape)
        self.origin = self.lo.astype(np.float64) * self.voxel
        self.threshold = float(threshold)
        self.zmin = float(zmin)
        self.zmax = float(zmax)
        self.step = float(step)
        self.version = df.version
        self.dist = df.dense(self.lo, self.shape)
        zc = self.origin[2] + (np.arange(self.shape[2]) + 0.5) * self.voxel
        zok = (zc >= zmin) & (zc <= zmax)
        self.flyable = np.ascontiguousarray(
            ((self.dist >= self.threshold) & zok[None, None, :]).view(np.uint8)
        )
        self.safe = safe_cells(self.flyable)
        self._levels: dict[int, np.ndarray] = {1: self.safe}
        self._state: dict[int, list] = {}

    # ----- geometry ----------------------------------------------------------------------
    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    def level(self, f: int) -> np.ndarray:
        """(CX, CY, CZ) uint8 usable nodes of level f (every f-th safe cell)."""
        if f not in self._levels:
            self._levels[f] = lattice(self.safe, f)
        return self._levels[f]

    def node_positions(self, f: int, flat: np.ndarray) -> np.ndarray:
        """(K, 3) world positions of level-f flat cells (K,)."""
        cells = self.level(f)
        fl = np.asarray(flat, dtype=np.int64)
        cy, cz = cells.shape[1], cells.shape[2]
        ijk = np.stack([fl // (cy * cz), (fl // cz) % cy, fl % cz], axis=1)
        return self.origin + (f * ijk + 1.0) * self.voxel

    def node_of(self, f: int, p: np.ndarray) -> np.ndarray:
        """(3,) int64 level-f cell holding world point p (may lie outside the level)."""
        u = (np.asarray(p, dtype=np.float64) - self.origin) * self.inv_v - 0.5
        return np.floor((u - 0.5) / f + 0.5).astype(np.int64)

    # ----- queries -----------------------------------------------------------------------
    def distance(self, points: np.ndarray) -> np.ndarray:
        """(N,) interpolated distances at world points (N, 3); -1 outside the grid or the band."""
        p = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        return _geom.sample_many(self.dist, self.origin, self.inv_v, self.zmin, self.zmax, p)

    def ctx(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float, float, float, float]:
        """Leading arguments of the :mod:`_geom` path functions."""
        return (
            self.safe,
            self.dist,
            self.origin,
            self.inv_v,
            self.zmin,
            self.zmax,
            self.threshold,
            self.step,
        )

    def sampled_ctx(self) -> tuple[np.ndarray, np.ndarray, float, float, float, float, float]:
        """Leading arguments of :func:`_geom.sampled_clear` / :func:`_geom.first_blocked`."""
        return (self.dist, self.origin, self.inv_v, self.zmin, self.zmax, self.threshold, self.step)

    def search_state(self, f: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """Reusable search arrays (g, parent, stamp) of level f and a fresh generation number."""
        n = int(self.level(f).size)
        st = self._state.get(f)
        if st is None:
            st = [np.empty(n, np.float32), np.empty(n, np.int32), np.zeros(n, np.int32), 0]
            self._state[f] = st
        st[3] += 1
        if 2 * st[3] + 1 >= np.iinfo(np.int32).max:
            st[2][:] = 0
            st[3] = 1
        return st[0], st[1], st[2], st[3]

    def refresh(self, df, blocks: np.ndarray) -> None:
        """Re-read the part of the grid covered by distance blocks ``blocks`` (K, 3) that changed
        (e.g. returned by ``DistanceField.update``) instead of rebuilding the whole grid."""
        b = np.asarray(blocks, dtype=np.int64).reshape(-1, 3)
        if len(b):
            B = df.map.block_size
            shape = np.array(self.shape)
            lo = np.clip(b.min(axis=0) * B - self.lo, 0, shape)
            hi = np.clip((b.max(axis=0) + 1) * B - self.lo, 0, shape)
            if np.all(hi > lo):
                box = tuple(slice(int(a), int(c)) for a, c in zip(lo, hi))
                self.dist[box] = df.dense(self.lo + lo, tuple(int(x) for x in hi - lo))
                zc = self.origin[2] + (np.arange(lo[2], hi[2]) + 0.5) * self.voxel
                zok = (zc >= self.zmin) & (zc <= self.zmax)
                self.flyable[box] = (self.dist[box] >= self.threshold) & zok[None, None, :]
                self.recompute_safe(lo, hi)
        self.version = df.version

    def recompute_safe(self, lo: np.ndarray, hi: np.ndarray, save: bool = False) -> list[tuple]:
        """Recompute the safe cells and every search level over the part that the flyable voxels
        ``[lo, hi)`` (3,) reach, after those voxels changed; only that box, not the whole grid.

        Returns:
            With ``save``, the old values, ``(level, box, array)`` per level (level 1 is ``safe``),
            for :meth:`restore`; else an empty list.
        """
        s_lo = np.maximum(np.asarray(lo) - 1, 0)
        s_hi = np.minimum(np.asarray(hi), np.array(self.safe.shape))
        if np.any(s_hi <= s_lo):
            return []
        saved: list[tuple] = []
        sbox = tuple(slice(int(a), int(b)) for a, b in zip(s_lo, s_hi))
        if save:
            saved.append((1, sbox, self.safe[sbox].copy()))
        fly = self.flyable[s_lo[0] : s_hi[0] + 1, s_lo[1] : s_hi[1] + 1, s_lo[2] : s_hi[2] + 1]
        self.safe[sbox] = safe_cells(np.ascontiguousarray(fly))
        for f, nodes in self._levels.items():
            if f == 1:
                continue  # level 1 is self.safe itself
            n_lo = -(-s_lo // f)  # level-f node I sits on safe cell f * I
            n_hi = np.minimum(-(-s_hi // f), np.array(nodes.shape))
            if np.any(n_hi <= n_lo):
                continue
            nbox = tuple(slice(int(a), int(b)) for a, b in zip(n_lo, n_hi))
            if save:
                saved.append((f, nbox, nodes[nbox].copy()))
            nodes[nbox] = self.safe[
                f * n_lo[0] : s_hi[0] : f, f * n_lo[1] : s_hi[1] : f, f * n_lo[2] : s_hi[2] : f
            ]
        return saved

    def restore(self, saved: list[tuple]) -> None:
        """Put back what :meth:`recompute_safe` saved (lists from several calls: newest first)."""
        for f, box, old in saved:
            self.level(f)[box] = old

    def nbytes(self) -> int:
        n = self.dist.nbytes + self.flyable.nbytes + sum(a.nbytes for a in self._levels.values())
        n += sum(a.nbytes for st in self._state.values() for a in st[:3])
        return int(n)
