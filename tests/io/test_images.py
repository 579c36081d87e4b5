"""Image reading and writing: every data set's images, bit depths, channel layouts, bad files."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image as PILImage

from skyrecon.errors import InputError
from skyrecon.io.images import encode_png, read_image, read_image_with_alpha, to_gray, write_image
from tests.conftest import require

REAL_IMAGES = [
    ("middlebury-2003-cones/cones/im2.png", (375, 450)),
    ("middlebury-2003-cones/cones/im6.png", (375, 450)),
    ("kitti2015-stereo-sample/training/image_2/000046_10.png", (375, 1242)),
    ("kitti2015-stereo-sample/training/image_3/000046_10.png", (375, 1242)),
    ("middlebury-mview-templeSparseRing/templeSR0001.png", (480, 640)),
    ("strecha-fountain-P11/images/0000.jpg", (2048, 3072)),
]


# ----- real images ---------------------------------------------------------------------------
@pytest.mark.realdata
@pytest.mark.parametrize("relative, shape", REAL_IMAGES)
def test_real_rgb_images(real_data, relative, shape):
    path = require(real_data, relative)
    rgb = read_image(path)
    assert rgb.shape == shape + (3,) and rgb.dtype == np.uint8
    assert rgb.flags.c_contiguous
    # RGB, not OpenCV's BGR: compare with PIL, which decodes to RGB.
    with PILImage.open(path) as im:
        np.testing.assert_array_equal(rgb, np.array(im.convert("RGB")))
    grey = read_image(path, "gray")
    assert grey.shape == shape and grey.dtype == np.uint8


@pytest.mark.realdata
def test_real_rock_grey_plus_alpha(real_data):
    path = require(real_data, "robovision-rock/2016_10_25__12_11_32/image_camera01.png")
    grey, alpha = read_image_with_alpha(path, "unchanged")
    assert grey.shape == (1024, 1280) and grey.dtype == np.uint8
    assert alpha.shape == (1024, 1280) and alpha.dtype == np.uint8
    no_data = alpha == 0
    assert 0.005 < no_data.mean() < 0.03  # SOURCE.md: about 1.7 % of pixels
    assert np.all(grey[no_data] == 0)
    assert grey.max() <= 200  # dark images
    rgb = read_image(path)
    assert rgb.shape == (1024, 1280, 3)
    np.testing.assert_array_equal(rgb[..., 0], grey)
    np.testing.assert_array_equal(rgb[..., 2], grey)
    np.testing.assert_array_equal(read_image(path, "gray"), grey)


@pytest.mark.realdata
def test_real_16bit_kitti_disparity_png(real_data):
    path = require(real_data, "kitti2015-stereo-sample/training/disp_occ_0/000046_10.png")
    raw = read_image(path, "unchanged")
    assert raw.dtype == np.uint16 and raw.shape == (375, 1242)
    assert raw.max() > 255
    scaled = read_image(path, "gray")
    assert scaled.dtype == np.uint8
    np.testing.assert_array_equal(scaled, ((raw.astype(np.uint32) + 128) // 257).astype(np.uint8))


@pytest.mark.realdata
def test_real_pgm(real_data):
    grey = read_image(require(real_data, "middlebury-2003-cones/cones/disp2.pgm"), "unchanged")
    assert grey.shape == (375, 450) and grey.dtype == np.uint8


# ----- round trips --------------------------------------------------------------------------------
@pytest.fixture
def rng():
    return np.random.default_rng(7)


@pytest.mark.parametrize(
    "shape, dtype",
    [
        ((5, 7), np.uint8),
        ((5, 7), np.uint16),
        ((5, 7, 3), np.uint8),
        ((5, 7, 3), np.uint16),
        ((5, 7, 4), np.uint8),
        ((5, 7, 4), np.uint16),
    ],
)
def test_png_round_trip_unchanged_exact(tmp_path, rng, shape, dtype):
    image = rng.integers(0, np.iinfo(dtype).max, shape, endpoint=True).astype(dtype)
    write_image(tmp_path / "a.png", image)
    data, alpha = read_image_with_alpha(tmp_path / "a.png", "unchanged")
    if shape[-1] == 4:
        np.testing.assert_array_equal(data, image[..., :3])
        np.testing.assert_array_equal(alpha, image[..., 3])
    else:
        np.testing.assert_array_equal(data, image)
        assert alpha is None


def test_png_channel_order_is_rgb_on_disk(tmp_path):
    image = np.zeros((2, 2, 3), np.uint8)
    image[..., 0] = 255  # pure red
    write_image(tmp_path / "red.png", image)
    with PILImage.open(tmp_path / "red.png") as im:
        assert im.mode == "RGB" and im.getpixel((0, 0)) == (255, 0, 0)
    np.testing.assert_array_equal(read_image(tmp_path / "red.png")[0, 0], [255, 0, 0])


def test_grey_alpha_written_by_pil(tmp_path, rng):
    la = rng.integers(0, 256, (6, 5, 2), dtype=np.uint8)
    PILImage.fromarray(la, "LA").save(tmp_path / "la.png")
    grey, alpha = read_image_with_alpha(tmp_path / "la.png", "unchanged")
    np.testing.assert_array_equal(grey, la[..., 0])
    np.testing.assert_array_equal(alpha, la[..., 1])
    assert read_image(tmp_path / "la.png").shape == (6, 5, 3)


def test_palette_and_bilevel_images(tmp_path):
    p = PILImage.new("P", (4, 3))
    p.putpalette([0, 0, 0, 10, 20, 30] + [0] * 762)
    p.putpixel((1, 1), 1)
    p.save(tmp_path / "p.png")
    rgb = read_image(tmp_path / "p.png")
    assert rgb.shape == (3, 4, 3) and tuple(rgb[1, 1]) == (10, 20, 30)
    PILImage.new("1", (4, 3), 1).save(tmp_path / "b.png")
    assert np.all(read_image(tmp_path / "b.png", "unchanged") == 255)


def test_rgb_modes_from_grey_and_16bit(tmp_path):
    write_image(tmp_path / "g16.png", np.array([[0, 65535, 257 * 100]], np.uint16))
    np.testing.assert_array_equal(read_image(tmp_path / "g16.png", "gray"), [[0, 255, 100]])
    np.testing.assert_array_equal(read_image(tmp_path / "g16.png")[0, 2], [100, 100, 100])
    write_image(tmp_path / "c16.png", np.full((1, 1, 3), 257 * 50, np.uint16))
    np.testing.assert_array_equal(read_image(tmp_path / "c16.png")[0, 0], [50, 50, 50])


def test_jpeg_round_trip_is_close(tmp_path):
    y, x = np.mgrid[0:64, 0:96]
    image = np.stack([x * 2, y * 3, (x + y)], axis=-1).astype(np.uint8)
    write_image(tmp_path / "a.jpg", image)
    assert (tmp_path / "a.jpg").read_bytes()[:2] == b"\xff\xd8"
    back = read_image(tmp_path / "a.jpg")
    assert back.shape == image.shape
    assert np.abs(back.astype(int) - image).mean() < 3  # and not channel-swapped
    write_image(tmp_path / "g.jpeg", image[..., 0])
    assert read_image(tmp_path / "g.jpeg", "unchanged").shape == (64, 96)


def test_to_gray_luma():
    rgb = np.array([[[255, 0, 0], [0, 255, 0], [0, 0, 255]]], np.uint8)
    np.testing.assert_array_equal(to_gray(rgb), [[76, 150, 29]])
    g = np.zeros((2, 2), np.uint16)
    assert to_gray(g) is g


def test_write_is_atomic_and_creates_parents(tmp_path):
    write_image(tmp_path / "a" / "b" / "c.png", np.zeros((2, 2), np.uint8))
    assert [p.name for p in (tmp_path / "a" / "b").iterdir()] == ["c.png"]


def test_write_rejects_bad_arrays(tmp_path):
    with pytest.raises(InputError, match="uint8 or uint16"):
        write_image(tmp_path / "f.png", np.zeros((2, 2), np.float32))
    with pytest.raises(InputError, match="shape"):
        write_image(tmp_path / "s.png", np.zeros((2, 2, 2), np.uint8))
    with pytest.raises(InputError):
        encode_png(np.zeros(5, np.uint8))
    assert list(tmp_path.iterdir()) == []


# ----- bad files ---------------------------------------------------------------------------------------
def _png_bytes() -> bytes:
    return encode_png((np.arange(64 * 64 * 3) % 251).astype(np.uint8).reshape(64, 64, 3))


@pytest.mark.parametrize(
    "content, words",
    [
        (b"", "empty"),
        (b"this is not an image at all", "cannot decode"),
        (b"\x89PNG\r\n\x1a\n" + b"\x00" * 20, "cannot decode"),
        ("half", "cannot decode"),
        ("header", "cannot decode"),
    ],
)
def test_corrupt_files_raise_input_error_naming_the_file(tmp_path, content, words):
    if content == "half":
        data = _png_bytes()
        content = data[: len(data) // 2]
    elif content == "header":
        content = _png_bytes()[:40]
    path = tmp_path / "bad.png"
    path.write_bytes(content)
    with pytest.raises(InputError) as info:
        read_image(path)
    assert str(path) in str(info.value) and words in str(info.value)


def test_truncated_jpeg(tmp_path):
    write_image(tmp_path / "a.jpg", np.random.default_rng(0).integers(0, 256, (128, 128, 3), dtype=np.uint8))
    data = (tmp_path / "a.jpg").read_bytes()
    (tmp_path / "t.jpg").write_bytes(data[: len(data) // 3])
    with pytest.raises(InputError) as info:
        read_image(tmp_path / "t.jpg")
    assert "t.jpg" in str(info.value)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(InputError, match="not found") as info:
        read_image(tmp_path / "none.png")
    assert "none.png" in str(info.value)
    with pytest.raises(InputError, match="directory"):
        read_image(tmp_path)


def test_float_tiff_is_refused_with_a_hint(tmp_path):
    PILImage.fromarray(np.zeros((2, 2), np.float32), "F").save(tmp_path / "f.tif")
    with pytest.raises(InputError, match="PFM"):
        read_image(tmp_path / "f.tif")
