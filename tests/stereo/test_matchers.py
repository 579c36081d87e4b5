"""Matchers on synthetic pairs with exact disparity: accuracy, interface, reuse."""

import cv2
import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.eval.stereo_metrics import evaluate_disparity
from skyrecon.stereo import (
    DisparityResult,
    Matcher,
    OpenCVSGBMSettings,
    SkyreconMatcher,
    SkyreconSettings,
    create_matcher,
)
from skyrecon.stereo import _kernels as K
from tests.stereo.conftest import random_texture, warp_pair

INNER = (slice(8, -8), slice(40, -8))  # away from the borders and the left band without matches


def _err(result, truth):
    return np.abs(result.disparity[INNER] - truth[INNER])


def test_subpixel_fronto_parallel_plane(fronto_pair):
    left, right, d = fronto_pair
    r = create_matcher("skyrecon", 32).compute(left, right)
    e = _err(r, d)
    assert np.isfinite(e).all()
    assert np.median(e) < 0.2 and np.mean(e) < 0.2 and np.percentile(e, 99) < 0.5
    # sub-pixel, not integer: the 0.3 fraction is recovered on average
    assert abs(np.mean(r.disparity[INNER]) - 12.3) < 0.2


def test_subpixel_slanted_plane(slanted_pair):
    left, right, d = slanted_pair
    r = create_matcher("skyrecon", 32).compute(left, right)
    e = _err(r, d)
    assert np.mean(e) < 0.1 and np.percentile(e, 95) < 0.25
    assert evaluate_disparity(r.disparity[INNER], d[INNER])["bad1"] < 0.005


def test_subpixel_modes_all_work(slanted_pair):
    left, right, d = slanted_pair
    errs = {}
    for mode in ("parabola", "equiangular", "none"):
        errs[mode] = np.mean(_err(create_matcher("skyrecon", 32, subpixel=mode).compute(left, right), d))
    assert errs["equiangular"] < errs["none"] and errs["parabola"] < errs["none"]
    assert errs["none"] < 0.35  # integer disparities: about a quarter pixel on average


@pytest.mark.parametrize("method", ["skyrecon-fast", "opencv-sgbm"])
def test_other_matchers_on_the_slanted_plane(method, slanted_pair):
    left, right, d = slanted_pair
    r = create_matcher(method, 32).compute(left, right)
    e = _err(r, d)
    ok = np.isfinite(e)
    assert ok.mean() > 0.9
    assert np.median(e[ok]) < 0.35


def test_result_fields(slanted_pair):
    left, right, d = slanted_pair
    m = create_matcher("skyrecon", 32)
    assert isinstance(m, Matcher)
    r = m.compute(left, right)
    assert isinstance(r, DisparityResult)
    assert r.disparity.shape == d.shape and r.disparity.dtype == np.float32
    assert r.filled.shape == d.shape and r.filled.dtype == bool
    assert r.method == "skyrecon" and (r.min_disparity, r.max_disparity) == (0, 32)
    assert r.density == 1.0  # filled everywhere
    # the band at the left border cannot be matched: it is filled, not measured
    assert r.filled[:, :5].mean() > 0.9 and r.measured[INNER].mean() > 0.95
    assert {"prepare", "match", "postprocess", "total"} <= set(r.timings_ms)
    assert 0 <= r.diagnostics["lr_rejected"] <= 1


def test_without_filling_invalid_pixels_are_nan(slanted_pair):
    left, right, d = slanted_pair
    r = create_matcher("skyrecon", 32, fill=False).compute(left, right)
    assert np.isnan(r.disparity[:, :5]).mean() > 0.9
    assert not r.filled.any()
    assert np.isfinite(r.disparity[INNER]).mean() > 0.95


def test_opencv_invalid_is_nan_and_range_rounds_to_16(slanted_pair):
    left, right, d = slanted_pair
    m = create_matcher("opencv-sgbm", 20, settings=OpenCVSGBMSettings(mode="hh4", block_size=3))
    assert m.num_disparities == 32 and m.max_disparity == 32
    r = m.compute(left, right)
    assert np.isnan(r.disparity[:, :10]).all()  # OpenCV leaves the left band empty
    assert np.nanmin(r.disparity) >= 0
    bm = create_matcher("opencv-bm", 32, block_size=9, texture_threshold=0)
    rb = bm.compute(left, right)
    assert np.nanmedian(np.abs(rb.disparity[INNER] - d[INNER])) < 0.5


