"""Replanning when the map changes."""

from __future__ import annotations

import numpy as np

from skyrecon.mapping import OccupancyMap
from skyrecon.planning import Planner, Replanner, remaining_path


def open_map() -> OccupancyMap:
    """A known, empty 30 x 20 x 12 m box (0.5 m voxels) with a floor."""
    occ = np.zeros((60, 40, 24), bool)
    occ[:, :, 0] = True
    return OccupancyMap.from_occupancy_grid(occ, np.array([0.0, 0.0, -0.5]), voxel_size_m=0.5)


def add_wall(m: OccupancyMap, x: float) -> None:
    """Observe a wall across the corridor at x (y 0..20 m, z 0..8 m) from a sensor in front of it."""
    yy, zz = np.meshgrid(np.arange(0.25, 20.0, 0.25), np.arange(0.25, 8.0, 0.25))
    pts = np.stack([np.full(yy.size, x), yy.ravel(), zz.ravel()], 1)
    for _ in range(4):  # a few hits turn free voxels occupied
        m.integrate_points(pts, np.array([x - 6.0, 10.0, 4.0]))


def test_replans_only_when_the_path_is_blocked():
    m = open_map()
    P = Planner(m, 1.0, min_z=1.0, max_z=11.0)
    goal = np.array([27.0, 10.0, 4.0])
    rp = Replanner(P, goal)
    first = rp.replan(np.array([2.0, 10.0, 4.0]))
    assert first.success and len(first.waypoints) == 2  # straight line

    # a change far from the path: nothing to re-check, nothing to replan
    m.integrate_points(np.array([[5.0, 18.5, 2.0]]), np.array([5.0, 12.0, 2.0]))
    d = rp.update(np.array([4.0, 10.0, 4.0]), m.pop_changed_blocks())
    assert d.clear and not d.replanned and not d.checked
    assert np.allclose(d.waypoints[0], [4.0, 10.0, 4.0]) and np.allclose(d.waypoints[-1], goal)

    # a wall appears across the path; it leaves a gap above it (z 8..11 m)
    add_wall(m, 15.0)
    d = rp.update(np.array([5.0, 10.0, 4.0]), m.pop_changed_blocks())
    assert d.checked and not d.clear and d.replanned and d.blocked_segment == 0
    assert d.result.success
    w = d.waypoints
    assert np.allclose(w[0], [5.0, 10.0, 4.0]) and np.allclose(w[-1], goal)
    ok, k = P.path_is_clear(w)
    assert ok and k == -1
    # the new path climbs over the wall
    samples = np.concatenate([a + (b - a) * np.linspace(0, 1, 50)[:, None] for a, b in zip(w[:-1], w[1:])])
    near_wall = samples[np.abs(samples[:, 0] - 15.0) < 0.5]
    assert near_wall[:, 2].min() > 8.0

    # nothing changed since: the remaining path stays as it is
    d2 = rp.update(np.array([6.0, 10.0, 4.5]), m.pop_changed_blocks())
    assert d2.clear and not d2.replanned


def test_replanning_reports_when_the_goal_is_cut_off():
    m = open_map()
    P = Planner(m, 1.0, min_z=1.0, max_z=8.0)  # no room above the wall now
    rp = Replanner(P, np.array([27.0, 10.0, 4.0]))
    assert rp.replan(np.array([2.0, 10.0, 4.0])).success
    add_wall(m, 15.0)
    d = rp.update(np.array([3.0, 10.0, 4.0]), m.pop_changed_blocks())
    assert d.replanned and not d.clear and not d.result.success
    assert d.result.reason in ("goal_enclosed", "start_enclosed")
    assert len(d.waypoints) == 0


def test_remaining_path():
    w = np.array([[0.0, 0, 0], [10, 0, 0], [10, 10, 0]])
    r = remaining_path(w, np.array([4.0, 0.5, 0.0]))
    assert np.allclose(r, [[4.0, 0.5, 0.0], [10, 0, 0], [10, 10, 0]])
    r = remaining_path(w, np.array([10.2, 3.0, 0.0]))
    assert np.allclose(r, [[10.2, 3.0, 0.0], [10, 10, 0]])


def test_incremental_grid_refresh_equals_a_fresh_grid():
    m = open_map()
    P = Planner(m, 1.0, min_z=1.0, max_z=11.0)
    P.plan(np.array([2.0, 10.0, 4.0]), np.array([27.0, 10.0, 4.0]))  # builds the grid
    add_wall(m, 15.0)
    P.update(m.pop_changed_blocks())
    fresh = Planner(m, 1.0, min_z=1.0, max_z=11.0)
    g1 = P.grid_for(np.array([2.0, 10.0, 4.0]), np.array([27.0, 10.0, 4.0]))
    g2 = fresh.grid_for(np.array([2.0, 10.0, 4.0]), np.array([27.0, 10.0, 4.0]))
    assert g1.version == P.df.version
    np.testing.assert_array_equal(g1.dist, g2.dist)
    np.testing.assert_array_equal(g1.flyable, g2.flyable)
    np.testing.assert_array_equal(g1.safe, g2.safe)
    np.testing.assert_array_equal(g1.level(3), g2.level(3))
