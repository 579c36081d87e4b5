"""read_stereo_calib: one entry point for Middlebury, KITTI and OpenCV stereo calibrations."""

import cv2
import numpy as np
import pytest

from skyrecon.core import Intrinsics, Rigid3, StereoRig
from skyrecon.errors import InputError
from skyrecon.io.calib import read_stereo_calib, write_kitti_calib


def write_opencv_yaml(path, K1, D1, K2, D2, R, T, size=None):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for name, value in (("K1", K1), ("D1", D1), ("K2", K2), ("D2", D2), ("R", R), ("T", T)):
        if value is not None:
            fs.write(name, np.asarray(value, dtype=np.float64))
    if size is not None:
        fs.write("width", size[0])
        fs.write("height", size[1])
    fs.release()


def test_opencv_yaml_unrectified_rig(tmp_path):
    K = np.array([[500.0, 0, 320], [0, 505, 240], [0, 0, 1]])
    R = Rigid3.from_rotvec([0.01, -0.02, 0.005], [0, 0, 0]).R
    T = np.array([-0.12, 0.002, 0.001])
    D = np.array([0.1, -0.05, 0.001, 0.0005, 0.0])
    write_opencv_yaml(tmp_path / "stereo.yml", K, D, K, D * 0.5, R, T, (640, 480))
    calib = read_stereo_calib(tmp_path / "stereo.yml", 640, 480)
    assert calib.kind == "opencv" and not calib.rig.is_rectified
    np.testing.assert_allclose(calib.rig.right_from_left.t, T)
    np.testing.assert_allclose(calib.rig.left.dist, D)
    with pytest.raises(InputError, match="640x480"):
        read_stereo_calib(tmp_path / "stereo.yml", 320, 240)
    write_opencv_yaml(tmp_path / "partial.yml", K, D, K, D, None, T)
    with pytest.raises(InputError, match="missing R"):
        read_stereo_calib(tmp_path / "partial.yml", 640, 480)


def test_kitti_and_middlebury_are_recognised(tmp_path):
    rig = StereoRig.rectified(Intrinsics(700, 700, 300, 200, 600, 400), 0.5)
    write_kitti_calib(tmp_path / "calib.txt", rig)
    calib = read_stereo_calib(tmp_path / "calib.txt", 600, 400)
    assert calib.kind == "kitti" and calib.rig.baseline_m == pytest.approx(0.5)
    mb = tmp_path / "mb.txt"
    mb.write_text(
        "cam0=[4161.221 0 1445.577; 0 4161.221 984.686; 0 0 1]\ncam1=[4161.221 0 1654.636; 0 4161.221 984.686; 0 0 1]\n"
        "doffs=209.059\nbaseline=176.252\nwidth=2880\nheight=1988\nndisp=280\n"
    )
    calib = read_stereo_calib(mb, 2880, 1988)
    assert calib.kind == "middlebury" and calib.max_disparity == 280
    assert calib.rig.baseline_m == pytest.approx(0.176252)
    with pytest.raises(InputError, match="2880x1988"):
        read_stereo_calib(mb, 1440, 994)
    unknown = tmp_path / "x.txt"
    unknown.write_text("focal 3\n")
    with pytest.raises(InputError, match="unknown stereo calibration format"):
        read_stereo_calib(unknown, 10, 10)
