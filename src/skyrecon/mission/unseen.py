"""Unseen spots: space on or beside the path that the cameras cannot observe from where the drone waits.

The drone only flies through space it has seen free (see :mod:`skyrecon.mission.navigator`):
when the path ahead, or the tube ``verify_radius_m`` beside and below it, holds a voxel that is
still unknown, the drone stops short of it and scans around it
(:func:`~skyrecon.mission.guidance.scan_look_at`). Some voxels stay unknown whatever it does.
The map carves a voxel free when the depth at the one pixel its centre projects to lies beyond
it; a voxel a metre or two ahead whose centre projects onto a plain surface far behind it (plain
ground under noise, a plain facade reaching out of the image) gets no depth there from any pose
of the scan, while all its neighbours are carved through measured pixels: held-out missions
waited 12-31 s in front of such a voxel until the no-progress failsafe sent them home (textured
city seed 10 beside a plain facade, plain city seeds 11 and 13 over plain ground).

Counting such a voxel as free would fly the drone through space nobody saw. Instead, after
:data:`UNSEEN_AFTER_S` held still by it (a whole scan), the unknown voxels there, with the unknown
voxels connected to them within :data:`POCKET_REACH_VOXELS`, become *unseen spots*: the planner
keeps clear of them (:mod:`skyrecon.planning.keep_out` capsules written into the planning grid
for each query, never into the map), so the next path goes round what the cameras cannot see.
It keeps ``drone_radius_m + safety_margin_m`` from each spot's voxel (from its centre, that plus
the voxel's half diagonal): were a thing hidden in the voxel, the drone would pass it with the
safety margin, and the tube the path is verified over (``verify_radius_m``, 1 m) stays out of
the spot. That is less than the planner's clearance from what is mapped (2.43 m by default):
a spot is space nobody has seen, not a thing known to be there, and two metres from the goal
(held-out plain seed 11) a full clearance from it left no way to the goal. A spot is forgotten
as soon as the map knows its voxel (free or occupied). When no path goes round the spots, they
are dropped again and the drone keeps its path and waits, as it did without them.

Frames and units: world frame (z up), metres; voxel indices as
:meth:`~skyrecon.mapping.OccupancyMap.voxel_index`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from skyrecon.mapping import OccupancyMap

#: Seconds held still by the same unobserved space before it becomes unseen spots: one second
#: before the scan begins and one whole scan (:func:`~skyrecon.mission.guidance.scan_look_at`
#: looks six ways, a second each).
UNSEEN_AFTER_S = 7.0
#: The unknown voxels connected (faces) to an unobserved probe's voxel within this many voxels of
#: it become spots with it: the same blind patch of a view is seldom one voxel, and taking one
#: voxel at a time would cost a scan for each.
POCKET_REACH_VOXELS = 3
#: At most this many spots are added at once (the nearest to the probes first).
MAX_NEW_SPOTS = 96


def unknown(log_odds: np.ndarray, observed_free_below: float) -> np.ndarray:
    """Whether voxels of ``log_odds`` (any shape, NaN never observed) are unknown to the drone:
    never observed, or free only by a prior map and not yet seen free by this flight's cameras
    (``observed_free_below``, see :mod:`skyrecon.mission.prior`) and not occupied."""
    lo = np.asarray(log_odds)
    with np.errstate(invalid="ignore"):
        return ~((lo < observed_free_below) | (lo >= 0.0))


def unknown_pocket(
    occ_map: OccupancyMap,
    points: np.ndarray,
    observed_free_below: float,
    reach_voxels: int = POCKET_REACH_VOXELS,
) -> np.ndarray:
    """The unknown voxels holding ``points`` (N, 3) world metres and those connected to them by
    faces through unknown voxels, within ``reach_voxels`` (per axis) of the points.

    Returns:
        (K, 3) int64 voxel indices, sorted by distance from the nearest point's voxel; (0, 3)
        when no point lies in an unknown voxel.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:
        return np.zeros((0, 3), np.int64)
    seeds = np.unique(occ_map.voxel_index(pts), axis=0)
    seeds = seeds[unknown(occ_map.log_odds_at(occ_map.voxel_center(seeds)), observed_free_below)]
    if len(seeds) == 0:
        return np.zeros((0, 3), np.int64)
    r = int(reach_voxels)
    lo = seeds.min(axis=0) - r
    ext = seeds.max(axis=0) + r + 1 - lo
    shape = (int(ext[0]), int(ext[1]), int(ext[2]))
    box = unknown(occ_map.dense_log_odds(lo, shape), observed_free_below)
    near = np.zeros(shape, bool)  # within reach of some seed (per axis)
    for s in seeds - lo:
        near[s[0] - r : s[0] + r + 1, s[1] - r : s[1] + r + 1, s[2] - r : s[2] + r + 1] = True
    labels, _ = ndimage.label(box & near)  # face connectivity
    keep = np.unique(labels[tuple((seeds - lo).T)])
    idx = np.argwhere(np.isin(labels, keep[keep > 0])) + lo
    d = np.min(np.abs(idx[:, None, :] - seeds[None, :, :]).sum(axis=2), axis=1)
    return idx[np.argsort(d, kind="stable")]


