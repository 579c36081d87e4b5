import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.odometry.checks import blank_reason, check_pair, is_frozen, to_grey


def test_to_grey_keeps_grey_and_converts_rgb():
    g = np.arange(12, dtype=np.uint8).reshape(3, 4)
    assert to_grey(g) is g or np.array_equal(to_grey(g), g)
    rgb = np.zeros((3, 4, 3), np.uint8)
    rgb[..., 1] = 200
    out = to_grey(rgb)
    assert out.shape == (3, 4) and out.dtype == np.uint8
    assert 100 < out[0, 0] < 130  # green weighs about 0.59


def test_check_pair_rejects_bad_inputs():
    ok = np.zeros((6, 8), np.uint8)
    check_pair(ok, ok, 8, 6)
    with pytest.raises(InputError, match="uint8"):
        check_pair(ok.astype(np.float32), ok, 8, 6)
    with pytest.raises(InputError, match="rig is 8x6"):
        check_pair(np.zeros((5, 8), np.uint8), ok, 8, 6)
    with pytest.raises(InputError, match="shape"):
        check_pair(np.zeros((6, 8, 4), np.uint8), ok, 8, 6)


def test_blank_reason():
    rng = np.random.default_rng(0)
    textured = rng.integers(0, 255, (64, 64), dtype=np.uint8)
    assert blank_reason(textured) == ""
    assert blank_reason(np.zeros((64, 64), np.uint8)).startswith("black frame")
    assert blank_reason(np.full((64, 64), 128, np.uint8)).startswith("near-constant frame")


def test_is_frozen():
    a = np.ones((4, 4), np.uint8)
    assert not is_frozen(a, None)
    assert is_frozen(a, a.copy())
    b = a.copy()
    b[0, 0] = 2
    assert not is_frozen(b, a)
