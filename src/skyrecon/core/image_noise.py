"""A camera's image noise, measured on the image, and texture thresholds that stand above it.

Texture tests ("is there enough grey-level variation here for a match to mean anything?") use
thresholds in grey levels. Chosen on noise-free rendered images, a fixed threshold passes every
window of a real camera's image: on a plain wall the sensor noise alone (1-2 grey levels on
many outdoor cameras) is above it, and the matcher's guesses there count as
measurements again. So the image's noise is estimated from the image itself and each threshold
is raised until pure noise of that level stays under it (:func:`noise_aware_threshold`).

The estimate is Immerkaer's (1996) measured where the image is flattest: the image convolved
with the difference of two Laplacians (``[[1, -2, 1], [-2, 4, -2], [1, -2, 1]]``) cancels smooth
shading and leaves ``6 sigma`` of Gaussian noise, and the mean absolute response times
``sqrt(pi / 2) / 6`` is ``sigma``. Texture and edges respond too, so the mean is taken per 16x16
block and the estimate is a low quantile (the tenth percentile) of the blocks, corrected for the
quantile's bias on pure noise; blocks with clipped pixels (0-2 or 253-255 grey levels, where noise
is cut off) are left out. Outdoor scenes have flat blocks (sky, walls, road); a scene of fine
texture everywhere reads high. On noise-free renders of the synthetic city it reads 0.00-0.01,
with noise of sigma 1, 1.5, 2 and 4 added 1.06-1.09, 1.55-1.58, 2.03-2.08 and 4.0-4.1 (the 8-bit
rounding adds 0.29 in quadrature); on a KITTI frame 0.65. 0.7 ms on a 640x480 image.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np

__all__ = [
    "NOISE_FREE_SIGMA",
    "image_noise_sigma",
    "excess_noise_sigma",
    "noise_aware_threshold",
    "gradient_noise_quantile",
    "std_noise_quantile",
    "corner_noise_quantile",
]

#: what :func:`image_noise_sigma` may read on a noise-free 8-bit image, grey levels: rounding to
#: whole grey levels (0.29) and fine texture passing for noise in the flattest blocks (at most
#: 0.29 over 864 views of mission cities, plain and textured, at 640x480). Thresholds chosen on
#: such images already allow for it, so only noise beyond it raises them
#: (:func:`excess_noise_sigma`). Measure at full resolution: a reduced image has fewer flat
#: blocks (the same views at 320x240 read up to 0.61); its noise is the full image's divided by
#: the reduction factor (an area average of k x k pixels).
NOISE_FREE_SIGMA = 0.35

#: side of the blocks whose mean response is compared, pixels
_BLOCK_PX = 16
#: the quantile of the block means taken as the noise (the flattest blocks)
_BLOCK_QUANTILE = 0.1
#: that quantile over the mean, on pure Gaussian noise (measured: 0.893 for 16x16 blocks)
_QUANTILE_BIAS = 0.893
#: blocks with a pixel outside these grey levels are clipped (no noise to measure there)
_UNCLIPPED = (3, 252)
_LAPLACE_DIFF = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
#: one-sided normal quantile for "pure noise stays under the threshold" (about 1 window in 1000)
_Z = 3.1


def image_noise_sigma(grey: np.ndarray) -> float:
    """Standard deviation of the image's noise, grey levels (0-255 scale; see the module).

    Args:
        grey: (H, W) grey image (uint8, or any numeric dtype on the 0-255 scale).
    Returns:
        The estimate (8-bit rounding included); 0.0 for an image smaller than one block or with
        no unclipped block.
    """
    g = np.asarray(grey)
    if g.ndim != 2:
        raise ValueError(f"image_noise_sigma needs a (H, W) grey image, got shape {g.shape}")
    H, W = g.shape
    h, w = (H - 2) // _BLOCK_PX, (W - 2) // _BLOCK_PX
    if h < 1 or w < 1:
        return 0.0
    gf = g.astype(np.float32, copy=False)
    rows, cols = slice(1, 1 + h * _BLOCK_PX), slice(1, 1 + w * _BLOCK_PX)
    response = np.abs(cv2.filter2D(gf, -1, _LAPLACE_DIFF))[rows, cols]
    block_mean = cv2.resize(response, (w, h), interpolation=cv2.INTER_AREA)
    inside = ((gf[rows, cols] >= _UNCLIPPED[0]) & (gf[rows, cols] <= _UNCLIPPED[1])).astype(np.float32)
    unclipped = cv2.resize(inside, (w, h), interpolation=cv2.INTER_AREA) >= 1.0 - 1e-6
    values = block_mean[unclipped]
    if values.size == 0:
        return 0.0
    low = float(np.quantile(values, _BLOCK_QUANTILE))
    return math.sqrt(math.pi / 2.0) * low / (6.0 * _QUANTILE_BIAS)


def excess_noise_sigma(sigma: float) -> float:
    """The part of a measured noise level beyond what a noise-free 8-bit image may read
    (:data:`NOISE_FREE_SIGMA`, taken off in quadrature), grey levels: what a threshold chosen on
    noise-free renders has not allowed for (0 for them)."""
    s = float(sigma)
    if not math.isfinite(s) or s <= NOISE_FREE_SIGMA:
        return 0.0
    return math.sqrt(s * s - NOISE_FREE_SIGMA**2)


def gradient_noise_quantile(window_px: int, both_axes: bool = False) -> float:
    """Upper quantile (about 1 in 1000) of the mean absolute central-difference gradient,
    ``|I(x+1) - I(x-1)| / 2``, over a ``window_px`` square of pure unit Gaussian noise (along x,
    or the sum of the x and y gradients with ``both_axes``); multiply by the noise sigma.
    Checked by simulation: 0.80 along x and 1.54 for both for a 7-pixel window."""
    w = max(1, int(window_px))
    # |N(0, 2)| / 2: mean 1 / sqrt(pi) = 0.564, standard deviation 0.426
    mean = 1.0 / math.sqrt(math.pi)
    sd = math.sqrt(2.0 * (1.0 - 2.0 / math.pi)) / 2.0
    # neighbouring differences share pixels: about 0.64 w^2 independent ones in the window
    spread = sd / (0.8 * w)
    if both_axes:  # the x and y gradients of a window share pixels: correlation about 0.5
        return 2.0 * mean + _Z * math.sqrt(3.0) * spread
    return mean + _Z * spread


def std_noise_quantile(window_px: int) -> float:
    """Upper quantile (about 1 in 1000) of the standard deviation over a ``window_px`` square of
    pure unit Gaussian noise; multiply by the noise sigma. Checked by simulation: 1.31 for 7
    pixels, 1.24 for 9."""
    n = max(2, int(window_px) ** 2)
    return 1.0 + _Z / math.sqrt(2.0 * (n - 1))


@functools.lru_cache(maxsize=8)
def corner_noise_quantile(block_px: int = 5) -> float:
    """Upper quantile (1 in 1000) of the Shi-Tomasi corner strength of a uint8 image, OpenCV's
    ``cornerMinEigenVal(image, block_px)`` (3x3 Sobel; on uint8 images OpenCV scales the gradients
    by 1/255), on pure unit Gaussian noise; multiply by the noise variance (sigma squared: the
    strength is quadratic in the grey levels). Measured by simulation on a seeded 480x640 image
    (about 30 ms, once per block size): 2.2e-5 for 5 pixels. A corner weaker than this is as
    likely noise as texture: tracked, it follows the noise."""
    rng = np.random.default_rng(0)
    noise = rng.normal(0.0, 1.0, (480, 640)).astype(np.float32)
    strength = cv2.cornerMinEigenVal(noise, int(block_px))  # float input: no 1/255 scaling
    b = int(block_px)  # the border, where the window is reflected, is left out
    return float(np.quantile(strength[b:-b, b:-b], 0.999)) / 255.0**2


def noise_aware_threshold(base: float, noise_sigma: float | None, per_sigma: float) -> float:
    """A texture threshold that pure noise stays under: ``hypot(base, per_sigma * excess)``,
    ``excess`` the noise beyond what a noise-free image reads (:func:`excess_noise_sigma`); ``base`` itself for a
    noise-free image or no estimate (None). A ``base`` of 0 asks only for more texture than
    noise (0 on a noise-free image).

    Args:
        base: the threshold chosen on noise-free images (same units as the measure, >= 0).
        noise_sigma: the image's noise, grey levels (:func:`image_noise_sigma`), or None.
        per_sigma: the measure's upper quantile on unit noise (:func:`gradient_noise_quantile`,
            :func:`std_noise_quantile`).
    """
    if noise_sigma is None:
        return float(base)
    excess = excess_noise_sigma(noise_sigma)
    return float(math.hypot(base, per_sigma * excess)) if excess > 0 else float(base)
