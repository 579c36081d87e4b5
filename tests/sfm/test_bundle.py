"""Bundle adjustment on synthetic problems with known answers: Jacobians, convergence to the
truth within the noise, robustness to outliers, gauge fixing, intrinsics refinement."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Rigid3, rotvec_to_matrix
from skyrecon.errors import InputError
from skyrecon.eval.sfm_metrics import evaluate_sfm_poses
from skyrecon.sfm import _ba_kernels as K
from skyrecon.sfm.align import umeyama
from skyrecon.sfm.bundle import BundleProblem, BundleSolverOptions, _structure, bundle_adjust
from skyrecon.sfm.pnp import estimate_absolute_pose


def _scene(
    seed: int = 0,
    n_img: int = 6,
    n_pt: int = 300,
    noise_px: float = 0.5,
    f: float = 500.0,
    dist: tuple[float, float] = (0.0, 0.0),
):
    """Cameras on an arc looking at a cloud of points; returns truth and noisy observations."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-2.0, 2.0, (n_pt, 3))
    R, t = [], []
    for k in range(n_img):
        a = np.radians(-40 + 80 * k / max(1, n_img - 1))
        T = Rigid3.look_at([9 * np.sin(a), -9 * np.cos(a), 2.0 + 0.3 * k], [0, 0, 0])
        R.append(T.R)
        t.append(T.t)
    R, t = np.array(R), np.array(t)
    cams = np.array([[f, f * 1.01, 320.0, 240.0, dist[0], dist[1]]])
    oi, op = np.meshgrid(np.arange(n_img), np.arange(n_pt), indexing="ij")
    oi, op = oi.ravel(), op.ravel()
    P = np.einsum("nij,nj->ni", R[oi], X[op]) + t[oi]
    x, y = P[:, 0] / P[:, 2], P[:, 1] / P[:, 2]
    r2 = x * x + y * y
    d = 1 + dist[0] * r2 + dist[1] * r2 * r2
    uv = np.stack([cams[0, 0] * d * x + 320.0, cams[0, 1] * d * y + 240.0], axis=1)
    uv_noisy = uv + rng.normal(0.0, noise_px, uv.shape)
    return R, t, X, cams, oi, op, uv_noisy


def _perturb(R, t, X, seed=1, rot=0.01, trans=0.05, pts=0.05):
    rng = np.random.default_rng(seed)
    Rp = np.array([rotvec_to_matrix(rng.normal(0, rot, 3)) @ r for r in R])
    tp = t + rng.normal(0, trans, t.shape)
    Xp = X + rng.normal(0, pts, X.shape)
    return Rp, tp, Xp


def _fix_gauge(prob: BundleProblem, R, t) -> None:
    """Hold image 0 (set to the truth) and the largest translation coordinate of image 1."""
    prob.R[0], prob.t[0] = R[0], t[0]
    prob.constant_images[0] = True
    c0, c1 = -R[0].T @ t[0], -R[1].T @ t[1]
    k = int(np.argmax(np.abs(R[1] @ (c1 - c0))))
    prob.t[1, k] = t[1, k]
    prob.constant_pose_coords[1, 3 + k] = True


def _centres(R, t):
    return -np.einsum("kji,kj->ki", R, t)


def test_analytic_jacobians_match_finite_differences():
    rng = np.random.default_rng(3)
    R = np.array([rotvec_to_matrix(rng.normal(0, 0.3, 3))])
    t = np.array([[0.1, -0.2, 5.0]])
    X = rng.normal(0, 1, (1, 3))
    cams = np.array([[500.0, 480.0, 320.0, 240.0, -0.1, 0.05]])
    idx = np.zeros(1, np.int64)

    def ev(R_, t_, X_, c_):
        out = [np.zeros((1, 2)), np.zeros((1, 2, 6)), np.zeros((1, 2, 3)), np.zeros((1, 2, 3)), np.zeros(1)]
        K.evaluate(
            R_, t_, X_, c_, idx, idx, idx, np.array([[300.0, 200.0]]), np.array([0.5]), 0, 1.0, True, *out
        )
        return out

    r, Jp, Ji, Jx, _ = ev(R, t, X, cams)
    h = 1e-7
    num_p = np.zeros((2, 6))
    num_x = np.zeros((2, 3))
    for a in range(3):
        dw = np.zeros(3)
        dw[a] = h
        num_p[:, a] = (ev(rotvec_to_matrix(dw)[None] @ R, t, X, cams)[0][0] - r[0]) / h
        dt = np.zeros((1, 3))
        dt[0, a] = h
        num_p[:, 3 + a] = (ev(R, t + dt, X, cams)[0][0] - r[0]) / h
        num_x[:, a] = (ev(R, t, X + dt, cams)[0][0] - r[0]) / h
    num_i = np.zeros((2, 3))
    c = cams.copy()
    c[0, 0] += h
    c[0, 1] += h * cams[0, 1] / cams[0, 0]
    num_i[:, 0] = (ev(R, t, X, c)[0][0] - r[0]) / h
    for a, col in ((1, 4), (2, 5)):
        c = cams.copy()
        c[0, col] += h
        num_i[:, a] = (ev(R, t, X, c)[0][0] - r[0]) / h
    assert np.allclose(num_p, Jp[0], atol=1e-4 * np.abs(Jp).max())
    assert np.allclose(num_x, Jx[0], atol=1e-4 * np.abs(Jx).max())
    assert np.allclose(num_i, Ji[0], atol=1e-4 * np.abs(Ji).max())


