"""Bad inputs raise InputError with a useful message; odd-but-valid inputs are converted."""

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.stereo import SkyreconSettings, available_matchers, create_matcher, prepare_pair
from tests.stereo.conftest import warp_pair

METHODS = ["skyrecon", "skyrecon-fast", "opencv-sgbm", "opencv-bm"]


@pytest.fixture(scope="module")
def pair():
    d = np.full((64, 96), 6.0, np.float32)
    return warp_pair(d, seed=5)


@pytest.mark.parametrize("method", METHODS)
def test_size_mismatch(method, pair):
    left, right = pair
    m = create_matcher(method, 32)
    with pytest.raises(InputError, match="same size"):
        m.compute(left, right[:, :-4])


@pytest.mark.parametrize("method", METHODS)
def test_disparity_range_wider_than_image(method, pair):
    left, right = pair
    m = create_matcher(method, 112)  # image is 96 wide
    with pytest.raises(InputError, match="image"):
        m.compute(left, right)


def test_empty_or_inverted_range():
    with pytest.raises(InputError, match="larger than min_disparity"):
        create_matcher("skyrecon", 10, min_disparity=10)
    with pytest.raises(InputError, match="whole pixels"):
        create_matcher("skyrecon", 10.5)


def test_unknown_method_and_setting():
    with pytest.raises(InputError, match="opencv-sgbm"):
        create_matcher("nope", 32)
    with pytest.raises(InputError, match="valid:"):
        create_matcher("skyrecon", 32, not_a_setting=1)
    with pytest.raises(InputError, match="block_size"):
        create_matcher("opencv-sgbm", 32, block_size=4)
    with pytest.raises(InputError, match="mode"):
        create_matcher("opencv-sgbm", 32, mode="fancy")
    with pytest.raises(InputError, match="paths"):
        SkyreconSettings(paths=5)
    with pytest.raises(InputError, match="32 bits"):
        SkyreconSettings(census_width=11, census_height=9)
    with pytest.raises(InputError, match="p2_edge_alpha"):
        SkyreconSettings(p2_edge_alpha=-1.0)
    # the edge-aware jump penalty: mild at full resolution, strong at half resolution, or as given
    assert SkyreconSettings().edge_alpha == 0.05 and SkyreconSettings(fast=True).edge_alpha == 0.5
    assert SkyreconSettings(fast=True, p2_edge_alpha=0.0).edge_alpha == 0.0
    assert set(METHODS) <= set(available_matchers())


def test_bad_dtypes_and_shapes(pair):
    left, right = pair
    m = create_matcher("skyrecon", 16)
    with pytest.raises(InputError, match="uint8"):
        m.compute(left.astype(np.float32), right.astype(np.float32))
    with pytest.raises(InputError, match="bit depth"):
        m.compute(left, right.astype(np.uint16))
    with pytest.raises(InputError, match="shape"):
        m.compute(left[..., None].repeat(2, axis=2), right)
    with pytest.raises(InputError, match="numpy array"):
        m.compute(left.tolist(), right)


def test_16bit_pair_is_converted_with_one_map(pair):
    left, right = pair
    # a 12-bit sensor: values 16x larger plus an offset; the census sees the same structure
    l16 = left.astype(np.uint16) * 16 + 100
    r16 = right.astype(np.uint16) * 16 + 100
    p = prepare_pair(l16, r16)
    assert p.converted_from_16bit and p.left_grey.dtype == np.uint8
    m = create_matcher("skyrecon", 16)
    d8 = m.compute(left, right).disparity
    d16 = m.compute(l16, r16).disparity
    inner = (slice(8, -8), slice(24, -8))
    assert np.nanmedian(np.abs(d16[inner] - 6.0)) < 0.25
    assert np.nanmean(np.abs(d16[inner] - d8[inner]) < 0.5) > 0.95
    assert m.compute(l16, r16).diagnostics["converted_from_16bit"]


@pytest.mark.parametrize("method", METHODS)
def test_grey_colour_mix_is_matched_in_grey(method, pair):
    left, right = pair
    left_rgb = np.repeat(left[..., None], 3, axis=2)
    m = create_matcher(method, 16)
    r = m.compute(left_rgb, right)
    assert r.disparity.shape == left.shape and r.disparity.dtype == np.float32
    inner = r.disparity[8:-8, 24:-8]
    assert np.nanmedian(np.abs(inner - 6.0)) < 0.5


def test_rgba_alpha_is_dropped(pair):
    left, right = pair
    rgba_l = np.dstack([left, left, left, np.full_like(left, 255)])
    rgba_r = np.dstack([right, right, right, np.full_like(right, 255)])
    r = create_matcher("skyrecon", 16).compute(rgba_l, rgba_r)
    assert np.nanmedian(np.abs(r.disparity[8:-8, 24:-8] - 6.0)) < 0.25
