import numpy as np
import pytest

from skyrecon.core import Intrinsics, Rigid3, StereoRig
from skyrecon.errors import InputError
from skyrecon.stereo import depth_error_bound, disparity_to_depth, disparity_to_points, max_disparity_for


def rig(doffs=0.0):
    return StereoRig.rectified(Intrinsics(400.0, 400.0, 31.5, 23.5, 64, 48), 0.25, doffs)


def test_depth_is_f_b_over_d_plus_doffs():
    r = rig(doffs=2.0)
    d = np.full((48, 64), 8.0, np.float32)
    d[0, 0] = np.nan
    d[0, 1] = -2.0  # d + doffs = 0: at infinity
    z = disparity_to_depth(d, r)
    assert z.dtype == np.float32 and z.shape == d.shape
    assert z[5, 5] == pytest.approx(400.0 * 0.25 / 10.0)
    assert np.isnan(z[0, 0]) and np.isnan(z[0, 1])


def test_points_colours_ranges_and_mask():
    r = rig()
    d = np.full((48, 64), 10.0, np.float32)  # 10 m
    d[:, :32] = 4.0  # 25 m
    img = np.zeros((48, 64, 3), np.uint8)
    img[..., 0] = 200
    cloud = disparity_to_points(d, r, img)
    assert len(cloud) == 48 * 64 and cloud.points.dtype == np.float32
    assert (cloud.colors[:, 0] == 200).all()
    near = disparity_to_points(d, r, img, min_depth_m=5.0, max_depth_m=20.0)
    assert len(near) == 48 * 32 and np.allclose(near.points[:, 2], 10.0)
    # the pixel (u, v) goes to ((u - cx) z / f, (v - cy) z / f, z) in the left camera frame
    p = near.points.reshape(48, 32, 3)
    assert p[0, 0] == pytest.approx([(32 - 31.5) * 10 / 400, (0 - 23.5) * 10 / 400, 10.0], abs=1e-5)
    mask = np.zeros((48, 64), bool)
    mask[10, 40] = True
    assert len(disparity_to_points(d, r, None, mask=mask)) == 1
    grey = np.full((48, 64), 77, np.uint8)
    assert (disparity_to_points(d, r, grey).colors == 77).all()


def test_depth_error_bound_and_max_disparity():
    r = rig()
    d = np.array([[10.0, 5.0, np.nan]], np.float32)
    big = np.zeros((48, 64), np.float32)
    big[0, :3] = d
    b = depth_error_bound(big, r, 0.5)
    assert b[0, 0] == pytest.approx(100.0 / 100.0 * 0.5)
    assert b[0, 1] == pytest.approx(100.0 / 25.0 * 0.5)
    assert np.isnan(b[0, 2])
    assert max_disparity_for(r, min_depth_m=2.0) == 64  # f B / z = 50 -> 64 (multiple of 16)
    assert max_disparity_for(r, min_depth_m=2.0, multiple=1) == 51


def test_bad_inputs():
    r = rig()
    with pytest.raises(InputError, match="calibration"):
        disparity_to_points(np.zeros((10, 10), np.float32), r)
    with pytest.raises(InputError, match="min_depth_m"):
        disparity_to_points(np.zeros((48, 64), np.float32), r, min_depth_m=5.0, max_depth_m=1.0)
    unrect = StereoRig(r.left, r.right, Rigid3(np.eye(3), [-0.25, 0.01, 0.0]))
    with pytest.raises(InputError, match="rectif"):
        disparity_to_depth(np.zeros((48, 64), np.float32), unrect)
    with pytest.raises(InputError, match="2-D"):
        disparity_to_depth(np.zeros((48, 64, 1), np.float32), r)
    with pytest.raises(InputError, match="mask"):
        disparity_to_points(np.zeros((48, 64), np.float32), r, mask=np.ones((2, 2), bool))
    with pytest.raises(InputError, match="min_depth_m"):
        max_disparity_for(r, 0.0)
