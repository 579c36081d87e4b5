"""Smoke tests on the real multi-view sets (skipped when the data is absent)."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.eval.mvs_metrics import evaluate_cloud, fraction_outside_box
from skyrecon.executor import SerialExecutor
from skyrecon.io import read_ply
from skyrecon.mvs import MVSSettings, load_views_and_images, run_mvs
from tests.conftest import real_data, require  # noqa: F401

pytestmark = pytest.mark.realdata

TEMPLE_BOX = ((-0.073568, 0.021728, -0.012445), (0.028855, 0.181892, 0.062736))


def test_temple_at_low_resolution(real_data) -> None:  # noqa: F811
    d = require(real_data, "middlebury-mview-templeSparseRing")
    views, _ = load_views_and_images(d, d / "templeSR_par.txt")
    res = run_mvs(views, None, MVSSettings(max_image_size=320), executor=SerialExecutor(), progress=False)
    assert len(res.cloud) > 10000
    assert fraction_outside_box(res.cloud.points, *TEMPLE_BOX, margin=0.005) < 0.06  # smoke test at half size
    assert len(res.depth_maps) == 16


def test_rock_against_reference_at_low_resolution(real_data) -> None:  # noqa: F811
    d = require(real_data, "robovision-rock/2016_10_25__12_11_32")
    views, _ = load_views_and_images(d, d)
    ref = read_ply(d / "reference.ply").points.astype(np.float64)
    box = (ref.min(0) - 0.002, ref.max(0) + 0.002)
    res = run_mvs(views, None, MVSSettings(max_image_size=256), executor=SerialExecutor(), progress=False)
    m = evaluate_cloud(res.cloud.points, ref, [0.002], crop=box)
    assert m.fscore[0] > 0.6, m
