import numpy as np

from skyrecon.odometry.window import window_bundle_adjust
from skyrecon.sim import default_rig


def _project(fx, fy, cx, cy, R, t, X):
    Q = X @ R.T + t
    return np.column_stack([fx * Q[:, 0] / Q[:, 2] + cx, fy * Q[:, 1] / Q[:, 2] + cy])


def test_window_recovers_perturbed_keyframes_and_points():
    rig = default_rig(640, 480)
    L, Rr = rig.left, rig.right
    rng = np.random.default_rng(0)
    n_kf, n_pt = 6, 200
    X = np.column_stack([rng.uniform(-10, 10, n_pt), rng.uniform(-5, 5, n_pt), rng.uniform(8, 40, n_pt)])
    R = np.stack([np.eye(3)] * n_kf)
    t = np.stack([np.array([0.2 * k, 0.0, -1.0 * k]) for k in range(n_kf)])  # left_from_world
    obs_kf, obs_pt, obs_uv, r_kf, r_pt, r_uv = [], [], [], [], [], []
    for k in range(n_kf):
        obs_kf += [k] * n_pt
        obs_pt += list(range(n_pt))
        obs_uv.append(_project(L.fx, L.fy, L.cx, L.cy, R[k], t[k], X))
        r_kf += [k] * n_pt
        r_pt += list(range(n_pt))
        r_uv.append(_project(Rr.fx, Rr.fy, Rr.cx, Rr.cy, R[k], t[k] + rig.right_from_left.t, X))
    fixed = np.zeros(n_kf, bool)
    fixed[:2] = True
    t_bad = t.copy()
    t_bad[2:] *= 0.96  # a 4 % scale error on the free keyframes
    t_bad[2:, 1] += 0.05
    X_bad = X + rng.normal(0.0, 0.3, X.shape)
    res = window_bundle_adjust(
        rig,
        R,
        t_bad,
        fixed,
        X_bad,
        np.array(obs_kf),
        np.array(obs_pt),
        np.vstack(obs_uv),
        np.array(r_kf),
        np.array(r_pt),
        np.vstack(r_uv),
        max_iterations=20,
    )
    assert res.rms_before_px > 1.0
    assert res.rms_after_px < 1e-3
    np.testing.assert_allclose(res.t, t, atol=1e-5)
    np.testing.assert_allclose(res.points, X, atol=1e-4)
    np.testing.assert_allclose(res.t[:2], t[:2])  # the gauge keyframes did not move
    assert res.point_error_px.max() < 1e-3