@pytest.mark.parametrize("loss", ["trivial", "huber", "cauchy"])
def test_converges_to_ground_truth_within_noise(loss):
    R, t, X, cams, oi, op, uv = _scene(noise_px=0.5)
    Rp, tp, Xp = _perturb(R, t, X)
    prob = BundleProblem(Rp, tp, Xp, cams, np.zeros(len(R), np.int64), oi, op, uv)
    _fix_gauge(prob, R, t)
    rep = bundle_adjust(prob, BundleSolverOptions(loss=loss))
    assert rep.initial_rms_px > 5.0
    # 2-D noise of 0.5 px per axis: rms of the residual norm about 0.7 px, a bit less after fitting
    assert 0.5 < rep.final_rms_px < 0.75
    assert rep.termination in ("function tolerance", "parameter tolerance", "gradient tolerance")
    # the same minimum as an adjustment started from the truth
    oracle = BundleProblem(R.copy(), t.copy(), X.copy(), cams, np.zeros(len(R), np.int64), oi, op, uv)
    _fix_gauge(oracle, R, t)
    bundle_adjust(oracle, BundleSolverOptions(loss=loss, function_tolerance=1e-12))
    assert np.abs(prob.t - oracle.t).max() < 1e-3
    assert np.abs(prob.points - oracle.points).max() < 1e-2
    # and the truth within the noise, after a similarity alignment (the gauge drifts with the noise)
    fit = umeyama(_centres(prob.R, prob.t), _centres(R, t))
    assert fit.residuals.max() < 0.01  # metres, cameras ~9 m from the points
    ev = evaluate_sfm_poses(
        {k: Rigid3(prob.R[k], prob.t[k]) for k in range(len(R))},
        {k: Rigid3(R[k], t[k]) for k in range(len(R))},
    )
    assert ev.rotation_errors_deg.max() < 0.2  # narrow field of view: rotation and translation trade off
    assert np.median(np.linalg.norm(fit.transform.apply(prob.points) - X, axis=1)) < 0.02


def test_exact_data_converges_to_exact_answer():
    R, t, X, cams, oi, op, uv = _scene(noise_px=0.0)
    Rp, tp, Xp = _perturb(R, t, X, rot=0.02, trans=0.1, pts=0.1)
    prob = BundleProblem(Rp, tp, Xp, cams, np.zeros(len(R), np.int64), oi, op, uv)
    _fix_gauge(prob, R, t)
    rep = bundle_adjust(
        prob, BundleSolverOptions(loss="trivial", function_tolerance=1e-14, max_iterations=100)
    )
    assert rep.final_rms_px < 1e-6
    assert np.abs(prob.t - t).max() < 1e-6
    assert np.abs(prob.points - X).max() < 1e-6


def test_robust_loss_handles_outliers():
    R, t, X, cams, oi, op, uv = _scene(noise_px=0.3, seed=4)
    rng = np.random.default_rng(5)
    bad = rng.random(len(uv)) < 0.1
    uv = uv.copy()
    uv[bad] += rng.uniform(-40, 40, (int(bad.sum()), 2))
    errs = {}
    for loss in ("trivial", "cauchy"):
        Rp, tp, Xp = _perturb(R, t, X)
        prob = BundleProblem(Rp, tp, Xp, cams, np.zeros(len(R), np.int64), oi, op, uv)
        _fix_gauge(prob, R, t)
        bundle_adjust(prob, BundleSolverOptions(loss=loss, loss_scale=1.0, max_iterations=100))
        errs[loss] = np.abs(_centres(prob.R, prob.t) - _centres(R, t)).max()
    assert errs["cauchy"] < 0.03
    assert errs["cauchy"] < 0.25 * errs["trivial"]


