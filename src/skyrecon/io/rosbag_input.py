"""ROS 1 bags, ROS 2 bags and MCAP files as stereo sequences (pure Python: the ``rosbags`` library).

Inputs: a ROS 2 bag directory (``metadata.yaml`` + ``.db3``/``.mcap``), a ROS 1 ``.bag`` file or
a bare ``.mcap`` file (ROS 2 profile). What is read (:class:`BagTopics` names the topics):

* left/right images: ``sensor_msgs/msg/Image`` (``rgb8``, ``bgr8``, ``mono8``, ``rgba8``, ``bgra8``)
  or ``sensor_msgs/msg/CompressedImage`` (png, jpeg); frames are the left images with a right image
  whose header stamp is within ``sync_tolerance_s`` (nearest one);
* camera info: ``sensor_msgs/msg/CameraInfo`` of each camera (the first message). When both have no
  distortion and ``R = I`` the images are taken as rectified and the rig comes from the two ``P``
  matrices (``P_right[0, 3] = -fx * baseline``); otherwise each image is rectified with OpenCV from
  ``K, D, R, P`` (the ROS convention) and the rig is the one of the ``P`` pair;
* optional poses of the left camera in the world frame (``world_from_left``, metres):
  ``nav_msgs/msg/Odometry``, ``geometry_msgs/msg/PoseStamped`` or ``geometry_msgs/msg/TransformStamped``,
  interpolated to image times (positions linearly, rotations by slerp).

Times are the messages' header stamps, seconds. Frames are decoded lazily by
:meth:`BagSequence.frame`. ``rosbags`` is an optional dependency (the ``ros`` extra), imported here
only when a bag is read.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from skyrecon.core.rigid import Rigid3, quaternion_to_matrix
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError
from skyrecon.io.calib import rectified_rig_from_projections
from skyrecon.io.trajectory import TimedTrajectory

__all__ = [
    "BagTopics",
    "BagSequence",
    "is_bag",
    "read_bag",
    "require_rosbags",
    "default_info_topic",
    "IMAGE_TYPES",
    "POSE_TYPES",
]

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
POSE_TYPES = ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/TransformStamped")
ROS_HINT = "reading ROS bags needs the 'ros' extra: pip install 'skyrecon[ros]'"


@dataclass(frozen=True)
class BagTopics:
    """The topics to read from a bag.

    Attributes:
        left, right: image topics (raw or compressed).
        left_info, right_info: CameraInfo topics; None: the image topic's namespace + ``/camera_info``.
        pose: topic with ``world_from_left`` poses, or None.
        sync_tolerance_s: largest left/right stamp difference of a pair, seconds.
    """

    left: str | None = None
    right: str | None = None
    left_info: str | None = None
    right_info: str | None = None
    pose: str | None = None
    sync_tolerance_s: float = 0.005


def default_info_topic(image_topic: str) -> str:
    """``/stereo/left/image_raw`` -> ``/stereo/left/camera_info``."""
    namespace = image_topic.rstrip("/").rsplit("/", 1)[0]
    return f"{namespace}/camera_info"


def is_bag(path: str | Path) -> bool:
    """True for a ROS 2 bag directory (``metadata.yaml``), a ``.bag`` file or an ``.mcap`` file."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    return p.suffix.lower() in (".bag", ".mcap")


def require_rosbags() -> None:
    """Raise InputError with the install hint when ``rosbags`` is not installed."""
    try:
        import rosbags  # noqa: F401
    except ImportError:
        raise InputError(ROS_HINT) from None


# ----- reading messages ------------------------------------------------------------------------
class _Bag:
    """An open bag: ``topics`` (name -> message type) and ``messages(topics, start, stop)``."""

    def __init__(self, path: Path, reader: Any, deserialize: Any, connections: list[Any]) -> None:
        self.path = path
        self._reader = reader
        self._deserialize = deserialize
        self._connections = connections
        self.topics: dict[str, str] = {c.topic: c.msgtype for c in connections}

    def messages(
        self, topics: set[str], start_ns: int | None = None, stop_ns: int | None = None
    ) -> Iterator[tuple[str, int, Any]]:
        """(topic, log time ns, message) of ``topics`` in log-time order."""
        conns = [c for c in self._connections if c.topic in topics]
        try:
            for conn, t_ns, raw in self._reader.messages(conns, start=start_ns, stop=stop_ns):
                yield conn.topic, int(t_ns), self._deserialize(raw, conn.msgtype)
        except InputError:
            raise
        except Exception as exc:  # rosbags raises its own error types per format
            raise InputError(f"cannot read the bag's messages ({exc})", self.path) from None


