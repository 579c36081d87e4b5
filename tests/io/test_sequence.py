"""Stereo sequences in the KITTI odometry layout: write/read round trips and validation."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError
from skyrecon.io.calib import read_kitti_calib
from skyrecon.io.images import read_image, write_image
from skyrecon.io.sequence import is_sequence_dir, read_sequence, write_sequence
from tests.conftest import require
from tests.io.test_calib import CAM_TO_CAM

W, H = 24, 16
RIG = StereoRig.rectified(Intrinsics(30.0, 30.0, 11.5, 7.5, W, H), 0.25)


def _frames(n: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    return [tuple(rng.integers(0, 256, (H, W, 3), dtype=np.uint8) for _ in range(2)) for _ in range(n)]


def _poses(n: int, seed: int = 0) -> list[Rigid3]:
    rng = np.random.default_rng(seed)
    return [
        Rigid3.from_rotvec(rng.normal(size=3), rng.normal(size=3) * 10, "world", "left") for _ in range(n)
    ]


def test_round_trip_with_poses(tmp_path):
    frames, poses = _frames(3), _poses(3)
    written = write_sequence(tmp_path / "seq", RIG, frames, poses)
    seq = read_sequence(tmp_path / "seq")
    assert len(seq) == len(written) == 3
    assert [p.name for p in seq.left_paths] == ["000000.png", "000001.png", "000002.png"]
    assert [p.parent.name for p in seq.right_paths] == ["image_3"] * 3
    for i, (left, right) in enumerate(frames):
        got_left, got_right = seq.frame(i)
        np.testing.assert_array_equal(got_left, left)
        np.testing.assert_array_equal(got_right, right)
    for got, want in zip(seq.world_from_left, poses):
        np.testing.assert_array_equal(got.matrix, want.matrix)  # full precision
        assert got.name == "world_from_left"
    np.testing.assert_array_equal(seq.rig.left.K, RIG.left.K)
    assert seq.rig.baseline_m == pytest.approx(0.25, rel=1e-15) and seq.rig.is_rectified
    assert is_sequence_dir(tmp_path / "seq")
    leftovers = [p.name for p in (tmp_path / "seq").rglob("*") if p.name.endswith(".tmp")]
    assert leftovers == []


def test_files_follow_the_kitti_layout(tmp_path):
    write_sequence(tmp_path, RIG, _frames(2), _poses(2))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["calib.txt", "image_2", "image_3", "poses.txt"]
    calib = read_kitti_calib(tmp_path / "calib.txt", W, H)
    assert calib.projections["P3"][0, 3] == pytest.approx(-30.0 * 0.25)
    rows = (tmp_path / "poses.txt").read_text().splitlines()
    assert len(rows) == 2 and all(len(r.split()) == 12 for r in rows)
    M = np.array(rows[1].split(), dtype=float).reshape(3, 4)
    np.testing.assert_array_equal(M, _poses(2)[1].matrix3x4)  # world_from_left, row-major 3x4


def test_without_poses_generator_grey_frames_and_progress(tmp_path):
    frames = ((np.full((H, W), i, np.uint8), np.full((H, W), 100 + i, np.uint8)) for i in range(2))
    seq = write_sequence(tmp_path, RIG, frames, progress=True)
    assert seq.world_from_left is None and not (tmp_path / "poses.txt").exists()
    left, right = seq.frame(-1)
    assert left.shape == (H, W, 3) and np.all(left == 1) and np.all(right == 101)


def test_rewriting_removes_stale_frames_and_poses(tmp_path):
    write_sequence(tmp_path, RIG, _frames(4), _poses(4))
    seq = write_sequence(tmp_path, RIG, _frames(2, seed=5))
    assert len(seq) == 2 and seq.world_from_left is None
    assert sorted(p.name for p in (tmp_path / "image_3").iterdir()) == ["000000.png", "000001.png"]


def test_frame_index_out_of_range(tmp_path):
    seq = write_sequence(tmp_path, RIG, _frames(1))
    with pytest.raises(IndexError):
        seq.frame(1)


def test_frame_with_wrong_size_names_the_image(tmp_path):
    seq = write_sequence(tmp_path, RIG, _frames(2))
    write_image(tmp_path / "image_3" / "000001.png", np.zeros((H + 1, W, 3), np.uint8))
    with pytest.raises(InputError) as info:
        seq.frame(1)
    assert "000001.png" in str(info.value) and f"{W}x{H + 1}" in str(info.value)


def test_is_sequence_dir(tmp_path):
    assert not is_sequence_dir(tmp_path)
    assert not is_sequence_dir(tmp_path / "missing")
    (tmp_path / "image_2").mkdir()
    (tmp_path / "image_3").mkdir()
    assert not is_sequence_dir(tmp_path)
    (tmp_path / "calib.txt").write_text("")
    assert is_sequence_dir(tmp_path)


# ----- writing errors ---------------------------------------------------------------------
def test_write_refuses_bad_inputs(tmp_path):
    with pytest.raises(InputError, match="3 poses for 2 frames"):
        write_sequence(tmp_path / "a", RIG, _frames(2), _poses(3))
    with pytest.raises(InputError, match="3 poses for 2 frames"):
        write_sequence(tmp_path / "b", RIG, iter(_frames(2)), _poses(3))
    inverted = [p.inverse() for p in _poses(2)]
    with pytest.raises(InputError, match="left_from_world"):
        write_sequence(tmp_path / "c", RIG, _frames(2), inverted)
    with pytest.raises(InputError, match="frame 1: the right image is"):
        frames = _frames(2)
        frames[1] = (frames[1][0], np.zeros((H, W + 2, 3), np.uint8))
        write_sequence(tmp_path / "d", RIG, frames)
    with pytest.raises(InputError, match="uint8"):
        write_sequence(tmp_path / "e", RIG, [(np.zeros((H, W), np.float32),) * 2])
    with pytest.raises(InputError, match="no frames"):
        write_sequence(tmp_path / "f", RIG, [])
    unrectified = StereoRig(RIG.left, RIG.right, Rigid3.from_rotvec([0, 0.2, 0], [-0.25, 0, 0]))
    with pytest.raises(InputError, match="rectif"):
        write_sequence(tmp_path / "g", unrectified, _frames(1))
    assert not (tmp_path / "g").exists()


# ----- reading errors ---------------------------------------------------------------------
@pytest.fixture
def seq_dir(tmp_path):
    write_sequence(tmp_path / "seq", RIG, _frames(3), _poses(3))
    return tmp_path / "seq"


def _expect(root, *words):
    with pytest.raises(InputError) as info:
        read_sequence(root)
    for w in words:
        assert w in str(info.value)


def test_read_missing_directory(tmp_path):
    _expect(tmp_path / "nothing", "not found", "nothing")


def test_read_missing_right_dir(seq_dir):
    for p in (seq_dir / "image_3").iterdir():
        p.unlink()
    (seq_dir / "image_3").rmdir()
    _expect(seq_dir, "image_3", "missing image directory")


def test_read_empty_left_dir(tmp_path):
    (tmp_path / "image_2").mkdir()
    (tmp_path / "image_3").mkdir()
    _expect(tmp_path, "no images", "image_2")


def test_read_mismatched_frame_names(seq_dir):
    (seq_dir / "image_3" / "000002.png").rename(seq_dir / "image_3" / "000007.png")
    _expect(seq_dir, "000002 only in image_2", "000007 only in image_3")


def test_read_missing_calib(seq_dir):
    (seq_dir / "calib.txt").unlink()
    _expect(seq_dir, "calib.txt", "missing")


def test_read_bad_calib(seq_dir):
    (seq_dir / "calib.txt").write_text("P2: 1 2 3\nP3: 1 2 3\n")
    _expect(seq_dir, "calib.txt", "line 1")


def test_read_corrupt_first_image(seq_dir):
    (seq_dir / "image_2" / "000000.png").write_bytes(b"not a png")
    _expect(seq_dir, "000000.png", "corrupt")


def test_read_pose_count_mismatch(seq_dir):
    rows = (seq_dir / "poses.txt").read_text().splitlines()
    (seq_dir / "poses.txt").write_text("\n".join(rows[:2]) + "\n")
    _expect(seq_dir, "poses.txt", "2 poses for 3 frames")


@pytest.mark.parametrize(
    "bad_row, words",
    [
        ("1 0 0 0 0 1 0 0 0 0 1 nan", "line 2: the pose contains NaN"),
        ("1 0 0 0 0 1 0 0 0 0 1", "line 2: a pose needs 12 numbers"),
        ("1 0 0 0 0 1 0 0 0 0 1 zero", "line 2: the pose: 'zero' is not a number"),
        ("2 0 0 0 0 1 0 0 0 0 1 0", "line 2: not a rotation"),
        ("-1 0 0 0 0 1 0 0 0 0 1 0", "line 2: not a rotation"),
    ],
)
def test_read_bad_pose_lines(seq_dir, bad_row, words):
    rows = (seq_dir / "poses.txt").read_text().splitlines()
    rows[1] = bad_row
    (seq_dir / "poses.txt").write_text("\n".join(rows) + "\n")
    _expect(seq_dir, "poses.txt", words)


def test_read_kitti_style_poses_with_seven_digits(seq_dir):
    # KITTI's own poses.txt prints 7 significant digits: rotations are orthonormal to ~1e-7.
    rows = [
        "1.000000e+00 9.043680e-12 2.326809e-11 5.551115e-17 9.043683e-12 1.000000e+00 "
        "2.392370e-10 3.330669e-16 2.326810e-11 2.392370e-10 9.999999e-01 -4.440892e-16"
    ] * 3
    (seq_dir / "poses.txt").write_text("\n".join(rows) + "\n")
    assert len(read_sequence(seq_dir).world_from_left) == 3


# ----- the real KITTI pair ----------------------------------------------------------------------
@pytest.mark.realdata
def test_real_kitti_pair_as_a_sequence(real_data, tmp_path):
    root = require(real_data, "kitti2015-stereo-sample/training")
    left = read_image(root / "image_2" / "000046_10.png")
    right = read_image(root / "image_3" / "000046_10.png")
    (tmp_path / "cam_to_cam.txt").write_text(CAM_TO_CAM)
    rig = read_kitti_calib(tmp_path / "cam_to_cam.txt").rig
    seq = write_sequence(tmp_path / "seq", rig, [(left, right)], [Rigid3.identity("world", "left")])
    got_left, got_right = seq.frame(0)
    np.testing.assert_array_equal(got_left, left)
    np.testing.assert_array_equal(got_right, right)
    assert seq.rig.baseline_m == pytest.approx(rig.baseline_m, rel=1e-14)
    np.testing.assert_array_equal(seq.rig.left.K, rig.left.K)


@pytest.mark.realdata
def test_real_kitti_training_dir_with_a_calib_reads_as_a_sequence(real_data, tmp_path):
    root = require(real_data, "kitti2015-stereo-sample/training")
    # Build the layout by linking (not copying) the real images.
    for d in ("image_2", "image_3"):
        (tmp_path / d).mkdir()
        (tmp_path / d / "000046_10.png").symlink_to(root / d / "000046_10.png")
    (tmp_path / "calib.txt").write_text(CAM_TO_CAM)
    seq = read_sequence(tmp_path)
    assert len(seq) == 1 and seq.world_from_left is None
    assert seq.frame(0)[0].shape == (375, 1242, 3)