class UnseenSpots:
    """The unseen spots of one mission (see the module docstring): voxel indices the planner
    keeps clear of until the map knows them.

    Args:
        voxel_size_m: the map's voxel edge, metres.
        keep_m: how far paths keep from a spot's voxel (from its surface, taken as the sphere
            round the voxel), metres.
    """

    def __init__(self, voxel_size_m: float, keep_m: float):
        self.voxel_size_m = float(voxel_size_m)
        self.keep_m = float(keep_m)
        self.index = np.zeros((0, 3), np.int64)
        self._before = self.index

    def __len__(self) -> int:
        return len(self.index)

    @property
    def radius_m(self) -> float:
        """A spot's voxel's half diagonal, metres."""
        return 0.5 * math.sqrt(3.0) * self.voxel_size_m

    def centres(self) -> np.ndarray:
        """(K, 3) world centres of the spots, metres."""
        return (self.index.astype(np.float64) + 0.5) * self.voxel_size_m

    def capsules(self, threshold_m: float) -> np.ndarray:
        """(K, 7) keep-out capsules (:mod:`skyrecon.planning.keep_out`) for a planner that keeps
        ``threshold_m`` (its clearance plus margin) from every capsule: one point capsule per
        spot, whose radius makes the planner keep :attr:`keep_m` from the spot's sphere (it is
        negative when that is less than the threshold)."""
        c = self.centres()
        return np.hstack([c, c, np.full((len(c), 1), self.radius_m + self.keep_m - threshold_m)])

    def add(self, index: np.ndarray) -> int:
        """Add voxel indices (K, 3) (at most :data:`MAX_NEW_SPOTS`, the first ones); returns how
        many were new. :meth:`undo` takes back the last call."""
        new = np.asarray(index, dtype=np.int64).reshape(-1, 3)[:MAX_NEW_SPOTS]
        self._before = self.index
        if len(new) == 0:
            return 0
        merged = np.unique(np.vstack([self.index, new]), axis=0)
        added = len(merged) - len(self.index)
        self.index = merged
        return added

    def undo(self) -> None:
        """Take back the spots of the last :meth:`add`."""
        self.index = self._before

    def forget_known(self, occ_map: OccupancyMap, observed_free_below: float) -> int:
        """Drop the spots whose voxel the map now knows (seen free, or occupied: then the map
        keeps the drone clear of it); returns how many were dropped."""
        if len(self.index) == 0:
            return 0
        still = unknown(occ_map.log_odds_at(self.centres()), observed_free_below)
        dropped = int(np.count_nonzero(~still))
        if dropped:
            self.index = self.index[still]
            self._before = self.index
        return dropped
