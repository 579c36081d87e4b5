"""ROS bags and MCAP files as stereo input: reading, synchronization, decoding and clear errors."""

from __future__ import annotations

import sys

import cv2
import numpy as np
import pytest

pytest.importorskip("rosbags")

from skyrecon.core.intrinsics import Intrinsics  # noqa: E402
from skyrecon.core.rigid import Rigid3  # noqa: E402
from skyrecon.core.stereo_rig import StereoRig  # noqa: E402
from skyrecon.errors import InputError  # noqa: E402
from skyrecon.io.calib import kitti_projections  # noqa: E402
from skyrecon.io.rosbag_input import (  # noqa: E402
    BagTopics,
    _pair,
    _rig_and_maps,
    decode_image,
    default_info_topic,
    read_bag,
)
from skyrecon.io.rosbag_output import TOPICS, write_stereo_bag  # noqa: E402
from skyrecon.io.stereo_input import open_stereo_sequence  # noqa: E402

RIG = StereoRig.rectified(Intrinsics(50.0, 50.0, 31.5, 23.5, 64, 48), 0.3)


def _frames(n: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    return [tuple(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(2)) for _ in range(n)]  # type: ignore[misc]


def _poses(n: int) -> list[Rigid3]:
    return [
        Rigid3.from_rotvec(np.array([0.0, 0.1 * i, 0.0]), np.array([i, 0.5 * i, 2.0]), "world", "left")
        for i in range(n)
    ]


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_round_trip(tmp_path, storage):
    frames, poses = _frames(3), _poses(3)
    path = tmp_path / ("f.mcap" if storage == "mcap" else "bag")
    write_stereo_bag(path, RIG, frames, [10**9 + i * 10**8 for i in range(3)], poses, storage)
    seq = open_stereo_sequence(path, TOPICS)
    assert seq.layout == "rosbag" and len(seq) == 3
    assert seq.rig.is_rectified and seq.rig.baseline_m == pytest.approx(0.3)
    np.testing.assert_allclose(seq.timestamps_s, [1.0, 1.1, 1.2])
    for i in range(3):
        left, right = seq.frame(i)
        np.testing.assert_array_equal(left, frames[i][0])
        np.testing.assert_array_equal(right, frames[i][1])
        assert seq.world_from_left is not None and seq.world_from_left[i].allclose(poses[i], atol=1e-12)


def test_poses_are_interpolated_to_image_times(tmp_path):
    poses = _poses(3)
    path = tmp_path / "bag"
    # poses stamped 50 ms after each image: frame 0 is before them, frames 1, 2 half-way
    write_stereo_bag(
        path,
        RIG,
        _frames(3),
        [i * 10**8 for i in range(3)],
        poses,
        pose_times_ns=[5 * 10**7 + i * 10**8 for i in range(3)],
    )
    seq = read_bag(path, TOPICS)
    assert seq.world_from_left is not None and seq.world_from_left[0] is None
    p = seq.world_from_left[1]
    assert p is not None
    np.testing.assert_allclose(p.t, 0.5 * (poses[0].t + poses[1].t))
    np.testing.assert_allclose(p.rotvec, [0.0, 0.05, 0.0], atol=1e-12)


def test_pairs_nearest_within_tolerance():
    left = np.array([0, 100, 200, 300]) * 10**6
    right = np.array([302, 1, 99, 260]) * 10**6  # 200 ms has no partner within 5 ms
    li, ri = _pair(left, right, 5 * 10**6)
    assert li.tolist() == [0, 1, 3] and ri.tolist() == [1, 2, 0]


class _Msg:
    def __init__(self, **kw):
        self.__dict__.update(kw)


def test_decode_raw_and_compressed():
    rgb = np.random.default_rng(1).integers(0, 256, (5, 7, 3), dtype=np.uint8)
    bgr = _Msg(
        encoding="bgr8",
        height=5,
        width=7,
        step=24,
        data=np.pad(rgb[:, :, ::-1].reshape(5, 21), ((0, 0), (0, 3))).reshape(-1),
    )
    np.testing.assert_array_equal(decode_image(bgr, None, "/t"), rgb)  # type: ignore[arg-type]
    mono = _Msg(encoding="mono8", height=5, width=7, step=7, data=rgb[:, :, 0].reshape(-1))
    np.testing.assert_array_equal(decode_image(mono, None, "/t")[:, :, 2], rgb[:, :, 0])  # type: ignore[arg-type]
    png = cv2.imencode(".png", rgb[:, :, ::-1])[1]
    np.testing.assert_array_equal(decode_image(_Msg(format="png", data=png), None, "/t"), rgb)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="16UC1"):
        decode_image(
            _Msg(encoding="16UC1", height=5, width=7, step=14, data=np.zeros(70, np.uint8)), None, "/t"
        )  # type: ignore[arg-type]


def test_unrectified_info_is_rectified_with_opencv():
    P_l, P_r = kitti_projections(RIG)
    K = np.array([[52.0, 0, 32.0], [0, 51.0, 24.0], [0, 0, 1]])
    info = {"K": K, "D": np.array([-0.1, 0.01, 0, 0, 0]), "R": np.eye(3), "width": 64, "height": 48}
    rig, maps = _rig_and_maps({**info, "P": P_l}, {**info, "P": P_r}, None)  # type: ignore[arg-type]
    assert maps is not None and maps[0][0].shape == (48, 64) and rig.baseline_m == pytest.approx(0.3)
    rig, maps = _rig_and_maps(
        {**info, "D": np.zeros(5), "P": P_l}, {**info, "D": np.zeros(5), "P": P_r}, None
    )  # type: ignore[arg-type]
    assert maps is None


