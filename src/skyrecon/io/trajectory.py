"""Camera trajectories on disk: TUM, KITTI ``poses.txt`` and EuRoC ground truth, and matching a
timed trajectory to frame times.

* TUM (``trajectory.txt``, read by ``evo``): one line per pose ``timestamp tx ty tz qx qy qz qw``
  (seconds, metres, Hamilton quaternion with the scalar LAST); the pose is ``world_from_camera``.
  Lines starting with ``#`` are comments.
* KITTI ``poses.txt``: 12 numbers per line, row-major 3x4 ``world_from_left_camera``; no times
  (frame ``i`` is frame ``i`` of the sequence).
* EuRoC/ASL ``state_groundtruth_estimate0/data.csv``: ``#timestamp [ns], p_RS_R_x, p_RS_R_y,
  p_RS_R_z, q_RS_w, q_RS_x, q_RS_y, q_RS_z, ...`` (comma separated): the pose of the BODY (IMU)
  frame S in the world R, ``world_from_body``, with the scalar FIRST. Convert to camera poses with
  the camera's ``body_from_camera`` (its ``T_BS``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from skyrecon.core.rigid import Rigid3, matrix_to_quaternion, quaternion_to_matrix
from skyrecon.errors import InputError
from skyrecon.io.atomic import write_text_atomic
from skyrecon.io.sequence import format_poses, parse_poses
from skyrecon.io.text import parse_numbers

__all__ = [
    "TimedTrajectory",
    "format_tum",
    "write_tum",
    "read_tum",
    "read_euroc_groundtruth",
    "read_trajectory",
    "format_poses",
]


@dataclass
class TimedTrajectory:
    """Poses with times.

    Attributes:
        timestamps_s: (N,) increasing seconds, or None for a KITTI file (frame index only).
        poses: N ``world_from_<frame>`` poses, metres.
        frame: what the poses locate (``"left"`` camera, or ``"body"`` for EuRoC ground truth).
    """

    timestamps_s: np.ndarray | None
    poses: list[Rigid3]
    frame: str = "left"

    def __len__(self) -> int:
        return len(self.poses)

    def transformed(self, frame_from_new: Rigid3, new_frame: str) -> TimedTrajectory:
        """The same times with ``world_from_new = world_from_frame @ frame_from_new`` (e.g.
        ``body_from_left`` turns body ground truth into left-camera poses)."""
        T = frame_from_new.with_frames(None, None)
        poses = [p.with_frames(None, None) @ T for p in self.poses]
        return TimedTrajectory(
            self.timestamps_s, [p.with_frames("world", new_frame) for p in poses], new_frame
        )

    def at_times(self, times_s: np.ndarray, max_gap_s: float = 0.1) -> tuple[np.ndarray, list[Rigid3]]:
        """Poses interpolated at ``times_s`` (M,) seconds: positions linearly, rotations by slerp,
        between the two neighbouring samples when both are within ``max_gap_s`` of the time.

        Returns:
            (indices into ``times_s`` that could be matched, their poses).
        """
        if self.timestamps_s is None:
            raise InputError("this trajectory has no timestamps (a KITTI poses.txt): match it by frame index")
        ts = self.timestamps_s
        times = np.asarray(times_s, dtype=np.float64)
        k = np.searchsorted(ts, times, side="right")  # ts[k-1] <= t < ts[k]
        lo, hi = np.clip(k - 1, 0, len(ts) - 1), np.clip(k, 0, len(ts) - 1)
        exact = np.abs(ts[lo] - times) <= 1e-9
        ok = (
            (k >= 1) & (k < len(ts)) & (times - ts[lo] <= max_gap_s) & (ts[hi] - times <= max_gap_s)
        ) | exact
        idx = np.flatnonzero(ok)
        if len(idx) == 0:
            return idx, []
        P = np.array([p.t for p in self.poses])
        rots = Rotation.from_matrix(np.array([p.R for p in self.poses]))
        out = []
        for m in idx:
            a, b = int(lo[m]), int(hi[m])
            if exact[m] or a == b:
                out.append(self.poses[a].with_frames("world", self.frame))
                continue
            w = (times[m] - ts[a]) / (ts[b] - ts[a])
            R = Slerp([0.0, 1.0], rots[[a, b]])([w]).as_matrix()[0]
            out.append(Rigid3(R, (1 - w) * P[a] + w * P[b], "world", self.frame))
        return idx, out


def format_tum(timestamps_s: Sequence[float] | np.ndarray, world_from_cam: Sequence[Rigid3]) -> str:
    """TUM text: ``timestamp tx ty tz qx qy qz qw`` per pose (``world_from_cam``), full precision."""
    if len(timestamps_s) != len(world_from_cam):
        raise InputError(f"{len(timestamps_s)} timestamps for {len(world_from_cam)} poses")
    lines = ["# timestamp tx ty tz qx qy qz qw\n"]
    for t, p in zip(timestamps_s, world_from_cam):
        w, x, y, z = matrix_to_quaternion(p.R)
        vals = [float(t), *map(float, p.t), float(x), float(y), float(z), float(w)]
        lines.append(" ".join(repr(v) for v in vals) + "\n")
    return "".join(lines)


def write_tum(
    path: str | Path, timestamps_s: Sequence[float] | np.ndarray, world_from_cam: Sequence[Rigid3]
) -> None:
    """Write a TUM trajectory atomically (see :func:`format_tum`)."""
    write_text_atomic(path, format_tum(timestamps_s, world_from_cam))


def _read_text(path: Path) -> str:
    if not path.is_file():
        raise InputError("trajectory file not found", path)
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read the trajectory ({exc})", path) from None


def _check_increasing(ts: np.ndarray, path: Path) -> None:
    if len(ts) == 0:
        raise InputError("no poses in the trajectory file", path)
    if np.any(np.diff(ts) <= 0):
        k = int(np.flatnonzero(np.diff(ts) <= 0)[0])
        raise InputError(f"timestamps must increase (pose {k + 2} is not after pose {k + 1})", path)


def _tum_lines(text: str, path: Path) -> TimedTrajectory:
    ts, poses = [], []
    for lineno, line in enumerate(text.splitlines(), start=1):
        words = line.split("#", 1)[0].replace(",", " ").split()
        if not words:
            continue
        if len(words) != 8:
            raise InputError(
                f"line {lineno}: a TUM pose needs 8 numbers (t tx ty tz qx qy qz qw), found {len(words)}",
                path,
            )
        v = parse_numbers(words, path, lineno, "the pose")
        try:
            R = quaternion_to_matrix(np.array([v[7], v[4], v[5], v[6]]))
        except InputError as exc:
            raise InputError(f"line {lineno}: {exc.reason}", path) from None
        ts.append(v[0])
        poses.append(Rigid3(R, v[1:4], "world", "left"))
    ts_arr = np.array(ts, dtype=np.float64)
    _check_increasing(ts_arr, path)
    return TimedTrajectory(ts_arr, poses, "left")


def read_tum(path: str | Path) -> TimedTrajectory:
    """A TUM trajectory (``world_from_camera`` per line, seconds)."""
    path = Path(path)
    return _tum_lines(_read_text(path), path)


def read_euroc_groundtruth(path: str | Path) -> TimedTrajectory:
    """EuRoC ``state_groundtruth_estimate0/data.csv`` (or ``vicon0``/``leica0`` ``data.csv`` with at
    least the 8 pose columns): ``world_from_body`` per row; nanosecond timestamps become seconds.
    A position-only file (``leica0``: 4 columns) gives identity rotations."""
    path = Path(path)
    text = _read_text(path)
    ts_ns: list[int] = []
    pos, quat = [], []
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#") or line.startswith("%"):
            continue
        words = [w.strip() for w in line.split(",")]
        if len(words) < 4:
            raise InputError(f"line {lineno}: expected 'timestamp [ns], x, y, z, qw, qx, qy, qz, ...'", path)
        try:
            ts_ns.append(int(words[0]))
        except ValueError:
            raise InputError(
                f"line {lineno}: the timestamp {words[0]!r} is not an integer of nanoseconds", path
            ) from None
        n = 8 if len(words) >= 8 else 4
        v = parse_numbers(words[1:n], path, lineno, "the pose")
        pos.append(v[:3])
        quat.append(v[3:7] if n == 8 else np.array([1.0, 0.0, 0.0, 0.0]))
    ts = (np.array(ts_ns, dtype=np.int64) - (ts_ns[0] if ts_ns else 0)).astype(np.float64) * 1e-9
    if ts_ns:
        ts += ts_ns[0] * 1e-9
    _check_increasing(ts, path)
    poses = []
    for k, (p, q) in enumerate(zip(pos, quat)):
        try:
            poses.append(Rigid3(quaternion_to_matrix(q), p, "world", "body"))
        except InputError as exc:
            raise InputError(f"pose {k + 1}: {exc.reason}", path) from None
    return TimedTrajectory(ts, poses, "body")


def read_trajectory(path: str | Path) -> TimedTrajectory:
    """Read ground truth in any of the three formats, told apart by their content: EuRoC (commas,
    nanosecond integer first column, 8+ columns or a ``#timestamp`` header), TUM (8 numbers per
    line), KITTI (12 numbers per line, no times).

    Raises:
        InputError: naming the file and line when the content is none of them.
    """
    path = Path(path)
    text = _read_text(path)
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith(("#", "%"))]
    if not lines:
        raise InputError("no poses in the trajectory file", path)
    first = lines[0]
    if "," in first:
        head = first.split(",")[0].strip()
        if head.isdigit() and len(head) >= 12:
            return read_euroc_groundtruth(path)
        return _tum_lines(text, path)
    n = len(first.split())
    if n == 12:
        return TimedTrajectory(None, parse_poses(text, path), "left")
    if n == 8:
        return _tum_lines(text, path)
    raise InputError(
        f"unknown trajectory format ({n} numbers on the first line): expected a KITTI poses.txt "
        "(12 numbers), a TUM file (8) or a EuRoC data.csv",
        path,
    )
