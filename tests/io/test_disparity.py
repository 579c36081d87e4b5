"""Disparity files (KITTI 16-bit PNG, Middlebury 8-bit PGM, PFM) and disparity/depth pictures."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from PIL import Image as PILImage

from skyrecon.errors import InputError
from skyrecon.io.disparity import (
    colorize_depth,
    colorize_disparity,
    encode_kitti_disparity,
    read_disparity,
    read_kitti_disparity_png,
    read_middlebury_disparity_pgm,
    write_kitti_disparity_png,
)
from skyrecon.io.images import write_image
from skyrecon.io.pfm import write_pfm
from tests.conftest import require

CONES = "middlebury-2003-cones/cones/disp2.pgm"
KITTI = "kitti2015-stereo-sample/training/disp_occ_0/000046_10.png"


# ----- real files -----------------------------------------------------------------
@pytest.mark.realdata
def test_real_cones_disp2_pgm(real_data):
    path = require(real_data, CONES)
    disp = read_middlebury_disparity_pgm(path)
    raw = np.array(PILImage.open(path))
    assert disp.shape == (375, 450) and disp.dtype == np.float32
    np.testing.assert_array_equal(np.isnan(disp), raw == 0)
    np.testing.assert_array_equal(disp[raw > 0], raw[raw > 0] / 4.0)
    assert 0.02 < np.isnan(disp).mean() < 0.05  # SOURCE.md: 3.2 % unknown
    assert np.nanmax(disp) <= 55.0 and np.nanmin(disp) >= 0.25
    np.testing.assert_array_equal(read_disparity(path), disp)


@pytest.mark.realdata
def test_real_kitti_disp_occ_16bit_png(real_data):
    path = require(real_data, KITTI)
    disp = read_kitti_disparity_png(path)
    assert disp.shape == (375, 1242) and disp.dtype == np.float32
    valid = np.isfinite(disp)
    assert 0.11 < valid.mean() < 0.125  # SOURCE.md: 11.8 % valid
    assert np.nanmin(disp) == pytest.approx(4.87, abs=0.01)
    assert np.nanmax(disp) == pytest.approx(65.74, abs=0.01)
    np.testing.assert_array_equal(read_disparity(path), disp)


@pytest.mark.realdata
def test_real_kitti_round_trip_is_exact(real_data, tmp_path):
    disp = read_kitti_disparity_png(require(real_data, KITTI))
    write_kitti_disparity_png(tmp_path / "d.png", disp)
    np.testing.assert_array_equal(read_kitti_disparity_png(tmp_path / "d.png"), disp)


@pytest.mark.realdata
def test_real_readers_refuse_the_other_format(real_data):
    with pytest.raises(InputError, match="16-bit"):
        read_kitti_disparity_png(require(real_data, CONES))
    with pytest.raises(InputError, match="8-bit"):
        read_middlebury_disparity_pgm(require(real_data, KITTI))


@pytest.mark.realdata
def test_real_colorize_cones(real_data):
    disp = read_disparity(require(real_data, CONES))
    rgb = colorize_disparity(disp)
    assert rgb.shape == (375, 450, 3) and rgb.dtype == np.uint8
    assert np.all(rgb[np.isnan(disp)] == 0)
    assert np.all(rgb[np.isfinite(disp)].max(axis=1) > 0)


# ----- KITTI encoding ----------------------------------------------------------------
def test_kitti_round_trip_exact_and_invalid_values(tmp_path):
    codes = np.array([[1, 256, 65535], [0, 1000, 12345]], dtype=np.uint16)
    disp = np.where(codes > 0, codes / 256.0, np.nan).astype(np.float32)
    write_kitti_disparity_png(tmp_path / "d.png", disp)
    back = read_kitti_disparity_png(tmp_path / "d.png")
    np.testing.assert_array_equal(back, disp)
    stored = np.array(PILImage.open(tmp_path / "d.png"))
    np.testing.assert_array_equal(stored, codes)


def test_kitti_encoding_rules():
    d = np.array([[np.nan, -3.0, 0.0, 1e-6, 300.0, np.inf, 10.3]], dtype=np.float32)
    codes = encode_kitti_disparity(d)
    assert codes.dtype == np.uint16
    # NaN, negative, zero, inf -> 0; tiny positive stays valid (1); clipped at 65535.
    np.testing.assert_array_equal(codes, [[0, 0, 0, 1, 65535, 0, round(10.3 * 256)]])


@settings(max_examples=30, deadline=None)
@given(hnp.arrays(np.uint16, hnp.array_shapes(min_dims=2, max_dims=2, max_side=8)))
def test_property_kitti_codes_round_trip(tmp_path_factory, codes):
    disp = np.where(codes > 0, codes / 256.0, np.nan).astype(np.float32)
    path = tmp_path_factory.mktemp("kitti") / "d.png"
    write_kitti_disparity_png(path, disp)
    np.testing.assert_array_equal(read_kitti_disparity_png(path), disp)


def test_kitti_write_rejects_3d(tmp_path):
    with pytest.raises(InputError) as info:
        write_kitti_disparity_png(tmp_path / "d.png", np.zeros((2, 2, 3)))
    assert "d.png" in str(info.value)


# ----- Middlebury and dispatch --------------------------------------------------------
def test_middlebury_scale_and_png(tmp_path):
    values = np.array([[0, 8, 255]], dtype=np.uint8)
    write_image(tmp_path / "d.png", values)
    np.testing.assert_array_equal(
        read_middlebury_disparity_pgm(tmp_path / "d.png", scale=8), [[np.nan, 1.0, 31.875]]
    )
    np.testing.assert_array_equal(read_disparity(tmp_path / "d.png"), [[np.nan, 2.0, 63.75]])
    with pytest.raises(InputError, match="scale"):
        read_middlebury_disparity_pgm(tmp_path / "d.png", scale=0)


def test_middlebury_pgm_written_by_pil(tmp_path):
    values = np.array([[4, 0], [40, 200]], dtype=np.uint8)
    PILImage.fromarray(values).save(tmp_path / "d.pgm")
    np.testing.assert_array_equal(read_disparity(tmp_path / "d.pgm"), [[1.0, np.nan], [10.0, 50.0]])


def test_read_disparity_dispatch(tmp_path):
    a = np.array([[1.5, np.nan]], dtype=np.float32)
    write_pfm(tmp_path / "d.pfm", a)
    np.testing.assert_array_equal(read_disparity(tmp_path / "d.pfm"), a)
    # By content, not by name: a PFM with a .png name is still a PFM.
    write_pfm(tmp_path / "d_misnamed.png", a)
    np.testing.assert_array_equal(read_disparity(tmp_path / "d_misnamed.png"), a)
    write_image(tmp_path / "k.png", np.array([[512, 0]], dtype=np.uint16))
    np.testing.assert_array_equal(read_disparity(tmp_path / "k.png"), [[2.0, np.nan]])


def test_read_disparity_errors(tmp_path):
    write_pfm(tmp_path / "c.pfm", np.zeros((2, 2, 3), np.float32))
    with pytest.raises(InputError, match="3 channels"):
        read_disparity(tmp_path / "c.pfm")
    (tmp_path / "x.bin").write_bytes(b"hello world")
    with pytest.raises(InputError, match="unknown disparity format"):
        read_disparity(tmp_path / "x.bin")
    (tmp_path / "e.png").write_bytes(b"")
    with pytest.raises(InputError, match="empty"):
        read_disparity(tmp_path / "e.png")
    with pytest.raises(InputError, match="not found") as info:
        read_disparity(tmp_path / "missing.png")
    assert "missing.png" in str(info.value)
    write_image(tmp_path / "rgb.png", np.zeros((2, 2, 3), np.uint8))
    with pytest.raises(InputError, match="single-channel") as info:
        read_disparity(tmp_path / "rgb.png")
    assert "rgb.png" in str(info.value)


def test_truncated_png_raises(tmp_path):
    write_image(tmp_path / "k.png", (np.arange(64 * 64).reshape(64, 64) * 7).astype(np.uint16))
    data = (tmp_path / "k.png").read_bytes()
    (tmp_path / "t.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError) as info:
        read_kitti_disparity_png(tmp_path / "t.png")
    assert "t.png" in str(info.value)


# ----- pictures --------------------------------------------------------------------------
def test_colorize_disparity_near_is_warm_far_is_cool():
    disp = np.array([[1.0, 50.0, np.nan, np.inf]], dtype=np.float32)
    rgb = colorize_disparity(disp)
    assert rgb.shape == (1, 4, 3) and rgb.dtype == np.uint8
    far, near = rgb[0, 0].astype(int), rgb[0, 1].astype(int)
    assert far[2] > far[0]  # small disparity: blue end of turbo
    assert near[0] > near[2]  # large disparity: red end
    assert np.all(rgb[0, 2:] == 0)


def test_colorize_disparity_vmin_vmax_and_degenerate_inputs():
    disp = np.array([[10.0, 20.0]], dtype=np.float32)
    a = colorize_disparity(disp, vmin=0.0, vmax=100.0)
    b = colorize_disparity(disp)
    assert not np.array_equal(a, b)
    assert np.all(colorize_disparity(np.full((2, 2), np.nan)) == 0)
    assert colorize_disparity(np.full((2, 2), 5.0)).shape == (2, 2, 3)
    with pytest.raises(InputError):
        colorize_disparity(np.zeros((2, 2, 3)))


def test_colorize_depth_inverse_depth():
    depth = np.array([[1.0, 100.0, np.nan, -1.0, 0.0]], dtype=np.float32)
    rgb = colorize_depth(depth)
    near, far = rgb[0, 0].astype(int), rgb[0, 1].astype(int)
    assert near[0] > near[2] and far[2] > far[0]
    assert np.all(rgb[0, 2:] == 0)
    fixed = colorize_depth(np.array([[2.0]]), vmin=1.0, vmax=4.0)
    assert fixed.shape == (1, 1, 3) and fixed.max() > 0
    with pytest.raises(InputError):
        colorize_depth(np.zeros(3))


@settings(max_examples=25, deadline=None)
@given(
    hnp.arrays(np.float32, hnp.array_shapes(min_dims=2, max_dims=2, max_side=6), elements=st.floats(width=32))
)
def test_property_colorize_any_values(disp):
    rgb = colorize_disparity(disp)
    assert rgb.shape == disp.shape + (3,) and rgb.dtype == np.uint8
    assert np.all(rgb[~np.isfinite(disp)] == 0)
