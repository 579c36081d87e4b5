"""Cameras: rig, street views, collision-free flights, rings and orbits."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Intrinsics, PosedView
from skyrecon.sim import (
    default_rig,
    flight_poses,
    generate_city,
    orbit_views,
    render,
    render_views,
    ring_views,
    street_view_pose,
)


def test_default_rig():
    rig = default_rig()
    assert rig.is_rectified and rig.left.size == (640, 480)
    assert rig.baseline_m == pytest.approx(0.12) and rig.left.fx == pytest.approx(320.0)


def test_street_view_pose(city):
    for seed in range(4):
        pose = street_view_pose(city, seed)
        assert pose.allclose(street_view_pose(city, seed))
        assert city.distance(pose.center, include_ground=True)[0] >= 2.0
        assert 10.0 <= pose.center[2] <= 30.0


def test_flight_poses_clear_smooth_and_deterministic(city, small_rig):
    n, speed, fps = 150, 5.0, 10.0
    poses = flight_poses(city, n, seed=7, speed_mps=speed, fps=fps)
    assert len(poses) == n and all(p.dst == "world" and p.src == "cam" for p in poses)
    c = np.array([p.t for p in poses])
    clear = city.distance(c, include_ground=True)
    steps = np.linalg.norm(np.diff(c, axis=0), axis=1)
    fwd = np.array([p.R[:, 2] for p in poses])  # camera z axis in the world
    turn = np.degrees(np.arccos(np.clip(np.sum(fwd[1:] * fwd[:-1], axis=1), -1, 1)))
    print(
        f"\nflight: {n} frames, {steps.sum():.1f} m, clearance min {clear.min():.2f} m, "
        f"step {steps.min():.3f}-{steps.max():.3f} m, max turn {turn.max():.2f} deg/frame"
    )
    assert clear.min() >= 2.0
    assert np.all(np.abs(steps - speed / fps) < 0.05)
    assert turn.max() < 8.0
    assert np.all(fwd[:, 2] < -0.1)  # pitched down
    assert np.all((c[:, 2] > 10.0) & (c[:, 2] < 40.0))
    again = flight_poses(city, n, seed=7, speed_mps=speed, fps=fps)
    assert all(a.allclose(b) for a, b in zip(poses, again))
    assert not np.allclose(c, np.array([p.t for p in flight_poses(city, n, seed=8)]))
    r = render(city, small_rig.left, poses[n // 2].inverse())
    assert np.isfinite(r.depth_m).mean() > 0.5 and np.nanmin(r.depth_m) > 1.0


def test_flights_over_many_seeds_stay_clear():
    for seed in range(6):
        city = generate_city(seed)
        c = np.array([p.t for p in flight_poses(city, 200, seed=seed)])
        assert city.distance(c, include_ground=True).min() >= 2.0


def test_ring_views_see_the_centre(object_scene):
    cam = Intrinsics.from_fov(320, 240, 90)
    centre = object_scene.center
    views = ring_views(centre, 6.0, centre[2] + 3.0, 12, cam)
    assert [v.name for v in views[:2]] == ["ring_000.png", "ring_001.png"]
    for v in views:
        uv, z = v.project(centre[None])
        assert z[0] > 0 and cam.in_image(uv, margin=10)[0]
        assert np.hypot(*(v.center_world[:2] - centre[:2])) == pytest.approx(6.0)
        assert object_scene.distance(v.center_world, include_ground=True)[0] > 0.5


def test_orbit_views_vary_in_height_and_see_the_centre(object_scene):
    cam = Intrinsics.from_fov(320, 240, 90)
    views = orbit_views(object_scene, 10, cam, seed=1)
    assert len(views) == 10 and views[0].name == "orbit_000.png"
    heights = np.array([v.center_world[2] for v in views])
    assert heights.max() - heights.min() > 1.0
    for v in views:
        uv, z = v.project(object_scene.center[None])
        assert z[0] > 0 and cam.in_image(uv, margin=10)[0]
        assert object_scene.distance(v.center_world, include_ground=True)[0] > 0.5
    again = orbit_views(object_scene, 10, cam, seed=1)
    assert all(a.cam_from_world.allclose(b.cam_from_world) for a, b in zip(views, again))
    results = render_views(object_scene, (v for v in views[:2]))
    assert len(results) == 2 and all(isinstance(v, PosedView) for v in views)
    assert all((r.object_id > 0).mean() > 0.05 for r in results)