@contextmanager
def _open_bag(path: Path) -> Iterator[_Bag]:
    """Open a ROS 1/ROS 2 bag or a bare MCAP file; InputError naming the file when it is not one."""
    require_rosbags()
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2.storage_mcap import McapReader
    from rosbags.typesys import Stores, get_typestore

    if not path.exists():
        raise InputError("bag not found; check the path", path)
    try:
        if path.is_file() and path.suffix.lower() == ".mcap":
            reader: Any = McapReader(path)
            reader.open()
            store = get_typestore(Stores.ROS2_HUMBLE)
            deserialize, connections = store.deserialize_cdr, list(reader.connections)
            closer = reader.close
        else:
            reader = AnyReader([path])
            reader.open()
            deserialize, connections, closer = reader.deserialize, list(reader.connections), reader.close
    except InputError:
        raise
    except Exception as exc:
        raise InputError(
            f"not a readable ROS bag ({type(exc).__name__}: {exc}); expected a ROS 2 bag directory, "
            "a ROS 1 .bag or an .mcap file",
            path,
        ) from None
    try:
        yield _Bag(path, reader, deserialize, connections)
    finally:
        closer()


# ----- message decoding ------------------------------------------------------------------------
def _stamp_ns(msg: Any) -> int:
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def decode_image(msg: Any, path: Path, topic: str) -> np.ndarray:
    """A ``sensor_msgs`` Image or CompressedImage as (H, W, 3) uint8 RGB."""
    if hasattr(msg, "format"):  # CompressedImage
        image = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise InputError(f"{topic}: cannot decode a compressed image (format {msg.format!r})", path)
        return np.ascontiguousarray(image[:, :, ::-1])
    enc = str(msg.encoding).lower()
    channels = {"rgb8": 3, "bgr8": 3, "mono8": 1, "8uc1": 1, "rgba8": 4, "bgra8": 4, "8uc3": 3}.get(enc)
    if channels is None:
        raise InputError(
            f"{topic}: image encoding {msg.encoding!r} is not supported (rgb8, bgr8, mono8, rgba8, bgra8)",
            path,
        )
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < w * channels or data.size < step * h:
        raise InputError(f"{topic}: image data ({data.size} bytes) too short for {w}x{h} {enc}", path)
    rows = data[: step * h].reshape(h, step)[:, : w * channels].reshape(h, w, channels)
    if channels == 1:
        return np.repeat(rows, 3, axis=2)
    if enc.startswith("bgr") or enc == "8uc3":
        rows = rows[:, :, 2::-1]
    return np.ascontiguousarray(rows[:, :, :3])


def _camera_info(msg: Any) -> dict[str, np.ndarray | int]:
    """K (3, 3), D (n,), R (3, 3), P (3, 4), width, height of a CameraInfo (ROS 1 or ROS 2 names)."""

    def get(name: str) -> np.ndarray:
        value = getattr(msg, name.lower(), None)
        if value is None:
            value = getattr(msg, name.upper())
        return np.asarray(value, dtype=np.float64)

    return {
        "K": get("k").reshape(3, 3),
        "D": get("d").reshape(-1),
        "R": get("r").reshape(3, 3),
        "P": get("p").reshape(3, 4),
        "width": int(msg.width),
        "height": int(msg.height),
    }


def _pose(msg: Any, msgtype: str) -> Rigid3:
    """``world_from_left`` of a pose message (Odometry, PoseStamped or TransformStamped)."""
    if msgtype == "nav_msgs/msg/Odometry":
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
    elif msgtype == "geometry_msgs/msg/PoseStamped":
        p, q = msg.pose.position, msg.pose.orientation
    else:
        p, q = msg.transform.translation, msg.transform.rotation
    R = quaternion_to_matrix(np.array([q.w, q.x, q.y, q.z], dtype=np.float64))
    return Rigid3(R, np.array([p.x, p.y, p.z], dtype=np.float64), "world", "left")


