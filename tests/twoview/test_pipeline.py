"""The two-view pipeline end to end: synthetic pairs with exact ground truth, degenerate pairs,
bad input, and one real fountain pair."""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from skyrecon.core import Intrinsics
from skyrecon.errors import EstimationError, InputError
from skyrecon.eval.gt_geometry import relative_pose
from skyrecon.eval.pose_metrics import rotation_error_deg, translation_direction_error_deg
from skyrecon.geometry.epipolar import sampson_distance
from skyrecon.io.images import read_image
from skyrecon.io.multiview import read_strecha_cameras
from skyrecon.twoview import (
    TwoViewGeometry,
    TwoViewSettings,
    compute_disparity,
    dense_model,
    draw_epipolar_lines,
    draw_matches,
    draw_rectified_pair,
    estimate_two_view_geometry,
    reconstruct_two_view,
    sparse_cloud,
)
from tests.conftest import require
from tests.twoview.conftest import small_settings


@pytest.fixture(scope="module")
def result(monument):
    return reconstruct_two_view(
        monument.images[0], monument.images[1], monument.intr, monument.intr, small_settings(), seed=0
    )


def test_synthetic_pose(result, monument):
    gt = monument.gt(0, 1)
    assert result.status == "ok" and result.warnings == []
    assert rotation_error_deg(result.R, gt.R) < 0.2
    assert translation_direction_error_deg(result.t, gt.t) < 0.5
    assert np.linalg.norm(result.t) == pytest.approx(1.0)
    assert result.num_inliers > 0.8 * result.num_matches > 100
    # F and E agree with the pose
    x1, x2 = result.x1[result.inliers], result.x2[result.inliers]
    assert np.median(sampson_distance(result.F, x1, x2)) < 0.5  # pixels
    F_from_E = np.linalg.inv(monument.intr.K).T @ result.E @ np.linalg.inv(monument.intr.K)
    F_from_E /= np.linalg.norm(F_from_E)
    assert min(np.abs(F_from_E - result.F).max(), np.abs(F_from_E + result.F).max()) < 1e-9


def _depth_error(cloud_points, monument, scale):
    """Relative depth error of camera-1-frame points against the rendered depth of view 0."""
    P = np.asarray(cloud_points, np.float64) * scale
    uv = monument.intr.project(P)
    ok = monument.intr.in_image(uv)
    ij = np.round(uv[ok]).astype(int)
    ij[:, 0] = np.clip(ij[:, 0], 0, monument.intr.width - 1)
    ij[:, 1] = np.clip(ij[:, 1], 0, monument.intr.height - 1)
    gt = monument.depths[0][ij[:, 1], ij[:, 0]]
    rel = np.abs(P[ok, 2] - gt) / gt
    return rel[np.isfinite(rel)]


def test_sparse_and_dense_clouds_match_the_rendered_depth(result, monument):
    scale = np.linalg.norm(monument.gt(0, 1).t)  # unit baseline -> metres
    rel = _depth_error(result.sparse.points, monument, scale)
    assert len(rel) > 100 and np.median(rel) < 0.005
    d = result.dense
    assert d is not None and d.disparity is not None and d.left.shape[:2] == d.disparity.shape
    assert len(d.cloud) > 20000 and d.cloud.colors is not None
    rel = _depth_error(d.cloud.points, monument, scale)
    assert np.median(rel) < 0.02 and np.mean(rel < 0.05) > 0.8


def test_metric_baseline_scales_the_clouds(result, monument):
    b = float(np.linalg.norm(monument.gt(0, 1).t))
    s = small_settings(baseline_m=b)
    cloud, idx = sparse_cloud(
        monument.images[0], result.geometry, result.x1, result.x2, monument.intr, monument.intr, s, 1.0
    )
    assert len(cloud) == len(idx) > 100
    rel = _depth_error(cloud.points, monument, 1.0)
    assert np.median(rel) < 0.005
    d = dense_model(
        monument.images[0],
        monument.images[1],
        monument.intr,
        monument.intr,
        result.geometry,
        result.x1[result.inliers],
        result.x2[result.inliers],
        small_settings(baseline_m=b, dense_max_image_size=320),
    )
    assert np.median(_depth_error(d.cloud.points, monument, 1.0)) < 0.03


def _dense(result, monument, **kw):
    return dense_model(
        monument.images[0],
        monument.images[1],
        monument.intr,
        monument.intr,
        result.geometry,
        result.x1[result.inliers],
        result.x2[result.inliers],
        small_settings(**kw),
    )


