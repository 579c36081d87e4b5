"""Rendering: determinism, photometric consistency of stereo pairs, exact depth on the scene's surfaces."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from skyrecon.core import DepthMap, Intrinsics, Rigid3
from skyrecon.sim import (
    City,
    generate_city,
    render,
    render_depth,
    render_stereo,
    ring_views,
    street_view_pose,
)
from skyrecon.sim.texture import MAT_BRICK, MAT_CONCRETE, MAT_PLAIN


def test_same_seed_same_images_different_seed_different_images(city, small_rig, street_frame):
    pose = street_view_pose(city, 3)
    again = render_stereo(generate_city(3), small_rig, street_view_pose(generate_city(3), 3))
    assert np.array_equal(again.left, street_frame.left) and np.array_equal(again.right, street_frame.right)
    assert np.array_equal(again.depth_left_m, street_frame.depth_left_m, equal_nan=True)
    other = render(generate_city(4), small_rig.left, pose)
    assert np.mean(other.image != street_frame.left) > 0.2


def photometric_residual(frame) -> dict:
    """Warp the right image by the left ground-truth disparity (bilinear, x_right = x - d) and compare.

    A left pixel is *non-occluded* when both right pixels of its bilinear support pass the
    left-right consistency check (right disparity, from the right depth, within 0.5 px of the
    left one); *same-surface* pixels also see the same object in both support pixels, which
    drops the silhouettes of sub-pixel poles that the disparity check cannot tell from the
    ground behind them. Returns mean absolute errors (grey levels, 0..255, averaged over RGB),
    the 99th percentile and the fractions of pixels used.
    """
    L = frame.left.astype(np.float32)
    R = frame.right.astype(np.float32)
    d = frame.disparity_left_px
    H, W = d.shape
    xr = np.arange(W, dtype=np.float32)[None, :] - d
    ys = np.repeat(np.arange(H, dtype=np.float32)[:, None], W, axis=1)
    warped = cv2.remap(
        R,
        np.where(np.isfinite(xr), xr, -10.0).astype(np.float32),
        ys,
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
    )
    err = np.abs(warped - L).mean(axis=2)
    dr = frame.disparity_right_px
    x0 = np.clip(np.floor(np.nan_to_num(xr)).astype(int), 0, W - 1)
    x1 = np.clip(x0 + 1, 0, W - 1)
    rows = np.arange(H)[:, None]
    with np.errstate(invalid="ignore"):
        lr = (
            np.isfinite(d)
            & (xr >= 0)
            & (xr <= W - 1)
            & (np.abs(dr[rows, x0] - d) < 0.5)
            & (np.abs(dr[rows, x1] - d) < 0.5)
        )
    lid, rid = frame.left_result.object_id, frame.right_result.object_id
    same = lr & (rid[rows, x0] == lid) & (rid[rows, x1] == lid)
    return {
        "mae_lr": float(err[lr].mean()),
        "mae_same": float(err[same].mean()),
        "p99_same": float(np.percentile(err[same], 99)),
        "used_lr": float(lr.mean()),
        "used_same": float(same.mean()),
    }


def test_right_image_warped_by_gt_disparity_reproduces_left(city, small_rig, street_frame):
    for seed in (3, 11):
        frame = street_frame if seed == 3 else render_stereo(city, small_rig, street_view_pose(city, seed))
        r = photometric_residual(frame)
        print(
            f"\nphotometric residual (seed {seed}, 320x240): MAE {r['mae_lr']:.2f} grey levels over "
            f"{r['used_lr'] * 100:.0f} % non-occluded pixels; {r['mae_same']:.2f} (p99 {r['p99_same']:.1f}) "
            f"over {r['used_same'] * 100:.0f} % same-surface pixels"
        )
        assert r["used_lr"] > 0.4 and r["used_same"] > 0.4
        assert r["mae_lr"] < 3.0
        assert r["mae_same"] < 1.5


def test_depth_lies_on_surfaces_and_matches_raycast(city, small_rig, street_frame):
    f = street_frame
    cloud = DepthMap(f.depth_left_m, small_rig.left, f.left_from_world).to_points_world()
    res = np.abs(city.distance(cloud.points.astype(np.float64), include_ground=True))
    print(
        f"\nsurface residual of back-projected depth: median {np.median(res):.1e} m, "
        f"p99 {np.percentile(res, 99):.1e} m, max {res.max():.1e} m over {len(res)} points"
    )
    assert np.percentile(res, 99) < 1e-3 and res.max() < 1e-3
    # depth agrees with an independent ray cast through the same pixels
    rng = np.random.default_rng(0)
    H, W = f.depth_left_m.shape
    uv = np.column_stack([rng.integers(W, size=500), rng.integers(H, size=500)]).astype(float)
    ray_cam = small_rig.left.unproject(uv, 1.0)
    unit = ray_cam / np.linalg.norm(ray_cam, axis=1, keepdims=True)
    world_from_cam = f.left_from_world.inverse()
    dist = city.raycast(f.left_from_world.center, world_from_cam.rotate(unit))
    z = dist * unit[:, 2]
    depth = f.depth_left_m[uv[:, 1].astype(int), uv[:, 0].astype(int)]
    assert np.array_equal(np.isfinite(z), np.isfinite(depth))
    ok = np.isfinite(z)
    assert np.allclose(depth[ok], z[ok], rtol=1e-6)
    # disparity is exactly fx * B / z, and the right depth is the left scene seen from the right
    assert np.allclose(
        f.disparity_left_px[np.isfinite(f.depth_left_m)],
        (small_rig.left.fx * small_rig.baseline_m / f.depth_left_m)[np.isfinite(f.depth_left_m)],
        rtol=1e-6,
    )
    right = DepthMap(f.depth_right_m, small_rig.right, f.right_from_world).to_points_world()
    assert np.abs(city.distance(right.points.astype(np.float64), include_ground=True)).max() < 1e-3


def test_normals_ids_and_sky(street_frame):
    r = street_frame.left_result
    sky = ~np.isfinite(r.depth_m)
    assert np.array_equal(sky, r.object_id == -1)
    assert np.all(np.isnan(r.normal_world[sky]))
    n = r.normal_world[~sky]
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    assert 0.02 < sky.mean() < 0.6
    # the sky is a smooth gradient, brighter at the horizon
    assert r.image[sky].std(axis=0).max() < 40


def test_textures_rich_with_some_low_texture_surfaces(city, street_frame):
    grey = cv2.cvtColor(street_frame.left, cv2.COLOR_RGB2GRAY)
    corners = cv2.goodFeaturesToTrack(grey, 2000, 0.01, 3)
    n_corners = 0 if corners is None else len(corners)
    ids = street_frame.left_result.object_id
    gx = cv2.Sobel(grey.astype(np.float32), cv2.CV_32F, 1, 0)
    gy = cv2.Sobel(grey.astype(np.float32), cv2.CV_32F, 0, 1)
    grad = np.hypot(gx, gy)
    box = np.where((ids >= 1) & (ids <= len(city.boxes)), ids - 1, 0)
    mat = np.where((ids >= 1) & (ids <= len(city.boxes)), city.box_material[box], -1)
    interior = cv2.erode((ids >= 0).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    same = cv2.erode(ids.astype(np.float32), np.ones((5, 5))) == cv2.dilate(
        ids.astype(np.float32), np.ones((5, 5))
    )
    textured = interior & same & np.isin(mat, (MAT_BRICK, MAT_CONCRETE))
    print(
        f"\nstreet view 320x240: {n_corners} Shi-Tomasi corners; mean gradient on brick/concrete facades "
        f"{grad[textured].mean():.1f}"
    )
    assert n_corners > 300
    assert grad[textured].mean() > 20
    # a plain facade rendered up close is almost flat
    plain = np.flatnonzero((city.box_material == MAT_PLAIN) & (city.box_kind == 0))[0]
    b = city.boxes[plain]
    eye = np.array([(b[0] + b[3]) / 2, b[1] - 6.0, min(b[5] / 2, 8.0)])
    cam = Intrinsics.from_fov(160, 120, 60)
    r = render(city, cam, Rigid3.look_at(eye, eye + [0, 1.0, 0]))
    facade = r.object_id == plain + 1
    g = cv2.cvtColor(r.image, cv2.COLOR_RGB2GRAY)[facade]
    print(f"plain facade from 6 m: {facade.mean() * 100:.0f} % of the view, grey std {g.std():.2f}")
    assert facade.mean() > 0.5 and g.std() < 3.0


def test_lens_distortion_is_honoured(city):
    cam = Intrinsics(90.0, 90.0, 79.5, 59.5, 160, 120, np.array([-0.2, 0.05, 0.001, -0.001, 0.0]))
    pose = street_view_pose(city, 5)
    r = render(city, cam, pose)
    pts = r.depth_map().to_points_world().points.astype(np.float64)
    assert np.abs(city.distance(pts, include_ground=True)).max() < 1e-3


def test_object_scene_ring_render(object_scene):
    cam = Intrinsics.from_fov(160, 120, 60)
    views = ring_views(object_scene.center, object_scene.view_radius_m, object_scene.center[2] + 2.0, 4, cam)
    for v in views:
        r = render(object_scene, cam, v.cam_from_world)
        assert r.object_id[60, 80] > 0  # the monument is in the middle of the picture
        assert np.mean(r.object_id > 0) > 0.1
        pts = r.depth_map().to_points_world().points.astype(np.float64)
        assert np.abs(object_scene.distance(pts, include_ground=True)).max() < 1e-3


def test_render_depth_matches_render(city, small_rig, street_frame):
    depth = render_depth(city, small_rig.left, street_frame.left_from_world)
    assert np.array_equal(depth, street_frame.depth_left_m, equal_nan=True)


def test_hand_made_and_empty_scenes():
    scene = City.from_obstacles([[-1.0, 4.0, 0.0, 1.0, 6.0, 3.0]], [[2.5, 5.0, 0.2, 0.0, 4.0]], seed=1)
    cam = Intrinsics.from_fov(64, 48, 90)
    pose = Rigid3.look_at([0.0, 0.0, 1.5], [0.0, 5.0, 1.5])
    r = render(scene, cam, pose)
    assert r.object_id[24, 32] == 1 and r.depth_m[24, 32] == pytest.approx(4.0, abs=0.2)
    assert np.any(r.object_id == 2)  # the pole
    assert scene.distance([0.0, 0.0, 1.5])[0] == pytest.approx(4.0)
    empty = City.from_obstacles(np.zeros((0, 6)))
    r = render(empty, cam, pose)
    assert set(np.unique(r.object_id)) <= {-1, 0}
    assert (
        np.isinf(empty.distance([0.0, 0.0, 1.0])[0])
        and empty.distance([0, 0, 1.0], include_ground=True)[0] == 1.0
    )
    assert np.isinf(empty.raycast([0, 0, 1.0], [1.0, 0, 0])[0])
    assert not empty.occupancy_grid(np.zeros(3), 1.0, (2, 2, 2)).any()
