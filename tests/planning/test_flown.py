"""Plans from where the vehicle has been: snapping endpoints, retracing the flown track."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.mapping import FREE, UNKNOWN, MapConfig, OccupancyMap
from skyrecon.planning import Planner, plan_with_flown_path, route_along_track


def _corridor_map() -> tuple[OccupancyMap, np.ndarray]:
    """A 40 x 12 x 12 m box, unknown except a known-free slab 3..9 m high (where paths can keep
    2 m from unknown space), and a flown track below it, at 1.5 m, that only the track marks free."""
    shape = (80, 24, 24)
    known = np.zeros(shape, bool)
    known[:, :, 6:18] = True  # z 3..9 m
    cfg = MapConfig(voxel_size_m=0.5, max_range_m=30.0)
    occ = OccupancyMap.from_occupancy_grid(np.zeros(shape, bool), np.zeros(3), cfg, known=known)
    track = np.array([[2.0, 6.0, 1.5], [20.0, 6.0, 1.5], [38.0, 6.0, 1.5]])
    occ.mark_flown_free(track, 0.35)
    return occ, track


def test_mark_flown_free_sets_the_swept_voxels_free_and_reports_the_change():
    occ = OccupancyMap(voxel_size_m=0.5)
    hit = np.array([[5.25, 0.25, 1.25]])
    occ.integrate_points(np.repeat(hit, 20, axis=0), np.array([0.25, 0.25, 1.25]))
    assert occ.state_at(hit)[0] == 1
    occ.pop_changed_blocks()
    occ.pop_changed_blocks(occupied_only=True)
    n = occ.mark_flown_free(np.array([[0.0, 0.2, 1.2], [10.0, 0.2, 1.2]]), 0.3)
    assert n > 0
    along = np.stack([np.linspace(0.2, 9.8, 40), np.full(40, 0.2), np.full(40, 1.2)], 1)
    assert np.all(occ.state_at(along) == FREE) and occ.state_at(hit)[0] == FREE  # the body was there
    assert occ.state_at(np.array([[5.0, 3.0, 1.2]]))[0] == UNKNOWN  # out of reach stays unknown
    assert len(occ.pop_changed_blocks(occupied_only=True)) >= 1  # the distance field must hear of it
    with pytest.raises(Exception, match="radius"):
        occ.mark_flown_free(along, -1.0)


def test_a_survey_long_track_is_swept_in_chunks_with_the_same_voxels():
    """Kilometres of track (many chunks of samples): the voxels set are exactly those within
    reach of the track's samples, as if all were proposed at once, and all of them read free."""
    from skyrecon.mapping.occupancy import _polyline_samples

    occ = OccupancyMap(voxel_size_m=0.5)
    track = np.array([[0.0, 0.0, 20.0], [600.0, 0.0, 20.0], [600.0, 40.0, 22.0], [0.0, 40.0, 20.0]])
    n = occ.mark_flown_free(track, 0.3)
    v, reach = 0.5, 0.3 + 0.25
    samples = _polyline_samples(track, 0.25 * v)
    k = int(np.ceil(reach / v)) + 1
    r = np.arange(-k, k + 1)
    offs = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
    assert len(samples) > 2 * 1_000_000 // len(offs)  # several chunks
    cand = (np.floor(samples / v).astype(np.int64)[:, None, :] + offs[None]).reshape(-1, 3)
    near = np.linalg.norm((cand + 0.5) * v - np.repeat(samples, len(offs), axis=0), axis=1)
    want = np.unique(cand[near <= reach + 0.125 * v], axis=0)
    assert n == len(want)
    assert np.all(occ.state_at((want + 0.5) * v) == FREE)


def test_an_unknown_start_snaps_to_the_nearest_usable_point_and_says_so():
    occ, track = _corridor_map()
    planner = Planner(occ, 2.0)
    start, goal = np.array([2.0, 9.0, 1.5]), track[-1] + [0, 0, 4.5]
    assert planner.plan(start, goal).reason == "start_unknown"
    assert planner.plan(track[0], goal).reason == "start_too_close"  # flown, but 2 m from unknown space
    r = planner.plan(start, goal, snap_radius_m=6.0)
    assert r.success and r.adjusted["start"]["reason"] == "start_unknown"
    assert np.allclose(r.waypoints[0], start) and np.allclose(r.waypoints[1], r.adjusted["start"]["to"])
    assert 0 < r.adjusted["start"]["distance_m"] <= 6.0
    assert not planner.plan(start, goal, snap_radius_m=1.0).success  # nothing usable that near


def test_route_along_track_goes_either_way():
    track = np.array([[0.0, 0, 0], [10, 0, 0], [10, 10, 0]])
    fwd = route_along_track(track, np.array([1.0, 0.5, 0]), np.array([10.5, 8, 0]), 1.0)
    assert fwd is not None and np.allclose(fwd[[0, -1]], [[1, 0.5, 0], [10.5, 8, 0]])
    assert any(np.allclose(p, [10, 0, 0]) for p in fwd)  # around the corner, as flown
    back = route_along_track(track, np.array([10.5, 8, 0]), np.array([1.0, 0.5, 0]), 1.0)
    assert np.allclose(back, fwd[::-1])
    assert route_along_track(track, np.array([5.0, 5.0, 0]), np.array([1.0, 0, 0]), 1.0) is None


def test_no_path_at_the_clearance_retraces_the_flown_track():
    occ, track = _corridor_map()
    r = plan_with_flown_path(occ, track[0], track[-1], 2.0, track, snap_radius_m=1.0)
    assert r.success and r.adjusted["route"] == "flown_path"
    assert np.allclose(r.waypoints, track)
    without = plan_with_flown_path(occ, track[0], track[-1], 2.0, None, snap_radius_m=1.0)
    assert not without.success
