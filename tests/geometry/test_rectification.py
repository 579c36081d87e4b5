"""Rectification: rows of rectified matches agree, disparities triangulate back exactly."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Intrinsics, rotvec_to_matrix
from skyrecon.errors import EstimationError
from skyrecon.geometry.epipolar import essential_from_pose, fundamental_from_essential
from skyrecon.geometry.rectification import (
    epipole_in_image,
    rectify_calibrated,
    rectify_opencv,
    rectify_uncalibrated,
    triangulate_disparity,
    warp_images,
)
from tests.geometry.synthetic import make_pair


def _row_and_disparity(rect, p):
    ql, qr = rect.to_rectified(p.intr1.normalized(p.x1), p.intr2.normalized(p.x2))
    return ql[:, 1] - qr[:, 1], ql[:, 0] - qr[:, 0], ql


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_calibrated_rectification_is_exact(side):
    p = make_pair(seed=2, n=200)
    if side < 0:  # camera 2 to the left of camera 1: swap roles
        R, t = p.R.T, -p.R.T @ p.t
        p.x1, p.x2 = p.x2, p.x1
        p.R, p.t = R, t
        p.X = p.X @ R.T + t * 0  # not used below
    rect = rectify_calibrated(
        p.intr1, p.intr2, p.R, p.t, 1.0, p.intr1.normalized(p.x1), p.intr2.normalized(p.x2)
    )
    assert rect.swapped == (side < 0)
    dy, d, ql = _row_and_disparity(rect, p)
    assert np.abs(dy).max() < 1e-8
    assert (
        np.all(d > 0)
        and rect.min_disparity <= d.min()
        and d.max() < rect.min_disparity + rect.num_disparities
    )
    # the disparities of the matches triangulate back onto the rays of the matches
    disp = np.full(rect.size[::-1], np.nan)
    xi = np.round(ql).astype(int)
    inside = (xi[:, 0] >= 0) & (xi[:, 0] < rect.size[0]) & (xi[:, 1] >= 0) & (xi[:, 1] < rect.size[1])
    k = np.nonzero(inside)[0][:20]
    # put each match at an integer pixel by moving along its own row: use the exact pixel instead
    for i in k:
        disp[xi[i, 1], xi[i, 0]] = d[i]
    X, pix = triangulate_disparity(disp, rect, p.R, p.t)
    assert len(X) == len(set(map(tuple, xi[k])))
    # every triangulated point projects onto its rectified left pixel
    nl = rect.from_rectified(pix.astype(float), "left")
    cam = X if not rect.swapped else X @ p.R.T + p.t
    np.testing.assert_allclose(cam[:, :2] / cam[:, 2:], nl, atol=1e-9)


def test_opencv_rectification_rows_agree():
    p = make_pair(seed=3, n=100)
    rect = rectify_opencv(p.intr1, p.intr2, p.R, p.t, 1.0, p.intr1.normalized(p.x1), p.intr2.normalized(p.x2))
    dy, d, _ = _row_and_disparity(rect, p)
    assert np.abs(dy).max() < 1e-6
    assert np.median(d) > 0


def test_uncalibrated_rectification_rows_agree():
    p = make_pair(seed=4, n=200)
    F = fundamental_from_essential(essential_from_pose(p.R, p.t), p.intr1.K, p.intr2.K)
    rect = rectify_uncalibrated(p.intr1, p.intr2, F, p.x1, p.x2)
    dy, d, _ = _row_and_disparity(rect, p)
    assert np.abs(dy).max() < 1e-4
    assert np.percentile(d, 5) > 0


def test_forward_motion_detected_and_zero_baseline_rejected():
    intr = Intrinsics.from_fov(640, 480, 60)
    assert epipole_in_image(np.eye(3), np.array([0.0, 0.0, -1.0]), intr, intr)
    assert not epipole_in_image(np.eye(3), np.array([-1.0, 0.0, 0.0]), intr, intr)
    with pytest.raises(EstimationError):
        rectify_calibrated(intr, intr, np.eye(3), np.zeros(3))


def test_warp_images_shapes_and_distortion():
    intr = Intrinsics(500, 500, 319.5, 239.5, 640, 480, np.array([-0.1, 0.01, 0, 0, 0]))
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)
    R = rotvec_to_matrix([0.0, 0.05, 0.0])
    rect = rectify_calibrated(intr, intr, R, np.array([-1.0, 0.0, 0.1]), 0.5)
    left, right = warp_images(img, img, intr, intr, rect)
    assert left.shape == (240, 320, 3) and right.dtype == np.uint8
