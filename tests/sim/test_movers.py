"""Moving obstacles: exact geometry in time, distances, rendering, generation rules, validation."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from skyrecon.core import Intrinsics, Rigid3
from skyrecon.errors import InputError
from skyrecon.sim import City, Mover, MovingScene, make_movers, mover_of_object_id, render
from skyrecon.sim.movers import CraneMotion, PolylineMotion, box_sdf
from skyrecon.sim.texture import MAT_METAL, MAT_PLAIN


@pytest.fixture(scope="module")
def mission(city):
    """An L-shaped street path at 15 m through the city of seed 3 (the conftest's ``city``)."""
    xs, ys = city.street_centers
    y0 = float(ys[len(ys) // 2])
    x1 = float(xs[len(xs) - 2])
    path = np.array([[-80.0, y0, 15.0], [x1, y0, 15.0], [x1, y0 + 60.0, 15.0]])
    assert np.all(city.distance(np.linspace(path[0], path[1], 200)) > 3.0)
    return path


@pytest.fixture(scope="module")
def scene(city, mission):
    return make_movers(city, 11, mission[0], mission[-1], mission)


def _box_city() -> City:
    return City.from_obstacles(np.array([[10.0, -5.0, 0.0, 20.0, 5.0, 25.0]]))


def _drone(name: str, pts, speed: float = 3.0, phase: float = 0.0) -> Mover:
    return Mover(name, "drone", PolylineMotion(np.asarray(pts, float), speed, False, phase))


def test_deterministic_and_round_trip(city, mission, scene):
    again = make_movers(city, 11, mission[0], mission[-1], mission)
    assert json.dumps(again.to_dict()) == json.dumps(scene.to_dict())
    kinds = [m.kind for m in scene.movers]
    assert kinds.count("drone") == 3 and kinds.count("vehicle") == 4 and kinds.count("crane") == 1
    copy = MovingScene.from_dict(json.loads(json.dumps(scene.to_dict())), city)
    for t in (0.0, 7.3, 41.0):
        np.testing.assert_array_equal(copy.mover_boxes(t), scene.mover_boxes(t))
        np.testing.assert_array_equal(again.mover_boxes(t), scene.mover_boxes(t))
    other = make_movers(city, 12, mission[0], mission[-1], mission)
    assert json.dumps(other.to_dict()) != json.dumps(scene.to_dict())
    assert [m.name for m in scene.new_obstacles] == ["crane-0"]


def test_plain_movers_are_the_same_movers_in_plain_paint(city, mission, scene):
    plain = make_movers(city, 11, mission[0], mission[-1], mission, plain=True)
    assert [m.name for m in plain.movers] == [m.name for m in scene.movers]
    assert {m.material for m in plain.movers} == {MAT_PLAIN} and MAT_PLAIN not in {
        m.material for m in scene.movers
    }
    for t in (0.0, 7.3, 41.0):
        np.testing.assert_array_equal(plain.mover_boxes(t), scene.mover_boxes(t))
    # rendered from the side, a plain drone is one flat grey inside its outline; a metal one is not
    cam = Intrinsics.from_fov(160, 120, 40.0)
    for material, textured in ((MAT_PLAIN, False), (MAT_METAL, True)):
        drone = _drone("drone-x", [[0.0, -10.0, 15.0], [0.0, 10.0, 15.0]], speed=2.0)
        drone = Mover(drone.name, drone.kind, drone.motion, material=material, texture_scale=0.3)
        world = MovingScene(_box_city(), [drone])
        c = drone.state_at(5.0)[0]
        snap = world.snapshot(5.0)
        res = render(snap, cam, Rigid3.look_at(c - np.array([4.0, 0.0, 0.0]), c))
        inside = mover_of_object_id(snap, res.object_id) == 0
        inner = (
            inside
            & np.roll(inside, 3, 0)
            & np.roll(inside, -3, 0)
            & np.roll(inside, 3, 1)
            & np.roll(inside, -3, 1)
        )
        assert inner.sum() > 200
        grey = (
            res.image.astype(np.float64).mean(axis=-1)
            if res.image.ndim == 3
            else res.image.astype(np.float64)
        )
        assert grey[inner].std() > 1.0 if textured else grey[inner].std() < 0.5, (material, grey[inner].std())


def test_distance_matches_brute_force_and_snapshot(scene):
    rng = np.random.default_rng(0)
    times = rng.uniform(0.0, 60.0, 300)
    centers = np.array([scene.movers[i % len(scene.movers)].state_at(t)[0] for i, t in enumerate(times)])
    pts = centers + rng.uniform(-4.0, 4.0, (300, 3))
    pts[:, 2] = np.maximum(pts[:, 2], 0.1)
    got = scene.distance(pts, times)
    brute = np.array([box_sdf(p[None], scene.mover_boxes(t)).min() for p, t in zip(pts, times)])
    np.testing.assert_allclose(scene.mover_distance(pts, times), brute, atol=1e-12)
    np.testing.assert_allclose(got, np.minimum(brute, scene.static.distance(pts, True)), atol=1e-12)
    assert np.any(got < 0) and np.any(got > 0)
    for t in (0.0, 12.5):
        snap = scene.snapshot(t)
        np.testing.assert_allclose(scene.distance(pts, t), snap.distance(pts, True), atol=1e-12)
        assert np.isinf(MovingScene(scene.static, []).mover_distance(pts[:3], t)).all()


def test_render_shows_the_drone_where_it_is():
    drone = _drone("drone-x", [[0.0, -10.0, 15.0], [0.0, 10.0, 15.0]], speed=2.0)
    scene = MovingScene(_box_city(), [drone])
    cam = Intrinsics.from_fov(160, 120, 40.0)
    for t in (5.0, 8.0):
        c, v, half = drone.state_at(t)
        assert abs(np.linalg.norm(v) - 2.0) < 1e-12 and np.allclose(half, [0.5, 0.5, 0.2])
        eye = c - np.array([8.0, 0.0, 0.0])
        snap = scene.snapshot(t)
        res = render(snap, cam, Rigid3.look_at(eye, c))
        mine = mover_of_object_id(snap, res.object_id)
        assert mine.shape == (120, 160) and set(np.unique(mine)) == {-1, 0}
        assert mine[60, 80] == 0 and mine[0, 0] == -1
        # the near face of the drone is 8 - 0.5 m in front of the camera
        np.testing.assert_allclose(res.depth_m[mine == 0], 7.5, atol=1e-4)
        assert 100 < np.count_nonzero(mine == 0) < 2000
        assert res.image[mine == 0].std() > 2.0  # textured
    # a camera looking where the drone was at t = 5 sees the building behind, not the drone, at t = 8
    c5 = drone.state_at(5.0)[0]
    res = render(scene.snapshot(8.0), cam, Rigid3.look_at(c5 - [8.0, 0.0, 0.0], c5))
    assert mover_of_object_id(scene.snapshot(8.0), res.object_id)[60, 80] == -1


def test_crossing_drones_cross_the_path(scene, mission):
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(mission, axis=0), axis=1))])
    drones = [m for m in scene.movers if m.kind == "drone"]
    for m in drones[:2]:
        p = m.motion.points
        assert 2.0 <= m.motion.speed_mps <= 4.5
        assert np.all(scene.static.distance(np.linspace(p[0], p[-1], 400)) >= 2.5)
        a, b = p[0, :2], p[-1, :2]
        hits = []
        for k in range(len(mission) - 1):
            c, d = mission[k, :2], mission[k + 1, :2]
            m2 = np.array([b - a, c - d]).T
            if abs(np.linalg.det(m2)) < 1e-9:
                continue
            s, u = np.linalg.solve(m2, c - a)
            if 0 <= s <= 1 and 0 <= u <= 1:
                hits.append((k, s, u))
        assert any(_good_crossing(m, mission, cum, *h) for h in hits), f"{m.name} does not cross the path"


