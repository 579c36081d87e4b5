"""Write a rectified stereo flight as a ROS 2 bag (sqlite3 storage) or a single MCAP file.

Topics (what :func:`skyrecon.io.rosbag_input.read_bag` reads back with the defaults of
:data:`TOPICS`): ``/stereo/left/image_raw`` and ``/stereo/right/image_raw``
(``sensor_msgs/msg/Image``, ``rgb8``), ``/stereo/left/camera_info`` and
``/stereo/right/camera_info`` (``sensor_msgs/msg/CameraInfo``: rectified, no distortion, ``R = I``,
``P`` as KITTI's P2/P3), and ``/stereo/left/pose`` (``geometry_msgs/msg/PoseStamped``,
``world_from_left``, frame ``world``). Header stamps and log times are the frame times.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from skyrecon.core.rigid import Rigid3, matrix_to_quaternion
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError
from skyrecon.io.atomic import make_temp_dir
from skyrecon.io.calib import kitti_projections
from skyrecon.io.rosbag_input import BagTopics, require_rosbags

__all__ = ["TOPICS", "write_stereo_bag"]

TOPICS = BagTopics(
    left="/stereo/left/image_raw",
    right="/stereo/right/image_raw",
    left_info="/stereo/left/camera_info",
    right_info="/stereo/right/camera_info",
    pose="/stereo/left/pose",
)


def _header(store: Any, t_ns: int, frame_id: str) -> Any:
    Time, Header = store.types["builtin_interfaces/msg/Time"], store.types["std_msgs/msg/Header"]
    return Header(stamp=Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000), frame_id=frame_id)


def _camera_info(store: Any, t_ns: int, frame_id: str, P: np.ndarray, width: int, height: int) -> Any:
    ROI = store.types["sensor_msgs/msg/RegionOfInterest"]
    return store.types["sensor_msgs/msg/CameraInfo"](
        header=_header(store, t_ns, frame_id),
        height=height,
        width=width,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=np.ascontiguousarray(P[:, :3], dtype=np.float64).reshape(-1),
        r=np.eye(3).reshape(-1),
        p=np.ascontiguousarray(P, dtype=np.float64).reshape(-1),
        binning_x=0,
        binning_y=0,
        roi=ROI(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )


def _image(store: Any, t_ns: int, frame_id: str, image: np.ndarray) -> Any:
    image = np.asarray(image, dtype=np.uint8)
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    h, w = image.shape[:2]
    return store.types["sensor_msgs/msg/Image"](
        header=_header(store, t_ns, frame_id),
        height=h,
        width=w,
        encoding="rgb8",
        is_bigendian=0,
        step=3 * w,
        data=np.ascontiguousarray(image[:, :, :3]).reshape(-1),
    )


def _pose(store: Any, t_ns: int, pose: Rigid3) -> Any:
    T = store.types
    w, x, y, z = (float(v) for v in matrix_to_quaternion(pose.R))
    px, py, pz = (float(v) for v in pose.t)
    return T["geometry_msgs/msg/PoseStamped"](
        header=_header(store, t_ns, "world"),
        pose=T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=px, y=py, z=pz),
            orientation=T["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
        ),
    )


def write_stereo_bag(
    path: str | Path,
    rig: StereoRig,
    frames: Iterable[tuple[np.ndarray, np.ndarray]],
    times_ns: Sequence[int],
    world_from_left: Sequence[Rigid3] | None = None,
    storage: str = "sqlite3",
    pose_times_ns: Sequence[int] | None = None,
) -> Path:
    """Write a stereo flight as a bag; built in a temporary directory, then moved into place.

    Args:
        path: ``storage="sqlite3"``: the bag directory (``metadata.yaml`` + ``<name>.db3``; other files
            already there are kept, an older bag's files are replaced). ``storage="mcap"``: the
            ``.mcap`` file.
        rig: a rectified rig, metres.
        frames: (left, right) images, (H, W, 3) uint8 RGB or (H, W) grey.
        times_ns: frame times, nanoseconds (header stamps and log times).
        world_from_left: pose of the left camera per frame, metres, or None.
        storage: ``"sqlite3"`` or ``"mcap"``.
        pose_times_ns: stamps of the poses, nanoseconds (default: the frame times).
    Returns:
        The path written.
    """
    require_rosbags()
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    if storage not in ("sqlite3", "mcap"):
        raise InputError(f"bag storage must be sqlite3 or mcap, got {storage!r}")
    path = Path(path)
    store = get_typestore(Stores.ROS2_HUMBLE)
    P_left, P_right = kitti_projections(rig)
    w, h = rig.left.width, rig.left.height
    parent = path.parent if storage == "mcap" else path
    parent.mkdir(parents=True, exist_ok=True)
    tmp = make_temp_dir(parent, "bag")
    name = path.stem if storage == "mcap" else path.name
    try:
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        with Writer(tmp / name, version=9, storage_plugin=plugin) as writer:
            specs = [
                ("left", TOPICS.left, "sensor_msgs/msg/Image"),
                ("right", TOPICS.right, "sensor_msgs/msg/Image"),
                ("left_info", TOPICS.left_info, "sensor_msgs/msg/CameraInfo"),
                ("right_info", TOPICS.right_info, "sensor_msgs/msg/CameraInfo"),
            ]
            if world_from_left is not None:
                specs.append(("pose", TOPICS.pose, "geometry_msgs/msg/PoseStamped"))
            conns = {key: writer.add_connection(str(topic), ty, typestore=store) for key, topic, ty in specs}
            count = 0
            for i, (left, right) in enumerate(frames):
                t_ns = int(times_ns[i])
                msgs = {
                    "left": _image(store, t_ns, "left", left),
                    "right": _image(store, t_ns, "right", right),
                    "left_info": _camera_info(store, t_ns, "left", P_left, w, h),
                    "right_info": _camera_info(store, t_ns, "right", P_right, w, h),
                }
                for key, msg in msgs.items():
                    writer.write(conns[key], t_ns, store.serialize_cdr(msg, msg.__msgtype__))
                if world_from_left is not None:
                    tp = t_ns if pose_times_ns is None else int(pose_times_ns[i])
                    msg = _pose(store, tp, world_from_left[i])
                    writer.write(conns["pose"], tp, store.serialize_cdr(msg, msg.__msgtype__))
                count = i + 1
        if count == 0:
            raise InputError("no frames to write")
        if storage == "mcap":
            os.replace(tmp / name / f"{name}.mcap", path)
        else:
            for f in path.glob("*.db3"):
                f.unlink()
            os.replace(tmp / name / f"{name}.db3", path / f"{name}.db3")
            os.replace(tmp / name / "metadata.yaml", path / "metadata.yaml")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return path