def test_negative_min_disparity(fronto_pair):
    left, right, d = fronto_pair
    # swap roles: the right image seen as "left" has disparity -12.3
    r = create_matcher("skyrecon", 0, min_disparity=-24).compute(right, left)
    inner = (slice(8, -8), slice(8, -40))
    assert np.median(np.abs(r.disparity[inner] + 12.3)) < 0.2


def test_matcher_is_reusable_across_frames_and_sizes(slanted_pair, fronto_pair):
    m = SkyreconMatcher(32)
    a1 = m.compute(*slanted_pair[:2]).disparity
    b = m.compute(*fronto_pair[:2]).disparity
    a2 = m.compute(*slanted_pair[:2]).disparity
    np.testing.assert_array_equal(a1, a2)  # deterministic, no state leaks between frames
    assert b.shape == fronto_pair[2].shape
    # a different size reallocates its buffers
    small = warp_pair(np.full((48, 80), 5.0, np.float32), seed=3)
    assert m.compute(*small).disparity.shape == (48, 80)


def test_single_thread_matches_multi_thread(slanted_pair):
    left, right, _ = slanted_pair
    d1 = create_matcher("skyrecon", 32, threads=1).compute(left, right).disparity
    d2 = create_matcher("skyrecon", 32, threads=2, band_margin=16).compute(left, right).disparity
    # the two bands hand their paths across; speckles are removed per band: almost every pixel
    assert np.mean(np.abs(d1 - d2) < 0.05) > 0.98
    d4 = create_matcher("skyrecon", 32, threads=4, band_margin=16).compute(left, right).disparity
    # two pairs of bands, a warm-up margin between the pairs
    assert np.mean(np.abs(d1 - d4) < 0.05) > 0.98


@pytest.mark.parametrize("kw", [{}, {"paths": 6}, {"horizontal_paths": True}, {"fast": True}])
def test_paired_bands_aggregate_exactly_like_one_band(sim_frame, kw):
    """Two bands of rows handing their SGM path states across their common edge (``sgm_band``
    phases 1 and 2) compute what one band does: the raw matches (no speckle removal, fill or
    median, which work per band) agree exactly, up to the saturation of the stored sums."""
    raw = dict(kw, fill=False, speckle_size=0, median=0)
    d1 = create_matcher("skyrecon", 64, threads=1, **raw).compute(sim_frame.left, sim_frame.right)
    d2 = create_matcher("skyrecon", 64, threads=2, **raw).compute(sim_frame.left, sim_frame.right)
    same = (d1.disparity == d2.disparity) | (np.isnan(d1.disparity) & np.isnan(d2.disparity))
    assert same.mean() > 0.9995
    if not kw:  # two paths a sweep: their sums never saturate
        assert same.all()


@pytest.mark.parametrize("P2", [100, 224])  # the default; the largest that fits 8 bits (31-bit census)
def test_path_states_in_8_bits_match_16_bits(sim_frame, monkeypatch, P2):
    """Path states are stored in 8 bits when they fit (a state is at most the matching cost
    plus the jump penalty above its predecessor's minimum): the disparities are exactly those
    of 16-bit states, up to the largest penalty that fits."""
    from skyrecon.stereo import sgm

    assert K.states_fit_uint8(31, 5, P2)
    assert not K.states_fit_uint8(31, 5, 225)  # 224 is the largest that fits a 31-bit census
    assert not K.states_fit_uint8(32, 5, 224) and not K.states_fit_uint8(31, 230, 200)
    d8 = create_matcher("skyrecon", 64, P2=P2).compute(sim_frame.left, sim_frame.right)
    monkeypatch.setattr(sgm.K, "states_fit_uint8", lambda *a: False)
    d16 = create_matcher("skyrecon", 64, P2=P2).compute(sim_frame.left, sim_frame.right)
    np.testing.assert_array_equal(d8.disparity, d16.disparity)


def test_band_pairs_stay_within_a_wave():
    from skyrecon.stereo.sgm import _band_pairs

    def pairs(parts, threads):
        return sorted((i, up) for i, (_, up, _) in _band_pairs(parts, threads).items())

    assert pairs(2, 2) == [(0, True), (1, False)]
    assert pairs(5, 2) == [(0, True), (1, False), (2, True), (3, False)]  # band 4 alone
    assert pairs(4, 3) == [(0, True), (1, False)]  # bands 2 and 3 run in different waves
    assert pairs(4, 1) == []
    p = _band_pairs(2, 2)
    assert p[0][0] is p[1][0] and p[1][2] == 0  # one barrier; the lower band knows the upper
    assert p[0][2] == 1  # and the upper the lower


