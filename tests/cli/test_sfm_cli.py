"""End to end: ``skyrecon sfm`` on a small rendered photo set with known cameras, its outputs, what
it does with bad images, and ``skyrecon align --positions`` on its model."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from skyrecon.cli.main import main
from skyrecon.cli.sfm import list_images
from skyrecon.core import Intrinsics
from skyrecon.errors import InputError
from skyrecon.eval.sfm_metrics import evaluate_sfm_poses
from skyrecon.io import read_colmap_text, read_image, read_ply, write_image
from skyrecon.io.calib import write_K_txt
from skyrecon.sfm.pairs import looks_like_sequence
from skyrecon.sim import generate_object_scene, orbit_views, render_views

INTR = Intrinsics.from_fov(320, 240, 70)


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    """8 rendered 320x240 views on a 100-degree arc around a monument, K.txt, true poses."""
    d = tmp_path_factory.mktemp("photos")
    scene = generate_object_scene(1)
    views = orbit_views(scene, 8, INTR, seed=0, arc_deg=100)
    (d / "images").mkdir()
    for v, r in zip(views, render_views(scene, views)):
        write_image(d / "images" / v.name, r.image)
    (d / "images" / "notes.txt").write_text("not an image")
    write_K_txt(d / "K.txt", INTR)
    return d, {v.name: v.cam_from_world for v in views}


@pytest.fixture(scope="module")
def sfm_run(photos, tmp_path_factory):
    """One run of the command (features at 256 px: the outputs must still be at 320x240)."""
    d, _ = photos
    out = tmp_path_factory.mktemp("sfm")
    code = main(
        [
            "sfm",
            str(d / "images"),
            "--camera",
            str(d / "K.txt"),
            "--out",
            str(out),
            "--max-image-size",
            "256",
            "--workers",
            "1",
            "--frusta",
            "--quiet",
        ]
    )
    return code, out


def _err_lines(capsys) -> list[str]:
    return capsys.readouterr().err.strip().splitlines()


def test_model_matches_ground_truth_at_the_input_size(photos, sfm_run):
    _, gt = photos
    code, out = sfm_run
    assert code == 0
    rec = read_colmap_text(out / "sparse")
    assert sorted(im.name for im in rec.images.values()) == sorted(gt)
    assert len(rec.cameras) == 1
    cam = rec.cameras[1]
    assert (cam.width, cam.height) == (320, 240)
    assert np.allclose(cam.K, INTR.K, atol=1e-9)
    s = evaluate_sfm_poses({im.name: im.cam_from_world for im in rec.images.values()}, gt).summary()
    assert s["rotation_max_deg"] < 0.5
    assert s["center_max_pct"] < 1.0
    assert len(rec.points3d) > 300
    # keypoints are in input pixels: the points reproject onto them
    assert np.median(rec.reprojection_errors()) < 0.5


def test_outputs_and_summary(photos, sfm_run):
    d, gt = photos
    _, out = sfm_run
    rec = read_colmap_text(out / "sparse")
    cloud = read_ply(out / "sparse.ply")
    assert cloud.colors is not None and len(cloud) > len(rec.points3d)  # points + frusta
    tj = json.loads((out / "transforms.json").read_text())
    assert len(tj["frames"]) == 8 and (tj["w"], tj["h"]) == (320, 240)
    assert all((out / f["file_path"]).resolve().is_file() for f in tj["frames"])  # paths relative to --out
    html = (out / "report.html").read_text()
    assert "Reprojection error" in html and "Track length" in html and "data:image/png;base64," in html
    summary = json.loads((out / "sfm.json").read_text())
    assert summary["status"] == "complete" and summary["left_out"] == {}
    assert summary["num_images"] == summary["num_registered"] == 8
    assert summary["num_points"] == len(rec.points3d)
    assert 0 < summary["mean_reprojection_error_px"] < 1.0
    assert summary["settings"]["pairing"] == "exhaustive" and summary["image_size"] == [320, 240]
    assert summary["timings_s"]["total_wall"] > 0 and "features" in summary["timings_s"]
    assert any((out / "workspace" / "features").glob("*.npz"))  # the feature cache for re-runs


def test_align_to_true_camera_positions(photos, sfm_run, tmp_path, capsys):
    _, gt = photos
    _, out = sfm_run
    names = sorted(gt)
    glitch = names[2]
    lines = ["# image  x y z (metres)"]
    for n in names:
        c = gt[n].center + (np.array([3.0, 0.0, 0.0]) if n == glitch else 0.0)
        lines.append(f"{n} {c[0]:.6f} {c[1]:.6f} {c[2]:.6f}")
    (tmp_path / "gps.txt").write_text("\n".join(lines) + "\n")
    assert (
        main(["align", str(out), "--positions", str(tmp_path / "gps.txt"), "--out", str(tmp_path / "a")]) == 0
    )
    err = _err_lines(capsys)
    assert any(line.startswith("warning:") and glitch in line for line in err)
    result = json.loads((tmp_path / "a" / "align.json").read_text())
    assert result["outliers"] == [glitch] and result["num_inliers"] == 7
    aligned = read_colmap_text(tmp_path / "a" / "sparse")
    extent = max(np.linalg.norm(gt[a].center - gt[b].center) for a in names for b in names)
    for im in aligned.images.values():
        assert np.linalg.norm(im.center_world - gt[im.name].center) < 0.01 * extent
        cos = (np.trace(im.cam_from_world.R @ gt[im.name].R.T) - 1) / 2
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))) < 0.5
    assert result["residual_rms_m"] < 0.005 * extent


def test_bad_images_are_left_out_with_a_warning(photos, sfm_run, tmp_path, capsys):
    d, gt = photos
    _, out = sfm_run
    images = tmp_path / "images"
    images.mkdir()
    names = sorted(gt)
    for n in names[:6]:
        shutil.copy(d / "images" / n, images / n)
    shutil.copy(d / "images" / names[3], images / "zz_duplicate.png")
    write_image(images / "zz_flat.png", np.full((240, 320, 3), 128, np.uint8))
    write_image(images / "zz_small.png", cv2.resize(read_image(d / "images" / names[4]), (240, 180)))
    code = main(
        [
            "sfm",
            str(images),
            "--camera",
            str(d / "K.txt"),
            "--out",
            str(tmp_path / "o"),
            "--workers",
            "1",
            "--max-image-size",
            "256",
            "--workspace",
            str(out / "workspace"),
            "--pairing",
            "sequential",
            "--window",
            "3",
        ]
    )
    assert code == 0
    err = _err_lines(capsys)
    warning = [line for line in err if line.startswith("warning:") and "left out" in line]
    assert len(warning) == 1
    assert all(n in warning[0] for n in ("zz_duplicate.png", "zz_flat.png", "zz_small.png"))
    assert not any(line.startswith("error:") for line in err)
    assert err[-2].startswith("registered 6 of 9 images")
    summary = json.loads((tmp_path / "o" / "sfm.json").read_text())
    left = summary["left_out"]
    assert set(left) == {"zz_duplicate.png", "zz_flat.png", "zz_small.png"}
    assert "duplicate" in left["zz_duplicate.png"] and names[3] in left["zz_duplicate.png"]
    assert "texture" in left["zz_flat.png"]
    assert "240x180" in left["zz_small.png"]
    assert summary["status"] == "partial" and summary["settings"]["pairing"] == "sequential"
    assert summary["diagnostics"]["features_cached"] == 6  # the shared workspace already had them
    rec = read_colmap_text(tmp_path / "o" / "sparse")
    assert sorted(im.name for im in rec.images.values()) == names[:6]


@pytest.mark.parametrize(
    "case",
    [
        "missing_dir",
        "one_image",
        "no_images",
        "K_missing",
        "K_corrupt",
        "K_other_size",
        "only_duplicates",
        "only_flat",
    ],
)
def test_bad_input_is_one_error_line_and_exit_2(photos, tmp_path, capsys, case):
    d, gt = photos
    images, k = tmp_path / "images", d / "K.txt"
    images.mkdir()
    first = d / "images" / sorted(gt)[0]
    if case == "missing_dir":
        images = tmp_path / "nope"
        expect = "not found"
    elif case == "one_image":
        shutil.copy(first, images / "a.png")
        expect = "only one image (a.png)"
    elif case == "no_images":
        (images / "readme.txt").write_text("x")
        expect = "found no image"
    elif case == "K_missing":
        shutil.copytree(d / "images", images, dirs_exist_ok=True)
        k = tmp_path / "missing_K.txt"
        expect = "not found"
    elif case == "K_corrupt":
        shutil.copytree(d / "images", images, dirs_exist_ok=True)
        k = tmp_path / "K.txt"
        k.write_text("160 0 159.5\n0 abc 119.5\n")
        expect = "K.txt"
    elif case == "K_other_size":
        shutil.copytree(d / "images", images, dirs_exist_ok=True)
        k = tmp_path / "K.txt"
        k.write_text("960 0 960\n0 960 540\n0 0 1\n")  # for 1920x1080 photos
        expect = "principal point"
    elif case == "only_duplicates":
        shutil.copy(first, images / "a.png")
        shutil.copy(first, images / "b.png")
        expect = "b.png: duplicate"
    else:
        for name in ("a.png", "b.png", "c.png"):
            write_image(images / name, np.full((240, 320, 3), 200, np.uint8))
        expect = "a.png: only 0 features"
    code = main(
        ["sfm", str(images), "--camera", str(k), "--out", str(tmp_path / "out"), "--workers", "1", "--quiet"]
    )
    err = _err_lines(capsys)
    assert code == 2
    assert len(err) == 1 and err[0].startswith("error:") and expect in err[0], err
    if case in ("only_duplicates", "only_flat"):  # the run started: its summary says why it stopped
        summary = json.loads((tmp_path / "out" / "sfm.json").read_text())
        assert summary["status"] == "failed" and expect in summary["error"]


def test_image_listing_and_sequence_detection(tmp_path):
    for name in ("f10.png", "f2.JPG", "f1.tif", ".hidden.png", "K.txt", "f3.jpeg"):
        (tmp_path / name).write_bytes(b"")
    assert [p.name for p in list_images(tmp_path)] == ["f1.tif", "f2.JPG", "f3.jpeg", "f10.png"]
    with pytest.raises(InputError, match="not a directory"):
        list_images(tmp_path / "K.txt")
    assert looks_like_sequence([f"frame_{k:06d}.png" for k in range(0, 300, 5)])
    assert looks_like_sequence([f"DJI_{k:04d}.JPG" for k in range(17, 90)])
    assert not looks_like_sequence(["church.jpg", "tower.jpg", "gate.jpg"])
    assert not looks_like_sequence(["a_1.jpg", "b_2.jpg", "c_3.jpg"])
    assert not looks_like_sequence([f"img{k}.png" for k in (1, 2, 50, 51, 300, 900)])
