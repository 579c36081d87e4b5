"""Prior maps from an earlier flight: weak beliefs, stale changes noticed, bad priors refused."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Intrinsics, Rigid3
from skyrecon.errors import InputError
from skyrecon.mapping import FREE, OCCUPIED, MapConfig, OccupancyMap
from skyrecon.mission.changes import city_changes
from skyrecon.mission.navigator import Navigator
from skyrecon.mission.prior import OBSERVED_FREE_LOG_ODDS, load_prior_map, prior_changes, prior_from_city
from skyrecon.mission.scenario import make_scenario
from skyrecon.sim import render


@pytest.fixture(scope="module")
def changed(tiny_config):
    cfg = tiny_config.with_overrides(city_changes=True)
    return cfg, make_scenario(5, cfg)


def _look_at(city, target: np.ndarray, frm: np.ndarray):
    """A 160x120 camera at ``frm`` looking at ``target`` and its depth."""
    cam = Intrinsics.from_fov(160, 120, 90.0)
    f = target - frm
    f /= np.linalg.norm(f)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    R = np.stack([r, d, f])  # rows: camera x (right), y (down), z (forward) in world
    cam_from_world = Rigid3(R, -R @ frm)
    return cam, cam_from_world, render(city, cam, cam_from_world).depth_m


def test_changes_are_deterministic_and_keep_the_mission_feasible(changed, tiny_config):
    cfg, sc = changed
    kinds = sorted(c.kind for c in sc.changes)
    assert kinds == ["added", "removed"]
    again = make_scenario(5, cfg)
    assert [c.to_dict() for c in again.changes] == [c.to_dict() for c in sc.changes]
    assert sc.shortest.success
    added = next(c for c in sc.changes if c.kind == "added")
    centre = np.array([[(added.box[0] + added.box[3]) / 2, (added.box[1] + added.box[4]) / 2, 15.0]])
    assert sc.city.distance(centre)[0] < 0 < sc.prior_city.distance(centre)[0]  # there today only
    d = sc.city.distance(np.stack([sc.start, sc.goal]), include_ground=True)
    assert np.all(d >= cfg.endpoint_clearance_m)


def test_prior_seeds_weak_beliefs_that_the_cameras_overturn(changed):
    cfg, sc = changed
    prior = prior_from_city(sc.prior_city, cfg, sc.box)
    nav = Navigator(cfg, sc.box, sc.goal, prior=prior)
    added = np.array(next(c for c in sc.changes if c.kind == "added").box)
    removed = np.array(next(c for c in sc.changes if c.kind == "removed").box)
    a_c = np.array([(added[0] + added[3]) / 2, (added[1] + added[4]) / 2, 15.0])
    r_c = np.array([(removed[0] + removed[3]) / 2, (removed[1] + removed[4]) / 2, 15.0])
    assert nav.map.state_at(a_c[None])[0] == FREE and nav.map.state_at(r_c[None])[0] == OCCUPIED
    # the prior plans, but does not count as seen: nothing ahead is verified before the cameras look
    path = np.stack([a_c + [12.0, 0, 0], a_c + [30.0, 0, 0]])
    assert nav.verified_distance(path, 9.0, 1.5) == 1.5
    # the new tower, seen once from 12 m, is in the map at the next frame
    frm = a_c + np.array([12.0, 0.5, 0.0])
    cam, cfw, depth = _look_at(sc.city, a_c, frm)
    nav.integrate(depth, cam, cfw)
    face = np.array([added[3] + 0.1, (added[1] + added[4]) / 2, 15.0])
    assert nav.map.state_at(face[None])[0] == OCCUPIED
    # the container stack is gone: the first frame that sees through where it stood frees it
    # (yesterday's belief, not yet measured today: MapConfig.stale_log_odds), and counts as seen
    frm = r_c + np.array([0.0, 0.0, 8.0]) + 10.0 * np.array([1.0, 0.3, 0.0])
    cam, cfw, depth = _look_at(sc.city, r_c - [0, 0, 8.0], frm)
    nav.integrate(depth, cam, cfw)
    assert nav.map.state_at(r_c[None])[0] == FREE
    assert nav.map.log_odds_at(r_c[None])[0] <= OBSERVED_FREE_LOG_ODDS
    # and stays free as the drone looks on
    for k in range(1, 5):
        cam, cfw, depth = _look_at(sc.city, r_c - [0, 0, 8.0], frm + [0, 0.1 * k, 0])
        nav.integrate(depth, cam, cfw)
    assert nav.map.state_at(r_c[None])[0] == FREE
    report = prior_changes(prior, nav.map)
    assert report["added_voxels"] > 0 and report["removed_voxels"] > 0
    assert report["disagreement"] < 0.3


def test_a_prior_from_another_place_or_voxel_size_is_refused(changed, tmp_path):
    cfg, sc = changed
    far = OccupancyMap.from_occupancy_grid(
        np.ones((8, 8, 8), bool), np.array([5000.0, 5000.0, 0.0]), MapConfig(voxel_size_m=cfg.voxel_size_m)
    )
    far.save(tmp_path / "far")
    with pytest.raises(InputError, match="does not overlap"):
        load_prior_map(tmp_path / "far", cfg, sc.box)
    coarse = OccupancyMap.from_occupancy_grid(
        np.ones((8, 8, 8), bool), np.zeros(3), MapConfig(voxel_size_m=1.0)
    )
    coarse.save(tmp_path / "coarse")
    with pytest.raises(InputError, match="voxel"):
        load_prior_map(tmp_path / "coarse", cfg, sc.box)
    with pytest.raises(InputError):
        load_prior_map(tmp_path / "missing", cfg, sc.box)
    ok = OccupancyMap.from_occupancy_grid(
        np.ones((8, 8, 8), bool), sc.box.origin, MapConfig(voxel_size_m=0.5)
    )
    ok.save(tmp_path / "ok")
    prior = load_prior_map(tmp_path / "ok", cfg, sc.box)
    assert 0 < prior.known_fraction < 1 and prior.occupied.sum() == 512


def test_city_changes_leave_the_base_city_alone(tiny_config):
    sc = make_scenario(5, tiny_config)
    n = len(sc.city.boxes)
    today, yesterday, changes = city_changes(
        sc.city, 5, sc.shortest.waypoints, sc.start, sc.goal, tiny_config
    )
    assert len(sc.city.boxes) == n
    assert len(today.boxes) == n + sum(c.kind == "added" for c in changes)
    assert len(yesterday.boxes) == n + sum(c.kind == "removed" for c in changes)