def _good_crossing(m: Mover, mission: np.ndarray, cum: np.ndarray, k: int, s: float, u: float) -> bool:
    """Within 2 m of the path's altitude, at 45-90 degrees, when a drone flying the path at 0.5-0.7 x 6 m/s
    passes."""
    p = m.motion.points
    x = p[0] + s * (p[-1] - p[0])
    if abs(x[2] - (mission[k, 2] + u * (mission[k + 1, 2] - mission[k, 2]))) > 2.0:
        return False
    d1, d2 = (p[-1, :2] - p[0, :2]), mission[k + 1, :2] - mission[k, :2]
    angle = math.degrees(math.acos(min(1.0, abs(d1 @ d2) / np.linalg.norm(d1) / np.linalg.norm(d2))))
    if not 45.0 - 1e-6 <= angle <= 90.0:
        return False
    arc = cum[k] + u * (cum[k + 1] - cum[k])
    ts = np.arange(arc / 4.2 - 0.1, arc / 3.0 + 0.1, 0.01)
    pos, _ = m.motion.at(ts)
    return bool(np.min(np.linalg.norm(pos - x, axis=1)) < 0.05)


def test_keep_off_start_and_goal(scene, mission):
    ts = np.arange(0.0, 5.0, 0.05)
    assert np.all(scene.distance(np.repeat(mission[:1], len(ts), 0), ts) >= 6.0)
    ts = np.arange(0.0, 400.0, 0.1)
    assert np.all(scene.mover_distance(np.repeat(mission[-1:], len(ts), 0), ts) >= 4.0)


