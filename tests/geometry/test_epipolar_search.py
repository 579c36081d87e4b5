"""Direct NCC/SSD window search along epipolar segments."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from skyrecon.core import Intrinsics
from skyrecon.errors import InputError
from skyrecon.geometry.epipolar_search import (
    clip_segments,
    match_along_epipolar_lines,
    search_segments_from_depth,
)


def _texture(w: int = 320, h: int = 240, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.resize(
        rng.integers(0, 256, (h // 4, w // 4), dtype=np.uint8), (w, h), interpolation=cv2.INTER_CUBIC
    )
    return cv2.GaussianBlur(img, (0, 0), 0.8)


@pytest.mark.parametrize("metric", ["ncc", "ssd"])
def test_finds_a_fronto_parallel_shift(metric):
    # camera 2 is 0.1 m to the right of camera 1 looking at a wall 5 m away: pure horizontal shift
    intr = Intrinsics(300.0, 300.0, 159.5, 119.5, 320, 240)
    R, t = np.eye(3), np.array([-0.1, 0.0, 0.0])
    shift = 300.0 * 0.1 / 5.0  # 6 px to the left in image 2
    a = _texture()
    M = np.float32([[1, 0, -shift], [0, 1, 0]])
    b = cv2.warpAffine(a, M, (320, 240), flags=cv2.INTER_CUBIC)
    v, u = np.mgrid[40:200:20, 60:260:20]
    x1 = np.stack([u.ravel(), v.ravel()], 1).astype(float)
    seg = search_segments_from_depth(x1, intr, intr, R, t, (2.0, 50.0))
    assert np.allclose(seg[:, 1], x1[:, 1]) and np.allclose(seg[:, 3], x1[:, 1])  # horizontal lines
    res = match_along_epipolar_lines(a, b, x1, seg, window=9, metric=metric)
    ok = np.isfinite(res.scores)
    assert ok.mean() > 0.9
    err = np.hypot(*(res.points2[ok] - (x1[ok] - [shift, 0])).T)
    assert np.median(err) < 0.1 and np.percentile(err, 90) < 0.5
    if metric == "ncc":
        assert np.median(res.scores[ok]) > 0.95


def test_clipping_and_bad_arguments():
    seg = clip_segments(np.array([[-10.0, 5.0, 50.0, 5.0], [-10.0, -10.0, -5.0, -5.0]]), 20, 10)
    np.testing.assert_allclose(seg[0], [0.0, 5.0, 19.0, 5.0])
    assert np.isnan(seg[1]).all()
    a = _texture()
    with pytest.raises(InputError):
        match_along_epipolar_lines(a, a, np.zeros((1, 2)), np.zeros((1, 4)), window=4)
    with pytest.raises(InputError):
        match_along_epipolar_lines(a, a, np.zeros((1, 2)), np.zeros((1, 4)), metric="sad")  # type: ignore[arg-type]
    with pytest.raises(InputError):
        search_segments_from_depth(
            np.zeros((1, 2)),
            Intrinsics.from_fov(320, 240, 60),
            Intrinsics.from_fov(320, 240, 60),
            np.eye(3),
            np.array([1.0, 0, 0]),
            (5.0, 1.0),
        )
