"""The cleanup step on hand-made fused clouds: outliers, oriented normals, voxel averaging."""

from __future__ import annotations

import numpy as np

from skyrecon.core import PointCloud
from skyrecon.mvs.cleanup import clean_fused_cloud
from skyrecon.mvs.fusion import FusedCloud
from skyrecon.mvs.settings import MVSSettings
from tests.mvs.test_fusion import plane_views


def grid_on_plane(n: int = 20, spacing: float = 0.05) -> np.ndarray:
    """(n*n, 3) float32 points on z = 0, world metres."""
    xs = (np.arange(n) - n / 2) * spacing
    x, y = np.meshgrid(xs, xs)
    return np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1).astype(np.float32)


def fused_of(points: np.ndarray) -> FusedCloud:
    n = len(points)
    colors = np.full((n, 3), 120, np.uint8)
    return FusedCloud(PointCloud(points, colors), np.zeros(n, np.int32), np.full(n, 3, np.int32))


def test_far_outlier_is_removed_and_normals_face_the_camera() -> None:
    views, _ = plane_views(1)  # one camera 5 m above the plane z = 0
    pts = np.concatenate([grid_on_plane(), [[0.0, 0.0, 3.0]]]).astype(np.float32)
    clean = clean_fused_cloud(fused_of(pts), views, MVSSettings(component_min_fraction=0.0))
    assert len(clean.cloud) == len(pts) - 1 and np.abs(clean.cloud.points[:, 2]).max() == 0
    assert clean.counts == {"points_fused": len(pts), "points_after_outlier_removal": len(pts) - 1}
    normals = clean.cloud.normals
    assert normals is not None
    np.testing.assert_allclose(normals[:, 2], 1.0, atol=1e-4)  # up, towards the camera
    assert len(clean.support) == len(clean.cloud)


def test_voxel_averaging_merges_points_and_keeps_the_best_support() -> None:
    views, _ = plane_views(1)
    pts = grid_on_plane(10, 0.05) + np.float32([0.275, 0.275, 0.0])  # 0.025, 0.075, ...: 2 x 2 per voxel
    fused = fused_of(pts)
    fused.support[0] = 7
    settings = MVSSettings(outlier_std=0.0, component_min_fraction=0.0, voxel_size_m=0.1)
    clean = clean_fused_cloud(fused, views, settings)
    assert clean.counts["points_after_voxel"] == len(clean.cloud) == 25
    assert clean.support.dtype == np.int32 and clean.support.max() == 7 and clean.support.min() == 3
    np.testing.assert_allclose(np.linalg.norm(clean.cloud.normals, axis=1), 1.0, atol=1e-5)
    assert clean.cloud.colors is not None and np.all(clean.cloud.colors == 120)


def test_empty_cloud_passes_through() -> None:
    views, _ = plane_views(1)
    clean = clean_fused_cloud(fused_of(np.zeros((0, 3), np.float32)), views, MVSSettings())
    assert len(clean.cloud) == 0 and clean.cloud.normals is not None and clean.cloud.normals.shape == (0, 3)
    assert clean.counts == {"points_fused": 0}


def test_small_components_are_dropped_and_the_links_are_those_of_the_k_nearest() -> None:
    from scipy.spatial.distance import cdist

    from skyrecon.mvs import cloud_ops

    rng = np.random.default_rng(5)
    main = rng.uniform(0, 10, (3000, 3)) * [1.0, 1.0, 0.02]
    blob = rng.uniform(0, 0.3, (20, 3)) + [30.0, 0.0, 0.0]  # a floater: 20 of 3020 points
    pts = np.concatenate([main, blob]).astype(np.float32)
    keep = cloud_ops.small_component_mask(pts, radius_m=1.0, min_fraction=0.01, k=8)
    assert keep[:3000].all() and not keep[3000:].any()
    # the same labels as a brute-force graph (every point linked to its 8 nearest within the radius)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    d = cdist(pts, pts)
    np.fill_diagonal(d, np.inf)
    nn = np.argsort(d, axis=1)[:, :8]
    rows = np.repeat(np.arange(len(pts)), 8)
    ok = d[rows, nn.ravel()] <= 1.0
    g = coo_matrix((np.ones(int(ok.sum())), (rows[ok], nn.ravel()[ok])), shape=(len(pts),) * 2)
    _, labels = connected_components(g, directed=False)
    sizes = np.bincount(labels)
    np.testing.assert_array_equal(keep, sizes[labels] >= int(np.ceil(0.01 * len(pts))))
    # and chunked (smaller chunks than points) gives the same
    old = cloud_ops._CHUNK
    try:
        cloud_ops._CHUNK = 700
        np.testing.assert_array_equal(cloud_ops.small_component_mask(pts, 1.0, 0.01, 8), keep)
    finally:
        cloud_ops._CHUNK = old


def test_orient_normals_faces_the_viewpoints_in_chunks() -> None:
    from skyrecon.mvs import cloud_ops

    rng = np.random.default_rng(5)
    n = 2 * cloud_ops._CHUNK + 17  # several chunks and a remainder
    points = rng.normal(size=(n, 3))
    normals = rng.normal(size=(n, 3)).astype(np.float32)
    centers = rng.normal(size=(7, 3)) * 10.0
    which = rng.integers(0, 7, n)
    by_index = cloud_ops.orient_normals(points, normals, centers, which)
    per_point = cloud_ops.orient_normals(points, normals, centers[which])
    np.testing.assert_array_equal(by_index, per_point)
    assert by_index.dtype == np.float32
    assert np.all(np.sum((centers[which] - points) * by_index, axis=1) >= 0)
    np.testing.assert_array_equal(np.abs(by_index), np.abs(normals))  # flipped, never changed
