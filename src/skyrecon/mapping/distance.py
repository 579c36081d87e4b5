"""Bounded Euclidean distance field over an occupancy map, updated incrementally.

For every voxel the field holds the Euclidean distance, metres, from its centre to the centre
of the nearest *obstacle* voxel, clipped at ``max_distance_m`` (0 inside obstacles). Obstacles
are the occupied voxels, and the unknown voxels too when ``unknown_is_occupied`` (the safe
default for planning: the drone then keeps its clearance from unexplored space as well).

Because the distance is clipped, a change of occupancy at voxel ``y`` can only alter the field
within ``max_distance_m`` of ``y``. :meth:`DistanceField.update` therefore recomputes, for each
group of changed blocks, the exact transform (:mod:`skyrecon.mapping._edt`) on their bounding box
grown by the clipping radius, reading the obstacles of a box grown by twice that radius, and
writes the inner box back: the result equals a full recomputation.

Storage: blocks of the same size as the map's (:class:`~skyrecon.mapping.blocks.BlockGrid`). Every
block of the map has a distance block; a point in a block without one reads 0 when unknown
space is an obstacle (such a block is unknown), else ``max_distance_m``.
"""

from __future__ import annotations

import math
import time

import numpy as np

from skyrecon.errors import InputError
from skyrecon.mapping._edt import bounded_distance
from skyrecon.mapping.blocks import BlockGrid
from skyrecon.mapping.inputs import check_points


