"""Map points measured again at a later keyframe take the more precise (nearer) measurement."""

from __future__ import annotations

import dataclasses

import numpy as np

from skyrecon.core import Rigid3
from skyrecon.odometry.engine import OdometrySettings, StereoOdometry
from skyrecon.sim import default_rig


def _engine(refresh: bool) -> StereoOdometry:
    rig = default_rig(640, 480, 90.0, 0.3)
    settings = dataclasses.replace(OdometrySettings(), refresh_points=refresh)
    return StereoOdometry(rig, settings, Rigid3.identity())


def _disparity(eng: StereoOdometry, depth_m: float) -> float:
    return float(eng._fb / depth_m - eng._doffs)


def test_a_point_seen_far_then_near_moves_to_the_near_measurement():
    true_depth = 40.0
    for refresh, expect_error_below in ((True, 0.05), (False, None)):
        eng = _engine(refresh)
        pts = np.array([[320.0, 240.0]], np.float32)
        ids = np.array([7])
        # first seen 40 m away with a +0.1 px disparity error (depth about 5 % short)
        d_far = _disparity(eng, true_depth) + 0.1
        eng._add_keyframe(0, np.eye(4), pts, ids, np.array([d_far]))
        far_z = eng._points[7][2]
        assert far_z < true_depth - 1.0
        # 30 m later (camera moved forward along z), measured with the same absolute error
        T = np.eye(4)
        T[2, 3] = 30.0
        d_near = _disparity(eng, true_depth - 30.0) + 0.1
        eng._add_keyframe(1, T, pts, ids, np.array([d_near]))
        z = eng._points[7][2]
        if expect_error_below is not None:
            assert abs(z - true_depth) < abs(far_z - true_depth) / 10
        else:
            assert z == far_z  # the old behaviour keeps the first measurement
