"""Consistency fusion and concatenation on hand-made depth maps of a plane."""

from __future__ import annotations

import numpy as np

from skyrecon.core import Intrinsics, Rigid3
from skyrecon.mvs import FusionSettings, fuse_concat, fuse_consistent
from skyrecon.mvs.frames import WorkingView
from skyrecon.mvs.fusion import _depth_slack_px

W, H = 80, 60


def plane_views(
    n: int = 4, radius_m: float = 1.0, size: tuple[int, int] = (W, H)
) -> tuple[list[WorkingView], list[np.ndarray]]:
    """``n`` cameras 5 m above the plane z = 0, ``radius_m`` from its origin, looking at it;
    exact (h, w) depth maps of ``size`` (w, h)."""
    W, H = size
    intr = Intrinsics.from_fov(W, H, 50.0)
    views, depths = [], []
    for k in range(n):
        a = 2 * np.pi * k / n
        eye = np.array([radius_m * np.cos(a), radius_m * np.sin(a), 5.0])
        pose = Rigid3.look_at(eye, [0.0, 0.0, 0.0], up_world=(0.0, 1.0, 0.0))
        rays = intr.ray_directions().reshape(-1, 3)  # camera frame, z = 1
        R_wc = pose.inverse().R
        dirs = rays @ R_wc.T
        t = -eye[2] / dirs[:, 2]  # ray-plane intersection (z = 0)
        depth = t.reshape(H, W).astype(np.float32)  # z-component of the camera ray is 1
        rgb = np.full((H, W, 3), 100 + 30 * k, np.uint8)
        views.append(
            WorkingView(f"v{k}.png", intr, pose, rgb, rgb[..., 0].astype(np.float32), np.ones((H, W), bool))
        )
        depths.append(depth)
    return views, depths


def all_neighbors(n: int) -> list[list[int]]:
    return [[j for j in range(n) if j != i] for i in range(n)]


def test_consistent_plane_is_kept_on_the_plane() -> None:
    views, depths = plane_views()
    fused = fuse_consistent(views, depths, all_neighbors(4), FusionSettings(min_consistent=2))
    pts = fused.cloud.points
    assert len(pts) > 0.5 * W * H
    assert np.abs(pts[:, 2]).max() < 1e-4
    # agreeing with 2 others (3 with the reference), or with the only neighbour that sees it
    assert fused.support.min() >= 2 and np.mean(fused.support >= 3) > 0.8 and fused.cloud.colors is not None
    # colours are averaged over the agreeing views (100, 130, 160, 190)
    assert 100 < fused.cloud.colors[:, 0].mean() < 190


def test_inconsistent_pixels_are_dropped() -> None:
    views, depths = plane_views()
    bad = [d.copy() for d in depths]
    bad[0][20:30, 30:50] *= 0.9  # a 10 % depth error: a floating patch in view 0 only
    fused = fuse_consistent(views, bad, all_neighbors(4), FusionSettings(min_consistent=2))
    assert np.abs(fused.cloud.points[:, 2]).max() < 1e-4  # nothing from the floating patch
    from_view0 = fused.view_index == 0
    assert from_view0.any()


def test_small_errors_within_tolerance_are_averaged() -> None:
    views, depths = plane_views()
    rng = np.random.default_rng(0)
    noisy = [d * (1 + rng.normal(0, 0.001, d.shape)).astype(np.float32) for d in depths]
    fused = fuse_consistent(views, noisy, all_neighbors(4), FusionSettings(min_consistent=2))
    raw_err = 5.0 * 0.001  # ~ depth * sigma
    assert len(fused.cloud) > 0.3 * W * H
    assert np.abs(fused.cloud.points[:, 2]).std() < raw_err


def test_min_consistent_counts_other_views() -> None:
    views, depths = plane_views(3)
    assert len(fuse_consistent(views, depths, all_neighbors(3), FusionSettings(min_consistent=2)).cloud) > 0
    strict = FusionSettings(min_consistent=3, adaptive=False)
    assert len(fuse_consistent(views, depths, all_neighbors(3), strict).cloud) == 0
    # adaptive: only 2 neighbours exist, so agreeing with both is enough
    assert len(fuse_consistent(views, depths, all_neighbors(3), FusionSettings(min_consistent=3)).cloud) > 0
    only_one = [depths[0], depths[1], None]
    fused = fuse_consistent(views, only_one, all_neighbors(3), FusionSettings(min_consistent=1))
    assert len(fused.cloud) > 0 and fused.support.max() == 2


def test_marking_used_pixels_avoids_duplicates() -> None:
    views, depths = plane_views()
    nb = all_neighbors(4)
    once = fuse_consistent(views, depths, nb, FusionSettings(min_consistent=2, mark_used=True))
    dup = fuse_consistent(views, depths, nb, FusionSettings(min_consistent=2, mark_used=False))
    assert len(dup.cloud) > 2.5 * len(once.cloud)


