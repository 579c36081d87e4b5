"""Synthetic stereo pairs with exact disparity for the stereo tests."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from skyrecon import sim


def random_texture(height: int, width: int, seed: int, sigma: float = 1.2) -> np.ndarray:
    """(H, W) float32 band-limited random texture, mean 128, std 40."""
    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.normal(0.0, 1.0, (height, width)).astype(np.float32), (0, 0), sigma)
    return (t - t.mean()) / t.std() * 40.0 + 128.0


def warp_pair(disparity: np.ndarray, seed: int = 0, colour: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """A rectified pair whose left image sees the right one shifted by ``disparity`` (H, W).

    ``left(x, y) = right(x - d(x, y), y)`` with a random texture painted in the right image's
    coordinates (cubic interpolation), so ``x_right = x_left - d`` holds exactly up to sampling.
    """
    H, W = disparity.shape
    pad = int(np.ceil(np.nanmax(np.abs(disparity)))) + 8
    T = random_texture(H, W + 2 * pad, seed)
    xs = np.arange(W, dtype=np.float32)[None, :].repeat(H, 0)
    ys = np.arange(H, dtype=np.float32)[:, None].repeat(W, 1)
    right = cv2.remap(T, xs + pad, ys, cv2.INTER_CUBIC)
    left = cv2.remap(T, xs - disparity.astype(np.float32) + pad, ys, cv2.INTER_CUBIC)
    left = np.clip(left, 0, 255).round().astype(np.uint8)
    right = np.clip(right, 0, 255).round().astype(np.uint8)
    if colour:
        tint = np.array([1.0, 0.9, 0.8], np.float32)
        left = np.clip(left[..., None] * tint, 0, 255).astype(np.uint8)
        right = np.clip(right[..., None] * tint, 0, 255).astype(np.uint8)
    return left, right


@pytest.fixture(scope="session")
def fronto_pair():
    """Fronto-parallel plane at 12.3 px disparity, 160x120 grey."""
    d = np.full((120, 160), 12.3, np.float32)
    left, right = warp_pair(d, seed=1)
    return left, right, d


@pytest.fixture(scope="session")
def slanted_pair():
    """Slanted plane d = 8 + 0.03 x + 0.02 y, 160x120 colour."""
    H, W = 120, 160
    d = (8.0 + 0.03 * np.arange(W)[None, :] + 0.02 * np.arange(H)[:, None]).astype(np.float32)
    left, right = warp_pair(d, seed=2, colour=True)
    return left, right, d


@pytest.fixture(scope="session")
def sim_frame():
    """A rendered street-view pair of the synthetic city (640x480, exact disparity)."""
    city = sim.generate_city(2)
    rig = sim.default_rig()
    return sim.render_stereo(city, rig, sim.street_view_pose(city, 2))
