"""Keep-out capsules: the planner avoids moving obstacles for one query, and the map's grid is restored."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.mapping import OccupancyMap
from skyrecon.planning import Planner, capsule_distance, path_conflict

V = 0.5


def open_map() -> OccupancyMap:
    """Known-free space 40 x 40 x 20 m with a floor voxel layer (so the map is not empty)."""
    shape = (80, 80, 40)
    occ = np.zeros(shape, bool)
    occ[:, :, 0] = True
    return OccupancyMap.from_occupancy_grid(occ, np.array([-20.0, -20.0, 0.0]), voxel_size_m=V)


def test_capsule_distance_matches_the_segment_geometry():
    caps = np.array([[0.0, 0.0, 0.0, 10.0, 0.0, 0.0, 1.0]])
    pts = np.array([[5.0, 3.0, 0.0], [-4.0, 0.0, 0.0], [13.0, 0.0, 4.0], [2.0, 0.5, 0.0]])
    d = capsule_distance(pts, caps)
    np.testing.assert_allclose(d, [2.0, 3.0, 5.0 - 1.0, -0.5])
    assert np.isinf(capsule_distance(pts, None)).all()
    with pytest.raises(InputError):
        capsule_distance(pts, np.array([[0, 0, 0, 1, 1, 1, np.nan]]))


def test_path_conflict_finds_the_first_blocked_sample():
    path = np.array([[0.0, 0.0, 10.0], [20.0, 0.0, 10.0]])
    caps = np.array([[8.0, -5.0, 10.0, 8.0, 5.0, 10.0, 0.5]])  # crosses the path at x = 8
    s = path_conflict(path, caps, 2.0, 0.25)
    assert 5.0 <= s <= 5.75  # 8 - 0.5 - 2.0 = 5.5
    assert np.isinf(path_conflict(path, caps[:, :] + [0, 0, 20, 0, 0, 20, 0], 2.0, 0.25))


def test_planner_detours_around_a_capsule_and_restores_the_grid():
    planner = Planner(open_map(), 2.0, min_z=5.0, max_z=15.0)
    s, g = np.array([-15.0, 0.0, 10.0]), np.array([15.0, 0.0, 10.0])
    straight = planner.plan(s, g)
    assert straight.success and len(straight.waypoints) == 2
    caps = np.array([[0.0, -8.0, 10.0, 0.0, 8.0, 10.0, 1.0]])  # a sweep across the way
    grid = planner.grid_for(s, g)
    dist_before = grid.dist.copy()
    with planner.avoiding(caps, s, g) as lowered:
        assert lowered > 0
        around = planner.plan(s, g)
    assert around.success and around.length_m > straight.length_m + 0.5
    pts = np.concatenate(
        [np.linspace(a, b, 200) for a, b in zip(around.waypoints[:-1], around.waypoints[1:])]
    )
    assert capsule_distance(pts, caps).min() >= 2.0 - 1e-6  # the clearance from the capsule's surface
    np.testing.assert_array_equal(grid.dist, dist_before)
    again = planner.plan(s, g)
    assert again.success and len(again.waypoints) == 2


def test_start_inside_a_capsule_can_escape():
    planner = Planner(open_map(), 2.0, min_z=5.0, max_z=15.0)
    p, g = np.array([0.0, 0.0, 10.0]), np.array([15.0, 0.0, 10.0])
    caps = np.array([[0.0, -6.0, 10.0, 0.0, 6.0, 10.0, 0.8]])
    with planner.avoiding(caps, p, g):
        r = planner.plan(p, g)
        assert not r.success and r.reason in ("start_too_close", "start_in_obstacle")
        esc = planner.nearest_clear_point(p, 5.0, toward=g)
    assert esc is not None and capsule_distance(esc[None], caps)[0] >= planner.threshold


def test_keep_out_matches_a_grid_rebuilt_with_the_capsules_and_restores_every_level():
    """Inside the block the grid (distances, flyable voxels, safe cells and every search level)
    equals one recomputed from scratch with the capsules' distances; on exit all is restored."""
    from skyrecon.planning._los import lattice, safe_cells

    planner = Planner(open_map(), 2.0, min_z=5.0, max_z=15.0)
    s, g = np.array([-15.0, 0.0, 10.0]), np.array([15.0, 0.0, 10.0])
    grid = planner.grid_for(s, g)
    for f in planner.levels:
        grid.level(f)
    before = {f: a.copy() for f, a in grid._levels.items()}
    dist_before, fly_before = grid.dist.copy(), grid.flyable.copy()
    # two overlapping capsules, one a sphere, one slanted, reaching out of the altitude band
    caps = np.array([[1.3, -7.9, 9.2, -2.6, 6.1, 13.7, 1.2], [3.0, 2.0, 6.0, 3.0, 2.0, 6.0, 2.5]])
    ijk = np.stack(np.meshgrid(*[np.arange(n) for n in grid.shape], indexing="ij"), -1).reshape(-1, 3)
    centres = grid.origin + (ijk + 0.5) * grid.voxel
    want_dist = np.minimum(
        dist_before, capsule_distance(centres, caps).reshape(grid.shape).astype(np.float32)
    )
    zc = centres[:, 2].reshape(grid.shape)
    want_fly = ((want_dist >= grid.threshold) & (zc >= 5.0) & (zc <= 15.0)).astype(np.uint8)
    want_safe = safe_cells(want_fly)
    with planner.avoiding(caps, s, g) as lowered:
        assert lowered >= int(np.count_nonzero(want_dist < dist_before)) > 0  # overlaps count twice
        np.testing.assert_array_equal(grid.dist, want_dist)
        np.testing.assert_array_equal(grid.flyable, want_fly)
        np.testing.assert_array_equal(grid.safe, want_safe)
        for f in before:
            np.testing.assert_array_equal(grid.level(f), lattice(want_safe, f))
    np.testing.assert_array_equal(grid.dist, dist_before)
    np.testing.assert_array_equal(grid.flyable, fly_before)
    for f, a in before.items():
        np.testing.assert_array_equal(grid.level(f), a)


def test_a_negative_radius_keeps_less_than_the_clearance_from_the_capsule():
    caps = np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -0.5]])
    d = capsule_distance(np.array([[2.0, 0.0, 0.0]]), caps)
    np.testing.assert_allclose(d, [2.5])  # a planner needing 2.5 m may pass 2 m from it
