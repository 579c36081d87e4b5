"""End to end: ``skyrecon mvs`` on rendered views with known cameras, checked against the true geometry."""

import json
import shutil

import cv2
import numpy as np
import pytest

from skyrecon.cli.main import main
from skyrecon.io import read_ply
from skyrecon.io.pfm import read_pfm
from skyrecon.sim import generate_object_scene

SEED = 4


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    out = tmp_path_factory.mktemp("mvs_photos")
    assert (
        main(
            [
                "render",
                "images",
                "--views",
                "8",
                "--width",
                "256",
                "--height",
                "192",
                "--seed",
                str(SEED),
                "--quiet",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    return out


def test_fused_cloud_lies_on_the_true_surfaces(photos, tmp_path):
    out = tmp_path / "mvs"
    assert (
        main(
            [
                "mvs",
                str(photos / "images"),
                "--cameras",
                str(photos / "gt_sparse"),
                "--out",
                str(out),
                "--max-image-size",
                "256",
                "--workers",
                "1",
                "--quiet",
            ]
        )
        == 0
    )
    cloud = read_ply(out / "fused.ply")
    assert len(cloud) > 5000 and cloud.colors is not None
    scene = generate_object_scene(SEED)
    err = np.abs(scene.distance(cloud.points.astype(np.float64), include_ground=True))
    assert np.median(err) < 0.02  # metres; the scene is about 15 m across
    assert np.mean(err < 0.1) > 0.97
    stems = sorted(p.stem for p in (photos / "images").iterdir())
    assert sorted(p.stem for p in (out / "depth").glob("*.pfm")) == stems
    depth = read_pfm(out / "depth" / f"{stems[0]}.pfm")
    assert depth.shape == (192, 256) and np.isfinite(depth).mean() > 0.3
    summary = json.loads((out / "mvs.json").read_text())
    assert summary["points"] == len(cloud)
    assert (out / "preview.png").is_file() and (out / "depth.png").is_file()


def test_concat_baseline_and_named_topology(photos, tmp_path):
    out = tmp_path / "concat"
    assert (
        main(
            [
                "mvs",
                str(photos / "images"),
                "--cameras",
                str(photos / "gt_sparse"),
                "--out",
                str(out),
                "--max-image-size",
                "256",
                "--fusion",
                "concat",
                "--topology",
                "adjacent",
                "--workers",
                "1",
                "--format",
                "las",
                "--quiet",
            ]
        )
        == 0
    )
    laspy = pytest.importorskip("laspy")
    las = laspy.read(out / "fused.las")
    assert len(las.points) > 1000 and not (out / "fused.ply").exists()
    assert json.loads((out / "mvs.json").read_text())["points"] == len(las.points)


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ")
    return err[0]


def test_extra_image_without_camera_is_named(photos, tmp_path, capsys):
    images = tmp_path / "images"
    shutil.copytree(photos / "images", images)
    shutil.copy(images / "orbit_000.png", images / "stray.png")
    assert (
        main(["mvs", str(images), "--cameras", str(photos / "gt_sparse"), "--out", str(tmp_path / "o")]) == 2
    )
    assert "stray.png" in _one_error_line(capsys)


def test_image_size_mismatch_is_an_error(photos, tmp_path, capsys):
    images = tmp_path / "images"
    shutil.copytree(photos / "images", images)
    small = cv2.imread(str(images / "orbit_003.png"))
    cv2.imwrite(str(images / "orbit_003.png"), cv2.resize(small, (128, 96)))
    assert (
        main(["mvs", str(images), "--cameras", str(photos / "gt_sparse"), "--out", str(tmp_path / "o")]) == 2
    )
    assert "orbit_003.png" in _one_error_line(capsys)


def test_missing_cameras_and_black_images(photos, tmp_path, capsys):
    assert (
        main(
            ["mvs", str(photos / "images"), "--cameras", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]
        )
        == 2
    )
    _one_error_line(capsys)
    images = tmp_path / "black"
    shutil.copytree(photos / "images", images)
    for p in images.iterdir():
        cv2.imwrite(str(p), np.zeros((192, 256, 3), np.uint8))
    assert (
        main(
            [
                "mvs",
                str(images),
                "--cameras",
                str(photos / "gt_sparse"),
                "--out",
                str(tmp_path / "o2"),
                "--workers",
                "1",
                "--quiet",
            ]
        )
        == 2
    )
    assert "blank" in _one_error_line(capsys)


def test_prior_summary_says_what_each_pass_filled():
    from skyrecon.cli.mvs import prior_summary

    assert prior_summary({}) is None
    assert prior_summary({"planar_prior": {"views": {}}}) is None
    views = {
        "a": {"filled_px": 1200, "shared_planes": {"filled_px": 300}},
        "b": {"filled_px": 0, "fallback": "no plain segments"},
        "c": {"filled_px": 50, "shared_planes": {"filled_px": 0}},
    }
    line = prior_summary({"planar_prior": {"views": views}})
    assert line == (
        "planar prior: plain segments took a plane in 2 of 3 views (1250 px); "
        "planes shared between views filled 300 px more in 1"
    )
    del views["a"]["shared_planes"]
    assert "shared" not in str(prior_summary({"planar_prior": {"views": views}}))
