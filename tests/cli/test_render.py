"""End to end: ``skyrecon render`` writes scenes that the readers load back consistently."""

import json

import numpy as np
import pytest

from skyrecon.cli.main import main
from skyrecon.io import read_cameras, read_image, read_kitti_calib, read_pfm, read_ply, read_sequence

SMALL = ["--width", "160", "--height", "120", "--seed", "5", "--quiet"]


def test_render_stereo(tmp_path):
    out = tmp_path / "stereo"
    assert main(["render", "stereo", "--out", str(out), *SMALL]) == 0
    left, right = read_image(out / "left.png"), read_image(out / "right.png")
    assert left.shape == right.shape == (120, 160, 3)
    rig = read_kitti_calib(out / "calib.txt", 160, 120).rig
    disparity, depth = read_pfm(out / "gt_disparity.pfm"), read_pfm(out / "gt_depth.pfm")
    ok = np.isfinite(depth)
    assert ok.mean() > 0.3
    np.testing.assert_allclose(rig.disparity_to_depth(disparity)[ok], depth[ok], rtol=1e-4)
    assert len(read_ply(out / "gt_points.ply")) == ok.sum()
    scene = json.loads((out / "scene.json").read_text())
    assert scene["seed"] == 5 and scene["kind"] == "stereo"


def test_render_is_deterministic(tmp_path):
    for name in ("a", "b"):
        assert main(["render", "stereo", "--out", str(tmp_path / name), *SMALL]) == 0
    assert (tmp_path / "a" / "left.png").read_bytes() == (tmp_path / "b" / "left.png").read_bytes()


def test_render_sequence_reads_back(tmp_path):
    out = tmp_path / "flight"
    assert main(["render", "sequence", "--out", str(out), "--frames", "3", *SMALL]) == 0
    seq = read_sequence(out)
    assert len(seq) == 3 and len(seq.world_from_left) == 3
    left, right = seq.frame(2)
    assert left.shape == (120, 160, 3)
    assert read_pfm(out / "depth_2" / "000002.pfm").shape == (120, 160)


@pytest.mark.parametrize("kind, model", [("ring", "sparse"), ("images", "gt_sparse")])
def test_render_views_read_back_as_cameras(tmp_path, kind, model):
    out = tmp_path / kind
    assert main(["render", kind, "--out", str(out), "--views", "4", *SMALL]) == 0
    views = read_cameras(out / model, image_dir=out / "images")
    assert len(views) == 4
    # the scene centre is in front of every camera and inside every image
    centre = np.mean([v.center_world for v in views], axis=0)
    centre[2] = 1.0
    for v in views:
        uv, z = v.project(centre[None])
        assert z[0] > 0 and v.intrinsics.in_image(uv)[0]
    if kind == "ring":
        assert read_pfm(out / "depth" / (views[0].name.rsplit(".", 1)[0] + ".pfm")).shape == (120, 160)


def test_render_plain_city(tmp_path, capsys):
    out = tmp_path / "plain"
    assert main(["render", "sequence", "--plain", "--out", str(out), "--frames", "2", *SMALL]) == 0
    assert json.loads((out / "scene.json").read_text())["plain"] is True
    assert len(read_sequence(out)) == 2
    plain = read_image(out / "image_2" / "000000.png")
    textured = tmp_path / "textured"
    assert main(["render", "sequence", "--out", str(textured), "--frames", "2", *SMALL]) == 0
    assert not np.array_equal(plain, read_image(textured / "image_2" / "000000.png"))
