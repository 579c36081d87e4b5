"""``skyrecon sfm --record`` (8 rendered 320x240 views around a monument) and ``skyrecon mvs
--record`` (6 rendered 256x192 views): the cameras (pose, thumbnail), the sparse points / the
depth maps and the fused cloud."""

from __future__ import annotations

import json

import pytest

from skyrecon.cli.main import main
from skyrecon.core.intrinsics import Intrinsics
from skyrecon.io.calib import write_K_txt
from skyrecon.io.images import write_image
from skyrecon.sim import generate_object_scene, orbit_views, render_views

from .readers import mcap_topics, rrd_frames, rrd_rows

pytest.importorskip("rerun")
pytest.importorskip("foxglove")
pytest.importorskip("mcap")

VIEWS = 6


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    out = tmp_path_factory.mktemp("photos")
    args = ["render", "images", "--views", str(VIEWS), "--width", "256", "--height", "192", "--seed", "4"]
    assert main([*args, "--quiet", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def monument(tmp_path_factory):
    """As tests/cli/test_sfm_cli.py: 8 views on a 100-degree arc around a monument, K.txt."""
    d = tmp_path_factory.mktemp("monument")
    intr = Intrinsics.from_fov(320, 240, 70)
    scene = generate_object_scene(1)
    views = orbit_views(scene, 8, intr, seed=0, arc_deg=100)
    (d / "images").mkdir()
    for v, r in zip(views, render_views(scene, views)):
        write_image(d / "images" / v.name, r.image)
    write_K_txt(d / "K.txt", intr)
    return d


def test_sfm_records_cameras_and_sparse_points(monument, tmp_path):
    out, rec = tmp_path / "sfm", tmp_path / "sfm.rrd"
    args = ["sfm", str(monument / "images"), "--camera", str(monument / "K.txt"), "--out", str(out)]
    assert main([*args, "--max-image-size", "256", "--workers", "1", "--quiet", "--record", str(rec)]) == 0
    registered = json.loads((out / "sfm.json").read_text())["num_registered"]
    assert registered >= 3
    rows = rrd_rows(rec)
    cameras = sorted(e for (e, a) in rows if e.startswith("/world/cameras/") and a == "Transform3D")
    assert len(cameras) == registered
    assert all(rows[(f"{c}/image", "EncodedImage")] == 1 for c in cameras)
    assert rows[("/world/sparse/points", "Points3D")] == 1
    assert rows[("/world/path/cameras", "LineStrips3D")] == 1
    assert rrd_frames(rec, cameras[0]) == [0]


def test_mvs_records_depth_maps_and_the_fused_cloud(photos, tmp_path):
    out, rec = tmp_path / "mvs", tmp_path / "mvs.mcap"
    args = ["mvs", str(photos / "images"), "--cameras", str(photos / "gt_sparse"), "--out", str(out)]
    assert main([*args, "--max-image-size", "128", "--workers", "1", "--quiet", "--record", str(rec)]) == 0
    topics = mcap_topics(rec)
    images = [t for t in topics if t.startswith("/cameras/") and t.endswith("/image")]
    depths = [t for t in topics if t.startswith("/cameras/") and t.endswith("/depth")]
    assert len(images) == VIEWS and len(depths) == VIEWS
    assert all(topics[t] == ("foxglove.RawImage", 1) for t in depths)
    assert topics["/fused/points"] == ("foxglove.PointCloud", 1)
    assert topics["/tf"] == ("foxglove.FrameTransform", VIEWS)
