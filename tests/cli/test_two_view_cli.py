"""End to end: ``skyrecon two-view`` on a rendered photo pair with known cameras."""

import json

import numpy as np
import pytest

from skyrecon.cli.main import main
from skyrecon.core import rotation_angle_deg
from skyrecon.io import read_cameras, read_ply


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    out = tmp_path_factory.mktemp("photos")
    assert (
        main(
            [
                "render",
                "images",
                "--views",
                "8",
                "--width",
                "480",
                "--height",
                "360",
                "--seed",
                "4",
                "--quiet",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    return out


def test_pose_matches_ground_truth(photos, tmp_path):
    views = {v.name: v for v in read_cameras(photos / "gt_sparse")}
    names = sorted(views)[:2]
    out = tmp_path / "pair"
    assert (
        main(
            [
                "two-view",
                str(photos / "images" / names[0]),
                str(photos / "images" / names[1]),
                "--camera",
                str(photos / "K.txt"),
                "--out",
                str(out),
                "--quiet",
            ]
        )
        == 0
    )
    result = json.loads((out / "two_view.json").read_text())
    gt = views[names[1]].cam_from_world @ views[names[0]].cam_from_world.inverse()
    R, t = np.array(result["R"]), np.array(result["t"])
    assert rotation_angle_deg(R @ gt.R.T) < 0.5
    direction_err = np.degrees(np.arccos(np.clip(t @ gt.t / np.linalg.norm(gt.t), -1, 1)))
    assert direction_err < 2.0
    assert abs(np.linalg.norm(t) - 1) < 1e-9 and result["num_inliers"] <= result["num_matches"]
    assert len(read_ply(out / "sparse.ply")) > 50
    for picture in ("matches.png", "epipolar.png"):
        assert (out / picture).stat().st_size > 0


def test_identical_images_are_refused(photos, tmp_path, capsys):
    image = str(photos / "images" / sorted(p.name for p in (photos / "images").iterdir())[0])
    code = main(
        [
            "two-view",
            image,
            image,
            "--camera",
            str(photos / "K.txt"),
            "--out",
            str(tmp_path / "o"),
            "--no-dense",
        ]
    )
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error:")


def test_K_for_another_size_is_refused(photos, tmp_path, capsys):
    k = tmp_path / "K.txt"
    k.write_text("2000 0 1500\n0 2000 1000\n0 0 1\n")
    image = str(next((photos / "images").iterdir()))
    assert main(["two-view", image, image, "--camera", str(k), "--out", str(tmp_path / "o")]) == 2
    assert "principal point" in capsys.readouterr().err
