"""The filling of rejected pixels: slope-continuing row fill and the colour-guided fill."""

from __future__ import annotations

import numpy as np

from skyrecon.stereo import _kernels as K
from skyrecon.stereo.sgm import SkyreconMatcher, fill_invalid


def _slanted_row_with_hole() -> tuple[np.ndarray, np.ndarray]:
    """A slanted background (d = 10 + 0.1 x) left of a foreground (d = 40) from x = 100, with
    the occluded background x = 70 .. 99 rejected; returns (map with holes, truth)."""
    x = np.arange(160, dtype=np.float32)
    truth = np.where(x < 100, 10 + 0.1 * x, 40.0).astype(np.float32)
    d = np.tile(truth, (6, 1))
    d[:, 70:100] = np.nan
    return d, np.tile(truth, (6, 1))


def test_row_fill_continues_the_background_slope():
    d, truth = _slanted_row_with_hole()
    filled = fill_invalid(d)
    err = np.abs(filled - truth)[:, 70:100]
    assert err.max() < 0.3
    # a constant fill (the farther neighbour's value) drifts off by up to 3 px here
    const = fill_invalid(d, span=0)
    assert np.abs(const - truth)[:, 70:100].max() > 2.5
    assert np.all(np.isfinite(filled))


def test_row_fill_never_rises_above_the_nearer_side_nor_below_the_smallest():
    d = np.full((2, 60), np.nan, np.float32)
    d[:, :20] = 20 + 0.3 * np.arange(20)  # steep rise towards the hole
    d[:, 40:] = 21.0
    f = fill_invalid(d)
    assert np.all(f[:, 20:40] <= 26.7 + 1e-4)  # max(a, b): the nearer bounding value
    assert np.all(f[:, 20:40] >= 20.0 - 1e-4)
    # the border run continues its only side, clipped to the smallest valid disparity
    e = np.full((1, 50), np.nan, np.float32)
    e[0, 20:] = 5 + 0.25 * np.arange(30)  # rises to the right: continued leftwards it falls
    g = fill_invalid(e)
    assert np.all(g[0, :20] >= np.nanmin(e) - 1e-4)


def _occluded_strip() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fixed-point map: background (d = 5 px) above and below, and in rows 20..39 two
    foreground objects (40 px left of x = 30, 45 px from x = 50) with the background strip
    between them rejected. The guide image paints the background grey 100, the objects 200."""
    H, W, s = 60, 80, 32
    fixed = np.full((H, W), 5 * s, np.int16)
    guide = np.full((H, W, 1), 100, np.uint8)
    fixed[20:40, :30] = 40 * s
    fixed[20:40, 50:] = 45 * s
    fixed[20:40, 30:50] = K.INVALID16
    guide[20:40, :30] = 200
    guide[20:40, 50:] = 200
    filled = np.empty_like(fixed)
    K.fill_background_fixed(fixed, filled, 0, H, float(s), 0.0, 48, K.FILL_MAX_SLOPE)
    return fixed, filled, guide


def test_guided_fill_takes_the_background_between_two_foreground_objects():
    fixed, filled, guide = _occluded_strip()
    # the row fill can only take the farther side, the left object
    assert np.all(filled[20:40, 30:50] == 40 * 32)
    m = SkyreconMatcher(64)
    out = m._guided_fill(fixed, filled, guide, 32.0, 1, 2)
    hole = out[20:40, 30:50]
    assert np.mean(hole == 5 * 32) > 0.95
    # valid pixels are untouched
    keep = fixed != K.INVALID16
    np.testing.assert_array_equal(out[keep], fixed[keep])


def test_guided_fill_never_goes_nearer_than_the_row_fill():
    fixed, filled, guide = _occluded_strip()
    # now the strip looks like the objects: candidates near the objects' values are
    # excluded (nearer than the row fill), so it may only keep the row fill or go farther
    guide[20:40, 30:50] = 200
    out = SkyreconMatcher(64)._guided_fill(fixed, filled, guide, 32.0, 1, 1)
    assert np.all(out[20:40, 30:50] <= filled[20:40, 30:50] + 32)


def test_guided_fill_setting(slanted_pair):
    left, right, _ = slanted_pair
    on = SkyreconMatcher(32)
    off = SkyreconMatcher(32, guided_fill=False)
    assert on._guided and not off._guided
    assert not SkyreconMatcher(32, fast=True)._guided
    assert SkyreconMatcher(32, fast=True, guided_fill=True)._guided
    for m in (on, off, SkyreconMatcher(32, fast=True, guided_fill=True)):
        r = m.compute(left, right)
        assert np.all(np.isfinite(r.disparity))


def test_warmup_compiles_the_guided_fill_kernels():
    SkyreconMatcher(32).warmup()
    for k in (K.guided_fill_targets, K.guided_fill_candidates, K.guided_fill_median, K.guided_fill_spread):
        assert len(k.signatures) >= 1


def test_guided_fill_same_result_on_one_or_two_threads(monkeypatch):
    from skyrecon.stereo import sgm

    monkeypatch.setattr(sgm, "_GUIDE_TARGETS_PER_THREAD", 1)
    fixed, filled, guide = _occluded_strip()
    m = SkyreconMatcher(64)
    one = m._guided_fill(fixed, filled, guide, 32.0, 1, 1).copy()
    two = m._guided_fill(fixed, filled, guide, 32.0, 1, 2).copy()
    np.testing.assert_array_equal(one, two)