def test_vehicles_stay_on_streets(scene):
    vehicles = [m for m in scene.movers if m.kind == "vehicle"]
    assert vehicles
    ts = np.arange(0.0, 120.0, 0.25)
    for m in vehicles:
        assert 5.0 <= m.motion.speed_mps <= 12.0
        b = m.boxes_many(ts)[:, 0]
        assert np.all(b[:, 2] == 0.0) and np.all(b[:, 5] <= 2.0)
        # no static obstacle within 0.3 m of the box: its corners are clear of buildings and poles
        corners = np.concatenate([b[:, [0, 1, 5]], b[:, [3, 4, 5]], b[:, [0, 4, 2]], b[:, [3, 1, 2]]])
        assert np.all(scene.static.distance(corners) > 0.3)
        assert not np.any(scene.static.is_occupied((b[:, :3] + b[:, 3:]) / 2))
        long_axis = np.argmax(m.size_m[:2])
        _, v = m.motion.at(ts)
        # drives along its long axis, but for the lane change at the city's ends
        assert np.mean(np.abs(v[:, long_axis]) > 0.99 * m.motion.speed_mps) > 0.9


def test_crane_boom():
    crane = CraneMotion(np.array([0.0, 0.0, 20.0]), 0.0, 22.0, math.radians(3.0), 0.4)
    m = Mover("crane-a", "crane", crane)
    for t in (0.0, 10.0, 33.0):
        tip = m.tip_at(t)
        _, v, _ = m.state_at(t)
        assert abs(np.linalg.norm(v) - math.radians(3.0) * 22.0) < 1e-12
        assert abs(np.linalg.norm(tip[:2]) - 22.0) < 1e-12 and tip[2] == 20.0
        boxes = m.boxes_at(t)
        cubes = boxes[1:]
        assert np.allclose(cubes[:, 3:] - cubes[:, :3], 1.0)
        centers = (cubes[:, :3] + cubes[:, 3:]) / 2
        assert np.all(np.linalg.norm(np.diff(centers, axis=0), axis=1) <= 1.0 + 1e-12)  # a connected chain
        assert box_sdf(tip[None], cubes).min() <= 0.0
    num = (m.tip_at(1.0 + 1e-4) - m.tip_at(1.0 - 1e-4)) / 2e-4
    np.testing.assert_allclose(num, m.state_at(1.0)[1], atol=1e-6)
    # back and forth over a sector: same tip speed, headings stay inside the sector
    sector = CraneMotion(np.array([0.0, 0.0, 20.0]), 0.0, 22.0, math.radians(4.0), 1.0, sweep_rad=1.5)
    th, w = sector.heading_rate(np.linspace(0.0, 200.0, 2001))
    assert th.min() >= 1.0 - 1e-12 and th.max() <= 2.5 + 1e-12 and np.allclose(np.abs(w), math.radians(4.0))


def test_generated_crane_sweeps_over_the_path(scene, mission):
    crane = next(m for m in scene.movers if m.kind == "crane")
    cm = crane.motion
    assert 18.0 <= cm.length_m <= 28.0 and 16.0 <= cm.pivot[2] <= 24.0
    assert math.radians(2.0) <= abs(cm.omega_rad_s) <= math.radians(5.0) + 1e-12
    # a path point within the boom's reach lies under some boom heading
    path_pts = np.concatenate([np.linspace(mission[k], mission[k + 1], 300) for k in range(len(mission) - 1)])
    rel = path_pts[:, :2] - cm.pivot[:2]
    reach = np.linalg.norm(rel, axis=1) < cm.length_m - 1.0
    assert np.any(reach)
    bearings = np.arctan2(rel[reach, 1], rel[reach, 0])
    th = cm.heading(np.arange(0.0, cm.period_s, 0.5))
    gap = np.abs(np.angle(np.exp(1j * (bearings[:, None] - th[None, :]))))
    assert gap.min() < math.radians(3.0)
    scene.validate(mission[0], 2.0)  # generated movers pass the user checks


def test_validate_rejects_bad_movers():
    city = _box_city()
    start = np.array([-20.0, 0.0, 15.0])
    inside = _drone("drone-in", [[0.0, 0.0, 15.0], [30.0, 0.0, 15.0]])
    with pytest.raises(InputError, match="drone-in.*inside a static obstacle"):
        MovingScene(city, [inside]).validate(start, 2.0)
    on_start = _drone("drone-start", [[-20.0, -5.0, 15.0], [-20.0, 5.0, 15.0]])
    with pytest.raises(InputError, match="drone-start.*start"):
        MovingScene(city, [on_start]).validate(start, 2.0)
    ok = _drone("drone-ok", [[0.0, -10.0, 15.0], [0.0, 10.0, 15.0]])
    MovingScene(city, [ok]).validate(start, 2.0)
    with pytest.raises(InputError):
        Mover("x", "boat", PolylineMotion(np.zeros((2, 3)) + [[0, 0, 0], [1, 0, 0]], 1.0))
    with pytest.raises(InputError):
        MovingScene(city, [ok, ok])
