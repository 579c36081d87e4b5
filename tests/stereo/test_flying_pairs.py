"""FlyingThings-style rendered pairs (skyrecon.sim.flying): exact geometry, and the matchers on
random objects with plain surfaces."""

import cv2
import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.eval.stereo_metrics import evaluate_disparity
from skyrecon.sim.flying import render_flying_pair
from skyrecon.stereo import create_matcher
from skyrecon.stereo.opencv_matchers import SGBM_REFERENCE as OPENCV_REFERENCE


@pytest.fixture(scope="module")
def plain_pair():
    """240x180, disparities below 32, every object nearly plain (low texture)."""
    return render_flying_pair(1, width=240, height=180, max_disparity=32, n_objects=8, plain_fraction=1.0)


def test_pair_is_deterministic_and_dense(plain_pair):
    left, right, d = plain_pair
    again = render_flying_pair(1, width=240, height=180, max_disparity=32, n_objects=8, plain_fraction=1.0)
    assert np.array_equal(left, again[0]) and np.array_equal(right, again[1])
    assert left.shape == right.shape == (180, 240, 3) and left.dtype == np.uint8
    assert d.shape == (180, 240) and d.dtype == np.float32
    assert np.isfinite(d).all() and d.min() > 0.5 and d.max() < 31.5


def test_ground_truth_warps_right_onto_left():
    """left(x, y) = right(x - d, y) except at occlusions and depth edges."""
    left, right, d = render_flying_pair(2, width=240, height=180, max_disparity=32, noise=0.0)
    H, W = d.shape
    xs = (np.arange(W, dtype=np.float32)[None, :] - d).astype(np.float32)
    ys = np.repeat(np.arange(H, dtype=np.float32)[:, None], W, 1)
    warped = cv2.remap(right.astype(np.float32), xs, ys, cv2.INTER_LINEAR)
    err = np.abs(warped - left.astype(np.float32)).mean(-1)
    inside = xs >= 1
    assert np.median(err[inside]) < 2.0
    assert np.mean(err[inside] < 5.0) > 0.75  # the rest: occlusions and antialiased edges


def test_bad_arguments():
    with pytest.raises(InputError):
        render_flying_pair(0, width=16)


def test_skyrecon_on_plain_objects(plain_pair):
    """Plain, nearly textureless objects at random depths: skyrecon within a bound and well
    below OpenCV SGBM's error (bad-1 with unmatched pixels as errors)."""
    left, right, d = plain_pair
    ours = evaluate_disparity(create_matcher("skyrecon", 32).compute(left, right).disparity, d)["bad1"]
    ocv = evaluate_disparity(
        create_matcher("opencv-sgbm", 32, **OPENCV_REFERENCE).compute(left, right).disparity, d
    )["bad1"]
    assert ours < 0.16  # 0.118 when written
    assert ours < 0.6 * ocv  # 0.40x when written
