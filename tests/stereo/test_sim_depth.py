"""The synthetic city: disparity accuracy against exact ground truth, depth and points."""

import numpy as np
import pytest

from skyrecon.eval.stereo_metrics import evaluate_disparity
from skyrecon.stereo import create_matcher, depth_error_bound, disparity_to_depth, disparity_to_points


@pytest.fixture(scope="module")
def sim_results(sim_frame):
    gt = sim_frame.disparity_left_px
    dmax = int(np.ceil(np.nanmax(gt) / 16) * 16)
    out = {}
    for method in ("skyrecon", "skyrecon-fast", "opencv-sgbm"):
        out[method] = create_matcher(method, dmax).compute(sim_frame.left, sim_frame.right)
    return out


def test_sim_bad1_at_most_half_of_opencv(sim_frame, sim_results):
    gt = sim_frame.disparity_left_px
    m = {k: evaluate_disparity(r.disparity, gt) for k, r in sim_results.items()}
    # measured on this frame: skyrecon 0.5 %, fast 2.3 %, OpenCV SGBM 3.2 %
    assert m["skyrecon"]["bad1"] < 0.015
    assert m["skyrecon"]["bad1"] <= 0.5 * m["opencv-sgbm"]["bad1"]
    assert m["skyrecon-fast"]["bad1"] <= m["opencv-sgbm"]["bad1"]
    assert m["skyrecon"]["epe"] < 0.25


def test_depth_error_within_first_order_bound(sim_frame, sim_results):
    rig = sim_frame.rig
    disp = sim_results["skyrecon"].disparity
    gt_depth = sim_frame.depth_left_m
    depth = disparity_to_depth(disp, rig)
    ok = np.isfinite(depth) & np.isfinite(gt_depth) & (sim_frame.disparity_left_px > 0.5)
    err_d = np.abs(disp - sim_frame.disparity_left_px)
    # |Z - Z_gt| <= f B / d^2 * |d - d_gt| to first order; second order adds a few percent
    bound = depth_error_bound(disp, rig, err_d)
    small = ok & (err_d < 0.25 * np.abs(disp))
    z_err = np.abs(depth - gt_depth)[small]
    assert np.mean(z_err <= bound[small] * 1.35 + 1e-4) > 0.99
    # and the 1-pixel bound holds wherever the disparity is within 1 px
    within = ok & (err_d <= 1.0) & (disp > 2.0)
    assert np.mean(np.abs(depth - gt_depth)[within] <= depth_error_bound(disp, rig, 1.0)[within] * 2.0) > 0.99


def test_points_in_left_frame_match_ground_truth(sim_frame, sim_results):
    rig = sim_frame.rig
    res = sim_results["skyrecon"]
    cloud = disparity_to_points(
        res.disparity, rig, sim_frame.left, min_depth_m=1.0, max_depth_m=40.0, mask=res.measured
    )
    assert len(cloud) > 1000 and cloud.colors is not None and cloud.colors.shape == (len(cloud), 3)
    z = cloud.points[:, 2]
    assert z.min() >= 1.0 and z.max() <= 40.0
    # project back to pixels (exactly the pixel centres) and compare with the true depth there;
    # the relative depth error is the relative disparity error (0.12 m baseline: d = 3.8 px at 10 m)
    uv = rig.left.project(cloud.points.astype(np.float64))
    u = np.rint(uv[:, 0]).astype(int)
    v = np.rint(uv[:, 1]).astype(int)
    assert np.abs(uv - np.stack([u, v], 1)).max() < 1e-3
    gt = sim_frame.depth_left_m[v, u]
    good = np.isfinite(gt)
    rel = np.abs(z[good] - gt[good]) / gt[good]
    assert np.median(rel) < 0.08
    near = gt[good] < 10.0
    assert near.sum() > 100 and np.median(rel[near]) < 0.04