def test_epipolar_dense_method(result, monument):
    d = _dense(result, monument, dense_method="epipolar", epipolar_step=8)
    assert d.method == "epipolar" and len(d.cloud) > 500
    rel = _depth_error(d.cloud.points, monument, np.linalg.norm(monument.gt(0, 1).t))
    assert np.median(rel) < 0.02


@pytest.mark.parametrize("rect", ["opencv", "uncalibrated"])
def test_other_rectifications(result, monument, rect):
    d = _dense(result, monument, rectification=rect, dense_max_image_size=320)
    assert len(d.cloud) > 5000
    rel = _depth_error(d.cloud.points, monument, np.linalg.norm(monument.gt(0, 1).t))
    assert np.median(rel) < 0.03


def test_fundamental_route(result, monument):
    gt = monument.gt(0, 1)
    for method in ("ransac", "magsac", "lmeds"):
        g = estimate_two_view_geometry(
            result.x1,
            result.x2,
            monument.intr,
            monument.intr,
            small_settings(pose_method="fundamental", fundamental_method=method),
            0,
        )
        assert g.status == "ok"
        assert rotation_error_deg(g.R, gt.R) < 0.3 and translation_direction_error_deg(g.t, gt.t) < 1.0


def test_deterministic(result, monument):
    again = reconstruct_two_view(
        monument.images[0],
        monument.images[1],
        monument.intr,
        monument.intr,
        small_settings(dense=False),
        seed=0,
    )
    assert np.array_equal(again.R, result.R) and np.array_equal(again.t, result.t)
    assert np.array_equal(again.inliers, result.inliers)


# ----- degenerate pairs: warnings, not made-up poses ------------------------------------------
def test_identical_images(monument):
    r = reconstruct_two_view(
        monument.images[0], monument.images[0], monument.intr, monument.intr, small_settings(), seed=0
    )
    assert r.status == "no_translation" and r.t is None and r.dense is None
    assert "identical" in r.warnings[0]
    assert rotation_error_deg(r.R, np.eye(3)) < 0.01


def test_pure_rotation(monument):
    r = reconstruct_two_view(
        monument.images[0], monument.images[2], monument.intr, monument.intr, small_settings(), seed=0
    )
    assert r.status == "no_translation" and r.t is None and r.E is None
    assert "rotation" in r.warnings[0]
    assert rotation_error_deg(r.R, monument.gt(0, 2).R) < 0.05


def test_unrelated_images(monument, other_scene_image):
    try:
        r = reconstruct_two_view(
            monument.images[0], other_scene_image, monument.intr, monument.intr, small_settings(), seed=0
        )
    except EstimationError as exc:  # so few matches that not even 8 survive: also a clear answer
        assert "matches" in str(exc)
        return
    assert r.status == "failed" and r.R is None and r.t is None
    assert "too few inliers" in r.warnings[0]


def test_wrong_intrinsics_are_flagged(monument):
    i = monument.intr
    wrong = Intrinsics(i.fx * 1.5, i.fy * 1.5, i.cx + 80, i.cy - 60, i.width, i.height)
    r = reconstruct_two_view(
        monument.images[0], monument.images[1], wrong, wrong, small_settings(dense=False), seed=0
    )
    assert r.status == "uncertain"
    assert any("K seem wrong" in w for w in r.warnings)


def test_planar_scene(monument):
    r = reconstruct_two_view(
        monument.images[3],
        monument.images[4],
        monument.intr,
        monument.intr,
        small_settings(dense=False),
        seed=0,
    )
    gt = monument.gt(3, 4)
    assert any("planar" in w for w in r.warnings)
    assert r.R is not None and rotation_error_deg(r.R, gt.R) < 0.5
    assert translation_direction_error_deg(r.t, gt.t) < 2.0


# ----- bad input ---------------------------------------------------------------------------------
def test_bad_input(monument):
    img = monument.images[0]
    i = monument.intr
    with pytest.raises(InputError, match="calibration"):
        reconstruct_two_view(img[:200], img, i, i)
    with pytest.raises(InputError):
        reconstruct_two_view(np.zeros((480, 640, 2)), img, i, i)
    with pytest.raises(InputError):
        reconstruct_two_view(img, img, i, "K")  # type: ignore[arg-type]
    blank = np.full_like(img, 128)
    with pytest.raises(EstimationError, match="matches"):
        reconstruct_two_view(blank, blank, i, i, small_settings())
    with pytest.raises(InputError):
        small_settings(threshold_px=0)
    with pytest.raises(InputError):
        small_settings(rectification="magic")


