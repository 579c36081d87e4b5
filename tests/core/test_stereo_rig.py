import numpy as np
import pytest

from skyrecon.core import Intrinsics, Rigid3, StereoRig
from skyrecon.errors import InputError


def make_rig(doffs=0.0):
    return StereoRig.rectified(Intrinsics(700.0, 700.0, 320.0, 240.0, 640, 480), 0.5, doffs)


@pytest.mark.parametrize("doffs", [0.0, 12.5])
def test_disparity_depth_round_trip_and_geometry(doffs):
    rig = make_rig(doffs)
    assert rig.is_rectified and abs(rig.baseline_m - 0.5) < 1e-12
    # a point seen by both cameras: disparity from the projections matches depth_to_disparity
    p_left = np.array([[1.0, -0.5, 7.0]])
    u_l = rig.left.project(p_left)[0, 0]
    u_r = rig.right.project(rig.right_from_left.apply(p_left))[0, 0]
    d = np.array([[u_l - u_r]])
    np.testing.assert_allclose(rig.disparity_to_depth(d), [[7.0]], rtol=1e-6)
    np.testing.assert_allclose(rig.depth_to_disparity(np.array([[7.0]])), d, rtol=1e-6)


def test_Q_matrix_reprojects_to_the_point():
    rig = make_rig(4.0)
    p = np.array([0.7, 0.3, 9.0])
    u, v = rig.left.project(p[None])[0]
    d = rig.depth_to_disparity(np.array([[9.0]]))[0, 0]
    X = rig.Q @ np.array([u, v, d, 1.0])
    np.testing.assert_allclose(X[:3] / X[3], p, rtol=1e-5)


def test_invalid_disparity_is_nan():
    rig = make_rig()
    depth = rig.disparity_to_depth(np.array([[np.nan, 0.0, -3.0, 10.0]]))
    assert np.isnan(depth[0, :3]).all() and depth[0, 3] == pytest.approx(35.0)


def test_from_projections_kitti_like():
    K = np.array([[721.5377, 0, 609.5593], [0, 721.5377, 172.854], [0, 0, 1]])
    P2 = np.hstack([K, K @ np.array([[0.06], [0], [0]])])
    P3 = np.hstack([K, K @ np.array([[-0.47], [0], [0]])])
    rig = StereoRig.from_projections(P2, P3, 1242, 375)
    assert rig.is_rectified
    assert rig.baseline_m == pytest.approx(0.53)


def test_bad_baseline_and_unrectified_Q():
    with pytest.raises(InputError):
        StereoRig.rectified(Intrinsics.from_fov(10, 10, 60), 0.0)
    cam = Intrinsics.from_fov(10, 10, 60)
    rig = StereoRig(cam, cam, Rigid3.from_rotvec([0, 0.1, 0], [-0.2, 0, 0]))
    assert not rig.is_rectified
    with pytest.raises(InputError, match="not rectified"):
        _ = rig.Q
