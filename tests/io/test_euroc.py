"""EuRoC/ASL reader: sensor.yaml parsing, rectification against a true rectified render, ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core.rigid import rotation_angle_deg
from skyrecon.errors import InputError
from skyrecon.io.euroc import is_euroc_dir, parse_sensor_yaml, read_euroc
from skyrecon.io.images import to_gray
from skyrecon.sim.euroc import write_synthetic_euroc
from skyrecon.sim.render import render_stereo

EUROC_YAML = """%YAML:1.0
# General sensor definitions.
sensor_type: camera
comment: VI-Sensor cam0 (MT9M034)

# Sensor extrinsics wrt. the body-frame.
T_BS:
  cols: 4
  rows: 4
  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
         0.0, 0.0, 0.0, 1.0]

# Camera specific definitions.
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
"""


def test_parse_the_real_euroc_sensor_yaml():
    cfg = parse_sensor_yaml(EUROC_YAML)
    assert cfg["sensor_type"] == "camera" and cfg["rate_hz"] == 20
    assert cfg["T_BS"]["rows"] == 4 and len(cfg["T_BS"]["data"]) == 16
    assert cfg["T_BS"]["data"][3] == pytest.approx(-0.0216401454975)
    assert cfg["intrinsics"] == [458.654, 457.296, 367.215, 248.375]
    assert cfg["distortion_coefficients"][3] == pytest.approx(1.76187114e-05)
    assert cfg["resolution"] == [752, 480]
    with pytest.raises(InputError, match="line 2"):
        parse_sensor_yaml("a: 1\nthis is not yaml\n")
    with pytest.raises(InputError, match="not closed"):
        parse_sensor_yaml("a: [1, 2,\n 3\n")


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    root = tmp_path_factory.mktemp("euroc")
    return write_synthetic_euroc(root / "seq", n_frames=3, seed=4, width=160, height=120)


def test_rectified_frames_match_a_true_rectified_render(synthetic):
    seq = read_euroc(synthetic.root)
    assert is_euroc_dir(synthetic.root) and is_euroc_dir(synthetic.root / "mav0")
    assert len(seq) == 3 and seq.rig.is_rectified
    assert seq.rig.baseline_m == pytest.approx(np.linalg.norm([0.11, 0.002, -0.0015]), rel=1e-6)
    assert np.allclose(np.diff(seq.timestamps_s), 0.05, atol=1e-6)
    # the rectified left camera sits where cam0 is, turned by the rectification
    k = 1
    world_from_cam0 = synthetic.world_from_cam0[k]
    world_from_left = world_from_cam0.with_frames(None, None) @ (
        synthetic.body_from_cam0.inverse().with_frames(None, None)
        @ seq.body_from_left.with_frames(None, None)
    )
    assert np.allclose(world_from_left.t, world_from_cam0.t, atol=1e-9)
    assert rotation_angle_deg(world_from_left.R.T @ world_from_cam0.R) < 2.0
    truth = render_stereo(synthetic.city, seq.rig, world_from_left.inverse())
    left, right = seq.frame(k)
    raw_left, _ = seq.raw_frame(k)
    h, w = left.shape[:2]
    inner = (slice(h // 8, -h // 8), slice(w // 8, -w // 8))
    for got, want in ((left, truth.left), (right, truth.right)):
        err = np.abs(to_gray(got).astype(float) - to_gray(want).astype(float))[inner]
        assert np.median(err) <= 2.0 and err.mean() < 5.0, (np.median(err), err.mean())
    # the raw (distorted, unrectified) image is far further from the rectified truth
    raw_err = np.abs(to_gray(raw_left).astype(float) - to_gray(truth.left).astype(float))[inner]
    assert np.median(raw_err) > 2 * np.median(
        np.abs(to_gray(left).astype(float) - to_gray(truth.left).astype(float))[inner]
    )


def test_groundtruth_becomes_left_camera_poses(synthetic):
    seq = read_euroc(synthetic.root)
    assert seq.world_from_left is not None and all(p is not None for p in seq.world_from_left)
    for k, pose in enumerate(seq.world_from_left):
        assert pose is not None
        want = synthetic.world_from_cam0[k]
        assert np.allclose(pose.t, want.t, atol=2e-3)  # interpolated between 100 Hz samples
        want_left = want.with_frames(None, None) @ (
            synthetic.body_from_cam0.inverse().with_frames(None, None)
            @ seq.body_from_left.with_frames(None, None)
        )
        assert rotation_angle_deg(pose.R.T @ want_left.R) < 0.05


def test_bad_inputs_name_the_file(synthetic, tmp_path):
    with pytest.raises(InputError, match="not a EuRoC sequence"):
        read_euroc(tmp_path)
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(synthetic.root, bad)
    yaml = bad / "mav0" / "cam1" / "sensor.yaml"
    yaml.write_text(yaml.read_text().replace("intrinsics: [", "intrinsics: [1, "))
    with pytest.raises(InputError, match="sensor.yaml.*intrinsics"):
        read_euroc(bad)