def test_gauge_is_held():
    R, t, X, cams, oi, op, uv = _scene(noise_px=0.5)
    Rp, tp, Xp = _perturb(R, t, X)
    prob = BundleProblem(Rp, tp, Xp, cams, np.zeros(len(R), np.int64), oi, op, uv)
    _fix_gauge(prob, R, t)
    fixed = prob.constant_pose_coords[1].copy()
    t1_fixed = prob.t[1, fixed[3:]].copy()
    bundle_adjust(prob, BundleSolverOptions())
    assert np.array_equal(prob.R[0], R[0]) and np.array_equal(prob.t[0], t[0])
    assert np.array_equal(prob.t[1, fixed[3:]], t1_fixed)


def test_refines_focal_length_and_radial_distortion():
    R, t, X, cams, oi, op, uv = _scene(noise_px=0.2, n_img=8, n_pt=400, dist=(-0.08, 0.02))
    start = cams.copy()
    start[0, 0] *= 1.04
    start[0, 1] *= 1.04
    start[0, 4:] = 0.0
    Rp, tp, Xp = _perturb(R, t, X, rot=0.005, trans=0.02, pts=0.02)
    prob = BundleProblem(Rp, tp, Xp, start, np.zeros(len(R), np.int64), oi, op, uv)
    _fix_gauge(prob, R, t)
    rep = bundle_adjust(
        prob, BundleSolverOptions(refine_focal_length=True, refine_distortion=True, max_iterations=100)
    )
    assert rep.final_rms_px < 0.3
    assert rep.termination != "max iterations"
    assert abs(prob.cameras[0, 0] / cams[0, 0] - 1) < 0.003
    assert abs(prob.cameras[0, 1] / prob.cameras[0, 0] - start[0, 1] / start[0, 0]) < 1e-12  # aspect kept
    assert abs(prob.cameras[0, 4] - cams[0, 4]) < 0.02  # k1 (k2 is weakly determined at this field of view)


@pytest.mark.parametrize("refine", [False, True])
def test_sparse_factorisation_gives_the_dense_answer(refine):
    """Above ``max_dense_columns`` the reduced system is factorised sparse: same adjustment to
    rounding, with held pose coordinates and (optionally) intrinsics columns."""
    R, t, X, cams, oi, op, uv = _scene(noise_px=0.5, n_img=8, dist=(0.05, 0.0))
    Rp, tp, Xp = _perturb(R, t, X)
    answers = []
    for max_dense in (10_000, 10):
        prob = BundleProblem(
            Rp.copy(), tp.copy(), Xp.copy(), cams.copy(), np.zeros(len(R), np.int64), oi, op, uv
        )
        _fix_gauge(prob, R, t)
        rep = bundle_adjust(
            prob,
            BundleSolverOptions(
                max_dense_columns=max_dense,
                refine_focal_length=refine,
                refine_distortion=refine,
                max_iterations=30,
            ),
        )
        assert rep.solver == ("dense" if max_dense > 10 else "sparse")
        assert rep.final_rms_px < 0.75
        answers.append(
            (prob.R.copy(), prob.t.copy(), prob.points.copy(), prob.cameras.copy(), rep.iterations)
        )
    (R0, t0, X0, c0, it0), (R1, t1, X1, c1, it1) = answers
    assert it0 == it1
    np.testing.assert_allclose(R1, R0, atol=1e-9)
    np.testing.assert_allclose(t1, t0, atol=1e-8)
    np.testing.assert_allclose(X1, X0, atol=1e-8)
    np.testing.assert_allclose(c1, c0, rtol=1e-9, atol=1e-9)


