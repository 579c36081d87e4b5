"""Camera sensor noise for rendered frames (the renderer's images are noise-free).

Real cameras add noise of 1-2 grey levels (standard deviation) on a well-lit outdoor scene;
more in low light. A rendered image with none of it flatters every texture test: a plain wall
is exactly flat. :func:`add_sensor_noise` adds white Gaussian noise of a given level, the same
in the three colour channels (so the grey image carries exactly that level), rounded and
clipped to 8 bits; deterministic in its generator.
"""

from __future__ import annotations

import numpy as np

__all__ = ["add_sensor_noise"]


def add_sensor_noise(image: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """``image`` ((H, W, 3) or (H, W) uint8) with white Gaussian noise of ``sigma`` grey levels,
    rounded and clipped to 0-255 (a new array; the image itself when ``sigma`` is 0)."""
    if not sigma > 0:
        return image
    img = np.asarray(image)
    n = rng.normal(0.0, float(sigma), img.shape[:2]).astype(np.float32)
    if img.ndim == 3:
        n = n[..., None]
    return np.clip(np.rint(img.astype(np.float32) + n), 0, 255).astype(np.uint8)