def test_a_failing_band_does_not_leave_its_pair_waiting(sim_frame, monkeypatch):
    import threading

    from skyrecon.stereo import sgm

    real = sgm.K.sgm_band

    def failing(*args):
        if args[-3] == 1 and not args[-2]:  # phase 1 of the lower band
            raise RuntimeError("boom")
        return real(*args)

    pair = (sim_frame.left, sim_frame.right)
    m = create_matcher("skyrecon", 32, threads=2)
    assert m.compute(*pair).diagnostics["bands"] == 2
    monkeypatch.setattr(sgm.K, "sgm_band", failing)
    errors: list[BaseException] = []

    def run():
        try:
            m.compute(*pair)
        except BaseException as e:  # noqa: BLE001 - collected for the assertion
            errors.append(e)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(30)
    assert not t.is_alive() and errors  # the error, not a hang on the pair's barrier


def test_settings_object_and_overrides(slanted_pair):
    s = SkyreconSettings(paths=4, P1=4, P2=80)
    m = create_matcher("skyrecon", 32, settings=s)
    assert m.settings.P1 == 4
    m2 = create_matcher("skyrecon-fast", 32)
    assert m2.settings.fast and m2.name == "skyrecon-fast"
    r = m2.compute(*slanted_pair[:2])
    assert r.method == "skyrecon-fast" and r.disparity.shape == slanted_pair[2].shape


def test_sequence_reuses_buffers_without_recompiling(slanted_pair, fronto_pair):
    m = SkyreconMatcher(32)
    frames = [slanted_pair[:2], fronto_pair[:2], slanted_pair[:2]]
    m.compute(*frames[0])
    kernels = (
        K.sgm_band,
        K.census_transform,
        K.to_fixed,
        K.from_fixed,
        K.fill_background_fixed,
        K.guided_fill_targets,
        K.guided_fill_candidates,
        K.guided_fill_median,
        K.guided_fill_spread,
    )
    before = [len(k.signatures) for k in kernels]
    buffers = {k: id(v) for k, v in m._buffers.items()}
    results = [m.compute(*f) for f in frames]
    assert [len(k.signatures) for k in kernels] == before  # no recompilation per frame
    # same-size frames reuse the same buffers
    m.compute(*frames[0])
    assert {k: id(v) for k, v in m._buffers.items() if k in buffers} == buffers
    # results are independent copies, not views of the internal buffers
    assert not np.shares_memory(results[0].disparity, results[2].disparity)
    np.testing.assert_array_equal(results[0].disparity, results[2].disparity)


@pytest.mark.parametrize("mode", ["sgbm", "hh", "sgbm_3way", "hh4"])
def test_every_opencv_sgbm_mode(mode, slanted_pair):
    left, right, d = slanted_pair
    m = create_matcher(
        "opencv-sgbm",
        32,
        mode=mode,
        block_size=3,
        P1=100,
        P2=800,
        disp12_max_diff=-1,
        pre_filter_cap=31,
        uniqueness_ratio=5,
        speckle_window_size=50,
        speckle_range=1,
        use_colour=False,
    )
    r = m.compute(left, right)
    assert r.diagnostics["channels"] == 1
    assert np.nanmedian(np.abs(r.disparity[INNER] - d[INNER])) < 0.35


@pytest.mark.parametrize("prefilter", ["xsobel", "normalized_response"])
def test_opencv_bm_prefilters(prefilter, slanted_pair):
    left, right, d = slanted_pair
    m = create_matcher(
        "opencv-bm",
        32,
        pre_filter_type=prefilter,
        pre_filter_size=9,
        pre_filter_cap=31,
        block_size=11,
        texture_threshold=0,
        uniqueness_ratio=5,
        speckle_window_size=0,
        speckle_range=0,
        disp12_max_diff=1,
    )
    r = m.compute(left, right)
    assert np.nanmedian(np.abs(r.disparity[INNER] - d[INNER])) < 0.5