def test_concat_keeps_every_valid_pixel() -> None:
    views, depths = plane_views()
    depths[1][:10] = np.nan
    fused = fuse_concat(views, list(enumerate(depths)))
    assert len(fused.cloud) == sum(int(np.isfinite(d).sum()) for d in depths)
    assert np.abs(fused.cloud.points[:, 2]).max() < 1e-4


def test_edge_of_coverage_needs_fewer_views() -> None:
    views, depths = plane_views()
    nb = all_neighbors(4)
    cut = [d.copy() for d in depths]
    cut[2][:] = np.nan  # view 2 sees nothing: pixels seen by views 0, 1, 3 only
    cut[3][:] = np.nan
    strict = fuse_consistent(views, cut, nb, FusionSettings(min_consistent=2, adaptive=False))
    adaptive = fuse_consistent(views, cut, nb, FusionSettings(min_consistent=2))
    assert len(strict.cloud) == 0  # only one other depth map agrees
    # views 2 and 3 still *see* the plane (empty depth there): two agreeing views are needed, except
    # at the edge of the coverage where only one neighbour's image contains the point
    assert len(adaptive.cloud) < 0.05 * W * H
    lonely = [depths[0], depths[1], None, None]
    assert len(fuse_consistent(views, lonely, nb, FusionSettings(min_consistent=2)).cloud) > 0


def test_planar_prior_pixels_need_fewer_agreeing_views() -> None:
    # a patch only two views have (a plain wall a planar prior filled in two of four views)
    views, depths = plane_views()
    patch = [d.copy() for d in depths]
    for k in (2, 3):
        patch[k][:] = np.nan
    filled = [np.ones((H, W), bool), np.ones((H, W), bool), None, None]
    strict = FusionSettings(min_consistent=2, adaptive=False)  # the default: the same count for all
    lenient = FusionSettings(min_consistent=2, adaptive=False, min_consistent_prior=1)
    assert len(fuse_consistent(views, patch, all_neighbors(4), strict).cloud) == 0
    assert len(fuse_consistent(views, patch, all_neighbors(4), strict, filled).cloud) == 0
    fused = fuse_consistent(views, patch, all_neighbors(4), lenient, filled)
    assert len(fused.cloud) > 0.3 * W * H and np.abs(fused.cloud.points[:, 2]).max() < 1e-4
    # only for the pixels the prior filled
    unfilled = [np.zeros((H, W), bool), np.zeros((H, W), bool), None, None]
    assert len(fuse_consistent(views, patch, all_neighbors(4), lenient, unfilled).cloud) == 0


def test_planes_of_two_views_a_little_apart_agree_within_the_depth_tolerance() -> None:
    """Two views fill the same plain surface with planes a fraction of a degree apart: their
    depths agree within the depth tolerance, but the points come back more than a pixel away.
    Plane against plane, the reprojection check allows what the depth tolerance lets through
    (max_reproj_px_prior); measured pixels keep the 1 px check."""
    w, h = 320, 240
    views, depths = plane_views(4, radius_m=4.0, size=(w, h))  # 40 degrees apart, like a ring
    tilted = [d.copy() for d in depths]
    rows = np.arange(h, dtype=np.float32)[:, None]
    for k in (1, 3):  # a slight tilt in two of the views: up to 0.6 % of the depth
        tilted[k] = tilted[k] * (1.0 + 0.006 * (rows - h / 2) / (h / 2))
    planes = [np.ones((h, w), bool)] * 4
    nb = all_neighbors(4)
    strict = FusionSettings(min_consistent=2, adaptive=False, max_reproj_px_prior=None)
    sliding = FusionSettings(min_consistent=2, adaptive=False)
    n_strict = len(fuse_consistent(views, tilted, nb, strict, planes).cloud)
    n_sliding = len(fuse_consistent(views, tilted, nb, sliding, planes).cloud)
    assert n_sliding > n_strict + 0.1 * w * h
    # without the prior's masks (measured pixels), or a plane against a measured pixel: 1 px
    assert len(fuse_consistent(views, tilted, nb, sliding).cloud) == n_strict
    half = [planes[0], planes[1], None, None]
    assert len(fuse_consistent(views, tilted, nb, sliding, half).cloud) < n_sliding
    # the slack is what a depth change of max_rel_depth_diff moves a point by, within the bounds
    slack = _depth_slack_px(views[0], views[2], np.array([[0.0, 0.0, 6.0], [0.5, 0.3, 6.2]]), sliding)
    assert np.all(slack > sliding.max_reproj_px) and np.all(slack <= sliding.max_reproj_px_prior)