def test_a_flight_stores_only_the_camera_pairs_that_share_points():
    """Cameras along a line, each point seen by 5 neighbours: the reduced system keeps the band
    (about 5 blocks a camera) instead of all pairs, and the sparse solve recovers the truth."""
    rng = np.random.default_rng(3)
    n_img = 120
    centres = np.stack([np.arange(n_img) * 2.0, np.zeros(n_img), np.full(n_img, 30.0)], axis=1)
    R = np.repeat(np.diag([1.0, -1.0, -1.0])[None], n_img, axis=0)  # looking straight down
    t = -np.einsum("nij,nj->ni", R, centres)
    X = np.stack(
        [rng.uniform(-4, 2 * n_img + 4, 3000), rng.uniform(-12, 12, 3000), rng.uniform(-2, 8, 3000)], 1
    )
    oi, op = [], []
    for j, x in enumerate(X):
        k0 = int(np.clip(np.round(x[0] / 2.0) - 2, 0, n_img - 5))
        oi += list(range(k0, k0 + 5))
        op += [j] * 5
    oi, op = np.array(oi), np.array(op)
    cams = np.array([[800.0, 800.0, 512.0, 512.0, 0.0, 0.0]])
    P = np.einsum("nij,nj->ni", R[oi], X[op]) + t[oi]
    uv = 800.0 * P[:, :2] / P[:, 2:] + 512.0 + rng.normal(0, 0.3, (len(oi), 2))
    Rp, tp, Xp = _perturb(R, t, X, rot=0.002, trans=0.05, pts=0.1)
    Rp[[0, -1]], tp[[0, -1]] = R[[0, -1]], t[[0, -1]]
    found = []
    for max_dense in (10_000, 60):
        prob = BundleProblem(Rp.copy(), tp.copy(), Xp.copy(), cams, np.zeros(n_img, np.int64), oi, op, uv)
        prob.constant_images[[0, -1]] = True
        rep = bundle_adjust(prob, BundleSolverOptions(max_dense_columns=max_dense, max_iterations=30))
        assert rep.final_rms_px < 0.45
        found.append(_centres(prob.R, prob.t))
    assert rep.solver == "sparse"
    s = _structure(prob, BundleSolverOptions())
    assert s.system.n_slots < 6 * n_img  # a band, not the n^2 / 2 = 7000 of a dense system
    np.testing.assert_allclose(found[1], found[0], atol=1e-6)
    np.testing.assert_allclose(found[1], centres, atol=0.3)


def test_points_behind_the_camera_do_not_break_it():
    R, t, X, cams, oi, op, uv = _scene(noise_px=0.5)
    Rp, tp, Xp = _perturb(R, t, X)
    Xp[:5] = -_centres(R, t)[0] * 3  # far behind camera 0
    prob = BundleProblem(Rp, tp, Xp, cams, np.zeros(len(R), np.int64), oi, op, uv)
    _fix_gauge(prob, R, t)
    rep = bundle_adjust(prob, BundleSolverOptions())
    assert np.isfinite(rep.final_cost) and rep.final_cost < rep.initial_cost
    assert np.isinf(rep.errors_px).any()


def test_bad_problems_are_rejected():
    R, t, X, cams, oi, op, uv = _scene()
    with pytest.raises(InputError):
        BundleProblem(R, t, X, cams, np.zeros(len(R), np.int64), oi, op + 10_000, uv)
    uv2 = uv.copy()
    uv2[0, 0] = np.nan
    with pytest.raises(InputError):
        BundleProblem(R, t, X, cams, np.zeros(len(R), np.int64), oi, op, uv2)
    with pytest.raises(InputError):
        BundleSolverOptions(loss="l7")


def test_absolute_pose_with_outliers():
    R, t, X, cams, oi, op, uv = _scene(noise_px=0.3, seed=7)
    sel = oi == 2
    xy = (uv[sel] - [320.0, 240.0]) / [cams[0, 0], cams[0, 1]]
    Xs = X[op[sel]]
    rng = np.random.default_rng(8)
    bad = rng.random(len(xy)) < 0.3
    xy[bad] += rng.uniform(-0.2, 0.2, (int(bad.sum()), 2))
    pose = estimate_absolute_pose(xy, Xs, cams[0, 0], threshold_px=2.0, seed=1)
    assert abs(pose.num_inliers - int((~bad).sum())) <= 5
    assert np.linalg.norm(_centres(pose.R[None], pose.t[None])[0] - _centres(R[2:3], t[2:3])[0]) < 0.02
    pose2 = estimate_absolute_pose(xy, Xs, cams[0, 0], threshold_px=2.0, seed=1)
    assert np.array_equal(pose.R, pose2.R)  # deterministic for a seed