def test_left_band_restart_keeps_a_striped_surfaces_alias_out():
    """A striped plane at 40 px disparity, plain noise texture from column 150 on: left of
    column 40 its match lies outside the right image and its pixels take an alias of the
    stripes (inside the right image). With the rightward diagonal paths restarted at the
    largest disparity, as at the border, the alias no longer spreads into the matched part."""
    H, W, d, pad = 160, 240, 40.0, 80
    yy, xx = np.mgrid[0:H, 0 : W + 2 * pad].astype(np.float32)
    stripes = 128 + 60 * np.sin(2 * np.pi * (xx * np.cos(0.2) + yy * np.sin(0.2)) / 18.0)
    texture = np.where(xx < 150 + pad - d, stripes, random_texture(H, W + 2 * pad, 3)).astype(np.float32)
    xs = np.arange(W, dtype=np.float32)[None, :].repeat(H, 0)
    ys = np.arange(H, dtype=np.float32)[:, None].repeat(W, 1)
    views = [cv2.remap(texture, xs - s + pad, ys, cv2.INTER_CUBIC) for s in (d, 0.0)]
    left, right = (np.clip(v, 0, 255).round().astype(np.uint8) for v in views)
    right_part = {}
    for restart in (False, True):
        disp = create_matcher("skyrecon", 48, left_band_restart=restart).compute(left, right).disparity
        right_part[restart] = float((np.abs(disp[:, 48:150] - d) <= 1).mean())
    assert right_part[True] > 0.97 and right_part[False] < 0.85


def test_six_paths_by_default_and_four_when_fast():
    """The third pair of diagonal paths is the full-resolution default; the fast setting keeps
    four (its frame budget); an explicit count wins either way."""
    assert SkyreconSettings().n_paths == 6 and SkyreconSettings(fast=True).n_paths == 4
    assert SkyreconSettings(paths=4).n_paths == 4 and SkyreconSettings(fast=True, paths=6).n_paths == 6


def test_the_third_diagonal_pair_lowers_the_error_on_flyingthings_style_pairs():
    """On FlyingThings-style pairs (objects in front of each other cut the paths that would
    carry a surface's disparity) the down-left/up-right paths bring it from another side:
    bad-1 falls on both pairs (seeds 3 and 4: 0.160 -> 0.142, 0.121 -> 0.113)."""
    from skyrecon.sim.flying import render_flying_pair

    for seed in (3, 4):
        left, right, gt = render_flying_pair(seed)
        bad1 = {}
        for p in (4, 6):
            disparity = create_matcher("skyrecon", 64, paths=p).compute(left, right).disparity
            bad1[p] = evaluate_disparity(disparity, gt)["bad1"]
        assert bad1[6] < bad1[4] - 0.005, (seed, bad1)


def test_the_diagnostics_name_the_paths_in_use():
    img = random_texture(40, 60, 1).astype(np.uint8)
    for kw, n in (({}, 6), ({"fast": True}, 4), ({"paths": 2}, 2)):
        diag = create_matcher("skyrecon", 16, **kw).compute(img, img).diagnostics
        assert diag["paths"] == n and diag["settings"]["paths"] == kw.get("paths")


def test_a_tolerant_census_keeps_plain_surfaces_matched_under_camera_noise(sim_frame):
    """Noise scrambles the classic census of a plain surface (random bits, random costs): far
    fewer pixels pass the checks. With the tolerance measured on the image (None), the codes of
    a plain surface tie again as without noise; on the noise-free pair the measured tolerance
    is 0 and the result is the classic census's, bit for bit."""
    from skyrecon.sim.sensor_noise import add_sensor_noise

    f = sim_frame
    clean = {
        t: create_matcher("skyrecon", 64, census_tolerance=t).compute(f.left, f.right) for t in (0.0, None)
    }
    np.testing.assert_array_equal(clean[0.0].disparity, clean[None].disparity)
    assert clean[None].diagnostics["census_tolerance"] == 0
    rng = np.random.default_rng(2)
    left, right = add_sensor_noise(f.left, 2.0, rng), add_sensor_noise(f.right, 2.0, rng)
    noisy = {t: create_matcher("skyrecon", 64, census_tolerance=t).compute(left, right) for t in (0.0, None)}
    assert noisy[None].diagnostics["image_noise"] == pytest.approx(2.0, abs=0.3)
    assert noisy[None].diagnostics["census_tolerance"] >= 4
    measured = {t: float(r.measured.mean()) for t, r in noisy.items()}
    assert measured[None] > measured[0.0] + 0.1
    assert measured[None] > 0.8 * float(clean[0.0].measured.mean())
    truth = f.disparity_left_px
    ok = noisy[None].measured & np.isfinite(truth)
    assert np.mean(np.abs(noisy[None].disparity[ok] - truth[ok]) > 3) < 0.03
    with pytest.raises(InputError, match="census_tolerance"):
        SkyreconSettings(census_tolerance=-1.0)
