"""End to end: ``skyrecon stereo`` and ``skyrecon eval stereo`` on rendered synthetic scenes."""

import json

import cv2
import numpy as np
import pytest

from skyrecon import sim
from skyrecon.cli.main import main
from skyrecon.core import Intrinsics, Rigid3, StereoRig, rotvec_to_matrix
from skyrecon.io import read_kitti_calib, read_pfm, read_ply, write_image
from skyrecon.stereo import depth_error_bound, rectify_rig

SMALL = ["--width", "192", "--height", "144", "--seed", "2", "--quiet"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("scene")
    assert main(["render", "stereo", "--out", str(out), *SMALL]) == 0
    return out


def test_pair_with_calibration_and_ground_truth(scene, tmp_path, capsys):
    out = tmp_path / "out"
    args = [
        "stereo",
        str(scene / "left.png"),
        str(scene / "right.png"),
        "--calib",
        str(scene / "calib.txt"),
        "--gt",
        str(scene / "gt_disparity.pfm"),
        "--max-disparity",
        "48",
        "--out",
        str(out),
    ]
    assert main(args) == 0
    summary = json.loads((out / "stereo.json").read_text())
    assert summary["metrics"]["bad1"] < 0.15, summary["metrics"]
    _disparity, depth = read_pfm(out / "disparity.pfm"), read_pfm(out / "depth.pfm")
    gt_depth, gt_disparity = read_pfm(scene / "gt_depth.pfm"), read_pfm(scene / "gt_disparity.pfm")
    # depth errors stay within the first-order bound f*B/d^2 * (1 px) on 90 % of the pixels
    rig = read_kitti_calib(scene / "calib.txt", 192, 144).rig
    bound = depth_error_bound(gt_disparity, rig, 1.0)
    ok = np.isfinite(depth) & np.isfinite(gt_depth) & np.isfinite(bound)
    assert np.mean(np.abs(depth[ok] - gt_depth[ok]) <= bound[ok]) > 0.9
    assert len(read_ply(out / "points.ply")) == summary["points"] > 0
    assert (out / "disparity.png").exists() and (out / "depth.png").exists()
    # the evaluator agrees with the summary
    assert (
        main(
            [
                "eval",
                "stereo",
                str(out / "disparity.pfm"),
                str(scene / "gt_disparity.pfm"),
                "--json",
                str(tmp_path / "s.json"),
            ]
        )
        == 0
    )
    assert json.loads((tmp_path / "s.json").read_text())["bad1"] == pytest.approx(
        summary["metrics"]["bad1"], abs=1e-4
    )


def test_sequence(tmp_path):
    seq = tmp_path / "flight"
    assert main(["render", "sequence", "--frames", "3", "--out", str(seq), *SMALL]) == 0
    out = tmp_path / "depth"
    assert (
        main(["stereo", str(seq), "--out", str(out), "--method", "skyrecon-fast", "--max-disparity", "32"])
        == 0
    )
    summary = json.loads((out / "stereo.json").read_text())
    assert summary["frames"] == 3 and summary["fps"] > 0
    assert read_pfm(out / "depth" / "000002.pfm").shape == (144, 192)


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:"), err
    return err[0]


def test_bad_inputs(scene, tmp_path, capsys):
    small = np.zeros((100, 120, 3), np.uint8)
    write_image(tmp_path / "small.png", small)
    assert (
        main(["stereo", str(scene / "left.png"), str(tmp_path / "small.png"), "--out", str(tmp_path / "o")])
        == 2
    )
    assert "differ in size" in _one_error_line(capsys)
    assert (
        main(["stereo", str(scene / "left.png"), str(tmp_path / "missing.png"), "--out", str(tmp_path / "o")])
        == 2
    )
    assert "missing.png" in _one_error_line(capsys)
    assert main(
        [
            "stereo",
            str(tmp_path / "small.png"),
            str(tmp_path / "small.png"),
            "--calib",
            str(scene / "calib.txt"),
            "--out",
            str(tmp_path / "o"),
        ]
    ) in (0, 2)
    capsys.readouterr()
    bad_calib = tmp_path / "calib.txt"
    bad_calib.write_text("hello world\n")
    assert (
        main(
            [
                "stereo",
                str(scene / "left.png"),
                str(scene / "right.png"),
                "--calib",
                str(bad_calib),
                "--out",
                str(tmp_path / "o"),
            ]
        )
        == 2
    )
    assert "calib" in _one_error_line(capsys)
    assert (
        main(
            [
                "stereo",
                str(scene / "left.png"),
                str(scene / "right.png"),
                "--max-disparity",
                "5000",
                "--out",
                str(tmp_path / "o"),
            ]
        )
        == 2
    )
    assert "disparit" in _one_error_line(capsys)
    assert main(["stereo", str(scene), "--out", str(tmp_path / "o")]) == 2
    assert "sequence" in _one_error_line(capsys)


def _unrectified_rig(width: int = 320, height: int = 240) -> StereoRig:
    """A rig with lens distortion, different intrinsics and a rotated, slightly offset right camera."""
    left = Intrinsics(165.0, 166.0, 161.0, 118.0, width, height, dist=[-0.08, 0.02, 0.001, -0.0005, 0.0])
    right = Intrinsics(163.0, 163.5, 158.0, 122.0, width, height, dist=[-0.06, 0.01, -0.0008, 0.0006, 0.0])
    right_from_left = Rigid3(rotvec_to_matrix([0.01, -0.03, 0.015]), np.array([-0.3, 0.008, 0.012]))
    return StereoRig(left, right, right_from_left)


def _write_opencv_yaml(path, rig: StereoRig) -> None:
    """What ``cv2.stereoCalibrate`` users save: K1 D1 K2 D2 R T (x_right = R x_left + T, metres)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("imageSize", np.array([rig.left.width, rig.left.height], dtype=np.int32))
    for key, value in (
        ("K1", rig.left.K),
        ("D1", np.asarray(rig.left.dist, dtype=np.float64).reshape(1, -1)),
        ("K2", rig.right.K),
        ("D2", np.asarray(rig.right.dist, dtype=np.float64).reshape(1, -1)),
        ("R", rig.right_from_left.R),
        ("T", rig.right_from_left.t.reshape(3, 1)),
    ):
        fs.write(key, value)
    fs.release()


@pytest.fixture(scope="module")
def unrectified_scene(tmp_path_factory):
    """A rendered pair of an unrectified, distorted rig, its OpenCV YAML and the true left depth."""
    out = tmp_path_factory.mktemp("unrectified")
    city = sim.generate_city(4)
    rig = _unrectified_rig()
    left_from_world = sim.street_view_pose(city, 4)
    left = sim.render(city, rig.left, left_from_world)
    right = sim.render(city, rig.right, rig.right_from_left @ left_from_world.with_frames("left", "world"))
    write_image(out / "left.png", left.image)
    write_image(out / "right.png", right.image)
    _write_opencv_yaml(out / "rig.yml", rig)
    return out, rig, left.depth_m


def test_pair_with_unrectified_opencv_yaml(unrectified_scene, tmp_path):
    scene, rig, true_depth = unrectified_scene
    out = tmp_path / "out"
    args = ["stereo", str(scene / "left.png"), str(scene / "right.png"), "--calib", str(scene / "rig.yml")]
    assert main([*args, "--max-disparity", "64", "--out", str(out), "--quiet"]) == 0
    summary = json.loads((out / "stereo.json").read_text())
    assert summary["rectified_here"] is True
    assert summary["baseline_m"] == pytest.approx(np.linalg.norm(rig.right_from_left.t), rel=1e-6)
    assert read_pfm(out / "depth.pfm").shape == (240, 320)
    # the points are in the rectified left frame: take them back to the original left camera and
    # compare their depth with the rendered depth at the pixels they project to
    cloud = read_ply(out / "points.ply")
    assert len(cloud) == summary["points"] > 10000
    left_rect_from_left = rectify_rig(rig).left_rect_from_left
    p = left_rect_from_left.inverse().apply(cloud.points.astype(np.float64))
    p = p[(p[:, 2] > 2.0) & (p[:, 2] < 40.0)]
    uv = rig.left.project(p)
    inside = rig.left.in_image(uv, margin=1)
    u, v = np.rint(uv[inside]).astype(int).T
    truth = true_depth[v, u]
    ok = np.isfinite(truth)
    assert ok.sum() > 5000
    rel = np.abs(p[inside][ok, 2] - truth[ok]) / truth[ok]
    assert np.median(rel) < 0.05
    assert np.mean(rel < 0.2) > 0.9


def test_sequence_refuses_a_separate_calibration(unrectified_scene, tmp_path, capsys):
    scene, _rig, _depth = unrectified_scene
    seq = tmp_path / "flight"
    assert main(["render", "sequence", "--frames", "1", "--out", str(seq), *SMALL]) == 0
    args = ["stereo", str(seq), "--calib", str(scene / "rig.yml"), "--out", str(tmp_path / "o")]
    assert main(args) == 2
    line = _one_error_line(capsys)
    assert "calib" in line and "rig.yml" in line


def test_census_tolerance_auto_on_a_noisy_pair(scene, tmp_path, capsys):
    """``--census-tolerance auto``: measured on the images (0 on the noise-free render, 4 or
    more with 2 grey levels of camera noise); a word that is no number, or the option with an
    OpenCV matcher, is one clear line and exit status 2."""
    from skyrecon.io import read_image
    from skyrecon.sim.sensor_noise import add_sensor_noise

    rng = np.random.default_rng(3)
    for name in ("left", "right"):
        write_image(tmp_path / f"{name}.png", add_sensor_noise(read_image(scene / f"{name}.png"), 2.0, rng))
    for src, expected in ((scene, 0), (tmp_path, 4)):
        out = tmp_path / f"out_{expected}"
        args = ["stereo", str(src / "left.png"), str(src / "right.png"), "--max-disparity", "48"]
        assert main([*args, "--census-tolerance", "auto", "--out", str(out), "--quiet"]) == 0
        got = json.loads((out / "stereo.json").read_text())["census_tolerance"]
        assert got >= expected if expected else got == 0
    pair = [str(scene / "left.png"), str(scene / "right.png")]
    assert main(["stereo", *pair, "--census-tolerance", "lots", "--out", str(tmp_path / "x")]) == 2
    assert "census-tolerance" in _one_error_line(capsys)
    assert (
        main(
            [
                "stereo",
                *pair,
                "--method",
                "opencv-sgbm",
                "--census-tolerance",
                "auto",
                "--out",
                str(tmp_path / "y"),
            ]
        )
        == 2
    )
    assert "skyrecon matchers" in _one_error_line(capsys)
