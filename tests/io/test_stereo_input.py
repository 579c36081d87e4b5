"""Opening either stereo layout for odometry: times, ground truth from the sequence or a file."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError
from skyrecon.io.sequence import write_sequence
from skyrecon.io.stereo_input import open_stereo_sequence
from skyrecon.io.trajectory import write_tum
from skyrecon.sim.euroc import write_synthetic_euroc
from skyrecon.sim.scenes import default_rig


@pytest.fixture
def kitti(tmp_path):
    rig = default_rig(64, 48)
    rng = np.random.default_rng(0)
    frames = [(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8),) * 2 for _ in range(4)]
    poses = [Rigid3(np.eye(3), [k, 0, 0], "world", "left") for k in range(4)]
    write_sequence(tmp_path / "k", rig, frames, poses)
    return tmp_path / "k", poses


def test_kitti_times_and_groundtruth(kitti, tmp_path):
    root, poses = kitti
    seq = open_stereo_sequence(root)
    assert seq.layout == "kitti" and seq.times_assumed and np.allclose(seq.timestamps_s, [0, 0.1, 0.2, 0.3])
    assert seq.gt_source == "poses.txt" and seq.world_from_left[3].allclose(poses[3])  # type: ignore[index,union-attr]
    (root / "times.txt").write_text("0.0\n0.2\n0.4\n0.6\n")
    seq = open_stereo_sequence(root)
    assert not seq.times_assumed and np.allclose(seq.timestamps_s, [0, 0.2, 0.4, 0.6])
    # a TUM ground truth at other times is interpolated at the frame times
    write_tum(tmp_path / "gt.txt", [0.0, 1.0], [Rigid3(np.eye(3), [0, 0, 0]), Rigid3(np.eye(3), [0, 10, 0])])
    seq.use_groundtruth(tmp_path / "gt.txt")
    assert seq.world_from_left[1].t[1] == pytest.approx(2.0)  # type: ignore[index,union-attr]
    (root / "times.txt").write_text("0.0\n0.2\n")
    with pytest.raises(InputError, match="times.txt"):
        open_stereo_sequence(root)


def test_euroc_body_groundtruth_needs_the_body_frame(kitti, tmp_path):
    root, _ = kitti
    syn = write_synthetic_euroc(tmp_path / "e", n_frames=2, seed=1, width=64, height=48)
    seq = open_stereo_sequence(syn.root)
    assert seq.layout == "euroc" and seq.body_from_left is not None and len(seq) == 2
    kitti_seq = open_stereo_sequence(root)
    with pytest.raises(InputError, match="body"):
        kitti_seq.use_groundtruth(syn.root / "mav0" / "state_groundtruth_estimate0" / "data.csv")
    with pytest.raises(InputError, match="not a stereo sequence"):
        open_stereo_sequence(tmp_path)
