"""The image-noise estimate and the texture thresholds raised above it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from skyrecon.core.image_noise import (
    NOISE_FREE_SIGMA,
    corner_noise_quantile,
    excess_noise_sigma,
    gradient_noise_quantile,
    image_noise_sigma,
    noise_aware_threshold,
    std_noise_quantile,
)


def _scene(rng: np.random.Generator) -> np.ndarray:
    """(240, 320) float32: a smooth sky gradient over a textured half (blobs of 2-3 pixels)."""
    sky = np.linspace(150.0, 200.0, 320, dtype=np.float32)[None, :].repeat(120, axis=0)
    texture = cv2.GaussianBlur(rng.normal(120.0, 50.0, (120, 320)).astype(np.float32), (0, 0), 1.5)
    return np.vstack([sky, texture])


@pytest.mark.parametrize("sigma", [1.0, 2.0, 4.0])
def test_the_estimate_reads_the_noise_of_a_textured_scene(sigma):
    rng = np.random.default_rng(1)
    img = np.clip(np.rint(_scene(rng) + rng.normal(0.0, sigma, (240, 320))), 0, 255).astype(np.uint8)
    expected = np.hypot(sigma, 1.0 / np.sqrt(12.0))  # 8-bit rounding adds its own
    assert image_noise_sigma(img) == pytest.approx(expected, rel=0.1)


def test_a_noise_free_image_reads_almost_nothing_and_odd_images_read_zero():
    rng = np.random.default_rng(2)
    assert image_noise_sigma(np.rint(_scene(rng)).astype(np.uint8)) < 0.1
    assert image_noise_sigma(np.full((100, 100), 255, np.uint8)) == 0.0  # clipped: nothing to measure
    assert image_noise_sigma(np.zeros((10, 10), np.uint8)) == 0.0  # smaller than a block
    with pytest.raises(ValueError, match="grey"):
        image_noise_sigma(np.zeros((40, 40, 3), np.uint8))


def test_the_noise_quantiles_match_simulated_noise():
    rng = np.random.default_rng(3)
    g = rng.normal(0.0, 1.0, (600, 600)).astype(np.float32)
    for w in (5, 7, 9):
        gx = cv2.boxFilter(np.abs(cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=1)), -1, (w, w)) / 2
        gy = cv2.boxFilter(np.abs(cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=1)), -1, (w, w)) / 2
        m = cv2.boxFilter(g, -1, (w, w))
        sd = np.sqrt(np.maximum(cv2.boxFilter(g * g, -1, (w, w)) - m * m, 0))
        assert gradient_noise_quantile(w) == pytest.approx(np.quantile(gx, 0.999), rel=0.05)
        assert gradient_noise_quantile(w, both_axes=True) == pytest.approx(
            np.quantile(gx + gy, 0.999), rel=0.05
        )
        assert std_noise_quantile(w) == pytest.approx(np.quantile(sd, 0.999), rel=0.05)


@pytest.mark.parametrize("sigma", [1.0, 3.0])
def test_the_corner_noise_quantile_bounds_the_corners_of_a_noisy_uint8_image(sigma):
    """OpenCV scales a uint8 image's gradients: the quantile is on that scale, times sigma^2."""
    rng = np.random.default_rng(4)
    img = np.clip(np.rint(128.0 + rng.normal(0.0, sigma, (400, 500))), 0, 255).astype(np.uint8)
    strength = cv2.cornerMinEigenVal(img, 5)[5:-5, 5:-5]
    variance = sigma**2 + 1.0 / 12.0  # the 8-bit rounding adds its own
    assert np.quantile(strength, 0.999) == pytest.approx(corner_noise_quantile(5) * variance, rel=0.1)


def test_thresholds_stay_as_given_without_noise_and_rise_above_it():
    assert noise_aware_threshold(1.0, None, 1.3) == 1.0
    assert noise_aware_threshold(1.0, NOISE_FREE_SIGMA, 1.3) == 1.0  # what a clean image reads
    assert noise_aware_threshold(0.0, 0.1, 1.3) == 0.0  # base 0: only more texture than noise
    assert noise_aware_threshold(0.0, 2.0, 1.3) == pytest.approx(1.3 * excess_noise_sigma(2.0))
    assert excess_noise_sigma(float("nan")) == 0.0
    assert excess_noise_sigma(2.0) == pytest.approx(np.sqrt(4.0 - NOISE_FREE_SIGMA**2))
    lo, hi = noise_aware_threshold(1.0, 1.0, 1.3), noise_aware_threshold(1.0, 3.0, 1.3)
    assert 1.0 < lo < hi and hi == pytest.approx(np.hypot(1.0, 1.3 * excess_noise_sigma(3.0)))
