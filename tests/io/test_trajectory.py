"""Trajectory files: TUM round trip, KITTI and EuRoC detection, interpolation at frame times."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core.rigid import Rigid3, matrix_to_quaternion, rotation_angle_deg, rotvec_to_matrix
from skyrecon.errors import InputError
from skyrecon.io.sequence import format_poses
from skyrecon.io.trajectory import read_trajectory, write_tum


def _poses(n: int = 12) -> list[Rigid3]:
    return [
        Rigid3(rotvec_to_matrix([0.02 * k, -0.1, 0.3 * k]), [k, 2.0 * k, 0.5], "world", "left")
        for k in range(n)
    ]


def test_tum_round_trip(tmp_path):
    poses = _poses()
    ts = 1.5 + 0.1 * np.arange(len(poses))
    write_tum(tmp_path / "t.txt", ts, poses)
    first = (tmp_path / "t.txt").read_text().splitlines()[1].split()
    assert len(first) == 8  # timestamp tx ty tz qx qy qz qw: scalar last
    w, x, y, z = matrix_to_quaternion(poses[0].R)
    assert [float(v) for v in first[4:]] == pytest.approx([x, y, z, w])
    traj = read_trajectory(tmp_path / "t.txt")
    assert np.allclose(traj.timestamps_s, ts)
    for a, b in zip(traj.poses, poses):
        assert a.allclose(b, atol=1e-12)


def test_kitti_poses_have_no_times(tmp_path):
    (tmp_path / "poses.txt").write_text(format_poses(_poses(5)))
    traj = read_trajectory(tmp_path / "poses.txt")
    assert traj.timestamps_s is None and len(traj) == 5
    with pytest.raises(InputError, match="no timestamps"):
        traj.at_times(np.zeros(1))


def test_euroc_groundtruth_interpolates_at_frame_times(tmp_path):
    t0 = 1403636579763555584
    lines = [
        "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []"
    ]
    for k in range(11):  # 10 Hz, yawing 1 degree per sample, moving 1 m per sample
        q = matrix_to_quaternion(rotvec_to_matrix([0, 0, np.radians(k)]))
        lines.append(f"{t0 + k * 100_000_000},{k}.0,0,0," + ",".join(str(v) for v in q) + ",0,0,0")
    (tmp_path / "data.csv").write_text("\n".join(lines) + "\n")
    traj = read_trajectory(tmp_path / "data.csv")
    assert traj.frame == "body" and len(traj) == 11
    times = t0 * 1e-9 + np.array([0.05, 0.25, 2.0])
    idx, poses = traj.at_times(times)
    assert list(idx) == [0, 1]  # 2.0 s is after the last sample
    assert poses[1].t[0] == pytest.approx(2.5, abs=1e-5)
    assert rotation_angle_deg(poses[1].R) == pytest.approx(2.5, abs=1e-4)


def test_bad_files_name_the_line(tmp_path):
    p = tmp_path / "t.txt"
    p.write_text("0 1 2 3 0 0 0 1\n0.1 1 2 3 0 0 1\n")
    with pytest.raises(InputError, match="t.txt: unknown|line 2"):
        read_trajectory(p)
    p.write_text("0 1 2 3 0 0 0 1\n0 1 2 3 0 0 0 1\n")
    with pytest.raises(InputError, match="must increase"):
        read_trajectory(p)
    p.write_text("1 2 3\n")
    with pytest.raises(InputError, match="unknown trajectory format"):
        read_trajectory(p)
