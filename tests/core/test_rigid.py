import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skyrecon.core import (
    FrameMismatchError,
    Rigid3,
    matrix_to_quaternion,
    matrix_to_rotvec,
    orthonormalize,
    quaternion_to_matrix,
    rotation_angle,
    rotation_angle_deg,
    rotvec_to_matrix,
)
from skyrecon.errors import InputError

vec3 = st.lists(st.floats(-3, 3, allow_nan=False), min_size=3, max_size=3)


def random_pose(rng, dst=None, src=None):
    return Rigid3.from_rotvec(rng.normal(size=3), rng.normal(size=3) * 5, dst, src)


def test_compose_and_inverse_give_identity():
    rng = np.random.default_rng(0)
    b_from_a = random_pose(rng, "b", "a")
    ident = b_from_a.inverse() @ b_from_a
    assert ident.allclose(Rigid3.identity(), atol=1e-12)
    assert ident.name == "a_from_a"
    assert (b_from_a @ b_from_a.inverse()).name == "b_from_b"


def test_composition_order_matches_point_mapping():
    rng = np.random.default_rng(1)
    b_from_a, c_from_b = random_pose(rng, "b", "a"), random_pose(rng, "c", "b")
    p_a = rng.normal(size=(10, 3))
    np.testing.assert_allclose(
        (c_from_b @ b_from_a).apply(p_a), c_from_b.apply(b_from_a.apply(p_a)), atol=1e-12
    )
    assert (c_from_b @ b_from_a).name == "c_from_a"


def test_frame_mismatch_is_caught():
    rng = np.random.default_rng(2)
    b_from_a, c_from_b = random_pose(rng, "b", "a"), random_pose(rng, "c", "b")
    with pytest.raises(FrameMismatchError):
        b_from_a @ c_from_b
    # unlabelled transforms compose freely
    random_pose(rng) @ random_pose(rng)


def test_center_is_camera_position_in_world():
    eye = np.array([3.0, -2.0, 10.0])
    cam_from_world = Rigid3.look_at(eye, [0, 0, 0])
    np.testing.assert_allclose(cam_from_world.center, eye, atol=1e-12)
    # the target is straight ahead on the optical axis
    p = cam_from_world.apply(np.zeros(3))
    assert p[2] > 0 and abs(p[0]) < 1e-9 and abs(p[1]) < 1e-9
    # world up maps to image "up" (negative y)
    up_cam = cam_from_world.rotate(np.array([[0, 0, 1.0]]))[0]
    assert up_cam[1] < 0


def test_rejects_bad_input():
    with pytest.raises(InputError):
        Rigid3(np.eye(3) * 2, np.zeros(3))
    with pytest.raises(InputError):
        Rigid3(np.eye(3), [0, np.nan, 0])
    with pytest.raises(InputError):
        Rigid3(np.eye(3), [0, 0])
    with pytest.raises(InputError):
        Rigid3.from_matrix(np.eye(2))
    with pytest.raises(InputError):
        Rigid3.look_at([1, 1, 1], [1, 1, 1])


def test_matrix_round_trip_and_float32_points():
    rng = np.random.default_rng(3)
    T = random_pose(rng)
    assert Rigid3.from_matrix(T.matrix).allclose(T)
    assert Rigid3.from_matrix(T.matrix3x4).allclose(T)
    pts = rng.normal(size=(5, 3)).astype(np.float32)
    assert T.apply(pts).dtype == np.float32


@settings(max_examples=200, deadline=None)
@given(vec3)
def test_rotvec_round_trip(w):
    w = np.asarray(w)
    R = rotvec_to_matrix(w)
    assert abs(np.linalg.det(R) - 1) < 1e-9
    np.testing.assert_allclose(rotvec_to_matrix(matrix_to_rotvec(R)), R, atol=1e-7)


@settings(max_examples=200, deadline=None)
@given(vec3)
def test_quaternion_round_trip(w):
    R = rotvec_to_matrix(np.asarray(w))
    q = matrix_to_quaternion(R)
    assert q[0] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
    np.testing.assert_allclose(quaternion_to_matrix(q), R, atol=1e-9)


def test_quaternion_convention_is_hamilton():
    # 90 degrees about z: q = (cos 45, 0, 0, sin 45) maps x to y
    q = np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
    np.testing.assert_allclose(quaternion_to_matrix(q) @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_rotation_angle_and_orthonormalize():
    R = rotvec_to_matrix([0, 0, np.radians(30)])
    assert abs(rotation_angle_deg(R) - 30) < 1e-9
    noisy = R + 1e-3 * np.random.default_rng(4).normal(size=(3, 3))
    Rn = orthonormalize(noisy)
    np.testing.assert_allclose(Rn @ Rn.T, np.eye(3), atol=1e-12)
    assert rotation_angle_deg(Rn.T @ R) < 0.2


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-6, 0.3, 2.0, np.pi - 1e-6, np.pi])
def test_rotation_angle_is_accurate_over_the_whole_range(angle):
    R = rotvec_to_matrix(angle * np.array([2.0, -1.0, 0.5]) / np.linalg.norm([2.0, -1.0, 0.5]))
    assert rotation_angle(R) == pytest.approx(angle, rel=1e-6, abs=1e-15)
    assert rotation_angle_deg(R) == pytest.approx(np.degrees(angle), rel=1e-6, abs=1e-13)