# ----- the sequence --------------------------------------------------------------------------
@dataclass
class BagSequence:
    """A stereo sequence read from a bag.

    Attributes:
        root: the bag (directory or file).
        topics: the topics read.
        rig: the rectified rig, metres.
        timestamps_s: (N,) left image stamps, seconds.
        left_log_ns, right_log_ns: (N,) log times of the pair's messages (to read them again).
        world_from_left: per-frame pose from the pose topic (None where it does not cover a frame), or None.
        rectify_maps: None when the images are already rectified, else OpenCV (map_x, map_y) per camera.
    """

    root: Path
    topics: BagTopics
    rig: StereoRig
    timestamps_s: np.ndarray
    left_log_ns: np.ndarray
    right_log_ns: np.ndarray
    world_from_left: list[Rigid3 | None] | None = None
    rectify_maps: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None
    frames_dropped: int = field(default=0)

    def __len__(self) -> int:
        return len(self.timestamps_s)

    def frame(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(left, right) rectified images of frame ``i``, (H, W, 3) uint8 RGB."""
        if not -len(self) <= i < len(self):
            raise IndexError(f"frame {i} of a {len(self)}-frame sequence")
        left_topic, right_topic = str(self.topics.left), str(self.topics.right)
        want = {left_topic: int(self.left_log_ns[i]), right_topic: int(self.right_log_ns[i])}
        got: dict[str, np.ndarray] = {}
        with _open_bag(self.root) as bag:
            for topic, t_ns, msg in bag.messages(set(want), min(want.values()), max(want.values()) + 1):
                if t_ns == want[topic] and topic not in got:
                    got[topic] = decode_image(msg, self.root, topic)
        images = []
        for k, (topic, camera) in enumerate(((left_topic, self.rig.left), (right_topic, self.rig.right))):
            if topic not in got:
                raise InputError(f"{topic}: the image of frame {i} could not be read again", self.root)
            image = got[topic]
            if self.rectify_maps is not None:
                mx, my = self.rectify_maps[k]
                image = cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            if image.shape[:2] != camera.shape:
                raise InputError(
                    f"{topic}: frame {i} is {image.shape[1]}x{image.shape[0]}, the camera info says "
                    f"{camera.width}x{camera.height}",
                    self.root,
                )
            images.append(image)
        return images[0], images[1]


def _check_topics(bag: _Bag, topics: BagTopics) -> tuple[str, str, str, str]:
    images = sorted(t for t, ty in bag.topics.items() if ty in IMAGE_TYPES)
    listing = ", ".join(f"{t} ({ty})" for t, ty in sorted(bag.topics.items())) or "none"
    if not topics.left or not topics.right:
        raise InputError(
            "name the stereo image topics with --left-topic and --right-topic; image topics in this bag: "
            + (", ".join(images) or "none"),
            bag.path,
        )
    left_info = topics.left_info or default_info_topic(topics.left)
    right_info = topics.right_info or default_info_topic(topics.right)
    wanted = [(topics.left, IMAGE_TYPES), (topics.right, IMAGE_TYPES), (left_info, (INFO_TYPE,))]
    wanted += [(right_info, (INFO_TYPE,))]
    if topics.pose:
        wanted.append((topics.pose, POSE_TYPES))
    for topic, types in wanted:
        if topic not in bag.topics:
            raise InputError(f"no topic {topic} in the bag; its topics: {listing}", bag.path)
        if bag.topics[topic] not in types:
            raise InputError(f"topic {topic} is {bag.topics[topic]}, expected {' or '.join(types)}", bag.path)
    return topics.left, topics.right, left_info, right_info


def _pair(left: np.ndarray, right: np.ndarray, tol_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into left, into right) of left stamps with a right stamp within ``tol_ns`` (nearest)."""
    order = np.argsort(right, kind="stable")
    rs = right[order]
    k = np.clip(np.searchsorted(rs, left), 1, max(1, len(rs) - 1))
    lo, hi = np.clip(k - 1, 0, len(rs) - 1), np.clip(k, 0, len(rs) - 1)
    pick = np.where(np.abs(rs[lo] - left) <= np.abs(rs[hi] - left), lo, hi)
    ok = np.abs(rs[pick] - left) <= tol_ns
    return np.flatnonzero(ok), order[pick[ok]]


def _rig_and_maps(
    info_l: dict[str, Any], info_r: dict[str, Any], path: Path
) -> tuple[StereoRig, tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None]:
    w, h = int(info_l["width"]), int(info_l["height"])
    if (w, h) != (int(info_r["width"]), int(info_r["height"])):
        raise InputError(
            f"the cameras differ in size ({w}x{h} and {info_r['width']}x{info_r['height']})", path
        )
    try:
        rig = rectified_rig_from_projections(info_l["P"], info_r["P"], w, h)
    except InputError as exc:
        raise InputError(f"camera info P matrices: {exc.reason}", path) from None
    rectified = all(
        not np.any(info["D"]) and (np.allclose(info["R"], np.eye(3)) or not np.any(info["R"]))
        for info in (info_l, info_r)
    )
    if rectified:
        return rig, None
    maps = []
    for info in (info_l, info_r):
        mx, my = cv2.initUndistortRectifyMap(
            info["K"], info["D"], info["R"], info["P"][:, :3], (w, h), cv2.CV_32FC1
        )
        maps.append((mx, my))
    return rig, (maps[0], maps[1])


def read_bag(path: str | Path, topics: BagTopics) -> BagSequence:
    """Index a bag as a stereo sequence (see the module docstring); images are read lazily.

    Raises:
        InputError: naming the bag: not a bag, missing topics (listing those it has), no
            synchronized pairs, poses that do not overlap the images in time.
    """
    root = Path(path)
    left_msgs: list[tuple[int, int]] = []  # (stamp ns, log ns)
    right_msgs: list[tuple[int, int]] = []
    infos: dict[str, dict[str, Any]] = {}
    pose_t: list[int] = []
    poses: list[Rigid3] = []
    with _open_bag(root) as bag:
        left, right, left_info, right_info = _check_topics(bag, topics)
        wanted = {left, right, left_info, right_info} | ({topics.pose} if topics.pose else set())
        pose_type = bag.topics.get(topics.pose or "", "")
        for topic, t_ns, msg in bag.messages(wanted):
            if topic == left:
                left_msgs.append((_stamp_ns(msg), t_ns))
            if topic == right:
                right_msgs.append((_stamp_ns(msg), t_ns))
            if topic in (left_info, right_info) and topic not in infos:
                infos[topic] = _camera_info(msg)
            if topic == topics.pose:
                pose_t.append(_stamp_ns(msg))
                poses.append(_pose(msg, pose_type))
    for topic, msgs in ((left, left_msgs), (right, right_msgs)):
        if not msgs:
            raise InputError(f"topic {topic} has no messages", root)
    for topic in (left_info, right_info):
        if topic not in infos:
            raise InputError(f"topic {topic} has no CameraInfo message", root)
    rig, maps = _rig_and_maps(infos[left_info], infos[right_info], root)
    L = np.array(sorted(left_msgs), dtype=np.int64)
    R = np.array(right_msgs, dtype=np.int64)
    tol_ns = int(round(topics.sync_tolerance_s * 1e9))
    li, ri = _pair(L[:, 0], R[:, 0], tol_ns)
    if len(li) == 0:
        raise InputError(
            f"no left image of {left} has a right image of {right} within {topics.sync_tolerance_s * 1e3:g} ms",
            root,
        )
    stamps_ns = L[li, 0]
    times = stamps_ns / 1e9
    seq = BagSequence(
        root, BagTopics(left, right, left_info, right_info, topics.pose), rig, times, L[li, 1], R[ri, 1]
    )
    seq.rectify_maps = maps
    seq.frames_dropped = len(L) - len(li)
    if topics.pose:
        seq.world_from_left = _poses_at(np.array(pose_t, dtype=np.int64), poses, stamps_ns, root, topics.pose)
    return seq


def _poses_at(
    pose_ns: np.ndarray, poses: list[Rigid3], image_ns: np.ndarray, path: Path, topic: str
) -> list[Rigid3 | None]:
    """``world_from_left`` at each image stamp (None outside the poses' span); InputError when none."""
    if len(poses) == 0:
        raise InputError(f"topic {topic} has no messages", path)
    order = np.argsort(pose_ns, kind="stable")
    pose_ns = pose_ns[order]
    keep = np.concatenate([[True], np.diff(pose_ns) > 0])
    traj = TimedTrajectory(pose_ns[keep] / 1e9, [poses[int(k)] for k in order[keep]], "left")
    span = float(traj.timestamps_s[-1] - traj.timestamps_s[0]) if len(traj) > 1 else 0.0  # type: ignore[index]
    times = image_ns / 1e9
    idx, interpolated = traj.at_times(times, max_gap_s=max(0.05, span + 1.0))
    if len(idx) == 0:
        assert traj.timestamps_s is not None
        raise InputError(
            f"the poses of {topic} ({traj.timestamps_s[0]:.3f}..{traj.timestamps_s[-1]:.3f} s) and the images "
            f"({times[0]:.3f}..{times[-1]:.3f} s) do not overlap in time",
            path,
        )
    out: list[Rigid3 | None] = [None] * len(times)
    for k, p in zip(idx, interpolated):
        out[int(k)] = p
    return out
