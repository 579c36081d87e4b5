"""Rectification of a calibrated rig with lens distortion and a rotated right camera."""

import cv2
import numpy as np
import pytest

from skyrecon import sim
from skyrecon.core import Intrinsics, Rigid3, StereoRig, rotvec_to_matrix
from skyrecon.errors import InputError
from skyrecon.stereo import create_matcher, disparity_to_points, rectify_rig


def unrectified_rig(width=640, height=480):
    left = Intrinsics(330.0, 332.0, 322.0, 236.0, width, height, dist=[-0.08, 0.02, 0.001, -0.0005, 0.0])
    right = Intrinsics(325.0, 326.0, 316.0, 244.0, width, height, dist=[-0.06, 0.01, -0.0008, 0.0006, 0.0])
    R = rotvec_to_matrix([0.01, -0.03, 0.015])
    t = np.array([-0.15, 0.004, 0.006])
    return StereoRig(left, right, Rigid3(R, t))


def random_points(n=200, seed=0):
    rng = np.random.default_rng(seed)
    z = rng.uniform(2.0, 30.0, n)
    x = rng.uniform(-0.6, 0.6, n) * z
    y = rng.uniform(-0.45, 0.45, n) * z
    return np.stack([x, y, z], 1)


@pytest.mark.parametrize("zero_disparity", [True, False])
def test_rectified_geometry(zero_disparity):
    rig = unrectified_rig()
    rect = rectify_rig(rig, alpha=0.0, zero_disparity=zero_disparity)
    r = rect.rig
    assert r.is_rectified and not rect.is_identity
    assert r.baseline_m == pytest.approx(np.linalg.norm(rig.right_from_left.t), rel=1e-6)
    np.testing.assert_allclose(rect.Q, r.Q)
    if zero_disparity:
        assert r.doffs_px == pytest.approx(0.0, abs=1e-9)
    P = random_points()
    p_rect_l = rect.left_rect_from_left.apply(P)
    p_rect_r = rect.right_rect_from_right.apply(rig.right_from_left.apply(P))
    # the rectified cameras are related by a pure x translation
    np.testing.assert_allclose(r.right_from_left.apply(p_rect_l), p_rect_r, atol=1e-9)
    uv_l = r.left.project(p_rect_l)
    uv_r = r.right.project(p_rect_r)
    inside = r.left.in_image(uv_l, margin=2) & r.right.in_image(uv_r, margin=2)
    assert inside.sum() > 50
    np.testing.assert_allclose(uv_l[inside, 1], uv_r[inside, 1], atol=1e-6)  # same row
    d = uv_l[inside, 0] - uv_r[inside, 0]
    np.testing.assert_allclose(r.disparity_to_depth(d[None])[0], p_rect_l[inside, 2], rtol=1e-5)
    # the remap tables send each rectified pixel back to the distorted original pixel
    for maps, uv_rect, intr, pts in (
        (rect.map_left, uv_l, rig.left, P),
        (rect.map_right, uv_r, rig.right, rig.right_from_left.apply(P)),
    ):
        mx, my = cv2.convertMaps(maps[0], maps[1], cv2.CV_32FC1)
        src = intr.project(pts)
        ui = np.rint(uv_rect[inside]).astype(int)
        # compare at integer rectified pixels: move the expected source by the rounding offset
        np.testing.assert_allclose(mx[ui[:, 1], ui[:, 0]], src[inside, 0], atol=1.5)
        np.testing.assert_allclose(my[ui[:, 1], ui[:, 0]], src[inside, 1], atol=1.5)


def test_apply_and_identity():
    rig = unrectified_rig(320, 240)
    rect = rectify_rig(rig)
    img = np.zeros((240, 320, 3), np.uint8)
    l, r = rect.apply(img, img[..., 0])
    assert l.shape == (240, 320, 3) and r.shape == (240, 320) and l.dtype == np.uint8
    assert rect.size == (320, 240)
    rect2 = rectify_rig(rig, new_size=(400, 300))
    assert rect2.apply_left(img).shape == (300, 400, 3)
    with pytest.raises(InputError, match="calibration"):
        rect.apply(img[:100], img)
    flat = StereoRig.rectified(Intrinsics(300.0, 300.0, 160.0, 120.0, 320, 240), 0.2)
    ident = rectify_rig(flat)
    assert ident.is_identity and ident.rig is flat
    a, b = ident.apply(img, img)
    assert a is img and b is img


def test_bad_rigs():
    rig = unrectified_rig()
    swapped = StereoRig(rig.left, rig.right, Rigid3(np.eye(3), [0.15, 0.0, 0.01]))
    with pytest.raises(InputError, match="swap"):
        rectify_rig(swapped)
    vertical = StereoRig(rig.left, rig.right, Rigid3(np.eye(3), [0.01, -0.2, 0.0]))
    with pytest.raises(InputError, match="vertical"):
        rectify_rig(vertical)
    small = Intrinsics(330.0, 330.0, 160.0, 120.0, 320, 240)
    with pytest.raises(InputError, match="equal image sizes"):
        rectify_rig(StereoRig(rig.left, small, rig.right_from_left))
    with pytest.raises(InputError, match="alpha"):
        rectify_rig(rig, alpha=2.0)


def test_end_to_end_rendered_unrectified_pair():
    city = sim.generate_city(4)
    rig = unrectified_rig()
    left_from_world = sim.street_view_pose(city, 4)
    left = sim.render(city, rig.left, left_from_world)
    right = sim.render(city, rig.right, rig.right_from_left @ left_from_world.with_frames("left", "world"))
    rect = rectify_rig(rig, alpha=0.0)
    lr, rr = rect.apply(left.image, right.image)
    res = create_matcher("skyrecon", 32).compute(lr, rr)
    cloud = disparity_to_points(
        res.disparity, rect.rig, lr, min_depth_m=2.0, max_depth_m=25.0, mask=res.measured
    )
    assert len(cloud) > 5000
    # back to the original left camera frame, then compare with the rendered depth there
    p = rect.left_rect_from_left.inverse().apply(cloud.points.astype(np.float64))
    uv = rig.left.project(p)
    inside = rig.left.in_image(uv, margin=1)
    u = np.rint(uv[inside, 0]).astype(int)
    v = np.rint(uv[inside, 1]).astype(int)
    gt = left.depth_m[v, u]
    ok = np.isfinite(gt)
    rel = np.abs(p[inside][ok, 2] - gt[ok]) / gt[ok]
    assert np.median(rel) < 0.05
    assert np.mean(rel < 0.2) > 0.9
