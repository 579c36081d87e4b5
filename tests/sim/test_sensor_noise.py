"""Camera sensor noise added to rendered frames."""

from __future__ import annotations

import numpy as np

from skyrecon.sim.sensor_noise import add_sensor_noise


def test_noise_is_grey_deterministic_and_of_the_level_asked():
    img = np.full((200, 300, 3), 100, np.uint8)
    a = add_sensor_noise(img, 2.0, np.random.default_rng(5))
    b = add_sensor_noise(img, 2.0, np.random.default_rng(5))
    np.testing.assert_array_equal(a, b)
    assert a.dtype == np.uint8 and a.shape == img.shape
    assert (a[..., 0] == a[..., 1]).all() and (a[..., 1] == a[..., 2]).all()  # the grey image carries it
    d = a[..., 0].astype(float) - 100
    assert abs(d.mean()) < 0.05 and abs(d.std() - 2.0) < 0.1


def test_zero_noise_is_the_image_itself_and_values_are_clipped():
    img = np.full((50, 50), 254, np.uint8)
    assert add_sensor_noise(img, 0.0, np.random.default_rng(0)) is img
    out = add_sensor_noise(img, 20.0, np.random.default_rng(0))
    assert out.shape == (50, 50) and out.max() == 255 and out.min() < 254