class DistanceField:
    """Distance to the nearest obstacle for an :class:`~skyrecon.mapping.occupancy.OccupancyMap`.

    Args:
        occ_map: the map (the field keeps a reference and follows its updates).
        max_distance_m: clipping radius, metres; keep it above the largest clearance you query.
        unknown_is_occupied: treat unknown voxels as obstacles.
        tile_blocks: changed blocks are grouped in cubes of this many blocks per edge, each
            recomputed with its own margin (unless all of them fit in one box of at most
            ``max_box_voxels`` voxels, margins included).
        max_box_voxels: size limit of a single recomputed box.
    """

    def __init__(
        self,
        occ_map,
        max_distance_m: float = 5.0,
        unknown_is_occupied: bool = True,
        tile_blocks: int = 16,
        max_box_voxels: int = 48_000_000,
    ):
        if not np.isfinite(max_distance_m) or max_distance_m <= 0:
            raise InputError(f"max_distance_m must be positive, got {max_distance_m}")
        self.map = occ_map
        self.max_distance = float(max_distance_m)
        self.unknown_is_occupied = bool(unknown_is_occupied)
        self.tile_blocks = int(tile_blocks)
        self.max_box_voxels = int(max_box_voxels)
        self.missing_value = np.float32(0.0 if self.unknown_is_occupied else self.max_distance)
        self.grid = BlockGrid(occ_map.block_size, float(self.missing_value))
        self.version = 0
        self.last_update_seconds = 0.0
        self.update(None)

    @property
    def voxel_size(self) -> float:
        return self.map.voxel_size

    @property
    def margin_voxels(self) -> int:
        """Clipping radius in voxels (rounded up), the margin of every recomputed box."""
        return int(math.ceil(self.max_distance / self.voxel_size)) + 1

    # ----- updates ---------------------------------------------------------------------
    def update(self, changed_blocks: np.ndarray | None = None) -> np.ndarray:
        """Bring the field up to date after the map changed.

        Args:
            changed_blocks: (M, 3) int block coordinates whose voxels changed state (from
                ``map.pop_changed_blocks()``); None recomputes everything.
        Returns:
            (K, 3) int32 coordinates of the distance blocks that were rewritten.
        """
        t0 = time.perf_counter()
        B = self.map.block_size
        if changed_blocks is None:
            changed = self.map.grid.block_coords.astype(np.int64)
        else:
            changed = np.asarray(changed_blocks, dtype=np.int64).reshape(-1, 3)
        if len(changed) == 0:
            self.last_update_seconds = time.perf_counter() - t0
            return np.zeros((0, 3), np.int32)
        m = self.margin_voxels
        mb = -(-m // B)  # margin in whole blocks
        whole = (changed.max(axis=0) - changed.min(axis=0) + 1 + 2 * mb) * B + 2 * m
        tile = self.tile_blocks if np.prod(whole.astype(np.float64)) > self.max_box_voxels else 1 << 40
        tiles = np.floor_divide(changed, tile)
        order = np.lexsort((tiles[:, 2], tiles[:, 1], tiles[:, 0]))
        tiles, changed = tiles[order], changed[order]
        cuts = np.flatnonzero(np.any(np.diff(tiles, axis=0) != 0, axis=1)) + 1
        written = []
        for group in np.split(changed, cuts):
            b0 = group.min(axis=0) - mb
            b1 = group.max(axis=0) + mb
            written.append(self._recompute(b0, b1, m))
        self.version += 1
        self.last_update_seconds = time.perf_counter() - t0
        out = np.concatenate(written) if written else np.zeros((0, 3), np.int32)
        return np.unique(out, axis=0) if len(out) else out

    def _recompute(self, b0: np.ndarray, b1: np.ndarray, m: int) -> np.ndarray:
        """Recompute the blocks ``b0..b1`` (inclusive block coordinates) exactly."""
        B = self.map.block_size
        w_lo = b0 * B
        w_shape = (b1 - b0 + 1) * B
        i_lo = w_lo - m
        i_shape = w_shape + 2 * m
        lodds = self.map.dense_log_odds(i_lo, tuple(int(s) for s in i_shape))
        thr = self.map._lodds[4]
        with np.errstate(invalid="ignore"):
            obstacle = lodds >= thr
        if self.unknown_is_occupied:
            obstacle |= np.isnan(lodds)
        dist = bounded_distance(obstacle, self.voxel_size, self.max_distance)
        inner = dist[m : m + w_shape[0], m : m + w_shape[1], m : m + w_shape[2]]
        nb = b1 - b0 + 1
        mins = inner.reshape(nb[0], B, nb[1], B, nb[2], B).min(axis=(1, 3, 5))
        coords = np.stack(
            np.meshgrid(*[np.arange(b0[i], b1[i] + 1) for i in range(3)], indexing="ij"), -1
        ).reshape(-1, 3)
        in_map = self.map.grid.find(coords) >= 0
        in_field = self.grid.find(coords) >= 0
        differs = (mins != self.missing_value).reshape(-1)
        keep = in_map | in_field | (differs & ~np.bool_(self.unknown_is_occupied))
        coords = coords[keep]
        ids = self.grid.ensure(coords)
        self.grid.scatter(ids, i_lo, dist)
        return coords.astype(np.int32)

    # ----- queries ---------------------------------------------------------------------
    def dense(self, lo_voxel: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
        """(X, Y, Z) float32 distances, metres, at the centres of the voxel box ``[lo, lo + shape)``."""
        return self.grid.gather(lo_voxel, shape, float(self.missing_value))

    def query_distance(self, points: np.ndarray, interpolate: bool = False) -> np.ndarray:
        """Distance to the nearest obstacle at world points.

        Args:
            points: (N, 3) world points, metres.
            interpolate: False: the value at the centre of the voxel holding each point;
                True: trilinear interpolation between the 8 surrounding voxel centres.
        Returns:
            (N,) float64 metres, clipped at ``max_distance_m``.
        """
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise InputError(f"points must have shape (N, 3), got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise InputError("points contain NaN or infinite values")
        v = self.voxel_size
        if not interpolate:
            return self.grid.lookup(np.floor(p / v).astype(np.int64)).astype(np.float64)
        g = p / v - 0.5
        base = np.floor(g).astype(np.int64)
        f = g - base
        offs = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], np.int64)
        vals = (
            self.grid.lookup((base[:, None, :] + offs[None]).reshape(-1, 3)).reshape(-1, 8).astype(np.float64)
        )
        w = np.ones((len(p), 8))
        for a in range(3):
            w *= np.where(offs[None, :, a] == 1, f[:, a : a + 1], 1.0 - f[:, a : a + 1])
        return np.sum(w * vals, axis=1)

    def nbytes(self) -> int:
        return self.grid.nbytes()


def brute_force_distance(obstacle_centers: np.ndarray, points: np.ndarray, max_distance: float) -> np.ndarray:
    """Reference: (N,) min over obstacle centres (M, 3) of the distance to points (N, 3), clipped. O(N M)."""
    c = check_points(obstacle_centers, "obstacle centres")
    p = check_points(points)
    if len(c) == 0:
        return np.full(len(p), max_distance)
    out = np.empty(len(p))
    for s in range(0, len(p), 256):
        d = np.sqrt(((p[s : s + 256, None, :] - c[None]) ** 2).sum(-1)).min(axis=1)
        out[s : s + 256] = d
    return np.minimum(out, max_distance)
