"""Feature detection (resolution mapping, descriptor kinds) and matching (ratio, mutual)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.features import (
    FeatureSettings,
    MatchSettings,
    detect_features,
    match_descriptors,
    match_features,
    resize_longer_side,
    to_gray_uint8,
)


def _blob_image(w: int, h: int, centres: list[tuple[float, float]], sigma: float) -> np.ndarray:
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    img = np.full((h, w), 40.0)
    for cu, cv in centres:
        img += 180.0 * np.exp(-((u - cu) ** 2 + (v - cv) ** 2) / (2 * sigma**2))
    return np.clip(img, 0, 255).astype(np.uint8)


def _texture(seed: int, w: int = 640, h: int = 480) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (h // 8, w // 8), dtype=np.uint8)
    img = cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    return cv2.GaussianBlur(img, (0, 0), 1.0)


@pytest.mark.parametrize("max_size", [None, 400])
def test_keypoints_are_in_full_resolution_pixels(max_size):
    centres = [(200.3, 150.7), (601.6, 420.2), (350.0, 600.4)]
    img = _blob_image(800, 800, centres, sigma=12.0)
    f = detect_features(img, FeatureSettings(method="sift", max_image_size=max_size))
    assert f.image_size == (800, 800)
    assert f.scale == (1.0 if max_size is None else 0.5)
    for c in centres:
        d = np.hypot(*(f.keypoints - np.array(c)).T)
        assert d.min() < 0.35, (c, d.min())


def test_descriptor_kinds():
    img = _texture(0)
    rs = detect_features(img, FeatureSettings(method="rootsift"))
    assert rs.descriptors.dtype == np.float32 and rs.descriptors.shape[1] == 128
    np.testing.assert_allclose(np.linalg.norm(rs.descriptors, axis=1), 1.0, atol=1e-5)
    assert rs.descriptors.min() >= 0
    for method in ("orb", "akaze"):
        if method == "akaze" and not hasattr(cv2, "AKAZE_create"):
            with pytest.raises(InputError, match="AKAZE"):
                detect_features(img, FeatureSettings(method=method))
            continue
        f = detect_features(img, FeatureSettings(method=method))
        assert f.descriptors.dtype == np.uint8 and len(f) > 50 and f.binary
    capped = detect_features(img, FeatureSettings(max_features=100))
    assert len(capped) <= 100


def test_resize_and_gray_helpers():
    img = np.zeros((1000, 3000, 3), np.uint8)
    small, sx, sy = resize_longer_side(img, 1536)
    assert small.shape[:2] == (512, 1536) and sx == pytest.approx(0.512) and sy == pytest.approx(0.512)
    assert resize_longer_side(img, None)[1] == 1.0
    assert to_gray_uint8(np.ones((20, 20), np.float32)).max() == 255
    assert to_gray_uint8(np.full((20, 20, 3), 65535, np.uint16)).max() == 255
    for bad in (np.zeros((5, 5)), np.zeros((20, 20, 2)), np.full((20, 20), np.nan, np.float32)):
        with pytest.raises(InputError):
            to_gray_uint8(bad)
    with pytest.raises(InputError):
        FeatureSettings(method="surf")  # type: ignore[arg-type]


def test_matching_agrees_with_opencv_bruteforce():
    a, b = _texture(1), _texture(1)
    M = np.array([[1.0, 0.05, 12.0], [-0.04, 1.0, -7.0]])
    b = cv2.warpAffine(a, M, (a.shape[1], a.shape[0]))
    fs = FeatureSettings(method="sift")
    f1, f2 = detect_features(a, fs), detect_features(b, fs)
    m = match_features(f1, f2, MatchSettings(ratio=0.8, mutual=False))
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(f1.descriptors, f2.descriptors, k=2)
    ref = {(k[0].queryIdx, k[0].trainIdx) for k in knn if len(k) == 2 and k[0].distance < 0.8 * k[1].distance}
    ours = set(map(tuple, m.pairs.tolist()))
    assert len(ours ^ ref) <= 0.02 * len(ref) + 2  # ties and float rounding only
    # the matches follow the warp
    pred = f1.keypoints[m.idx1] @ M[:, :2].T + M[:, 2]
    assert np.median(np.hypot(*(pred - f2.keypoints[m.idx2]).T)) < 0.5
    mutual = match_features(f1, f2, MatchSettings(ratio=0.8, mutual=True))
    assert set(map(tuple, mutual.pairs.tolist())) <= ours
    assert len(np.unique(mutual.idx2)) == len(mutual)


def test_ratio_and_mutual_rules_on_crafted_descriptors():
    e = np.eye(4, dtype=np.float32)
    d1 = np.stack([e[0], e[1], (e[2] + e[3]) / np.sqrt(2)]).astype(np.float32)
    d2 = np.stack([e[0], e[1], e[2], e[3]]).astype(np.float32)
    m = match_descriptors(d1, d2, MatchSettings(ratio=0.8))
    # the third descriptor is equidistant to two candidates: rejected by the ratio test
    assert m.pairs.tolist() == [[0, 0], [1, 1]]
    assert np.all(m.ratios < 0.8)
    # binary descriptors
    rng = np.random.default_rng(0)
    b1 = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    m = match_descriptors(b1, b1.copy(), MatchSettings())
    assert m.pairs.tolist() == [[i, i] for i in range(50)]
    assert len(match_descriptors(np.zeros((0, 32), np.uint8), b1)) == 0
    with pytest.raises(InputError):
        match_descriptors(b1, d2)
    with pytest.raises(InputError):
        MatchSettings(ratio=1.5)


def test_flann_matches_mostly_agree_with_bruteforce():
    a = _texture(3)
    b = cv2.warpAffine(a, np.array([[1.0, 0.0, 5.0], [0.0, 1.0, 3.0]]), (a.shape[1], a.shape[0]))
    f1, f2 = detect_features(a), detect_features(b)
    bf = set(map(tuple, match_features(f1, f2, MatchSettings()).pairs.tolist()))
    fl = set(map(tuple, match_features(f1, f2, MatchSettings(matcher="flann")).pairs.tolist()))
    assert len(bf & fl) >= 0.9 * len(bf)