def test_ros1_bag(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    P_l, P_r = kitti_projections(RIG)
    frames, poses = _frames(2), _poses(2)
    path = tmp_path / "flight.bag"

    def header(t_ns):
        return T["std_msgs/msg/Header"](
            seq=0,
            stamp=T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9),
            frame_id="cam",
        )

    with Writer(path) as w:
        c = {
            name: w.add_connection(topic, ty, typestore=store)
            for name, topic, ty in [
                ("l", "/cam/left/image", "sensor_msgs/msg/Image"),
                ("r", "/cam/right/image", "sensor_msgs/msg/Image"),
                ("li", "/cam/left/camera_info", "sensor_msgs/msg/CameraInfo"),
                ("ri", "/cam/right/camera_info", "sensor_msgs/msg/CameraInfo"),
                ("o", "/odom", "nav_msgs/msg/Odometry"),
            ]
        }
        for i, (left, right) in enumerate(frames):
            t = 5 * 10**9 + i * 10**8
            for key, img in (("l", left), ("r", right)):
                msg = T["sensor_msgs/msg/Image"](
                    header=header(t + (2 * 10**6 if key == "r" else 0)),
                    height=48,
                    width=64,
                    encoding="rgb8",
                    is_bigendian=0,
                    step=192,
                    data=img.reshape(-1),
                )
                w.write(c[key], t, store.serialize_ros1(msg, msg.__msgtype__))
            for key, P in (("li", P_l), ("ri", P_r)):
                roi = T["sensor_msgs/msg/RegionOfInterest"](
                    x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
                )
                msg = T["sensor_msgs/msg/CameraInfo"](
                    header=header(t),
                    height=48,
                    width=64,
                    distortion_model="plumb_bob",
                    D=np.zeros(5),
                    K=P[:, :3].reshape(-1),
                    R=np.eye(3).reshape(-1),
                    P=P.reshape(-1),
                    binning_x=0,
                    binning_y=0,
                    roi=roi,
                )
                w.write(c[key], t, store.serialize_ros1(msg, msg.__msgtype__))
            q = T["geometry_msgs/msg/Quaternion"]
            from skyrecon.core.rigid import matrix_to_quaternion

            qw, qx, qy, qz = matrix_to_quaternion(poses[i].R)
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=poses[i].t[0], y=poses[i].t[1], z=poses[i].t[2]),
                orientation=q(x=qx, y=qy, z=qz, w=qw),
            )
            cov = np.zeros(36)
            msg = T["nav_msgs/msg/Odometry"](
                header=header(t),
                child_frame_id="left",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](
                    twist=T["geometry_msgs/msg/Twist"](
                        linear=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                        angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                    ),
                    covariance=cov,
                ),
            )
            w.write(c["o"], t, store.serialize_ros1(msg, msg.__msgtype__))
    seq = open_stereo_sequence(path, BagTopics("/cam/left/image", "/cam/right/image", pose="/odom"))
    assert len(seq) == 2 and seq.rig.baseline_m == pytest.approx(0.3)
    np.testing.assert_array_equal(seq.frame(1)[1], frames[1][1])
    assert seq.world_from_left is not None and seq.world_from_left[1].allclose(poses[1], atol=1e-12)


# ----- errors --------------------------------------------------------------------------------
def test_missing_topics_are_listed(tmp_path):
    path = tmp_path / "bag"
    write_stereo_bag(path, RIG, _frames(2), [0, 10**8], None)
    with pytest.raises(
        InputError, match="no topic /cam/left in the bag; its topics: /stereo/left/camera_info"
    ) as e:
        read_bag(path, BagTopics("/cam/left", "/cam/right"))
    assert e.value.path == path
    with pytest.raises(
        InputError, match="image topics in this bag: /stereo/left/image_raw, /stereo/right/image_raw"
    ):
        read_bag(path, BagTopics())
    with pytest.raises(InputError, match="no topic /stereo/left/pose"):
        read_bag(path, BagTopics(TOPICS.left, TOPICS.right, pose=TOPICS.pose))


def test_poses_not_overlapping_images(tmp_path):
    path = tmp_path / "bag"
    write_stereo_bag(path, RIG, _frames(2), [0, 10**8], _poses(2), pose_times_ns=[100 * 10**9, 101 * 10**9])
    with pytest.raises(InputError, match=r"do not overlap in time") as e:
        read_bag(path, TOPICS)
    assert e.value.path == path


@pytest.mark.parametrize("name", ["junk.bag", "junk.mcap", "dir"])
def test_not_a_bag(tmp_path, name):
    path = tmp_path / name
    if name == "dir":
        path.mkdir()
        (path / "metadata.yaml").write_text("not: [a, bag")
    else:
        path.write_bytes(b"this is not a bag\n" * 10)
    with pytest.raises(InputError, match="not a readable ROS bag") as e:
        open_stereo_sequence(path, TOPICS)
    assert e.value.path == path


def test_missing_library_gives_the_install_hint(tmp_path, monkeypatch):
    path = tmp_path / "f.mcap"
    path.write_bytes(b"x")
    monkeypatch.setitem(sys.modules, "rosbags", None)
    with pytest.raises(InputError, match=r"pip install 'skyrecon\[ros\]'"):
        open_stereo_sequence(path, TOPICS)


def test_default_info_topic():
    assert default_info_topic("/stereo/left/image_raw") == "/stereo/left/camera_info"
