"""Depth maps stored beside a stereo sequence (``SEQUENCE/depth_2/<frame>.pfm``)."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Intrinsics, Rigid3, StereoRig
from skyrecon.errors import InputError
from skyrecon.io.depth_dir import iter_depth_maps, read_depth_map, sequence_depth_paths
from skyrecon.io.pfm import write_pfm
from skyrecon.io.sequence import read_sequence, write_sequence

CAM = Intrinsics.from_fov(32, 24, 60.0)


def test_depth_maps_of_a_sequence(tmp_path):
    rig = StereoRig.rectified(CAM, 0.3)
    black = np.zeros((24, 32, 3), np.uint8)
    poses = [Rigid3(np.eye(3), np.array([float(i), 0.0, 0.0]), "world", "left") for i in range(3)]
    write_sequence(tmp_path, rig, [(black, black)] * 3, poses)
    seq = read_sequence(tmp_path)
    paths = sequence_depth_paths(seq, "depth_2")
    assert [p.parent.name for p in paths] == ["depth_2"] * 3
    assert [p.stem for p in paths] == [p.stem for p in seq.left_paths]
    for i, p in enumerate(paths):
        p.parent.mkdir(exist_ok=True)
        write_pfm(p, np.full((24, 32), 5.0 + i, np.float32))
    depths = list(iter_depth_maps(paths, CAM))
    assert [float(d[0, 0]) for d in depths] == [5.0, 6.0, 7.0]
    write_pfm(paths[1], np.ones((12, 16), np.float32))
    with pytest.raises(InputError, match="16x12"):
        read_depth_map(paths[1], CAM)
    with pytest.raises(InputError):
        read_depth_map(tmp_path / "missing.pfm", CAM)
