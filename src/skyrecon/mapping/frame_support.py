"""Multi-frame support: a voxel that several frames' untrusted depth puts a surface in.

Some depth is a guess rather than a measurement: a stereo matcher's value interpolated into a
plain wall, or smoothed over it. One such guess says little (it may be anywhere between the
wall's edges), and it says nothing about the space in front of it, so it may never carve free
space. But where the guesses of several frames, seen from different places, fall into the same
voxel, a surface there is likely. :class:`FrameSupport` counts, per voxel, the frames whose
guesses hit it; once ``min_frames`` frames have, each further guess is a hit (without rays) in
the map, unless the map already knows the voxel as free (trusted rays passed through it) or
(``next_to_occupied``) none of its neighbours is occupied.

Frames and units: depth (H, W) float32 metres along the camera's optical axis; poses
``world_from_cam`` (world frame, z up, metres); voxel indices ``floor(p / voxel_size)``.
"""

from __future__ import annotations

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError
from skyrecon.mapping.inputs import as_world_from_cam
from skyrecon.mapping.occupancy import OccupancyMap
from skyrecon.mapping.rays import camera_rays

_OFF = 1 << 20  # voxel indices within +-2^20 pack into 21 bits per axis
_NEIGHBOURS = np.array(
    [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if (i, j, k) != (0, 0, 0)],
    np.int64,
)


def _pack(vox: np.ndarray) -> np.ndarray:
    v = vox + _OFF
    return (v[:, 0] << 42) | (v[:, 1] << 21) | v[:, 2]


def _unpack(keys: np.ndarray) -> np.ndarray:
    m = (1 << 21) - 1
    return np.stack([(keys >> 42) & m, (keys >> 21) & m, keys & m], axis=1) - _OFF


class FrameSupport:
    """Counts, per voxel, the frames whose guessed depth hits it, and passes the supported hits
    on to a map.

    Args:
        occupancy: the map to update.
        min_frames: frames that must hit a voxel before its hits count (>= 2).
        max_range_m: guesses farther than this from the camera are ignored, metres.
        pixel_step: use every ``pixel_step``-th pixel of each row and column (the voxels are
            much larger than a pixel's footprint within the range).
        next_to_occupied: a supported voxel also needs an occupied neighbour (of its 26) in the
            map: guesses fill the holes of a surface that trusted depth has found and extend
            it, but do not start an obstacle in the air on their own.
    """

    def __init__(
        self,
        occupancy: OccupancyMap,
        min_frames: int,
        max_range_m: float,
        pixel_step: int = 3,
        next_to_occupied: bool = True,
    ):
        if int(min_frames) < 2:
            raise InputError(f"multi-frame support needs at least 2 frames, got {min_frames}")
        self.map = occupancy
        self.min_frames = int(min_frames)
        self.max_range_m = float(max_range_m)
        self.step = max(1, int(pixel_step))
        self.next_to_occupied = bool(next_to_occupied)
        self._keys = np.zeros(0, np.int64)  # sorted packed voxel indices
        self._frames = np.zeros(0, np.int32)  # frames that hit each

    def add(
        self,
        guess_depth_m: np.ndarray,
        intrinsics: Intrinsics,
        world_from_cam: Rigid3 | np.ndarray,
        strided: bool = False,
    ) -> int:
        """Count one frame's guesses and add the supported ones to the map as hits.

        Args:
            guess_depth_m: (H, W) float32 guessed depth, metres along the optical axis, NaN none.
            intrinsics: the depth camera.
            world_from_cam: its pose.
            strided: ``guess_depth_m`` holds only the pixels ``[::pixel_step, ::pixel_step]``.
        Returns:
            The number of voxels that got a hit.
        """
        pose = as_world_from_cam(world_from_cam)
        d = np.asarray(guess_depth_m)
        if not strided:
            d = d[:: self.step, :: self.step]
        dirs, lengths = camera_rays(intrinsics, self.step)
        with np.errstate(invalid="ignore"):
            ok = (d > 0) & (d * lengths <= self.max_range_m)  # NaN: False
        pc = dirs[ok] * d[ok, None]
        if len(pc) == 0:
            return 0
        vox = np.floor(pose.apply(pc) / self.map.voxel_size).astype(np.int64)
        keys = np.unique(_pack(vox))
        # count this frame once per voxel
        pos = np.searchsorted(self._keys, keys)
        pos_c = np.minimum(pos, max(len(self._keys) - 1, 0))
        known = (
            (pos < len(self._keys)) & (self._keys[pos_c] == keys)
            if len(self._keys)
            else np.zeros(len(keys), bool)
        )
        self._frames[pos[known]] += 1
        new = keys[~known]
        if len(new):
            self._keys = np.concatenate([self._keys, new])
            self._frames = np.concatenate([self._frames, np.ones(len(new), np.int32)])
            order = np.argsort(self._keys, kind="stable")
            self._keys, self._frames = self._keys[order], self._frames[order]
        count = self._frames[np.searchsorted(self._keys, keys)]
        supported = _unpack(keys[count >= self.min_frames])
        if len(supported) == 0:
            return 0
        # the map around them, as one dense box of log-odds (NaN unknown)
        lo = supported.min(axis=0) - 1
        shape = supported.max(axis=0) - lo + 2
        dense = self.map.dense_log_odds(lo, (int(shape[0]), int(shape[1]), int(shape[2])))
        with np.errstate(invalid="ignore"):
            occupied = dense >= self.map.config.log_odds[4]
        rel = supported - lo
        here = dense[rel[:, 0], rel[:, 1], rel[:, 2]]
        keep = np.isnan(here) | occupied[rel[:, 0], rel[:, 1], rel[:, 2]]  # not known free
        if self.next_to_occupied:
            near = np.zeros(len(supported), bool)
            for off in _NEIGHBOURS:
                q = rel + off
                near |= occupied[q[:, 0], q[:, 1], q[:, 2]]
            keep &= near
        return self.map.add_hits(supported[keep])
