"""Small inputs for the viewer tests, written with skyrecon's own writers (no kernels compiled)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skyrecon.core.depth import PointCloud
from skyrecon.io.ply import write_ply
from skyrecon.mapping.config import MapConfig
from skyrecon.mapping.storage import write_flown_path, write_map_files
from skyrecon.planning import write_path_json


def make_cloud(n: int = 5000, offset=(0.0, 0.0, 0.0), seed: int = 0) -> PointCloud:
    """A wavy coloured surface 40 m x 30 m (metres, z up), shifted by ``offset``."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([-20, -15], [20, 15], (n, 2))
    z = 2.0 * np.sin(xy[:, 0] / 5.0) + 3.0
    pts = np.c_[xy, z] + np.asarray(offset)
    colors = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    return PointCloud(pts, colors)


def make_map(directory, voxel: float = 0.5) -> np.ndarray:
    """A map directory with a 2 x 2 x 3 m box of occupied voxels (one 8^3 block at the origin);
    returns the (M, 3) occupied centres."""
    cfg = MapConfig(voxel_size_m=voxel, block_size=8)
    lo = np.full((1, 8, 8, 8), np.nan, np.float32)
    lo[0, :, :, :] = -2.0  # free
    lo[0, 2:6, 2:6, 0:6] = 3.0  # occupied
    write_map_files(directory, cfg, np.zeros((1, 3), np.int32), lo)
    i, j, k = np.nonzero(lo[0] > 0)
    return (np.c_[i, j, k] + 0.5) * voxel


@pytest.fixture
def ply_file(tmp_path):
    p = tmp_path / "cloud.ply"
    write_ply(p, make_cloud())
    return p


@pytest.fixture
def map_dir(tmp_path):
    d = tmp_path / "map"
    make_map(d)
    write_flown_path(d, np.array([[-3.0, -3, 2], [0, -3, 2], [3, 0, 3]]), 0.3)
    return d


@pytest.fixture
def mission_dir(tmp_path):
    """The files of a mission directory the viewer reads: mission.json, path.json, map/."""
    d = tmp_path / "mission"
    make_map(d / "map")
    flown = np.array([[-5.0, -5, 2], [-2, -4, 3], [6, 6, 3]])
    planned = np.array([[-2.0, -4, 3], [2, 1, 3], [6, 6, 3]])
    d.mkdir(exist_ok=True)
    write_path_json(d / "path.json", flown, kind="flown", last_planned_path=planned)
    (d / "mission.json").write_text(json.dumps({"format": "skyrecon.mission", "version": 1}))
    return d
