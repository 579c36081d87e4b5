"""Probabilistic occupancy map in sparse voxel blocks, fed by depth images or point clouds.

Every voxel holds the log-odds ``l = log(p / (1 - p))`` that it is occupied, or NaN while it
is unknown (never observed). A hit adds ``logit(prob_hit)``, a miss adds ``logit(prob_miss)``,
and the result is clamped to ``[logit(clamp_min), logit(clamp_max)]``. A known voxel is
*occupied* when ``l >= logit(occupancy_threshold)``, else *free*.

Frames and units: world frame (right-handed, z up), metres. Voxel ``i`` (integer per axis)
spans ``[i, i + 1) * voxel_size``; see :mod:`skyrecon.mapping.blocks` for the block layout.

Depth images are integrated projectively (each voxel of the frustum once per frame, see
:mod:`skyrecon.mapping._projective`), point clouds by ray casting from the sensor origin
(see :mod:`skyrecon.mapping._raycast`). Both record which blocks changed state, and which
blocks changed their set of occupied voxels, so that the distance field can be updated
incrementally (:meth:`OccupancyMap.pop_changed_blocks`).
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skyrecon.core.depth import DepthMap
from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError
from skyrecon.mapping import _projective as proj
from skyrecon.mapping import _raycast as rc
from skyrecon.mapping.blocks import BlockGrid
from skyrecon.mapping.config import MapConfig
from skyrecon.mapping.inputs import as_world_from_cam, check_depth, check_point3, check_points
from skyrecon.mapping.storage import BLOCKS, read_map_files, write_map_files

UNKNOWN, FREE, OCCUPIED = -1, 0, 1


def _polyline_samples(points: np.ndarray, step: float) -> np.ndarray:
    """(M, 3) points every ``step`` (or closer) along the polyline through ``points`` (N, 3), ends included."""
    if len(points) == 1:
        return points.copy()
    out = [points[:1]]
    for a, b in zip(points[:-1], points[1:]):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
        out.append(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
    return np.concatenate(out)


@dataclass
class IntegrationStats:
    """What one integration did.

    Attributes:
        blocks_touched: blocks visited (created or updated).
        free_updates, hit_updates: voxel updates as free / occupied.
        changed_blocks: blocks in which some voxel changed state.
        seconds: wall time of the call.
    """

    blocks_touched: int
    free_updates: int
    hit_updates: int
    changed_blocks: int
    seconds: float


class OccupancyMap:
    """A sparse probabilistic voxel map of the world.

    Args:
        config: the update model and geometry (:class:`MapConfig`); keyword overrides are
            applied on top, e.g. ``OccupancyMap(voxel_size_m=0.5)``.
    """

    def __init__(self, config: MapConfig | None = None, **overrides):
        base = config or MapConfig()
        if overrides:
            base = MapConfig.from_dict({**base.to_dict(), **overrides})
        self.config = base
        self.grid = BlockGrid(base.block_size, np.nan)
        # per block, bits of the changes not popped yet: CHANGED_STATE, CHANGED_OCCUPIED (see _projective)
        self._dirty = np.zeros(self.grid.coords.shape[0], np.uint8)
        self._sat = np.zeros(self.grid.coords.shape[0], np.uint8)  # block saturated free (see _projective)
        # per-frame scratch of depth integration (see _projective.mark_endpoints)
        self._local_of_pool = np.full(self.grid.coords.shape[0], -1, np.int32)
        self._hitmask = np.zeros((0, base.block_size**3), np.uint8)
        self._octflag = np.zeros((0, 8), np.uint8)
        self._lodds = base.log_odds
        self._camera_cache: dict[tuple, tuple] = {}
        self.version = 0  # incremented by every change
        self.last_build_stats: list[IntegrationStats] = []  # per frame, of build_map_from_depth_frames
        self._bounds_cache: tuple | None = None

    def __repr__(self) -> str:
        c = self.counts()
        return (
            f"OccupancyMap(voxel={self.voxel_size} m, blocks={c['blocks']}, occupied={c['occupied']}, "
            f"free={c['free']}, {self.memory_bytes() / 1e6:.1f} MB)"
        )

    # ----- geometry --------------------------------------------------------------------
    @property
    def voxel_size(self) -> float:
        return self.config.voxel_size_m

    @property
    def block_size(self) -> int:
        return self.config.block_size

    def voxel_index(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) int64 voxel indices of world points (N, 3) metres."""
        return np.floor(np.asarray(points, dtype=np.float64).reshape(-1, 3) / self.voxel_size).astype(
            np.int64
        )

    def voxel_center(self, index: np.ndarray) -> np.ndarray:
        """(N, 3) float64 world centres, metres, of voxel indices (N, 3)."""
        return (np.asarray(index, dtype=np.float64).reshape(-1, 3) + 0.5) * self.voxel_size

    def voxel_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Voxel index box ``[lo, hi)`` (3,) int64 of the allocated blocks (zeros when empty)."""
        key = (self.version, self.grid.count)
        if self._bounds_cache is None or self._bounds_cache[0] != key:
            if self.grid.count == 0:
                lo = hi = np.zeros(3, np.int64)
            else:
                c = self.grid.block_coords.astype(np.int64)
                lo, hi = c.min(axis=0) * self.block_size, (c.max(axis=0) + 1) * self.block_size
            self._bounds_cache = (key, lo, hi)
        return self._bounds_cache[1].copy(), self._bounds_cache[2].copy()

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """World box ``(lo, hi)`` (3,) metres covered by the allocated blocks (zeros when empty)."""
        lo, hi = self.voxel_bounds()
        return lo * self.voxel_size, hi * self.voxel_size

    # ----- change tracking -------------------------------------------------------------
    def _grow_flags(self) -> None:
        n = self.grid.coords.shape[0]
        for name in ("_dirty", "_sat"):
            a = getattr(self, name)
            if a.shape[0] < n:
                b = np.zeros(n, np.uint8)
                b[: a.shape[0]] = a
                setattr(self, name, b)
        if self._local_of_pool.shape[0] < n:
            self._local_of_pool = np.full(n, -1, np.int32)

    def _mark(self, ids: np.ndarray, changed: np.ndarray) -> int:
        """Record the change codes ``changed`` (M,) uint8 of the distinct blocks ``ids`` (M,)."""
        self._grow_flags()
        changed = np.asarray(changed, dtype=np.uint8)
        sel = changed != 0
        hit = ids[sel]
        self._dirty[hit] |= changed[sel]
        if len(ids):
            self.version += 1
        return int(len(hit))

    def _changed_bit(self, occupied_only: bool) -> int:
        return proj.CHANGED_OCCUPIED if occupied_only else proj.CHANGED_STATE

    def changed_blocks(self, occupied_only: bool = False) -> np.ndarray:
        """Blocks changed since they were last popped, without forgetting them.

        Args:
            occupied_only: False: blocks in which some voxel changed state (unknown, free or
                occupied); True: blocks in which some voxel became or stopped being occupied
                (what a distance field that counts unknown space as free depends on).
        Returns:
            (M, 3) int32 block coordinates (block ``b`` holds voxels ``b * block_size`` to
            ``(b + 1) * block_size - 1`` per axis), in pool order.
        """
        idx = np.flatnonzero(self._dirty[: self.grid.count] & self._changed_bit(occupied_only))
        return self.grid.coords[idx].copy()

    def pop_changed_blocks(self, occupied_only: bool = False) -> np.ndarray:
        """The blocks changed since the last call (as :meth:`changed_blocks`), and forget them.

        The two kinds of record are kept and forgotten separately: ``pop_changed_blocks()``
        (every state change, for a distance field that counts unknown space as occupied)
        does not clear the record of ``pop_changed_blocks(occupied_only=True)`` (changes of
        the occupied voxels, for one that counts unknown space as free), and vice versa, so
        each consumer sees every change once.

        Returns:
            (M, 3) int32 block coordinates (see :meth:`changed_blocks`).
        """
        out = self.changed_blocks(occupied_only)
        self._dirty[: self.grid.count] &= np.uint8(~self._changed_bit(occupied_only) & 0xFF)
        return out

    # ----- integration -----------------------------------------------------------------
    def _camera_tables(self, intr: Intrinsics) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Cached per camera: (H, W, 3) float32 ray directions with z = 1 and (H, W) float32
        their lengths (camera frame); (4, 3) frustum side-plane normals; (25, 3) unit ray fan."""
        key = (intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy, intr.skew, tuple(intr.dist))
        tables = self._camera_cache.get(key)
        if tables is None:
            rd = np.ascontiguousarray(intr.ray_directions(), dtype=np.float32)
            rn = np.ascontiguousarray(np.linalg.norm(rd, axis=2), dtype=np.float32)
            tables = (rd, rn) + self._frustum(intr)
            if len(self._camera_cache) > 8:
                self._camera_cache.clear()
            self._camera_cache[key] = tables
        return tables

    @staticmethod
    def _frustum(intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
        """Inward side-plane normals (4, 3) and a (25, 3) fan of unit ray directions (camera frame)."""
        W, H = intr.width, intr.height
        e = np.linspace(-0.5, W - 0.5, 33)
        f = np.linspace(-0.5, H - 0.5, 25)
        border = np.concatenate(
            [
                np.stack([e, np.full_like(e, -0.5)], 1),
                np.stack([e, np.full_like(e, H - 0.5)], 1),
                np.stack([np.full_like(f, -0.5), f], 1),
                np.stack([np.full_like(f, W - 0.5), f], 1),
            ]
        )
        xy = intr.normalized(border)
        xl, xr = xy[:, 0].min(), xy[:, 0].max()
        yt, yb = xy[:, 1].min(), xy[:, 1].max()
        planes = np.array([[1, 0, -xl], [-1, 0, xr], [0, 1, -yt], [0, -1, yb]], dtype=np.float64)
        planes /= np.linalg.norm(planes, axis=1, keepdims=True)
        gx, gy = np.meshgrid(np.linspace(xl, xr, 5), np.linspace(yt, yb, 5))
        fan = np.stack([gx.ravel(), gy.ravel(), np.ones(25)], 1)
        return planes, fan / np.linalg.norm(fan, axis=1, keepdims=True)

    def _surface_push_m(self) -> float:
        """How far a measured point moves along its ray before it is binned, metres: a hair
        into the surface (so that a surface on a voxel face, the ground at z = 0, marks the voxel
        behind it), less the config's ``surface_pull_voxels``."""
        return (0.005 - self.config.surface_pull_voxels) * self.voxel_size

    def integrate_depth(
        self,
        depth_m: np.ndarray,
        intrinsics: Intrinsics,
        world_from_cam: Rigid3 | np.ndarray,
        carve_only: np.ndarray | None = None,
    ) -> IntegrationStats:
        """Integrate one depth image taken from a known pose.

        Args:
            depth_m: (H, W) depth along the optical axis, metres; NaN (or <= 0) invalid, +inf
                "no return within range" (carves free space up to the maximum range).
            intrinsics: the depth camera (size must match ``depth_m``).
            world_from_cam: the camera pose, ``p_world = R @ p_cam + t`` (Rigid3 or 4x4 / 3x4).
            carve_only: optional (H, W) bool: pixels whose depth is not trusted to mark a
                surface (see :class:`~skyrecon.mapping.far_hits.FarHitFilter`); they carve free
                space up to a voxel's half diagonal in front of their point and mark no hit.
        Returns:
            IntegrationStats.
        Raises:
            InputError: wrong shape, NaN pose, or depth not plausibly in metres.
        """
        t0 = time.perf_counter()
        cfg = self.config
        pose = as_world_from_cam(world_from_cam)
        depth = check_depth(depth_m, intrinsics, cfg.max_plausible_depth_m)
        cam_from_world = pose.inverse()
        v = self.voxel_size
        eps = self._surface_push_m()
        dirs, ray_norm, planes, fan = self._camera_tables(intrinsics)
        hit_depth = depth
        if carve_only is None:
            carve = np.zeros(depth.shape, np.bool_)
        else:
            carve = np.asarray(carve_only, np.bool_)
            if carve.shape != depth.shape:
                raise InputError(
                    f"carve_only mask {carve.shape} does not match the depth image {depth.shape}"
                )
            if carve.any():
                hit_depth = depth.copy()
                hit_depth[carve] = np.nan
        plane, lo, hi = proj.prepare_depth(
            depth,
            dirs,
            ray_norm,
            pose.R,
            intrinsics.fx,
            intrinsics.fy,
            cfg.min_range_m,
            cfg.max_range_m,
            v,
            eps,
            cfg.grazing_cap_voxels * v,
            carve,
        )
        mn, mx, offs, _hs, ws = proj.build_pyramid(lo, hi)
        t1 = time.perf_counter()
        centre = pose.t
        rmax = cfg.max_range_m
        pts = np.concatenate([centre[None], centre + pose.rotate(fan) * rmax])
        pad = 0.05 * rmax + cfg.block_edge_m
        sedge = cfg.block_edge_m * proj.SUPER
        s_lo = np.floor((pts.min(axis=0) - pad) / sedge).astype(np.int64)
        s_hi = np.floor((pts.max(axis=0) + pad) / sedge).astype(np.int64)
        s_n = s_hi - s_lo + 1
        simple = intrinsics.has_distortion or intrinsics.skew != 0.0
        cam = np.array(
            [
                intrinsics.fx,
                intrinsics.fy,
                intrinsics.cx,
                intrinsics.cy,
                intrinsics.width,
                intrinsics.height,
                1e-3,
                rmax,
                intrinsics.skew,
            ]
        )
        R = np.ascontiguousarray(cam_from_world.R)
        t = np.ascontiguousarray(cam_from_world.t)
        cls = proj.classify_blocks(
            s_lo, s_n, self.block_size, self.voxel_size, R, t, cam, planes, mn, mx, offs, ws, simple
        )
        coords, kinds = proj.collect_blocks(cls, s_lo, s_n)
        t2 = time.perf_counter()
        ids = self.grid.ensure(coords)
        t3 = time.perf_counter()
        dist = np.concatenate([[1.0 if intrinsics.has_distortion else 0.0], intrinsics.dist]).astype(
            np.float64
        )
        self._grow_flags()
        # rows of the per-frame endpoint scratch for the PARTIAL blocks
        part = np.flatnonzero(kinds == proj.PARTIAL)
        loc = np.full(len(ids), -1, np.int32)
        loc[part] = np.arange(len(part), dtype=np.int32)
        B3 = self.block_size**3
        if self._hitmask.shape[0] < len(part):
            self._hitmask = np.zeros((int(len(part) * 1.3) + 64, B3), np.uint8)
            self._octflag = np.zeros((self._hitmask.shape[0], 8), np.uint8)
        self._local_of_pool[ids[part]] = loc[part]
        proj.mark_endpoints(
            hit_depth,
            dirs,
            ray_norm,
            pose.R,
            pose.t,
            v,
            self.block_size,
            cfg.min_range_m,
            cfg.max_range_m,
            eps,
            self.grid.tkeys,
            self.grid.tvals,
            self._local_of_pool,
            self._hitmask,
            self._octflag,
        )
        self._local_of_pool[ids[part]] = -1
        changed, counts = proj.update_blocks(
            self.grid.data,
            self._sat,
            self.grid.coords,
            ids,
            kinds,
            self.block_size,
            self.voxel_size,
            R,
            t,
            cam,
            dist,
            plane,
            self._lodds,
            planes,
            mn,
            mx,
            offs,
            ws,
            simple,
            loc,
            self._hitmask,
            self._octflag,
        )
        self._hitmask[: len(part)] = 0
        self._octflag[: len(part)] = 0
        n_changed = self._mark(ids, changed)
        t4 = time.perf_counter()
        self.last_timing = {"prepare": t1 - t0, "classify": t2 - t1, "allocate": t3 - t2, "update": t4 - t3}
        return IntegrationStats(
            len(ids), int(counts[:, 0].sum()), int(counts[:, 1].sum()), n_changed, t4 - t0
        )

    def integrate_depth_map(self, depth: DepthMap) -> IntegrationStats:
        """Integrate a :class:`DepthMap` that carries its ``cam_from_world`` pose."""
        if depth.cam_from_world is None:
            raise InputError("this depth map has no camera pose; cannot place it in the world")
        return self.integrate_depth(
            depth.depth_m, depth.intrinsics, depth.cam_from_world.inverse().with_frames("world", "cam")
        )

    def integrate_points(self, points_world: np.ndarray, sensor_origin: np.ndarray) -> IntegrationStats:
        """Integrate a point cloud by casting a ray from the sensor to every point.

        Args:
            points_world: (N, 3) measured surface points, world frame, metres (NaN rows ignored).
            sensor_origin: (3,) sensor position, world frame, metres.
        Returns:
            IntegrationStats. Points beyond ``max_range_m`` carve free space up to the range and
            give no hit; points nearer than ``min_range_m`` are ignored. Each point is pushed
            ``0.005 * voxel_size`` further along its ray before it is binned (less
            ``surface_pull_voxels`` of the config).
        """
        t0 = time.perf_counter()
        cfg = self.config
        o = check_point3(sensor_origin, "sensor origin")
        p = check_points(points_world)
        d = p - o
        rng = np.linalg.norm(d, axis=1)
        keep = rng >= max(cfg.min_range_m, 1e-9)
        p, d, rng = p[keep], d[keep], rng[keep]
        far = rng > cfg.max_range_m
        # end points pushed a hair into the surface (so that a surface lying exactly on a voxel
        # face, the ground at z = 0, marks the voxel behind it) less the configured pull, as
        # depth integration does
        ends = p + d * (self._surface_push_m() / rng)[:, None]
        ends[far] = o + d[far] * (cfg.max_range_m / rng[far])[:, None]
        v = self.voxel_size
        o_v = o / v
        ends_v = np.ascontiguousarray(ends / v)
        is_hit = (~far).astype(np.uint8)
        max_steps = int(3 * (cfg.max_range_m / v) + 8)
        blocks = rc.collect_ray_blocks(o_v, ends_v, self.block_size, max_steps)
        ids = self.grid.ensure(blocks)
        uniq = np.unique(ids)
        local = np.full(self.grid.count, -1, np.int32)
        local[uniq] = np.arange(len(uniq), dtype=np.int32)
        free, hits = rc.mark_rays(
            self.grid.tkeys,
            self.grid.tvals,
            local,
            len(uniq),
            o_v,
            ends_v,
            is_hit,
            self.block_size,
            max_steps,
        )
        self._grow_flags()
        changed, counts = rc.apply_flags(
            self.grid.data, self._sat, uniq.astype(np.int32), free, hits, self._lodds
        )
        n_changed = self._mark(uniq, changed)
        return IntegrationStats(
            len(uniq), int(counts[:, 0].sum()), int(counts[:, 1].sum()), n_changed, time.perf_counter() - t0
        )

    def mark_flown_free(self, positions: np.ndarray, radius_m: float) -> int:
        """Mark the space a vehicle flew through as known free.

        The vehicle's body swept every voxel whose centre lies within ``radius_m`` of the flown
        polyline (plus half a voxel, so that a radius below the voxel size still covers the
        voxels the path crosses): those voxels are set to the free clamp (``clamp_min``), whatever
        the cameras said of them (nothing solid can be where the vehicle was; later measurements
        may still mark a voxel occupied, e.g. when something moves in).

        Args:
            positions: (N, 3) vehicle positions in flight order, world metres (N >= 1).
            radius_m: the vehicle's radius, metres (>= 0).
        Returns:
            The number of voxels set.
        """
        pts = check_points(positions)
        if not (np.isfinite(radius_m) and radius_m >= 0):
            raise InputError(f"the vehicle radius must be a non-negative number of metres, got {radius_m}")
        if len(pts) == 0:
            return 0
        v = self.voxel_size
        reach = float(radius_m) + 0.5 * v
        samples = _polyline_samples(pts, 0.25 * v)
        k = int(np.ceil(reach / v)) + 1
        r = np.arange(-k, k + 1)
        offs = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
        # each sample proposes the voxels around it whose centre lies within reach of it (a voxel
        # centre within reach of the polyline lies within reach + v/8 of its nearest sample); in
        # chunks of samples, so that a survey's kilometres of track never hold every sample's
        # (2k+1)^3 candidates at once (gigabytes)
        per_chunk = max(1, 1_000_000 // len(offs))
        parts = []
        for a in range(0, len(samples), per_chunk):
            chunk = samples[a : a + per_chunk]
            cand = (np.floor(chunk / v).astype(np.int64)[:, None, :] + offs[None]).reshape(-1, 3)
            near = np.linalg.norm((cand + 0.5) * v - np.repeat(chunk, len(offs), axis=0), axis=1)
            parts.append(np.unique(cand[near <= reach + 0.125 * v], axis=0))
        vox = np.unique(np.concatenate(parts), axis=0)
        if len(vox) == 0:
            return 0
        ids, flat = self._slots(vox)
        data = self.grid.data
        before = data[ids, flat]
        data[ids, flat] = self._lodds[2]
        self._mark_written(ids, before, data[ids, flat])
        return int(len(vox))

    def _slots(self, vox: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The (block id, flat index) of voxels (N, 3) in the grid, allocating missing blocks."""
        B = self.block_size
        blocks, local = np.divmod(vox, B)
        ids = self.grid.ensure(blocks.astype(np.int32))
        self._grow_flags()
        return ids, (local[:, 0] * B + local[:, 1]) * B + local[:, 2]

    def _mark_written(self, ids: np.ndarray, before: np.ndarray, after: np.ndarray) -> None:
        """Flag the blocks whose voxels changed state (unknown, free, occupied) from ``before`` to
        ``after`` (log-odds, NaN unknown) for the distance field and the planner."""
        thr = self._lodds[4]
        was_unknown = np.isnan(before)
        was_occupied = ~was_unknown & (before >= thr)
        became = after >= thr
        changed = np.where(was_unknown | (was_occupied != became), proj.CHANGED_STATE, 0).astype(np.uint8)
        changed[was_occupied != became] |= proj.CHANGED_OCCUPIED
        uniq, inv = np.unique(ids, return_inverse=True)
        per_block = np.zeros(len(uniq), np.uint8)
        np.bitwise_or.at(per_block, inv, changed)
        self._mark(uniq, per_block)
        self._bounds_cache = None

    def add_hits(self, voxels: np.ndarray) -> int:
        """Add one hit (``prob_hit``, clamped) to each of the given voxels, without casting rays:
        no voxel is carved free. For evidence that places a surface but cannot vouch for the
        space in front of it (see :class:`skyrecon.mapping.StereoMapper`'s multi-frame support).

        Args:
            voxels: (N, 3) integer voxel indices (``floor(p / voxel_size)``); repeats count once.
        Returns:
            The number of distinct voxels updated.
        """
        vox = np.unique(np.asarray(voxels, dtype=np.int64).reshape(-1, 3), axis=0)
        if len(vox) == 0:
            return 0
        ids, flat = self._slots(vox)
        data = self.grid.data
        before = data[ids, flat]
        l_hit, lo_max, stale = self._lodds[0], self._lodds[3], self._lodds[5]
        # an unknown voxel, or one still at an earlier flight's stale belief, starts from 0
        start = np.where(np.isnan(before) | (before == stale), np.float32(0.0), before)
        after = np.minimum(start + l_hit, lo_max).astype(np.float32)
        data[ids, flat] = after
        self._mark_written(ids, before, after)
        return int(len(vox))

    def fill_unknown_from(self, other: OccupancyMap) -> int:
        """Copy ``other``'s log-odds into the voxels this map has not observed (e.g. a prior map
        from an earlier flight under today's map); observed voxels keep their values.

        Raises:
            InputError: the maps have different voxel sizes.
        Returns:
            Number of voxels filled.
        """
        if abs(other.voxel_size - self.voxel_size) > 1e-9:
            raise InputError(
                f"cannot combine maps with {self.voxel_size:g} m and {other.voxel_size:g} m voxels"
            )
        coords = other.grid.block_coords.copy()
        if len(coords) == 0:
            return 0
        vals = other.grid.blocks.copy()
        ids = self.grid.ensure(coords)
        cur = self.grid.data[ids]
        fill = np.isnan(cur) & ~np.isnan(vals)
        cur[fill] = vals[fill]
        self.grid.data[ids] = cur
        with np.errstate(invalid="ignore"):
            occ = np.any(fill & (vals >= self._lodds[4]), axis=1)
        changed = np.where(np.any(fill, axis=1), proj.CHANGED_STATE, 0) | np.where(
            occ, proj.CHANGED_OCCUPIED, 0
        )
        self._mark(ids, changed)
        return int(np.count_nonzero(fill))

    # ----- queries ---------------------------------------------------------------------
    def log_odds_at(self, points: np.ndarray) -> np.ndarray:
        """(N,) float32 log-odds of the voxels holding world points (N, 3); NaN where unknown."""
        return self.grid.lookup(self.voxel_index(points), np.nan)

    def probability_at(self, points: np.ndarray) -> np.ndarray:
        """(N,) float64 occupancy probability at world points (N, 3); NaN where unknown."""
        l = self.log_odds_at(points).astype(np.float64)
        return 1.0 / (1.0 + np.exp(-l))

    def state_at(self, points: np.ndarray) -> np.ndarray:
        """(N,) int8 state at world points (N, 3): -1 unknown, 0 free, 1 occupied."""
        return self.classify(self.log_odds_at(points))

    def classify(self, log_odds: np.ndarray) -> np.ndarray:
        """int8 states (-1 unknown, 0 free, 1 occupied) of log-odds values (any shape)."""
        l = np.asarray(log_odds)
        out = np.full(l.shape, UNKNOWN, np.int8)
        with np.errstate(invalid="ignore"):
            out[l >= self._lodds[4]] = OCCUPIED
            out[l < self._lodds[4]] = FREE
        return out

    def dense_log_odds(self, lo_voxel: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
        """(X, Y, Z) float32 log-odds of the voxel box ``[lo, lo + shape)`` (NaN unknown)."""
        return self.grid.gather(lo_voxel, shape, np.nan)

    def _block_ranges(self) -> Iterator[tuple[int, int]]:
        """Ranges [a, b) of the allocated blocks, about 16 MB of voxels each: a test of every voxel
        runs per range, so that no temporary is the size of the whole map (gigabytes for a city)."""
        per = max(1, (16 << 20) // max(1, self.block_size**3))
        n = len(self.grid.blocks)
        for a in range(0, n, per):
            yield a, min(n, a + per)

    def occupied_voxels(self) -> np.ndarray:
        """(M, 3) int64 indices of the occupied voxels (block order, then voxel order)."""
        B = self.block_size
        blocks = self.grid.blocks
        occupied = self._lodds[4]
        with np.errstate(invalid="ignore"):  # counted first, then filled in place: no second copy
            n = sum(int(np.count_nonzero(blocks[a:b] >= occupied)) for a, b in self._block_ranges())
        out = np.empty((n, 3), np.int64)
        m = 0
        for a, b in self._block_ranges():
            with np.errstate(invalid="ignore"):
                k, q = np.nonzero(blocks[a:b] >= occupied)
            part = out[m : m + len(k)]
            part[:] = self.grid.block_coords[a + k].astype(np.int64) * B
            part[:, 0] += q // (B * B)
            part[:, 1] += (q // B) % B
            part[:, 2] += q % B
            m += len(k)
        return out

    def occupied_centers(self) -> np.ndarray:
        """(M, 3) float64 world centres, metres, of the occupied voxels."""
        return self.voxel_center(self.occupied_voxels())

    def counts(self) -> dict[str, int]:
        """Numbers of blocks and of occupied / free / unknown voxels inside the allocated blocks."""
        blocks = self.grid.blocks
        occ = free = 0
        for a, b in self._block_ranges():
            with np.errstate(invalid="ignore"):
                occ += int(np.count_nonzero(blocks[a:b] >= self._lodds[4]))
                free += int(np.count_nonzero(blocks[a:b] < self._lodds[4]))
        return {
            "blocks": self.grid.count,
            "occupied": occ,
            "free": free,
            "unknown": int(blocks.size) - occ - free,
        }

    def memory_bytes(self) -> int:
        """Bytes held by the map's arrays (including spare capacity)."""
        return self.grid.nbytes() + int(self._dirty.nbytes)

    def __getstate__(self) -> dict:
        """Pickled without caches other modules keep on the map (the planner's grids)."""
        return {k: v for k, v in self.__dict__.items() if not k.startswith("_skyrecon_")}

    def copy(self) -> OccupancyMap:
        m = OccupancyMap(self.config)
        m.grid = self.grid.copy()
        m._dirty = self._dirty.copy()
        m._sat = self._sat.copy()
        m.version = self.version
        return m

    # ----- construction from ground truth ----------------------------------------------
    @classmethod
    def from_occupancy_grid(
        cls,
        occupied: np.ndarray,
        origin_m: np.ndarray,
        config: MapConfig | None = None,
        known: np.ndarray | None = None,
        **overrides,
    ) -> OccupancyMap:
        """A fully observed map from a dense boolean grid (e.g. ground truth).

        Args:
            occupied: (X, Y, Z) bool, voxel ``[i, j, k]`` has its lower corner at
                ``origin_m + (i, j, k) * voxel_size``.
            origin_m: (3,) world position of the grid's lower corner, metres; must be a
                multiple of the voxel size.
            known: optional (X, Y, Z) bool; voxels where False stay unknown.
        Occupied voxels get ``logit(clamp_max)``, free ones ``logit(clamp_min)``.
        """
        m = cls(config, **overrides)
        occ = np.asarray(occupied, dtype=bool)
        if occ.ndim != 3:
            raise InputError(f"an occupancy grid must be 3-D, got shape {occ.shape}")
        lo = m._origin_voxel(origin_m)
        vals = np.where(occ, m._lodds[3], m._lodds[2]).astype(np.float32)
        if known is not None:
            vals[~np.asarray(known, dtype=bool)] = np.nan
        return m._fill_dense(vals, lo)

    @classmethod
    def from_dense_log_odds(
        cls, log_odds: np.ndarray, origin_m: np.ndarray, config: MapConfig | None = None, **overrides
    ) -> OccupancyMap:
        """A map holding a dense box of log-odds (e.g. a prior map re-weighted for a new flight).

        Args:
            log_odds: (X, Y, Z) float log-odds, NaN unknown; voxel ``[i, j, k]`` has its lower
                corner at ``origin_m + (i, j, k) * voxel_size``.
            origin_m: (3,) world position of the box's lower corner, metres (a multiple of the voxel size).
        """
        m = cls(config, **overrides)
        vals = np.asarray(log_odds, dtype=np.float32)
        if vals.ndim != 3:
            raise InputError(f"a log-odds grid must be 3-D, got shape {vals.shape}")
        lo = m._origin_voxel(origin_m)
        return m._fill_dense(vals, lo)

    def _origin_voxel(self, origin_m: np.ndarray) -> np.ndarray:
        """(3,) int64 voxel index of a grid's lower corner ``origin_m`` (3,) metres, which must be
        a multiple of the voxel size."""
        o = check_point3(origin_m, "grid origin") / self.voxel_size
        lo = np.rint(o).astype(np.int64)
        if np.abs(o - lo).max() > 1e-6:
            raise InputError(
                f"grid origin {np.asarray(origin_m).tolist()} is not a multiple of the voxel size {self.voxel_size} m"
            )
        return lo

    def _fill_dense(self, vals: np.ndarray, lo: np.ndarray) -> OccupancyMap:
        """Write the dense float32 log-odds ``vals`` (X, Y, Z) at voxel ``lo`` (3,) into this
        (empty) map, allocating the blocks it covers and marking them changed."""
        m = self
        B = m.block_size
        b0 = np.floor_divide(lo, B)
        b1 = np.floor_divide(lo + np.array(vals.shape) - 1, B)
        rngs = [np.arange(b0[i], b1[i] + 1) for i in range(3)]
        bc = np.stack(np.meshgrid(*rngs, indexing="ij"), -1).reshape(-1, 3)
        ids = m.grid.ensure(bc)
        m.grid.scatter(ids, lo, vals)
        with np.errstate(invalid="ignore"):
            has_occupied = np.any(m.grid.data[ids] >= m._lodds[4], axis=1)
        m._mark(ids, np.where(has_occupied, proj.CHANGED_STATE | proj.CHANGED_OCCUPIED, proj.CHANGED_STATE))
        return m

    # ----- persistence -----------------------------------------------------------------
    @classmethod
    def from_blocks(cls, config: MapConfig, coords: np.ndarray, log_odds: np.ndarray) -> OccupancyMap:
        """A map holding the given blocks, every one of them reported as changed.

        Args:
            config: the map's settings.
            coords: (N, 3) int block coordinates.
            log_odds: (N, B, B, B) float log-odds, NaN unknown (see :mod:`skyrecon.mapping.storage`).
        Raises:
            InputError: arrays that do not fit together.
        """
        m = cls(config)
        B = config.block_size
        try:
            m.grid = BlockGrid.from_blocks(B, np.nan, coords, np.asarray(log_odds).reshape(len(coords), -1))
        except ValueError as e:
            raise InputError(f"corrupt block file ({e})") from None
        m._dirty = np.full(m.grid.coords.shape[0], 3, np.uint8)  # every block changed, occupied ones included
        m._sat = np.zeros(m.grid.coords.shape[0], np.uint8)
        return m

    def save(self, directory: str | Path, compress: bool = False) -> None:
        """Write the map to ``directory`` (see :mod:`skyrecon.mapping.storage` for the format)."""
        B = self.block_size
        n = self.grid.count
        write_map_files(
            directory,
            self.config,
            self.grid.block_coords.copy(),
            self.grid.blocks.reshape(n, B, B, B),
            compress,
        )

    @classmethod
    def load(cls, directory: str | Path) -> OccupancyMap:
        """Read a map written by :meth:`save` (or a tiled map, assembled whole: see
        :mod:`skyrecon.mapping.tiles`); raises InputError for missing or corrupt files."""
        from skyrecon.mapping.tiles import TiledMap, is_tiled_map  # tiles builds on this module

        if is_tiled_map(directory):
            return TiledMap.open(directory).to_map()
        stored = read_map_files(directory)
        try:
            return cls.from_blocks(stored.config, stored.coords, stored.log_odds)
        except InputError as e:
            raise InputError(e.reason, Path(directory) / BLOCKS) from None


def save_map(occ_map: OccupancyMap, directory: str | Path, compress: bool = False) -> None:
    """Write ``occ_map`` to ``directory`` (created if missing); see :meth:`OccupancyMap.save`."""
    occ_map.save(directory, compress)


def load_map(directory: str | Path) -> OccupancyMap:
    """Read a map directory written by :func:`save_map`; raises InputError if missing or corrupt."""
    return OccupancyMap.load(directory)


def build_map_from_depth_frames(
    depths: Sequence[np.ndarray | DepthMap],
    intrinsics: Intrinsics | Sequence[Intrinsics] | None,
    world_from_cam: Sequence[Rigid3 | np.ndarray] | np.ndarray | None,
    config: MapConfig | None = None,
    progress=None,
    **overrides,
) -> OccupancyMap:
    """Build an occupancy map from posed depth frames.

    Args:
        depths: N depth images (H, W) float32 metres along the optical axis (NaN invalid), or
            N :class:`DepthMap` objects that carry their intrinsics and ``cam_from_world`` (then
            ``intrinsics`` and ``world_from_cam`` may be None).
        intrinsics: one camera for all frames or one per frame.
        world_from_cam: N poses ``p_world = R p_cam + t`` (Rigid3, or an (N, 4, 4) / (N, 3, 4) array).
        config: map settings; keyword overrides (e.g. ``voxel_size_m=0.5``) are applied on top.
        progress: optional callable ``progress(i, n)`` after each frame.
    Returns:
        The map; its per-frame statistics are in ``map.last_build_stats``.
    Raises:
        InputError: counts that do not match, NaN poses, depth not in metres, wrong sizes.
    """
    images, intr, poses = _posed_frames(list(depths), intrinsics, world_from_cam)
    n = len(images)
    checked = [as_world_from_cam(p, f"pose {i}") for i, p in enumerate(poses)]
    m = OccupancyMap(config, **overrides)
    stats: list[IntegrationStats] = []
    for i in range(n):
        try:
            stats.append(m.integrate_depth(images[i], intr[i], checked[i]))
        except InputError as e:
            raise InputError(f"frame {i}: {e}") from None
        if progress is not None:
            progress(i + 1, n)
    m.last_build_stats = stats
    return m


def _posed_frames(
    depths: list[np.ndarray | DepthMap],
    intrinsics: Intrinsics | Sequence[Intrinsics] | None,
    world_from_cam: Sequence[Rigid3 | np.ndarray] | np.ndarray | None,
) -> tuple[list[np.ndarray], list[Intrinsics], list[Rigid3 | np.ndarray]]:
    """(depth images, cameras, world_from_cam poses), one each per frame, of the arguments of
    :func:`build_map_from_depth_frames` (poses not yet checked)."""
    n = len(depths)
    if n == 0:
        raise InputError("no depth frames to build a map from")
    maps = [d for d in depths if isinstance(d, DepthMap)]
    if len(maps) == n and world_from_cam is None:
        poses: list[Rigid3 | np.ndarray] = []
        for i, d in enumerate(maps):
            if d.cam_from_world is None:
                raise InputError(f"depth frame {i} has no camera pose")
            poses.append(d.cam_from_world.inverse().with_frames("world", "cam"))
        return [d.depth_m for d in maps], [d.intrinsics for d in maps], poses
    if world_from_cam is None:
        raise InputError("camera poses are required (world_from_cam, one per depth frame)")
    if isinstance(world_from_cam, np.ndarray) and world_from_cam.ndim != 3:
        raise InputError(
            f"poses array must have shape (N, 4, 4) or (N, 3, 4), got {np.shape(world_from_cam)}"
        )
    poses = list(world_from_cam)
    images = [d.depth_m if isinstance(d, DepthMap) else d for d in depths]
    if intrinsics is None:
        given = [d.intrinsics if isinstance(d, DepthMap) else None for d in depths]
        intr = [c for c in given if c is not None]
        if len(intr) != n:
            raise InputError("intrinsics are required for plain depth images")
    elif isinstance(intrinsics, Intrinsics):
        intr = [intrinsics] * n
    else:
        intr = list(intrinsics)
        if len(intr) != n:
            raise InputError(f"{len(intr)} intrinsics for {n} depth frames; give one camera or one per frame")
    if len(poses) != n:
        raise InputError(
            f"{len(poses)} poses for {n} depth frames; give exactly one world_from_cam pose per frame"
        )
    return images, intr, poses
