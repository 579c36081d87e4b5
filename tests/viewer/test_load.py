"""Loading every kind of output the viewer reads, and refusing what it does not."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.reconstruction import Image, Point3D, Reconstruction
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError
from skyrecon.io.colmap import write_colmap_text
from skyrecon.io.ply import read_ply, write_ply
from skyrecon.viewer import load_scene
from tests.viewer.conftest import make_cloud, make_map


def test_ply(ply_file):
    scene = load_scene(ply_file)
    cloud = read_ply(ply_file)
    np.testing.assert_array_equal(scene.points, cloud.points)
    np.testing.assert_array_equal(scene.colors, cloud.colors)
    assert scene.total_points == len(cloud.points) and not len(scene.voxel_centers)


def test_las_keeps_large_coordinates(tmp_path):
    pytest.importorskip("laspy")
    from skyrecon.io.las import write_las

    cloud = make_cloud(500)
    p = tmp_path / "cloud.las"
    write_las(p, cloud)
    scene = load_scene(p)
    np.testing.assert_allclose(scene.points, cloud.points, atol=1e-3)
    np.testing.assert_array_equal(scene.colors, cloud.colors)
    assert scene.points.dtype == np.float64


def _colmap_model(directory):
    K = Intrinsics(100.0, 100.0, 63.5, 47.5, 128, 96)
    images = {}
    for i, x in enumerate((0.0, 1.0, 2.0), start=1):
        # cameras on the x axis looking along +y (world): cam z = world y
        R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # cam_from_world
        images[i] = Image(i, f"{i}.png", 1, Rigid3(R, -R @ np.array([x, 0.0, 0.0])))
    points = {j + 1: Point3D(j + 1, np.array([j * 0.1, 5.0, 0.0]), np.array([10, 20, 30])) for j in range(20)}
    write_colmap_text(directory, Reconstruction({1: K}, images, points))


def test_colmap_model_and_sfm_output(tmp_path):
    _colmap_model(tmp_path / "sfm" / "sparse")
    for path in (tmp_path / "sfm" / "sparse", tmp_path / "sfm"):
        scene = load_scene(path)
        assert (
            len(scene.points) == 20 and scene.colors is not None and (scene.colors[0] == [10, 20, 30]).all()
        )
        segs = scene.camera_segments
        assert segs.shape == (3 * 8, 2, 3)
        # each frustum starts at its camera centre and points along +y (the optical axis)
        np.testing.assert_allclose(segs[0, 0], [0, 0, 0], atol=1e-9)
        np.testing.assert_allclose(segs[8, 0], [1, 0, 0], atol=1e-9)
        assert (segs[:4, 1, 1] > 0).all()


def test_map_directory(map_dir):
    scene = load_scene(map_dir)
    assert len(scene.voxel_centers) == 4 * 4 * 6 and scene.voxel_size_m == 0.5
    assert [p.name for p in scene.paths] == ["flown"] and len(scene.paths[0].points) == 3
    assert load_scene(map_dir / "map.json").total_voxels == 96


def test_mission_directory(mission_dir):
    scene = load_scene(mission_dir)
    assert len(scene.voxel_centers) == 96
    assert [p.name for p in scene.paths] == ["flown", "planned"]
    np.testing.assert_allclose(scene.paths[1].points[-1], [6, 6, 3])
    assert load_scene(mission_dir / "mission.json").total_voxels == 96


def test_path_json_and_plan_output(tmp_path):
    from skyrecon.planning import write_path_json

    d = tmp_path / "route"
    d.mkdir()
    write_path_json(d / "path.json", np.array([[0.0, 0, 10], [5, 5, 12], [9, 1, 10]]))
    for p in (d, d / "path.json"):
        scene = load_scene(p)
        assert [x.name for x in scene.paths] == ["path"] and len(scene.paths[0].points) == 3


def test_mvs_output(tmp_path):
    write_ply(tmp_path / "fused.ply", make_cloud(100))
    assert len(load_scene(tmp_path).points) == 100


@pytest.mark.parametrize("kind", ["missing", "dir", "txt", "json", "badjson"])
def test_unrecognised_inputs_say_what_is_accepted(tmp_path, kind):
    p = tmp_path / "x"
    if kind == "dir":
        p.mkdir()
        (p / "notes.txt").write_text("hello")
    elif kind == "txt":
        p = tmp_path / "x.txt"
        p.write_text("hello")
    elif kind == "json":
        p = tmp_path / "x.json"
        p.write_text(json.dumps({"hello": 1}))
    elif kind == "badjson":
        p = tmp_path / "x.json"
        p.write_text("{")
    with pytest.raises(InputError) as e:
        load_scene(p)
    msg = str(e.value)
    assert str(p) in msg and ".ply" in msg and "map directory" in msg and "\n" not in msg


def test_corrupt_map_is_an_input_error(tmp_path):
    make_map(tmp_path / "m")
    (tmp_path / "m" / "blocks.npz").write_bytes(b"junk")
    with pytest.raises(InputError, match="blocks.npz"):
        load_scene(tmp_path / "m")
