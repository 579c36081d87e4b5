import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skyrecon.core import Intrinsics
from skyrecon.errors import InputError


def test_project_unproject_round_trip():
    cam = Intrinsics(500.0, 510.0, 320.5, 239.0, 640, 480)
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-2, 2, 50), rng.uniform(-2, 2, 50), rng.uniform(1, 20, 50)])
    uv = cam.project(pts)
    np.testing.assert_allclose(cam.unproject(uv, pts[:, 2]), pts, atol=1e-9)


def test_principal_point_and_pixel_centre_convention():
    cam = Intrinsics.from_fov(640, 480, 90.0)
    # the optical axis hits the image centre, between pixels 319 and 320
    np.testing.assert_allclose(cam.project(np.array([[0, 0, 1.0]])), [[319.5, 239.5]])
    # 90 degree horizontal FOV: rays at +-45 degrees hit the outer edges of the first and last pixels
    np.testing.assert_allclose(cam.project(np.array([[1.0, 0, 1.0], [-1.0, 0, 1.0]]))[:, 0], [639.5, -0.5])


def test_behind_camera_is_nan_and_not_in_image():
    cam = Intrinsics.from_fov(100, 100, 60)
    uv = cam.project(np.array([[0, 0, -1.0], [0, 0, 1.0]]))
    assert np.isnan(uv[0]).all()
    assert cam.in_image(uv).tolist() == [False, True]


@settings(max_examples=100, deadline=None)
@given(
    st.floats(-0.3, 0.3),
    st.floats(-0.1, 0.1),
    st.floats(-0.01, 0.01),
    st.floats(-0.01, 0.01),
)
def test_distortion_round_trip(k1, k2, p1, p2):
    cam = Intrinsics(400, 400, 200, 150, 400, 300, dist=[k1, k2, p1, p2, 0.0])
    uv = np.array([[10.0, 10.0], [200, 150], [390, 290], [50, 250]])
    pts = cam.unproject(uv, 3.0)
    np.testing.assert_allclose(cam.project(pts), uv, atol=1e-6)


def test_K_round_trip_and_scaling():
    K = np.array([[800.0, 0, 400], [0, 780, 300], [0, 0, 1]])
    cam = Intrinsics.from_K(K, 800, 600)
    np.testing.assert_allclose(cam.K, K)
    half = cam.scaled(0.5)
    assert half.size == (400, 300)
    # a point's pixel scales with the image (pixel-centre convention)
    p = np.array([[0.3, -0.2, 2.0]])
    uv, uv_half = cam.project(p)[0], half.project(p)[0]
    np.testing.assert_allclose((uv + 0.5) * 0.5 - 0.5, uv_half, atol=1e-9)


def test_ray_directions_match_unproject():
    cam = Intrinsics(300, 300, 40, 30, 80, 60, dist=[0.1, 0, 0, 0, 0])
    rays = cam.ray_directions()
    assert rays.shape == (60, 80, 3)
    np.testing.assert_allclose(rays[10, 20], cam.unproject(np.array([[20.0, 10.0]]), 1.0)[0])


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(fx=-1, fy=1, cx=0, cy=0, width=10, height=10),
        dict(fx=1, fy=1, cx=np.nan, cy=0, width=10, height=10),
        dict(fx=1, fy=1, cx=0, cy=0, width=0, height=10),
        dict(fx=1, fy=1, cx=0, cy=0, width=10, height=10, dist=np.zeros(6)),
    ],
)
def test_invalid_intrinsics(kwargs):
    with pytest.raises(InputError):
        Intrinsics(**kwargs)


def test_invalid_K_and_size_check():
    with pytest.raises(InputError):
        Intrinsics.from_K(np.ones((3, 3)), 10, 10)
    cam = Intrinsics.from_fov(64, 48, 60)
    with pytest.raises(InputError, match="64x48"):
        cam.check_image(np.zeros((50, 64)))
