"""The geometry stage of the pipeline on synthetic correspondences (no images: fast)."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Intrinsics, rotvec_to_matrix
from skyrecon.errors import EstimationError
from skyrecon.eval.pose_metrics import rotation_error_deg, translation_direction_error_deg
from skyrecon.twoview import TwoViewSettings, estimate_two_view_geometry, fit_rotation
from tests.geometry.synthetic import make_pair


def test_general_scene_is_ok():
    p = make_pair(seed=1, n=400, noise_px=0.5, outlier_ratio=0.2)
    g = estimate_two_view_geometry(p.x1, p.x2, p.intr1, p.intr2, TwoViewSettings(), 0)
    assert g.status == "ok" and g.warnings == []
    assert rotation_error_deg(g.R, p.R) < 0.1 and translation_direction_error_deg(g.t, p.t) < 0.5


def test_fewer_than_eight_matches_raise():
    p = make_pair(seed=1, n=7)
    with pytest.raises(EstimationError, match="only 7"):
        estimate_two_view_geometry(p.x1, p.x2, p.intr1, p.intr2)


def test_pure_rotation_has_no_translation():
    p = make_pair(seed=2, n=300, noise_px=0.3, outlier_ratio=0.2, baseline=1e-6)
    g = estimate_two_view_geometry(p.x1, p.x2, p.intr1, p.intr2, TwoViewSettings(), 0)
    assert g.status == "no_translation" and g.t is None and g.F is None
    assert rotation_error_deg(g.R, p.R) < 0.05
    assert "rotation" in g.warnings[0]


def test_random_matches_fail():
    rng = np.random.default_rng(0)
    intr = Intrinsics.from_fov(1000, 800, 60)
    x1 = rng.uniform([0, 0], [999, 799], (200, 2))
    x2 = rng.uniform([0, 0], [999, 799], (200, 2))
    g = estimate_two_view_geometry(x1, x2, intr, intr, TwoViewSettings(), 0)
    assert g.status == "failed" and g.R is None and g.t is None
    assert "too few inliers" in g.warnings[0]


def test_wrong_focal_length_is_flagged():
    p = make_pair(seed=3, n=400, noise_px=0.3, depth=(3, 30), rotation_deg=20)
    wrong = Intrinsics(
        p.intr1.fx * 0.6, p.intr1.fy * 0.6, p.intr1.cx, p.intr1.cy, p.intr1.width, p.intr1.height
    )
    g = estimate_two_view_geometry(p.x1, p.x2, wrong, wrong, TwoViewSettings(), 0)
    assert g.status == "uncertain" and any("K seem wrong" in w for w in g.warnings)
    good = estimate_two_view_geometry(p.x1, p.x2, p.intr1, p.intr2, TwoViewSettings(), 0)
    assert good.status == "ok"


def test_planar_scene_is_warned_and_correct():
    p = make_pair(seed=4, n=300, noise_px=0.5, outlier_ratio=0.1, planar=True)
    g = estimate_two_view_geometry(p.x1, p.x2, p.intr1, p.intr2, TwoViewSettings(), 0)
    assert any("planar" in w for w in g.warnings)
    assert rotation_error_deg(g.R, p.R) < 0.3


def test_small_baseline_is_warned():
    p = make_pair(seed=5, n=500, noise_px=0.2, baseline=0.08, depth=(8, 12), rotation_deg=3)
    g = estimate_two_view_geometry(p.x1, p.x2, p.intr1, p.intr2, TwoViewSettings(), 0)
    assert g.status in ("ok", "no_translation")
    if g.status == "ok":
        assert any("small baseline" in w for w in g.warnings)
        assert g.diagnostics["median_parallax_deg"] < 1.0


def test_fit_rotation_with_outliers():
    rng = np.random.default_rng(0)
    R = rotvec_to_matrix([0.1, -0.3, 0.05])
    X = rng.normal(size=(300, 3))
    X[:, 2] = np.abs(X[:, 2]) + 3
    x1 = X[:, :2] / X[:, 2:]
    Y = X @ R.T
    x2 = Y[:, :2] / Y[:, 2:]
    x2[:150] += rng.normal(scale=0.3, size=(150, 2))
    Rf, res = fit_rotation(x1, x2, 1e-3)
    assert rotation_error_deg(Rf, R) < 1e-3 and np.count_nonzero(res < 1e-3) == 150
