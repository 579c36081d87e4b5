"""The filling of rejected pixels: slope-continuing row fill and the colour-guided fill."""

from __future__ import annotations

import numpy as np
import pytest

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
    K.fill_background_fixed(fixed, filled, 0, H, float(s), 0.0, 48, K.FILL_MAX_SLOPE, K.FILL_NEARER_LEFT_PX)
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


def _reference_fill_row(row, invalid, unit, lo, span, max_slope, rounded, nearer_left_px):
    """The row fill written plainly (every pixel of the span visited): the reference of
    ``_kernels._fill_rows``, which visits only the valid ones."""
    W = len(row)
    ok = [not (v != v or v == invalid) for v in row]
    out = np.array(row, copy=True)
    x = 0
    while x < W:
        if ok[x]:
            x += 1
            continue
        x0 = x
        while x < W and not ok[x]:
            x += 1
        has_a, has_b = x0 > 0, x < W
        if not (has_a or has_b):
            out[x0:x] = invalid
            continue
        a = np.float32(row[x0 - 1]) if has_a else np.float32(0)
        b = np.float32(row[x]) if has_b else np.float32(0)
        left = has_a and (not has_b or a <= b or a > b + nearer_left_px * unit)
        side, bx, base = (-1, x0 - 1, a) if left else (1, x, b)
        lim = max(a, b) if has_a and has_b else np.float32(np.inf)
        sx = sy = sxx = sxy = np.float32(0)
        cnt, slope, icpt = 0, np.float32(0), base
        for j in range(span):
            xx = bx + side * j
            if xx < 0 or xx >= W:
                break
            if not ok[xx]:
                continue
            fv = np.float32(row[xx])
            if abs(fv - base) > (np.float32(2.0) + np.float32(0.25) * j) * np.float32(unit):
                break
            fj = np.float32(j)
            sx, sy, sxx, sxy, cnt = sx + fj, sy + fv, sxx + fj * fj, sxy + fj * fv, cnt + 1
        if cnt >= span // 2:
            den = cnt * sxx - sx * sx
            if den > 0:
                sl = (cnt * sxy - sx * sy) / den
                icpt = (sy - sl * sx) / cnt
                slope = min(max(-sl, -np.float32(max_slope)), np.float32(max_slope))
        for xx in range(x0, x):
            f = min(max(icpt + slope * np.float32(abs(xx - bx)), np.float32(lo)), lim)
            out[xx] = np.floor(f + np.float32(0.5)) if rounded else f
    return out


def test_row_fill_matches_the_plain_reference():
    """Random rows of slanted segments with holes of every length (isolated pixels, long
    runs, runs at the row ends, rows with no valid pixel): the compacted kernel fills exactly
    like the plain loop (exactly in fixed point, to rounding in float)."""
    rng = np.random.default_rng(7)
    H, W = 40, 200
    x = np.arange(W, dtype=np.float32)
    d = np.empty((H, W), np.float32)
    for y in range(H):
        cut = rng.integers(20, W - 20)
        d[y] = np.where(x < cut, 10 + rng.uniform(-0.2, 0.2) * x, 30 + rng.uniform(-0.1, 0.1) * x)
    d += rng.normal(0, 0.3, d.shape).astype(np.float32)
    holes = rng.random((H, W)) < 0.35
    for y in rng.integers(0, H, 12):  # long runs
        a = rng.integers(0, W - 30)
        holes[y, a : a + rng.integers(5, 60)] = True
    holes[3] = True  # a row without any valid pixel
    d[holes] = np.nan
    fixed = np.where(np.isfinite(d), np.rint(d * 32), K.INVALID16).astype(np.int16)
    out = np.empty_like(fixed)
    rule = K.FILL_NEARER_LEFT_PX
    K.fill_background_fixed(fixed, out, 0, H, 32.0, 0.0, 48, K.FILL_MAX_SLOPE, rule)
    ref = np.stack(
        [
            _reference_fill_row(r, np.int16(K.INVALID16), 32.0, 0.0, 48, K.FILL_MAX_SLOPE, True, rule)
            for r in fixed
        ]
    )
    np.testing.assert_array_equal(out, ref)
    outf = np.empty_like(d)
    K.fill_background(d, outf, 0, H, np.float32(1.0), 48, np.float32(K.FILL_MAX_SLOPE), np.float32(rule))
    reff = np.stack(
        [_reference_fill_row(r, np.float32(np.nan), 1.0, 1.0, 48, K.FILL_MAX_SLOPE, False, rule) for r in d]
    )
    # float32 in the kernel, NumPy scalars here: the same sums, rounded alike to a few ulps
    np.testing.assert_allclose(outf, reff, rtol=1e-5)


