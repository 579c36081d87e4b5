"""Reference two-view geometry from known cameras (synthetic)."""

from __future__ import annotations

import numpy as np

from skyrecon.core import Intrinsics, PosedView, Rigid3
from skyrecon.eval.gt_geometry import (
    epipolar_distances,
    essential_from_views,
    fundamental_from_views,
    relative_pose,
    skew_matrix,
    symmetric_epipolar_distance,
)


def two_views() -> tuple[PosedView, PosedView, np.ndarray]:
    rng = np.random.default_rng(3)
    k1 = Intrinsics(700.0, 710.0, 319.5, 239.5, 640, 480)
    k2 = Intrinsics(900.0, 905.0, 400.0, 300.0, 800, 600)
    v1 = PosedView("a", k1, Rigid3.look_at([0, -4, 1], [0, 0, 0]))
    v2 = PosedView("b", k2, Rigid3.look_at([1.5, -3.5, 1.3], [0.1, 0, 0]))
    pts = rng.uniform(-1, 1, (50, 3))
    return v1, v2, pts


def test_fundamental_vanishes_on_true_correspondences() -> None:
    v1, v2, pts = two_views()
    x1, _ = v1.project(pts)
    x2, _ = v2.project(pts)
    F = fundamental_from_views(v1, v2)
    assert abs(np.linalg.norm(F) - 1) < 1e-12 and abs(np.linalg.det(F)) < 1e-12
    h1 = np.c_[x1, np.ones(len(x1))]
    h2 = np.c_[x2, np.ones(len(x2))]
    assert np.abs(np.sum(h2 * (h1 @ F.T), axis=1)).max() < 1e-9
    assert symmetric_epipolar_distance(F, x1, x2).max() < 1e-6
    # Swapping the views transposes F.
    np.testing.assert_allclose(fundamental_from_views(v2, v1), F.T, atol=1e-12)


def test_epipolar_distance_is_in_pixels() -> None:
    v1, v2, pts = two_views()
    x1, _ = v1.project(pts[:1])
    x2, _ = v2.project(pts[:1])
    F = fundamental_from_views(v1, v2)
    line = F @ np.append(x1[0], 1.0)
    normal = line[:2] / np.linalg.norm(line[:2])
    d1, d2 = epipolar_distances(F, x1, x2 + 2.5 * normal)  # move 2.5 px off the line in image 2
    assert abs(d2[0] - 2.5) < 1e-6 and d1[0] > 0


def test_relative_pose_and_essential() -> None:
    v1, v2, pts = two_views()
    rel = relative_pose(v1, v2)
    np.testing.assert_allclose(
        rel.apply(v1.cam_from_world.apply(pts)), v2.cam_from_world.apply(pts), atol=1e-12
    )
    E = essential_from_views(v1, v2)
    np.testing.assert_allclose(np.linalg.svd(E, compute_uv=False), [1, 1, 0], atol=1e-12)
    np.testing.assert_allclose(skew_matrix([1, 2, 3]) @ [4, 5, 6], np.cross([1, 2, 3], [4, 5, 6]))
