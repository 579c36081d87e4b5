"""Umeyama similarity, robust alignment to known positions and ICP: exactness and robustness."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Image, Intrinsics, Point3D, PointCloud, Reconstruction, Rigid3, rotvec_to_matrix
from skyrecon.errors import EstimationError, InputError
from skyrecon.sfm.align import Sim3, align_reconstruction, estimate_normals, icp, robust_umeyama, umeyama


def _sim(seed: int = 0) -> Sim3:
    rng = np.random.default_rng(seed)
    return Sim3(rotvec_to_matrix(rng.normal(0, 1.0, 3)), rng.normal(0, 5, 3), float(rng.uniform(0.3, 3.0)))


def test_sim3_algebra_round_trips():
    T = _sim(1)
    p = np.random.default_rng(2).normal(size=(10, 3))
    assert np.allclose(T.inverse().apply(T.apply(p)), p)
    U = _sim(3)
    assert np.allclose((U @ T).apply(p), U.apply(T.apply(p)))
    M = T.matrix
    assert np.allclose((np.c_[p, np.ones(10)] @ M.T)[:, :3], T.apply(p))


@pytest.mark.parametrize("with_scale", [True, False])
def test_umeyama_is_exact_on_exact_data(with_scale):
    rng = np.random.default_rng(0)
    src = rng.normal(size=(20, 3))
    T = _sim(4)
    if not with_scale:
        T = Sim3(T.R, T.t, 1.0)
    fit = umeyama(src, T.apply(src), with_scale=with_scale)
    assert np.allclose(fit.transform.R, T.R, atol=1e-10)
    assert np.allclose(fit.transform.t, T.t, atol=1e-9)
    assert abs(fit.transform.scale - T.scale) < 1e-10
    assert fit.rms < 1e-9


def test_umeyama_handles_reflections_and_degeneracy():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(10, 3))
    fit = umeyama(src, src * [1, 1, -1])  # a mirror image: best proper rotation, det +1
    assert np.linalg.det(fit.transform.R) > 0
    with pytest.raises(EstimationError, match="collinear"):
        umeyama(np.outer(np.arange(5.0), [1, 2, 3]), np.outer(np.arange(5.0), [3, 2, 1]))
    with pytest.raises(InputError):
        umeyama(src[:2], src[:2])
    with pytest.raises(InputError):
        umeyama(src, src[:5])


def test_robust_umeyama_ignores_gross_outliers():
    rng = np.random.default_rng(5)
    src = rng.uniform(-50, 50, (40, 3))
    T = _sim(6)
    dst = T.apply(src) + rng.normal(0, 0.05, src.shape)
    dst[:8] += rng.uniform(20, 60, (8, 3))  # GPS glitches
    plain = umeyama(src, dst)
    robust = robust_umeyama(src, dst, threshold=0.5, seed=0)
    assert robust.num_inliers == 32
    assert not robust.inliers[:8].any()
    assert np.abs(robust.transform.apply(src[8:]) - T.apply(src[8:])).max() < 0.2
    assert np.abs(plain.transform.apply(src[8:]) - T.apply(src[8:])).max() > 1.0


def _toy_reconstruction() -> Reconstruction:
    cam = Intrinsics(100, 100, 50, 40, 100, 80)
    rec = Reconstruction({1: cam})
    for k in range(4):
        pose = Rigid3.look_at([3 * np.cos(k), 3 * np.sin(k), 1.0 + 0.2 * k], [0, 0, 0])
        rec.images[k + 1] = Image(k + 1, f"im{k}.png", 1, pose, np.zeros((1, 2)), np.array([1]))
    rec.points3d[1] = Point3D(1, np.array([0.1, 0.2, 0.3]), track=np.array([[k + 1, 0] for k in range(4)]))
    return rec


def test_align_reconstruction_moves_poses_and_points_consistently():
    rec = _toy_reconstruction()
    T = _sim(7)
    positions = {im.name: T.apply(im.center_world) for im in rec.images.values()}
    aligned, fit = align_reconstruction(rec, positions)
    assert fit.rms < 1e-9
    for im in aligned.images.values():
        assert np.allclose(im.center_world, positions[im.name], atol=1e-9)
    # the projection of the point is unchanged by the similarity
    cam = rec.cameras[1]
    for k in rec.images:
        a = cam.project(rec.images[k].cam_from_world.apply(rec.points3d[1].xyz[None]))
        b = cam.project(aligned.images[k].cam_from_world.apply(aligned.points3d[1].xyz[None]))
        assert np.allclose(a, b, atol=1e-9)
    with pytest.raises(InputError, match="at least 3"):
        align_reconstruction(rec, {"im0.png": np.zeros(3)})


def _box_surface(n: int, seed: int) -> np.ndarray:
    """Points on the faces of a 4 x 3 x 2 box plus a ground patch (a well-constrained shape)."""
    rng = np.random.default_rng(seed)
    pts = []
    for axis, size in ((0, 4.0), (1, 3.0), (2, 2.0)):
        for side in (0.0, 1.0):
            p = rng.uniform(0, 1, (n, 3)) * [4.0, 3.0, 2.0]
            p[:, axis] = side * size
            pts.append(p)
    g = np.c_[rng.uniform(-3, 7, (n, 2)), np.full(n, -0.5)]
    return np.concatenate(pts + [g])


@pytest.mark.parametrize("point_to_plane", [True, False])
def test_icp_recovers_a_known_motion(point_to_plane):
    target = _box_surface(600, 0)
    T = Sim3(rotvec_to_matrix([0.05, -0.03, 0.08]), [0.2, -0.1, 0.15], 1.0)
    source = T.inverse().apply(_box_surface(600, 1))  # different samples of the same surface
    res = icp(
        PointCloud(source.astype(np.float32)),
        PointCloud(target.astype(np.float32)),
        point_to_plane=point_to_plane,
        max_iterations=80,
    )
    assert res.converged
    assert np.abs(res.transform.apply(source) - T.apply(source)).max() < 0.03
    assert res.fitness == 1.0


def test_icp_is_robust_to_outliers_and_partial_overlap():
    target = _box_surface(600, 2)
    T = Sim3(rotvec_to_matrix([0.02, 0.04, -0.06]), [-0.15, 0.1, 0.05], 1.0)
    src_true = _box_surface(600, 3)
    rng = np.random.default_rng(4)
    outliers = rng.uniform(-6, 10, (900, 3))  # 20 % clutter in the source
    source = T.inverse().apply(np.concatenate([src_true, outliers]))
    robust = icp(source, target, robust=True, loss="tukey", max_iterations=100)
    plain = icp(source, target, robust=False, max_iterations=100)
    err_r = np.abs(robust.transform.apply(source[: len(src_true)]) - T.apply(source[: len(src_true)])).max()
    err_p = np.abs(plain.transform.apply(source[: len(src_true)]) - T.apply(source[: len(src_true)])).max()
    assert err_r < 0.05
    assert err_r < err_p


def test_icp_with_scale_point_to_point():
    target = _box_surface(400, 5)
    T = Sim3(rotvec_to_matrix([0.03, 0.0, 0.05]), [0.1, 0.0, -0.1], 1.05)
    source = T.inverse().apply(_box_surface(400, 5))  # identical samples: exact correspondences
    res = icp(source, target, point_to_plane=False, with_scale=True, max_iterations=100)
    assert abs(res.transform.scale - 1.05) < 1e-3
    with pytest.raises(InputError):
        icp(source, target, point_to_plane=True, with_scale=True)


def test_icp_reports_no_overlap():
    a = _box_surface(100, 6)
    with pytest.raises(EstimationError, match="max_distance"):
        icp(a, a + 100.0, max_distance=1.0)


def test_estimated_normals_are_perpendicular_to_a_plane():
    rng = np.random.default_rng(7)
    p = np.c_[rng.uniform(0, 1, (500, 2)), np.zeros(500)]
    n = estimate_normals(p)
    assert np.allclose(np.abs(n[:, 2]), 1.0, atol=1e-9)
