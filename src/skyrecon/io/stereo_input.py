"""One way to open a stereo sequence of any kind we read: KITTI odometry, EuRoC/ASL, or a ROS bag.

:func:`open_stereo_sequence` tells them apart and returns a :class:`StereoInput`: the rectified rig,
frame times, lazily read rectified frames and the ground truth the sequence carries (KITTI
``poses.txt``, EuRoC ``state_groundtruth_estimate0``, a bag's pose topic), as ``world_from_left``
per frame. Bags (ROS 2 directories, ROS 1 ``.bag``, ``.mcap``) need the topics named
(:class:`skyrecon.io.rosbag_input.BagTopics`).

KITTI times come from ``times.txt`` (one number of seconds per line, as in the KITTI odometry
dataset) when present, else frames are taken as 10 Hz (KITTI's rate).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skyrecon.core.rigid import Rigid3
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError
from skyrecon.io.euroc import EurocSequence, is_euroc_dir, read_euroc
from skyrecon.io.rosbag_input import BagSequence, BagTopics, is_bag, read_bag
from skyrecon.io.sequence import StereoSequence, is_sequence_dir, read_sequence
from skyrecon.io.trajectory import TimedTrajectory, read_trajectory

__all__ = ["StereoInput", "open_stereo_sequence", "kitti_times", "KITTI_DEFAULT_FPS"]

KITTI_DEFAULT_FPS = 10.0


@dataclass
class StereoInput:
    """A stereo sequence ready for odometry.

    Attributes:
        root: the directory (or bag file) given.
        layout: ``"kitti"``, ``"euroc"`` or ``"rosbag"``.
        rig: the rectified rig, metres.
        timestamps_s: (N,) frame times, seconds.
        world_from_left: ground truth per frame (None entries where it does not cover a frame), or None.
        gt_source: where the ground truth came from (a description), or "".
        body_from_left: EuRoC only: the rectified left camera in the body frame.
        times_assumed: KITTI without ``times.txt``: times are ``index / 10``.
    """

    root: Path
    layout: str
    rig: StereoRig
    timestamps_s: np.ndarray
    sequence: StereoSequence | EurocSequence | BagSequence
    world_from_left: list[Rigid3 | None] | None = None
    gt_source: str = ""
    body_from_left: Rigid3 | None = None
    times_assumed: bool = False

    def __len__(self) -> int:
        return len(self.sequence)

    def frame(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(left, right) rectified images of frame ``i``, (H, W, 3) uint8 RGB."""
        return self.sequence.frame(i)

    def use_groundtruth(self, path: str | Path) -> None:
        """Replace the ground truth by a file (KITTI poses.txt by frame index; TUM by time; EuRoC body
        poses by time, turned into left-camera poses with the sequence's ``body_from_left``)."""
        traj = read_trajectory(path)
        self.world_from_left = associate(traj, self, Path(path))
        self.gt_source = str(path)


def associate(traj: TimedTrajectory, seq: StereoInput, path: Path) -> list[Rigid3 | None]:
    """``world_from_left`` per frame of ``seq`` from a ground-truth trajectory (see
    :meth:`StereoInput.use_groundtruth`)."""
    n = len(seq)
    if traj.timestamps_s is None:
        if len(traj) != n:
            raise InputError(
                f"{len(traj)} poses for {n} frames; a KITTI poses file needs one line per frame", path
            )
        return list(traj.poses)
    if traj.frame == "body":
        if seq.body_from_left is None:
            raise InputError(
                "EuRoC ground truth gives body (IMU) poses, but this sequence has no body-to-camera "
                "transform; give a TUM or KITTI file of left-camera poses",
                path,
            )
        traj = traj.transformed(seq.body_from_left, "left")
    assert traj.timestamps_s is not None
    spacing = float(np.median(np.diff(traj.timestamps_s))) if len(traj) > 1 else 0.0
    idx, poses = traj.at_times(seq.timestamps_s, max_gap_s=max(0.05, 1.01 * spacing))
    if len(idx) < 2:
        raise InputError(
            f"the ground truth covers {len(idx)} of the {n} frame times "
            f"({seq.timestamps_s[0]:.3f}..{seq.timestamps_s[-1]:.3f} s); are the clocks the same?",
            path,
        )
    out: list[Rigid3 | None] = [None] * n
    for k, p in zip(idx, poses):
        out[int(k)] = p
    return out


def kitti_times(root: Path, n: int) -> tuple[np.ndarray, bool]:
    """(frame times in seconds (n,), True when assumed at 10 Hz for want of ``root/times.txt``)."""
    path = root / "times.txt"
    if not path.is_file():
        return np.arange(n) / KITTI_DEFAULT_FPS, True
    words = path.read_text(encoding="utf-8").split()
    try:
        t = np.array([float(w) for w in words])
    except ValueError:
        raise InputError("times.txt must hold one number of seconds per frame", path) from None
    if len(t) != n:
        raise InputError(f"{len(t)} times for {n} frames; times.txt needs one line per frame", path)
    if np.any(np.diff(t) <= 0):
        raise InputError("times must increase", path)
    return t, False


def open_stereo_sequence(path: str | Path, bag_topics: BagTopics | None = None) -> StereoInput:
    """Open a KITTI-layout or EuRoC-layout stereo sequence directory, or a ROS bag / MCAP file.

    Args:
        path: the sequence directory, ROS 2 bag directory, ``.bag`` or ``.mcap`` file.
        bag_topics: the topics to read from a bag (ignored for the directory layouts).
    Raises:
        InputError: none of these, or a file of the layout is bad (named).
    """
    root = Path(path)
    if root.exists() and is_bag(root):
        b = read_bag(root, bag_topics or BagTopics())
        source = f"{b.topics.pose} (pose topic)" if b.world_from_left is not None else ""
        return StereoInput(root, "rosbag", b.rig, b.timestamps_s, b, b.world_from_left, source)
    if not root.is_dir():
        raise InputError("sequence directory not found; check the path", root)
    if is_euroc_dir(root):
        e = read_euroc(root)
        return StereoInput(
            root,
            "euroc",
            e.rig,
            e.timestamps_s,
            e,
            e.world_from_left,
            "state_groundtruth_estimate0/data.csv" if e.world_from_left is not None else "",
            e.body_from_left,
        )
    if is_sequence_dir(root):
        k = read_sequence(root)
        t, assumed = kitti_times(root, len(k))
        gt = list(k.world_from_left) if k.world_from_left is not None else None
        return StereoInput(root, "kitti", k.rig, t, k, gt, "poses.txt" if gt else "", None, assumed)  # type: ignore[arg-type]
    raise InputError(
        "not a stereo sequence: expected the KITTI layout (image_2/, image_3/, calib.txt), the "
        "EuRoC layout (mav0/cam0/data.csv, mav0/cam1/) or a ROS bag (metadata.yaml, .bag, .mcap)",
        root,
    )
