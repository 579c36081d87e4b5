"""End to end: ``skyrecon stereo`` and ``skyrecon eval stereo`` on rendered synthetic scenes."""

import json

import numpy as np
import pytest

from skyrecon.cli.main import main
from skyrecon.io import read_kitti_calib, read_pfm, read_ply, write_image
from skyrecon.stereo import depth_error_bound

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