def test_pictures_and_json(result, monument):
    a, b = monument.images[0], monument.images[1]
    m = draw_matches(a, b, result.x1, result.x2, result.inliers)
    e = draw_epipolar_lines(a, b, result.F, result.x1[result.inliers], result.x2[result.inliers])
    r = draw_rectified_pair(result.dense.left, result.dense.right)
    for pic in (m, e, r):
        assert pic.dtype == np.uint8 and pic.ndim == 3 and pic.shape[2] == 3
    assert m.shape[1] == 1280
    d = json.loads(json.dumps(result.to_json_dict()))
    assert np.allclose(np.array(d["R"]), result.R) and abs(np.linalg.norm(d["t"]) - 1) < 1e-12
    assert d["num_matches"] == result.num_matches and d["status"] == "ok"


# ----- real data -----------------------------------------------------------------------------
@pytest.mark.realdata
def test_fountain_pair(real_data):
    root = require(real_data, "strecha-fountain-P11")
    views = {v.name: v for v in read_strecha_cameras(root / "gt_dense_cameras")}
    v1, v2 = views["0004.jpg"], views["0005.jpg"]
    s = TwoViewSettings()
    s = replace(s, features=replace(s.features, max_image_size=1024), dense_max_image_size=384)
    r = reconstruct_two_view(
        read_image(v1.image_path), read_image(v2.image_path), v1.intrinsics, v2.intrinsics, s, seed=0
    )
    gt = relative_pose(v1, v2)
    assert r.status == "ok"
    assert rotation_error_deg(r.R, gt.R) < 0.2
    assert translation_direction_error_deg(r.t, gt.t) < 1.0
    assert r.dense is not None and len(r.dense.cloud) > 20000


def test_dense_refuses_forward_motion_and_unknown_matchers(result, monument):
    fwd = TwoViewGeometry(
        "ok",
        np.eye(3),
        np.array([0.0, 0.0, -1.0]),
        np.zeros((3, 3)),
        np.zeros((3, 3)),
        result.inliers,
        result.geometry.errors_px,
    )
    args = (
        monument.images[0],
        monument.images[1],
        monument.intr,
        monument.intr,
        fwd,
        result.x1[result.inliers],
        result.x2[result.inliers],
    )
    with pytest.raises(EstimationError, match="viewing direction"):
        dense_model(*args, small_settings(dense_fallback=False))
    # with the fallback, the epipolar search runs instead (on this wrong geometry it finds little)
    try:
        d = dense_model(*args, small_settings(epipolar_step=16))
        assert d.method == "epipolar" and "instead of stereo" in d.warnings[0]
    except EstimationError as exc:
        assert "epipolar search failed" in str(exc)
    with pytest.raises(InputError, match="stereo matcher"):
        compute_disparity(monument.images[0], monument.images[1], 0, 64, "no-such-matcher")
    with pytest.raises(InputError):
        dense_model(
            monument.images[0],
            monument.images[1],
            monument.intr,
            monument.intr,
            TwoViewGeometry("failed", None, None, None, None, result.inliers, result.geometry.errors_px),
            result.x1,
            result.x2,
            small_settings(),
        )


def test_grey_images_of_different_sizes(monument):
    """A grey 640x480 image against a colour one downscaled to 480x360 (different cameras)."""
    a = cv2.cvtColor(monument.images[0], cv2.COLOR_RGB2GRAY)
    b = cv2.resize(monument.images[1], (480, 360), interpolation=cv2.INTER_AREA)
    i2 = monument.intr.scaled(0.75)
    assert isinstance(i2, Intrinsics) and (i2.width, i2.height) == (480, 360)
    r = reconstruct_two_view(a, b, monument.intr, i2, small_settings(dense_max_image_size=320), seed=0)
    gt = monument.gt(0, 1)
    assert r.status == "ok"
    assert rotation_error_deg(r.R, gt.R) < 0.3 and translation_direction_error_deg(r.t, gt.t) < 1.0
    assert r.sparse.colors is not None and r.dense is not None


def test_forward_flight_falls_back_to_epipolar_search(flight):
    r = reconstruct_two_view(
        flight.images[0], flight.images[1], flight.intr, flight.intr, small_settings(epipolar_step=6), seed=0
    )
    gt = flight.gt(0, 1)
    assert r.status == "ok"
    assert rotation_error_deg(r.R, gt.R) < 0.1 and translation_direction_error_deg(r.t, gt.t) < 1.0
    assert r.dense is not None and r.dense.method == "epipolar" and len(r.dense.cloud) > 300
    assert any("instead of stereo" in w for w in r.warnings)
    rel = _depth_error(r.dense.cloud.points, flight, np.linalg.norm(gt.t))
    assert np.median(rel) < 0.05
