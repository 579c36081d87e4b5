"""Change tracking of the occupancy map: ``pop_changed_blocks`` for every state change and for
changes of the occupied voxels only."""

from __future__ import annotations

import numpy as np

from skyrecon.core import Intrinsics, Rigid3
from skyrecon.mapping import OccupancyMap, load_map, save_map

CAM = Intrinsics.from_fov(64, 48, 60.0)
POSE = (
    Rigid3.look_at(np.array([0.05, 0.05, 0.05]), np.array([10.05, 0.05, 0.05]))
    .inverse()
    .with_frames("world", "cam")
)


def wall(d: float) -> np.ndarray:
    """(48, 64) depth of a wall perpendicular to the optical axis, d metres ahead (inf: open sky)."""
    return np.full((CAM.height, CAM.width), d, np.float32)


def as_set(blocks: np.ndarray) -> set:
    return {tuple(b) for b in np.asarray(blocks).tolist()}


def occupied_blocks(m: OccupancyMap) -> set:
    return as_set(np.floor_divide(m.occupied_voxels(), m.block_size))


def test_occupied_only_reports_blocks_whose_occupied_voxels_change():
    m = OccupancyMap(voxel_size_m=0.25, max_range_m=30.0)
    m.integrate_depth(wall(np.inf), CAM, POSE)  # open sky: free space only
    every = m.pop_changed_blocks()
    assert every.dtype == np.int32 and every.ndim == 2 and every.shape[1] == 3 and len(every) > 0
    assert len(m.pop_changed_blocks(occupied_only=True)) == 0

    m.integrate_depth(wall(10.0), CAM, POSE)  # a wall appears
    peek_all, peek_occ = m.changed_blocks(), m.changed_blocks(occupied_only=True)
    occ = m.pop_changed_blocks(occupied_only=True)
    assert as_set(occ) == as_set(peek_occ) == occupied_blocks(m) and len(occ) > 0
    assert as_set(occ) <= as_set(peek_all)
    assert len(m.changed_blocks(occupied_only=True)) == 0  # popped...
    assert as_set(m.pop_changed_blocks()) == as_set(peek_all)  # ...independently of the other record

    m.integrate_depth(wall(10.0), CAM, POSE)  # seen again: nothing new
    assert len(m.pop_changed_blocks(occupied_only=True)) == 0

    before = occupied_blocks(m)
    for _ in range(12):  # the wall moves back: its old voxels are carved free
        m.integrate_depth(wall(14.0), CAM, POSE)
    assert before & occupied_blocks(m) == set()
    changed = as_set(m.pop_changed_blocks(occupied_only=True))
    assert before <= changed and occupied_blocks(m) <= changed


def test_point_clouds_and_dense_grids_record_occupied_changes():
    m = OccupancyMap(voxel_size_m=0.5)
    m.integrate_points(np.array([[5.25, 0.25, 0.25]]), np.array([0.25, 0.25, 0.25]))
    assert as_set(m.pop_changed_blocks(occupied_only=True)) == {(1, 0, 0)}  # 8 voxels per block
    assert (0, 0, 0) in as_set(m.pop_changed_blocks())  # the free voxels along the ray

    occ = np.zeros((16, 8, 8), bool)
    occ[12, 2, 2] = True
    g = OccupancyMap.from_occupancy_grid(occ, np.zeros(3), voxel_size_m=0.5)
    assert as_set(g.pop_changed_blocks()) == {(0, 0, 0), (1, 0, 0)}
    assert as_set(g.pop_changed_blocks(occupied_only=True)) == {(1, 0, 0)}


def test_a_loaded_map_reports_every_block(tmp_path):
    m = OccupancyMap(voxel_size_m=0.25, max_range_m=30.0)
    m.integrate_depth(wall(10.0), CAM, POSE)
    save_map(m, tmp_path / "m")
    n = m.counts()["blocks"]
    back = load_map(tmp_path / "m")
    assert len(back.pop_changed_blocks()) == n and len(back.pop_changed_blocks(occupied_only=True)) == n
    assert len(back.pop_changed_blocks()) == 0 and len(back.pop_changed_blocks(occupied_only=True)) == 0
