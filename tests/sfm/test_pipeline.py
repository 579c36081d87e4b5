"""End-to-end structure from motion on a small synthetic orbit, its outputs, bad inputs, and a few
real fountain images."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from skyrecon.core import Intrinsics
from skyrecon.errors import EstimationError, InputError
from skyrecon.eval.sfm_metrics import evaluate_sfm_poses
from skyrecon.executor import SerialExecutor, get_executor
from skyrecon.io import read_colmap_text, read_image, read_ply, read_strecha_cameras, write_image
from skyrecon.sfm import SfMSettings, run_sfm, write_sfm_outputs
from skyrecon.sfm.settings import MapperSettings
from skyrecon.sim import generate_object_scene, orbit_views, render_views
from tests.conftest import require

INTR = Intrinsics.from_fov(320, 240, 70)


@pytest.fixture(scope="module")
def orbit(tmp_path_factory):
    """12 rendered 320x240 views on a 120-degree arc around a monument, with their true poses."""
    d = tmp_path_factory.mktemp("orbit")
    scene = generate_object_scene(1)
    views = orbit_views(scene, 12, INTR, seed=0, arc_deg=120)
    paths = []
    for v, r in zip(views, render_views(scene, views)):
        write_image(d / v.name, r.image)
        paths.append(d / v.name)
    return d, paths, {v.name: v.cam_from_world for v in views}


@pytest.fixture(scope="module")
def orbit_result(orbit, tmp_path_factory):
    d, paths, gt = orbit
    ws = tmp_path_factory.mktemp("ws")
    res = run_sfm(paths, INTR, SfMSettings(), executor=get_executor("process", 2), seed=0, workspace=ws)
    return res, ws


def test_orbit_is_reconstructed_accurately(orbit, orbit_result):
    _, paths, gt = orbit
    res, _ = orbit_result
    assert res.complete, res.note
    assert res.num_registered == 12
    est = {im.name: im.cam_from_world for im in res.reconstruction.images.values()}
    ev = evaluate_sfm_poses(est, gt)
    s = ev.summary()
    assert s["rotation_max_deg"] < 0.3
    assert s["center_max_pct"] < 0.3
    assert res.mean_reprojection_error_px() < 0.5
    assert len(res.reconstruction.points3d) > 1000
    res.reconstruction.validate()
    # every point is seen by at least two registered images, with small errors
    assert min(len(p.track) for p in res.reconstruction.points3d.values()) >= 2
    assert np.percentile(res.reconstruction.reprojection_errors(), 99) < 4.0
    assert set(res.timings) >= {"features", "pairs", "matching", "tracks", "mapping", "total"}


def test_same_seed_same_result_and_features_are_cached(orbit, orbit_result):
    _, paths, _ = orbit
    res, ws = orbit_result
    again = run_sfm(paths, INTR, SfMSettings(), executor=SerialExecutor(), seed=0, workspace=ws)
    assert again.diagnostics["features_cached"] == len(paths)
    a = {im.name: im.cam_from_world for im in res.reconstruction.images.values()}
    b = {im.name: im.cam_from_world for im in again.reconstruction.images.values()}
    assert all(np.allclose(a[n].matrix, b[n].matrix, atol=1e-9) for n in a)
    assert len(again.reconstruction.points3d) == len(res.reconstruction.points3d)


def test_outputs_are_written_and_read_back(orbit_result, tmp_path):
    res, _ = orbit_result
    files = write_sfm_outputs(tmp_path, res, frusta=True)
    for name in (
        "sparse/cameras.txt",
        "sparse/images.txt",
        "sparse/points3D.txt",
        "sparse.ply",
        "transforms.json",
        "report.html",
        "summary.json",
    ):
        assert (tmp_path / name).is_file(), name
        assert name in files
    rec = read_colmap_text(tmp_path / "sparse")
    assert len(rec.images) == 12 and len(rec.points3d) == len(res.reconstruction.points3d)
    cam = rec.cameras[1]
    assert (cam.width, cam.height) == (320, 240) and abs(cam.cx - INTR.cx) < 1e-9
    im = next(iter(res.reconstruction.images.values()))
    back = rec.images[im.image_id]
    assert np.allclose(back.cam_from_world.matrix, im.cam_from_world.matrix, atol=1e-9)
    assert np.allclose(back.keypoints, im.keypoints)
    cloud = read_ply(tmp_path / "sparse.ply")
    assert len(cloud) > len(res.reconstruction.points3d)  # points + frusta
    assert cloud.colors is not None
    tj = json.loads((tmp_path / "transforms.json").read_text())
    assert len(tj["frames"]) == 12
    html = (tmp_path / "report.html").read_text()
    assert "<svg" in html and "data:image/png;base64," in html
    assert "src='http" not in html and 'src="http' not in html and "<link" not in html  # self-contained
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["num_registered"] == 12


def test_bad_images_are_left_out_with_reasons(orbit, tmp_path):
    d, paths, gt = orbit
    good = [shutil.copy(p, tmp_path / p.name) for p in paths[:8]]
    dup = tmp_path / "zz_duplicate.png"
    shutil.copy(paths[3], dup)
    flat = tmp_path / "zz_flat.png"
    write_image(flat, np.full((240, 320, 3), 128, np.uint8))
    small = tmp_path / "zz_small.png"
    write_image(small, cv2.resize(read_image(paths[4]), (240, 180)))
    noise = tmp_path / "zz_noise.png"
    rng = np.random.default_rng(0)
    write_image(noise, cv2.GaussianBlur(rng.integers(0, 255, (240, 320, 3), dtype=np.uint8), (0, 0), 1.5))
    broken = tmp_path / "zz_broken.png"
    broken.write_bytes(b"this is not an image")
    res = run_sfm(
        [*good, dup, flat, small, noise, broken], INTR, SfMSettings(), executor=SerialExecutor(), seed=0
    )
    left = res.unregistered
    assert set(left) == {"zz_duplicate.png", "zz_flat.png", "zz_small.png", "zz_noise.png", "zz_broken.png"}
    assert "duplicate" in left["zz_duplicate.png"] and paths[3].name in left["zz_duplicate.png"]
    assert "texture" in left["zz_flat.png"]
    assert "240x180" in left["zz_small.png"] and "320x240" in left["zz_small.png"]
    assert "no verified matches" in left["zz_noise.png"]
    assert "decode" in left["zz_broken.png"]
    assert res.num_registered == 8
    assert "zz_noise.png" in res.note and "left out" in res.warnings[0]
    out = write_sfm_outputs(tmp_path / "out", res, cloud_format="laz")
    summary = json.loads(out["summary.json"].read_text())
    assert set(summary["left_out"]) == set(left)
    # --format laz: the sparse cloud as LAZ (readable by laspy), no PLY beside it
    assert "sparse.laz" in out and not (tmp_path / "out" / "sparse.ply").exists()
    laspy = pytest.importorskip("laspy")
    las = laspy.read(out["sparse.laz"])
    xyz = np.column_stack([las.x, las.y, las.z])
    truth = np.array([p.xyz for p in res.reconstruction.points3d.values()])
    assert len(xyz) == len(truth)
    np.testing.assert_allclose(np.sort(xyz, axis=0), np.sort(truth, axis=0), atol=6e-4)


def test_input_errors(orbit, tmp_path):
    _, paths, _ = orbit
    with pytest.raises(InputError, match="at least two"):
        run_sfm(paths[:1], INTR, executor=SerialExecutor())
    with pytest.raises(InputError, match="not found"):
        run_sfm([paths[0], tmp_path / "missing.png"], INTR, executor=SerialExecutor())
    big = Intrinsics.from_fov(960, 720, 70)  # K for 3x larger images
    shifted = Intrinsics(big.fx, big.fy, big.cx, big.cy, 320, 240)
    with pytest.raises(InputError, match="principal point"):
        run_sfm(paths[:3], shifted, executor=SerialExecutor())
    with pytest.raises(InputError, match="960x720"):
        run_sfm(paths[:3], big, executor=SerialExecutor())
    flat = tmp_path / "flat.png"
    write_image(flat, np.full((240, 320, 3), 90, np.uint8))
    with pytest.raises(InputError, match="fewer than two usable images.*flat.png"):
        run_sfm([paths[0], flat], INTR, executor=SerialExecutor())


def test_images_without_overlap_cannot_start(orbit, tmp_path):
    _, paths, _ = orbit
    rng = np.random.default_rng(1)
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    for p in (a, b):
        write_image(p, cv2.GaussianBlur(rng.integers(0, 255, (240, 320, 3), dtype=np.uint8), (0, 0), 1.5))
    with pytest.raises(EstimationError, match="cannot start the reconstruction"):
        run_sfm([a, b], INTR, executor=SerialExecutor())


@pytest.mark.realdata
def test_fountain_images_at_reduced_size(real_data, tmp_path):
    root = require(real_data, "strecha-fountain-P11")
    views = read_strecha_cameras(root / "gt_dense_cameras")[:5]
    paths = []
    for v in views:
        img = read_image(v.image_path)
        small = cv2.resize(img, (768, 512), interpolation=cv2.INTER_AREA)
        write_image(tmp_path / f"{Path(v.name).stem}.png", small)
        paths.append(tmp_path / f"{Path(v.name).stem}.png")
    intr = views[0].intrinsics.scaled(768 / 3072)
    res = run_sfm(paths, intr, SfMSettings(), executor=SerialExecutor(), seed=0)
    assert res.complete, res.note
    gt = {f"{Path(v.name).stem}.png": v.cam_from_world for v in views}
    ev = evaluate_sfm_poses({im.name: im.cam_from_world for im in res.reconstruction.images.values()}, gt)
    s = ev.summary()
    assert s["rotation_max_deg"] < 0.2
    assert s["center_max_pct"] < 0.3


@pytest.mark.parametrize("check_images", [200, 4])
def test_a_wrong_focal_length_is_reported(orbit, check_images):
    """Also when the check runs on a thinned model (every second image here, as on a long
    flight: at most ``focal_check_images`` images)."""
    _, paths, _ = orbit
    wrong = Intrinsics(INTR.fx * 1.5, INTR.fy * 1.5, INTR.cx, INTR.cy, 320, 240)
    settings = SfMSettings(mapper=MapperSettings(focal_check_images=check_images))
    res = run_sfm(paths[:8], wrong, settings, executor=SerialExecutor(), seed=0)
    assert any("focal length in K seems off" in w for w in res.warnings), res.warnings
    assert res.diagnostics["mapper"]["focal_check_images"] == min(8, check_images)


def test_image_names_of_symbolic_links_are_the_links_names(tmp_path):
    """A folder of links (``photo_*.png`` to ``frame_*.png`` elsewhere) is named by its links, so
    the names join back onto the folder the user gave (transforms.json, the survey's photos)."""
    from skyrecon.sfm.pipeline import image_names

    (tmp_path / "store").mkdir()
    (tmp_path / "links" / "sub").mkdir(parents=True)
    links = []
    for k, rel in enumerate(["photo_b.png", "photo_a.png", "sub/photo_c.png"]):
        target = tmp_path / "store" / f"frame_{k:04d}.png"
        target.write_bytes(b"x")
        link = tmp_path / "links" / rel
        link.symlink_to(target)
        links.append(link)
    names = image_names(links)
    assert names == ["photo_b.png", "photo_a.png", "sub/photo_c.png"]
    assert all((tmp_path / "links" / n).is_file() for n in names)
    assert image_names([Path("rel") / ".." / "x" / "a.png", Path("x/b.png")]) == ["a.png", "b.png"]


def test_weaker_initial_pair_when_none_has_the_matches_it_needs(orbit, orbit_result):
    """No pair has ``init_min_inliers`` verified matches (small images: a 12-photo survey at 320x240
    had 99 for 100): the mapper starts from the best pair down to half of that, says so, and the
    model is as good; without that step it could not start."""
    _, paths, gt = orbit
    chosen = orbit_result[0].diagnostics["mapper"]["init_pair_inliers"]
    settings = SfMSettings(mapper=MapperSettings(init_min_inliers=2 * chosen))
    res = run_sfm(paths, INTR, settings, executor=SerialExecutor(), seed=0)
    assert any("started from a weaker pair" in w for w in res.warnings), res.warnings
    assert res.num_registered == len(paths)
    est = {im.name: im.cam_from_world for im in res.reconstruction.images.values()}
    s = evaluate_sfm_poses(est, gt).summary()
    assert s["rotation_max_deg"] < 0.3 and s["center_max_pct"] < 0.3
