"""Calibration files: K.txt, Middlebury 2014 calib.txt, KITTI odometry and calib_cam_to_cam."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError
from skyrecon.io.calib import (
    read_K_txt,
    read_kitti_calib,
    read_middlebury_calib,
    rectified_rig_from_projections,
    write_K_txt,
    write_kitti_calib,
)
from tests.conftest import require

# ----- K.txt ------------------------------------------------------------------------


@pytest.mark.realdata
def test_real_strecha_K_txt(real_data):
    K = read_K_txt(require(real_data, "strecha-fountain-P11/images/K.txt"), 3072, 2048)  # CRLF file
    assert (K.fx, K.fy, K.cx, K.cy) == (2759.48, 2764.16, 1520.69, 1006.81)
    assert K.size == (3072, 2048) and K.skew == 0 and not K.has_distortion


def test_K_txt_round_trip_exact(tmp_path):
    K = Intrinsics(1234.5678901234567, 1200.1, 639.5, 479.25, 1280, 960, skew=0.125)
    write_K_txt(tmp_path / "K.txt", K)
    back = read_K_txt(tmp_path / "K.txt", 1280, 960)
    np.testing.assert_array_equal(back.K, K.K)
    assert len((tmp_path / "K.txt").read_text().splitlines()) == 3


@settings(max_examples=40, deadline=None)
@given(
    st.floats(1e-3, 1e6),
    st.floats(1e-3, 1e6),
    st.floats(-1e4, 1e4),
    st.floats(-1e4, 1e4),
    st.floats(-10, 10),
    st.integers(1, 10000),
    st.integers(1, 10000),
)
def test_property_K_txt_round_trip(tmp_path_factory, fx, fy, cx, cy, skew, w, h):
    K = Intrinsics(fx, fy, cx, cy, w, h, skew=skew)
    path = tmp_path_factory.mktemp("k") / "K.txt"
    write_K_txt(path, K)
    np.testing.assert_array_equal(read_K_txt(path, w, h).K, K.K)


def test_K_txt_tolerates_blank_lines_and_tabs(tmp_path):
    (tmp_path / "K.txt").write_text("\n100\t0 50\n\n0 100 40\n0 0 1\n\n")
    assert read_K_txt(tmp_path / "K.txt", 100, 80).cx == 50


@pytest.mark.parametrize(
    "text, words",
    [
        ("", "empty"),
        ("100 0 50\n0 100 40\n", "3 lines"),
        ("100 0 50\n0 100 40\n0 0 1\n1 2 3\n", "3 lines"),
        ("100 0 50 7\n0 100 40\n0 0 1\n", "line 1: expected 3 numbers, found 4"),
        ("100 0 50\n0 100\n0 0 1\n", "line 2"),
        ("100 0 nan\n0 100 40\n0 0 1\n", "line 1: NaN"),
        ("100 0 fifty\n0 100 40\n0 0 1\n", "expected numbers"),
        ("100 0 50\n3 100 40\n0 0 1\n", "upper triangular"),
        ("-100 0 50\n0 100 40\n0 0 1\n", "positive"),
    ],
)
def test_K_txt_malformed(tmp_path, text, words):
    path = tmp_path / "K.txt"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        read_K_txt(path, 100, 80)
    assert str(path) in str(info.value) and words in str(info.value)


def test_K_txt_missing_and_binary(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_K_txt(tmp_path / "K.txt", 10, 10)
    (tmp_path / "b.txt").write_bytes(b"\xff\xfe\x00\x81")
    with pytest.raises(InputError, match="not text"):
        read_K_txt(tmp_path / "b.txt", 10, 10)


# ----- Middlebury 2014 ------------------------------------------------------------------

ADIRONDACK = """cam0=[4161.221 0 1445.577; 0 4161.221 984.686; 0 0 1]
cam1=[4161.221 0 1654.636; 0 4161.221 984.686; 0 0 1]
doffs=209.059
baseline=176.252
width=2880
height=1988
ndisp=280
isint=0
vmin=33
vmax=218
dyavg=0
dymax=0
"""


def test_middlebury_adirondack(tmp_path):
    (tmp_path / "calib.txt").write_text(ADIRONDACK)
    c = read_middlebury_calib(tmp_path / "calib.txt")
    assert c.rig.is_rectified
    assert c.rig.baseline_m == pytest.approx(0.176252, abs=1e-12)
    assert c.baseline_mm == pytest.approx(176.252)
    assert c.doffs_px == pytest.approx(209.059, abs=1e-9)
    assert (c.rig.left.fx, c.rig.left.cx, c.rig.left.cy) == (4161.221, 1445.577, 984.686)
    assert c.rig.right.cx == 1654.636
    assert (c.width, c.height, c.ndisp, c.isint, c.vmin, c.vmax, c.dyavg, c.dymax) == (
        2880,
        1988,
        280,
        0,
        33,
        218,
        0,
        0,
    )
    np.testing.assert_array_equal(c.K1[0], [4161.221, 0, 1654.636])
    # Middlebury's formula: Z [mm] = baseline * f / (d + doffs).
    z = c.rig.disparity_to_depth(np.array([[100.0]]))[0, 0]
    assert z == pytest.approx(176.252 * 4161.221 / (100 + 209.059) / 1000, rel=1e-6)


def test_middlebury_optional_keys_and_windows_newlines(tmp_path):
    text = "\r\n".join(ADIRONDACK.splitlines()[:6]) + "\r\n"
    (tmp_path / "calib.txt").write_bytes(text.encode())
    c = read_middlebury_calib(tmp_path / "calib.txt")
    assert c.ndisp is None and c.vmin is None and c.dymax is None


def _without(key: str) -> str:
    return "".join(line + "\n" for line in ADIRONDACK.splitlines() if not line.startswith(key + "="))


@pytest.mark.parametrize(
    "text, words",
    [
        (_without("baseline"), "missing 'baseline='"),
        (_without("cam1"), "missing 'cam1='"),
        (_without("width"), "missing 'width='"),
        (ADIRONDACK.replace("doffs=209.059", "doffs=200"), "doffs=200.0 disagrees"),
        (ADIRONDACK.replace("baseline=176.252", "baseline=nan"), "NaN"),
        (ADIRONDACK.replace("baseline=176.252", "baseline=-1"), "positive"),
        (ADIRONDACK.replace("baseline=176.252", "baseline=1 2"), "needs one number"),
        (ADIRONDACK.replace("ndisp=280", "ndisp=28.5"), "integer"),
        (
            ADIRONDACK.replace("0 4161.221 984.686; 0 0 1]\ncam1", "0 4161.221; 0 0 1]\ncam1"),
            "line 1: expected a 3x3 matrix",
        ),
        (ADIRONDACK.replace("cam1=[4161.221", "cam1=[4000"), "share f"),
        (ADIRONDACK + "garbage\n", "line 13: expected 'key=value'"),
        ("", "empty"),
    ],
)
def test_middlebury_malformed(tmp_path, text, words):
    path = tmp_path / "calib.txt"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        read_middlebury_calib(path)
    assert str(path) in str(info.value) and words in str(info.value)


# ----- KITTI ---------------------------------------------------------------------------------

# calib_cam_to_cam.txt of KITTI raw 2011_09_26 (the calibration of the 1242x375 KITTI 2015 images).
CAM_TO_CAM = """calib_time: 09-Jan-2012 13:57:47
corner_dist: 9.950000e-02
S_00: 1.392000e+03 5.120000e+02
K_00: 9.842439e+02 0.000000e+00 6.900000e+02 0.000000e+00 9.808141e+02 2.331966e+02 0.000000e+00 0.000000e+00 1.000000e+00
D_00: -3.728755e-01 2.037299e-01 2.219027e-03 1.383707e-03 -7.233722e-02
R_00: 1.000000e+00 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00
T_00: 2.573699e-16 -1.059758e-16 1.614870e-16
S_rect_00: 1.242000e+03 3.750000e+02
R_rect_00: 9.999239e-01 9.837760e-03 -7.445048e-03 -9.869795e-03 9.999421e-01 -4.278459e-03 7.402527e-03 4.351614e-03 9.999631e-01
P_rect_00: 7.215377e+02 0.000000e+00 6.095593e+02 0.000000e+00 0.000000e+00 7.215377e+02 1.728540e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00
S_01: 1.392000e+03 5.120000e+02
K_01: 9.895267e+02 0.000000e+00 7.020000e+02 0.000000e+00 9.878386e+02 2.455590e+02 0.000000e+00 0.000000e+00 1.000000e+00
D_01: -3.644661e-01 1.790019e-01 1.148107e-03 -6.298563e-04 -5.314062e-02
R_01: 9.993513e-01 1.860866e-02 -3.083487e-02 -1.887662e-02 9.997863e-01 -8.421873e-03 3.067156e-02 8.998467e-03 9.994890e-01
T_01: -5.370000e-01 4.822061e-03 -1.252488e-02
S_rect_01: 1.242000e+03 3.750000e+02
R_rect_01: 9.996878e-01 -8.976826e-03 2.331651e-02 8.876121e-03 9.999508e-01 4.418952e-03 -2.335503e-02 -4.210612e-03 9.997184e-01
P_rect_01: 7.215377e+02 0.000000e+00 6.095593e+02 -3.875744e+02 0.000000e+00 7.215377e+02 1.728540e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00
S_02: 1.392000e+03 5.120000e+02
K_02: 9.597910e+02 0.000000e+00 6.960217e+02 0.000000e+00 9.569251e+02 2.241806e+02 0.000000e+00 0.000000e+00 1.000000e+00
D_02: -3.691481e-01 1.968681e-01 1.353473e-03 5.677587e-04 -6.770705e-02
R_02: 9.999758e-01 -5.267463e-03 -4.552439e-03 5.251945e-03 9.999804e-01 -3.413835e-03 4.570332e-03 3.389843e-03 9.999838e-01
T_02: 5.956621e-02 2.900141e-04 2.577209e-03
S_rect_02: 1.242000e+03 3.750000e+02
R_rect_02: 9.998817e-01 1.511453e-02 -2.841595e-03 -1.511724e-02 9.998853e-01 -9.338510e-04 2.827154e-03 9.766976e-04 9.999955e-01
P_rect_02: 7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+01 0.000000e+00 7.215377e+02 1.728540e+02 2.163791e-01 0.000000e+00 0.000000e+00 1.000000e+00 2.745884e-03
S_03: 1.392000e+03 5.120000e+02
K_03: 9.037596e+02 0.000000e+00 6.957519e+02 0.000000e+00 9.019653e+02 2.242509e+02 0.000000e+00 0.000000e+00 1.000000e+00
D_03: -3.639558e-01 1.788651e-01 6.029694e-04 -3.922424e-04 -5.382460e-02
R_03: 9.995599e-01 1.699522e-02 -2.431313e-02 -1.704422e-02 9.998531e-01 -1.809756e-03 2.427880e-02 2.223358e-03 9.997028e-01
T_03: -4.731050e-01 5.551470e-03 -5.250882e-03
S_rect_03: 1.242000e+03 3.750000e+02
R_rect_03: 9.998321e-01 -7.193136e-03 1.685599e-02 7.232804e-03 9.999712e-01 -2.293585e-03 -1.683901e-02 2.415116e-03 9.998553e-01
P_rect_03: 7.215377e+02 0.000000e+00 6.095593e+02 -3.395242e+02 0.000000e+00 7.215377e+02 1.728540e+02 2.199936e+00 0.000000e+00 0.000000e+00 1.000000e+00 2.729905e-03
"""

# calib.txt of KITTI odometry sequence 00 (P0..P3 and Tr, no image size).
ODOMETRY = """P0: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 0.000000000000e+00 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P1: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 -3.861448000000e+02 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P2: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 4.538225000000e+01 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 -1.130887000000e-01 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 3.779761000000e-03
P3: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 -3.372877000000e+02 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 2.369057000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 4.915215000000e-03
Tr: 4.276802385584e-04 -9.999672484946e-01 -8.084491683471e-03 -1.198459927713e-02 -7.210626507497e-03 8.081198471645e-03 -9.999413164504e-01 -5.403984729748e-02 9.999738645903e-01 4.859485810390e-04 -7.206933692422e-03 -2.921968648686e-01
"""


def test_kitti_cam_to_cam_2011_09_26(tmp_path):
    (tmp_path / "calib_cam_to_cam.txt").write_text(CAM_TO_CAM)
    c = read_kitti_calib(tmp_path / "calib_cam_to_cam.txt")
    assert (c.width, c.height) == (1242, 375)
    assert sorted(c.projections) == ["P0", "P1", "P2", "P3"]
    assert c.projections["P3"][0, 3] == -3.395242e02
    rig = c.rig
    assert rig.is_rectified
    assert rig.baseline_m == pytest.approx(0.5327, abs=2e-4)
    assert (rig.left.fx, rig.left.fy, rig.left.cx, rig.left.cy) == (721.5377, 721.5377, 609.5593, 172.854)
    assert rig.doffs_px == 0
    assert rig.left.size == (1242, 375)
    assert c.entries["D_02"].shape == (5,) and c.entries["S_rect_02"].tolist() == [1242, 375]
    assert c.cam0_from_velo is None
    # KITTI depth: Z = fx * B / d.
    assert rig.disparity_to_depth(np.array([[40.0]]))[0, 0] == pytest.approx(721.5377 * 0.5327 / 40, rel=1e-3)


def test_kitti_cam_to_cam_size_given_must_match(tmp_path):
    (tmp_path / "c.txt").write_text(CAM_TO_CAM)
    assert read_kitti_calib(tmp_path / "c.txt", 1242, 375).width == 1242
    with pytest.raises(InputError, match="1242x375") as info:
        read_kitti_calib(tmp_path / "c.txt", 1241, 376)
    assert str(tmp_path / "c.txt") in str(info.value)


def test_kitti_odometry_format(tmp_path):
    (tmp_path / "calib.txt").write_text(ODOMETRY)
    c = read_kitti_calib(tmp_path / "calib.txt", 1241, 376)
    assert c.rig.is_rectified and c.rig.left.size == (1241, 376)
    assert c.rig.baseline_m == pytest.approx(0.533, abs=2e-3)
    assert c.rig.left.cx == 607.1928
    assert isinstance(c.cam0_from_velo, Rigid3) and c.cam0_from_velo.name == "cam0_from_velo"
    # The grey pair P0/P1 is kept too.
    grey = rectified_rig_from_projections(c.projections["P0"], c.projections["P1"], 1241, 376)
    assert grey.baseline_m == pytest.approx(386.1448 / 718.856, rel=1e-9)


def test_kitti_object_format_with_R0_rect(tmp_path):
    text = (
        ODOMETRY.replace("Tr:", "Tr_velo_to_cam:")
        + "R0_rect: 1 0 0 0 1 0 0 0 1\nTr_imu_to_velo: 1 0 0 0 0 1 0 0 0 0 1 0\n"
    )
    (tmp_path / "000046.txt").write_text(text)
    c = read_kitti_calib(tmp_path / "000046.txt", 1242, 375)
    assert c.cam0_from_velo is not None and c.entries["R0_rect"].size == 9


def test_kitti_needs_a_size(tmp_path):
    (tmp_path / "calib.txt").write_text(ODOMETRY)
    with pytest.raises(InputError, match="width and height"):
        read_kitti_calib(tmp_path / "calib.txt")


def test_from_projections_keeps_the_tiny_offsets_rectified_rig_drops_them(tmp_path):
    (tmp_path / "c.txt").write_text(CAM_TO_CAM)
    c = read_kitti_calib(tmp_path / "c.txt")
    exact = StereoRig.from_projections(c.projections["P2"], c.projections["P3"], 1242, 375)
    assert exact.right_from_left.t[0] == pytest.approx(-c.rig.baseline_m, rel=1e-12)
    assert abs(exact.right_from_left.t[1]) < 0.005 and abs(exact.right_from_left.t[2]) < 1e-4


@pytest.mark.parametrize("doffs", [0.0, 12.5])
def test_write_kitti_calib_round_trip(tmp_path, doffs):
    rig = StereoRig.rectified(
        Intrinsics(700.123456789, 700.123456789, 600.5, 180.25, 1240, 370), 0.54321, doffs
    )
    write_kitti_calib(tmp_path / "calib.txt", rig)
    lines = (tmp_path / "calib.txt").read_text().splitlines()
    assert [line.split(":")[0] for line in lines] == ["P0", "P1", "P2", "P3"]
    c = read_kitti_calib(tmp_path / "calib.txt", 1240, 370)
    np.testing.assert_array_equal(c.projections["P0"], c.projections["P2"])
    np.testing.assert_array_equal(c.projections["P2"][:, 3], 0)
    assert c.projections["P3"][0, 3] == pytest.approx(-700.123456789 * 0.54321, rel=1e-15)
    np.testing.assert_array_equal(c.rig.left.K, rig.left.K)
    np.testing.assert_array_equal(c.rig.right.K, rig.right.K)
    assert c.rig.baseline_m == pytest.approx(0.54321, rel=1e-14)
    assert c.rig.is_rectified


@settings(max_examples=30, deadline=None)
@given(
    st.floats(10, 5000), st.floats(-100, 2000), st.floats(-100, 2000), st.floats(1e-3, 10), st.floats(-50, 50)
)
def test_property_kitti_rig_round_trip(tmp_path_factory, f, cx, cy, baseline, doffs):
    rig = StereoRig.rectified(Intrinsics(f, f, cx, cy, 640, 480), baseline, doffs)
    path = tmp_path_factory.mktemp("kitti") / "calib.txt"
    write_kitti_calib(path, rig)
    back = read_kitti_calib(path, 640, 480).rig
    np.testing.assert_allclose(back.left.K, rig.left.K, rtol=1e-14)
    np.testing.assert_allclose(back.right.K, rig.right.K, rtol=1e-14)
    assert back.baseline_m == pytest.approx(baseline, rel=1e-12)


def test_write_kitti_calib_refuses_unrectified_rig(tmp_path):
    K = Intrinsics(500, 500, 320, 240, 640, 480)
    rig = StereoRig(K, K, Rigid3.from_rotvec([0, 0.1, 0], [-0.5, 0, 0]))
    with pytest.raises(InputError, match="rectif") as info:
        write_kitti_calib(tmp_path / "calib.txt", rig)
    assert "calib.txt" in str(info.value)
    assert not (tmp_path / "calib.txt").exists()


P2_LINE = ODOMETRY.splitlines()[2]


@pytest.mark.parametrize(
    "text, words",
    [
        (
            "".join(line + "\n" for line in ODOMETRY.splitlines() if not line.startswith("P3")),
            "no 'P2:'/'P3:'",
        ),
        (ODOMETRY.replace(P2_LINE, P2_LINE.rsplit(" ", 1)[0]), "line 3: 'P2' needs 12 numbers"),
        (ODOMETRY.replace("4.538225000000e+01", "nan"), "line 3: NaN"),
        (ODOMETRY.replace("4.538225000000e+01", "abc"), "line 3: expected numbers"),
        (ODOMETRY + "this is not calibration\n", "line 6: expected 'KEY: numbers'"),
        (ODOMETRY.replace("-3.372877000000e+02", "3.372877000000e+02"), "right camera is not to the right"),
        (ODOMETRY.replace("P3: 7.188560000000e+02", "P3: 7.000000000000e+02"), "not a rectified pair"),
        (ODOMETRY.replace("Tr: 4.276802385584e-04", "Tr: 4.0"), "line 5: 'Tr'"),
        ("", "empty"),
    ],
)
def test_kitti_malformed(tmp_path, text, words):
    path = tmp_path / "calib.txt"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        read_kitti_calib(path, 1241, 376)
    assert str(path) in str(info.value) and words in str(info.value)


def test_kitti_bad_S_rect(tmp_path):
    path = tmp_path / "c.txt"
    path.write_text(
        CAM_TO_CAM.replace("S_rect_02: 1.242000e+03 3.750000e+02", "S_rect_02: 1.2425e+03 3.75e+02")
    )
    with pytest.raises(InputError, match="S_rect_02"):
        read_kitti_calib(path)


def test_calib_missing_files(tmp_path):
    for reader in (lambda p: read_kitti_calib(p, 1, 1), read_middlebury_calib):
        with pytest.raises(InputError, match="not found") as info:
            reader(tmp_path / "nope.txt")
        assert "nope.txt" in str(info.value)
