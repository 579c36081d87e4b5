"""Planner: optimality on known maps, safety against true geometry, failures with reasons, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from skyrecon.errors import InputError
from skyrecon.mapping import DistanceField, OccupancyMap
from skyrecon.planning import Planner, plan_path

V = 0.25


def wall_map(y_half: float = 4.0) -> OccupancyMap:
    """Open space 24 x 24 x 12 m with a thin wall x in [-0.25, 0.25], |y| <= y_half, z in [0, 12]."""
    shape = (96, 96, 48)
    origin = np.array([-12.0, -12.0, 0.0])
    occ = np.zeros(shape, bool)
    x = origin[0] + (np.arange(shape[0]) + 0.5) * V
    y = origin[1] + (np.arange(shape[1]) + 0.5) * V
    occ[np.ix_(np.abs(x) < 0.25, np.abs(y) < y_half, np.ones(shape[2], bool))] = True
    return OccupancyMap.from_occupancy_grid(occ, origin, voxel_size_m=V)


def shortest_around(centres_xy: np.ndarray, r: float, s: np.ndarray, g: np.ndarray) -> float:
    """2-D shortest path from s to g around the convex set (hull of centres_xy) inflated by r."""
    a = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    disk = r * np.stack([np.cos(a), np.sin(a)], 1)
    body = (centres_xy[:, None, :] + disk[None]).reshape(-1, 2)
    pts = np.vstack([body, s[None], g[None]])
    hull = pts[ConvexHull(pts).vertices]
    i = int(np.argmin(np.linalg.norm(hull - s, axis=1)))
    j = int(np.argmin(np.linalg.norm(hull - g, axis=1)))
    seg = np.linalg.norm(np.diff(np.vstack([hull, hull[:1]]), axis=0), axis=1)
    k = len(hull)
    one = sum(seg[(i + t) % k] for t in range((j - i) % k))
    return float(min(one, seg.sum() - one))


def test_path_around_a_wall_is_near_the_analytic_shortest():
    m = wall_map()
    clearance = 1.0
    P = Planner(m, clearance, min_z=2.0, max_z=8.0)
    s, g = np.array([-8.0, 0.3, 5.0]), np.array([8.0, -0.4, 5.0])
    r = P.plan(s, g)
    assert r.success, r.message
    # the distance field sees the occupied voxel centres; the planner keeps clearance + margin from them
    cx = np.array([-0.125, 0.125])
    cy = np.arange(-4.0 + 0.125, 4.0, 0.25)
    centres = np.stack(np.meshgrid(cx, cy, indexing="ij"), -1).reshape(-1, 2)
    best = shortest_around(centres, clearance + r.margin_m, s[:2], g[:2])
    best = np.hypot(best, g[2] - s[2])
    assert 0.995 * best <= r.length_m <= 1.02 * best
    assert r.min_distance_m >= clearance + r.margin_m - 1e-6
    assert np.allclose(r.waypoints[0], s) and np.allclose(r.waypoints[-1], g)


def test_an_inflated_heuristic_searches_less_and_stays_within_its_bound():
    """Weighted A* (the delivery loop's planner, weight 1.2): fewer expansions than the optimal
    search (0.63x around this wall; 0.03x around a mover's keep-out in flight), a path at most
    that factor longer, and the same clearance."""
    m = wall_map(y_half=3.0)
    s, g = np.array([-8.0, 0.3, 5.0]), np.array([8.0, -0.4, 5.0])
    best = Planner(m, 1.0, min_z=2.0, max_z=8.0, levels=(1,)).plan(s, g)
    fast = Planner(m, 1.0, min_z=2.0, max_z=8.0, levels=(1,), heuristic_weight=1.2).plan(s, g)
    assert best.success and fast.success
    assert fast.expansions < 0.8 * best.expansions
    assert best.length_m - 1e-9 <= fast.length_m <= 1.2 * best.length_m
    assert fast.min_distance_m >= 1.0 + fast.margin_m - 1e-6
    with pytest.raises(InputError):
        Planner(m, 1.0, heuristic_weight=0.9)


def test_straight_line_when_nothing_is_in_the_way():
    m = wall_map()
    r = plan_path(m, [-8.0, 8.0, 5.0], [8.0, 9.0, 6.0], clearance_m=1.0)
    assert r.success and len(r.waypoints) == 2
    assert r.length_m == pytest.approx(np.linalg.norm([16.0, 1.0, 1.0]))


def test_no_collisions_with_the_true_city(small_city):
    v = 0.5
    origin = np.array([-30.0, -30.0, -1.0])
    shape = (120, 120, 62)
    occ = small_city.occupancy_grid(origin, v, shape, include_ground=True)
    m = OccupancyMap.from_occupancy_grid(occ, origin, voxel_size_m=v)
    clearance = 1.5
    P = Planner(m, clearance, min_z=1.0, max_z=28.0)
    rng = np.random.default_rng(4)
    pts = rng.uniform([-28, -28, 2], [28, 28, 25], size=(400, 3))
    pts = pts[small_city.distance(pts, include_ground=True) > clearance + 1.0]
    n_ok = 0
    for s, g in zip(pts[0:24:2], pts[1:24:2]):
        r = P.plan(s, g)
        if not r.success:
            assert r.reason in ("start_enclosed", "goal_enclosed", "start_too_close", "goal_too_close")
            continue
        n_ok += 1
        w = r.waypoints
        samples = np.concatenate(
            [
                a + (b - a) * np.linspace(0, 1, max(2, int(np.linalg.norm(b - a) / 0.05)))[:, None]
                for a, b in zip(w[:-1], w[1:])
            ]
        )
        true = small_city.distance(samples, include_ground=True)
        assert true.min() >= clearance - 1e-6, (
            f"path from {s} to {g} comes {true.min():.3f} m from an obstacle"
        )
        assert np.all((samples[:, 2] >= 1.0 - 1e-9) & (samples[:, 2] <= 28.0 + 1e-9))
    assert n_ok >= 8


def box_room_map() -> OccupancyMap:
    """A 20 m cube of free space (0.25 m voxels) holding a pillar (x, y in [2, 3] m, all z) and a
    closed hollow box, walls [12.5, 13.25] and [16.75, 17.5] m on each axis, free inside."""
    shape = (80, 80, 80)
    occ = np.zeros(shape, bool)
    occ[50:70, 50:70, 30:50] = True
    occ[53:67, 53:67, 33:47] = False
    occ[8:12, 8:12, :] = True
    return OccupancyMap.from_occupancy_grid(occ, np.zeros(3), voxel_size_m=V)


@pytest.mark.parametrize(
    "start, goal, reason",
    [
        ([6.0, 6.0, 5.0], [15.0, 15.0, 10.0], "goal_enclosed"),  # goal inside the closed room
        ([15.0, 15.0, 10.0], [6.0, 6.0, 5.0], "start_enclosed"),
        ([6.0, 6.0, 5.0], [12.8, 15.0, 10.0], "goal_in_obstacle"),  # in the room's wall
        ([2.5, 2.5, 10.0], [6.0, 6.0, 5.0], "start_in_obstacle"),  # in the pillar
        ([6.0, 6.0, 5.0], [3.3, 2.5, 10.0], "goal_too_close"),  # 0.3 m from the pillar
        ([6.0, 6.0, 0.5], [6.0, 9.0, 10.0], "start_altitude"),
    ],
)
def test_failures_say_why(start, goal, reason):
    m = box_room_map()
    P = Planner(m, 1.0, min_z=1.0)
    r = P.plan(np.array(start), np.array(goal))
    assert not r.success and r.reason == reason, (r.reason, r.message)
    assert r.message and len(r.waypoints) == 0 and np.isinf(r.length_m)


def test_unknown_space_is_not_flyable_unless_allowed():
    known = np.ones((60, 60, 40), bool)
    known[25:35, :, :] = False  # an unexplored slab across the whole map
    m = OccupancyMap.from_occupancy_grid(np.zeros_like(known), np.zeros(3), known=known, voxel_size_m=V)
    s, g = np.array([2.0, 7.0, 5.0]), np.array([13.0, 7.0, 5.0])
    r = Planner(m, 0.5).plan(s, g)
    assert not r.success and r.reason == "start_enclosed"
    r = Planner(m, 0.5).plan(np.array([7.5, 7.0, 5.0]), g)
    assert r.reason == "start_unknown"
    r = Planner(m, 0.5, allow_unknown=True).plan(s, g)
    assert r.success and r.length_m == pytest.approx(11.0)


def test_bad_inputs_raise_input_error():
    m = wall_map()
    P = Planner(m, 1.0)
    with pytest.raises(InputError, match="outside the map"):
        P.plan([-8.0, 0.0, 5.0], [80.0, 0.0, 5.0])
    with pytest.raises(InputError, match="outside the map"):
        P.plan([-8.0, 0.0, -30.0], [8.0, 0.0, 5.0])
    with pytest.raises(InputError, match="NaN"):
        P.plan([np.nan, 0.0, 5.0], [8.0, 0.0, 5.0])
    with pytest.raises(InputError, match="3 coordinates"):
        P.plan([1.0, 2.0], [8.0, 0.0, 5.0])
    with pytest.raises(InputError, match="clearance"):
        Planner(m, -1.0)
    with pytest.raises(InputError, match="min_z < max_z"):
        Planner(m, 1.0, min_z=5.0, max_z=2.0)
    with pytest.raises(InputError, match="clipped"):
        Planner(DistanceField(m, 0.5), 1.0)
    with pytest.raises(InputError, match="empty"):
        Planner(OccupancyMap(), 1.0)


def test_paths_on_a_map_built_from_depth_avoid_the_true_city(small_city, city_depth_map):
    m = city_depth_map
    clearance = 1.0
    P = Planner(m, clearance, min_z=1.0)
    # candidate endpoints: known free voxel centres well inside the explored space
    lo, hi = m.voxel_bounds()
    rng = np.random.default_rng(7)
    cand = (rng.integers(lo, hi, size=(4000, 3)) + 0.5) * m.voxel_size
    d = P.df.query_distance(cand)
    cand = cand[(d >= clearance + P.margin + 1.0) & (cand[:, 2] > 2.0)]
    assert len(cand) >= 10
    n_ok = 0
    for s, g in zip(cand[0:20:2], cand[1:20:2]):
        r = P.plan(s, g)
        if not r.success:
            assert r.reason in ("start_enclosed", "goal_enclosed")
            continue
        n_ok += 1
        w = r.waypoints
        samples = np.concatenate(
            [
                a + (b - a) * np.linspace(0, 1, max(2, int(np.linalg.norm(b - a) / 0.05)))[:, None]
                for a, b in zip(w[:-1], w[1:])
            ]
        )
        assert small_city.distance(samples, include_ground=True).min() > clearance - 1e-6
        assert np.all(m.state_at(samples) == 0)  # never through unknown or occupied voxels
    assert n_ok >= 3


def test_plan_path_reuses_the_planner():
    m = wall_map()
    r1 = plan_path(m, [-8.0, 0.3, 5.0], [8.0, -0.4, 5.0], clearance_m=1.0, min_z=2.0, max_z=8.0)
    r2 = plan_path(m, [-8.0, 0.3, 5.0], [8.0, -0.4, 5.0], clearance_m=1.0, min_z=2.0, max_z=8.0)
    assert r1.success and r2.success and r1.length_m == pytest.approx(r2.length_m)
    assert r2.timings["grid"] < 0.5 * max(r1.timings["grid"], 1e-3) or r2.timings["grid"] < 0.01
