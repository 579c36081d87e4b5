import cv2
import numpy as np

from skyrecon.odometry.frontend import (
    build_pyramid,
    detect_corners,
    disparity_lookup,
    grid_coverage,
    refine_to_anchor,
    stereo_match,
    track_points,
)


def _texture(h=120, w=160, seed=0):
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 255, (h // 4, w // 4), dtype=np.uint8)
    return cv2.GaussianBlur(cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR), (3, 3), 0)


def _shift(img, dx, dy):
    M = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]])
    return cv2.warpAffine(
        img, M, (img.shape[1], img.shape[0]), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT
    )


def test_detect_corners_spreads_and_avoids_existing():
    img = _texture()
    pts = detect_corners(img, np.zeros((0, 2), np.float32), 96, grid=(4, 3), min_distance_px=5)
    assert 40 <= len(pts) <= 96
    assert grid_coverage(pts, 160, 120, (4, 3)) == 1.0
    more = detect_corners(img, pts, 96, grid=(4, 3), min_distance_px=5)
    if len(more):
        d = np.linalg.norm(more[:, None] - pts[None], axis=2).min(axis=1)
        assert d.min() >= 4.0
    assert len(more) < len(pts)  # the cells are (nearly) full already


def test_detect_corners_leaves_noise_corners_out_above_a_strength_floor():
    """Half texture, half a plain area with 2 grey levels of noise: each cell's best corners
    include the plain cells' noise, unless corners must be stronger than the noise floor."""
    from skyrecon.core.image_noise import corner_noise_quantile

    rng = np.random.default_rng(5)
    img = _texture().astype(np.float32)
    img[:, 80:] = 128.0
    img = np.clip(np.rint(img + rng.normal(0.0, 2.0, img.shape)), 0, 255).astype(np.uint8)
    none = np.zeros((0, 2), np.float32)
    every = detect_corners(img, none, 96, grid=(4, 3), min_distance_px=5)
    assert np.count_nonzero(every[:, 0] > 84) >= 20  # noise "corners" in the plain half
    floor = 4.0 * corner_noise_quantile(5) * 4.0
    strong = detect_corners(img, none, 96, grid=(4, 3), min_distance_px=5, min_strength=floor)
    assert np.count_nonzero(strong[:, 0] > 84) == 0
    assert np.count_nonzero(strong[:, 0] < 76) >= 0.8 * np.count_nonzero(every[:, 0] < 76)


def test_track_points_follows_a_shift_and_drops_bad_tracks():
    img = _texture()
    moved = _shift(img, 3.3, -1.7)
    pts = detect_corners(img, np.zeros((0, 2), np.float32), 60, grid=(4, 3), min_distance_px=5)
    pts = pts[(pts[:, 0] > 15) & (pts[:, 0] < 140) & (pts[:, 1] > 15) & (pts[:, 1] < 100)]
    out, ok = track_points(build_pyramid(img, 15, 2), build_pyramid(moved, 15, 2), pts)
    assert ok.mean() > 0.9
    err = out[ok] - pts[ok] - np.array([3.3, -1.7])
    assert np.median(np.abs(err)) < 0.05
    # against an unrelated image the forward-backward check rejects most tracks
    _, ok2 = track_points(build_pyramid(img, 15, 2), build_pyramid(_texture(seed=5), 15, 2), pts)
    assert ok2.mean() < 0.5


def test_stereo_match_finds_row_disparity():
    left = _texture()
    right = _shift(left, -2.5, 0.0)  # x_right = x_left - 2.5
    pts = detect_corners(left, np.zeros((0, 2), np.float32), 60, grid=(4, 3), min_distance_px=5)
    pts = pts[(pts[:, 0] > 15) & (pts[:, 0] < 140) & (pts[:, 1] > 15) & (pts[:, 1] < 100)]
    d = stereo_match(build_pyramid(left, 15, 2), build_pyramid(right, 15, 2), pts)
    assert np.isfinite(d).mean() > 0.9
    assert np.nanmedian(np.abs(d - 2.5)) < 0.05
    # a minimum disparity above the true one rejects every match
    d2 = stereo_match(build_pyramid(left, 15, 2), build_pyramid(right, 15, 2), pts, min_disparity_px=4.0)
    assert not np.isfinite(d2).any()


def test_disparity_lookup_interpolates_and_rejects_edges():
    disp = np.full((10, 10), 4.0, np.float32)
    disp[:, 5:] = 20.0  # a depth edge between columns 4 and 5
    disp[0, 0] = np.nan
    pts = np.array([[2.5, 2.5], [4.5, 3.0], [0.2, 0.2], [7.0, 7.0]], np.float32)
    d = disparity_lookup(disp, pts)
    assert d[0] == 4.0 and d[3] == 20.0
    assert np.isnan(d[1]) and np.isnan(d[2])


def test_grid_coverage():
    assert grid_coverage(np.zeros((0, 2)), 100, 100) == 0.0
    pts = np.array([[1, 1], [99, 99]], float)
    assert grid_coverage(pts, 100, 100, (4, 4)) == 2 / 16


def test_refine_to_anchor_removes_accumulated_track_error():
    img = _texture()
    moved = _shift(img, 2.6, 1.2)
    pts = detect_corners(img, np.zeros((0, 2), np.float32), 60, grid=(4, 3), min_distance_px=5)
    pts = pts[(pts[:, 0] > 15) & (pts[:, 0] < 140) & (pts[:, 1] > 15) & (pts[:, 1] < 100)]
    truth = pts + np.array([2.6, 1.2], np.float32)
    rng = np.random.default_rng(1)
    drifted = truth + rng.uniform(-0.6, 0.6, truth.shape).astype(np.float32)  # a chained track's error
    out, refined = refine_to_anchor(img, moved, pts, drifted, 15, max_move_px=1.5)
    assert refined.mean() > 0.9
    assert np.median(np.linalg.norm(out[refined] - truth[refined], axis=1)) < 0.05
    # a refinement that would jump too far is refused: the guess is kept
    far = truth + np.array([6.0, 0.0], np.float32)
    out2, refined2 = refine_to_anchor(img, moved, pts, far, 15, max_move_px=1.5)
    assert not refined2.any()
    assert np.array_equal(out2, far)