def test_the_post_processing_split_over_threads_changes_nothing():
    """The median filter and the guided fill's first and last steps on bands of rows in
    parallel: the same output as on one thread."""
    import cv2

    from skyrecon.stereo.sgm import _median_blur

    rng = np.random.default_rng(3)
    img = rng.integers(-2000, 2000, (400, 400)).astype(np.int16)  # two bands of 65536+ pixels
    np.testing.assert_array_equal(_median_blur(img, 5, 2), cv2.medianBlur(img, 5))
    np.testing.assert_array_equal(_median_blur(img, 3, 4), cv2.medianBlur(img, 3))
    # occluded strips between foreground blocks, tiled over a map big enough for threads
    s = 32
    fixed = np.full((400, 400), 5 * s, np.int16)
    guide = np.full((400, 400, 1), 100, np.uint8)
    for y0 in range(10, 390, 40):
        for x0 in range(10, 390, 60):
            fixed[y0 : y0 + 20, x0 : x0 + 20] = 40 * s
            fixed[y0 : y0 + 20, x0 + 40 : x0 + 55] = 45 * s
            fixed[y0 : y0 + 20, x0 + 20 : x0 + 40] = K.INVALID16
            guide[y0 : y0 + 20, x0 : x0 + 20] = 200
    filled = np.empty_like(fixed)
    K.fill_background_fixed(fixed, filled, 0, 400, float(s), 0.0, 48, K.FILL_MAX_SLOPE, K.FILL_NEARER_LEFT_PX)
    one = SkyreconMatcher(64)._guided_fill(fixed, filled, guide, 32.0, 1, 1).copy()
    two = SkyreconMatcher(64)._guided_fill(fixed, filled, guide, 32.0, 1, 2)
    np.testing.assert_array_equal(one, two)
    assert np.mean(one[10:30, 30:50] == 5 * s) > 0.9  # the strips took the background


def test_a_run_with_the_nearer_side_on_its_left_takes_that_side():
    """Left of a nearer surface an invalid run is an occlusion of the background (farther
    side); right of it no occlusion of the left view lies, so the run continues the nearer
    left side (unless the rule is off: inf, as for the column fill)."""
    s = 32
    row = np.full((2, 60), K.INVALID16, np.int16)
    row[0, :20], row[0, 40:] = 10 * s, 30 * s  # farther on the left: an occlusion
    row[1, :20], row[1, 40:] = 30 * s, 10 * s  # nearer on the left: no occlusion
    out = np.empty_like(row)
    K.fill_background_fixed(row, out, 0, 2, float(s), 0.0, 0, K.FILL_MAX_SLOPE, K.FILL_NEARER_LEFT_PX)
    assert np.all(out[0, 20:40] == 10 * s) and np.all(out[1, 20:40] == 30 * s)
    K.fill_background_fixed(row, out, 0, 2, float(s), 0.0, 0, K.FILL_MAX_SLOPE, np.inf)
    assert np.all(out[0, 20:40] == 10 * s) and np.all(out[1, 20:40] == 10 * s)


def test_the_nearer_left_rule_is_off_for_the_fast_matcher():
    from skyrecon.errors import InputError
    from skyrecon.stereo.sgm import SkyreconSettings

    assert SkyreconSettings().nearer_left_px == K.FILL_NEARER_LEFT_PX
    assert SkyreconSettings(fast=True).nearer_left_px == np.inf
    assert SkyreconSettings(fast=True, fill_nearer_left_px=2.0).nearer_left_px == 2.0
    with pytest.raises(InputError, match="fill_nearer_left_px"):
        SkyreconSettings(fill_nearer_left_px=-1.0)


@pytest.mark.parametrize("kw", [{}, {"fast": True}, {"paths": 4}])
def test_warmup_compiles_the_aggregation_kernel_the_frames_use(kw):
    """The SGM kernel is compiled once per number of paths: a matcher's warmup compiles the
    variant its frames then use (the fast one aggregates along four paths, the default six),
    so that no frame pays for compilation."""
    m = SkyreconMatcher(32, **kw)
    m.warmup()
    n = len(K.sgm_band.signatures)
    img = np.random.default_rng(1).integers(0, 255, (120, 160), dtype=np.uint8)
    m.compute(img, np.roll(img, -5, axis=1))
    assert len(K.sgm_band.signatures) == n
