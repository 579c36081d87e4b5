import math

import numpy as np
from scipy.spatial.transform import Rotation

from skyrecon.odometry.pose_graph import PoseEdge, edge_errors, optimize_pose_graph


def _inv(T):
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def _circle(n, radius=30.0):
    """Poses on a horizontal circle, each heading along it (world_from_node)."""
    out = []
    for k in range(n):
        a = 2 * math.pi * k / n
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("z", a + math.pi / 2).as_matrix()
        T[:3, 3] = [radius * math.cos(a), radius * math.sin(a), 0.0]
        out.append(T)
    return np.stack(out)


def _drifted(true, yaw_bias=0.002, scale_bias=0.01, seed=0):
    """Odometry edges with a yaw bias, a scale bias and noise; the poses chained from them."""
    rng = np.random.default_rng(seed)
    est, edges = [true[0]], []
    for k in range(1, len(true)):
        Z = _inv(true[k - 1]) @ true[k]
        D = np.eye(4)
        D[:3, :3] = Rotation.from_rotvec([0, 0, yaw_bias] + rng.normal(0, 1e-4, 3)).as_matrix()
        Zm = Z @ D
        Zm[:3, 3] = Z[:3, 3] * (1 + scale_bias) + rng.normal(0, 0.005, 3)
        est.append(est[-1] @ Zm)
        edges.append(PoseEdge(k - 1, k, Zm, 0.02, math.radians(0.1)))
    return np.stack(est), edges


def _loop(true, i, j, robust=True, error=None):
    Z = _inv(true[i]) @ true[j]
    if error is not None:
        Z = Z @ error
    return PoseEdge(i, j, Z, 0.05, math.radians(0.2), robust)


def test_loop_edge_recovers_a_known_drift_on_a_circle():
    true = _circle(60)
    est, edges = _drifted(true)
    before = np.linalg.norm(est[:, :3, 3] - true[:, :3, 3], axis=1).max()
    assert before > 3.0  # metres: the drift to undo
    loops = [_loop(true, 0, 59), _loop(true, 1, 58)]
    first = optimize_pose_graph(est, edges + loops, loss_scale=1e3)
    res = optimize_pose_graph(first.poses, edges + loops, loss_scale=3.0)
    after = np.linalg.norm(res.poses[:, :3, 3] - true[:, :3, 3], axis=1).max()
    assert after < 0.25 * before, (before, after)  # a scale bias cannot be undone in the middle
    assert res.cost_after < 1e-2 * first.cost_before
    assert np.allclose(res.poses[0], est[0])  # the gauge stays
    err0_m, err0_deg = edge_errors(est, loops)
    err_m, err_deg = edge_errors(res.poses, loops)
    assert err0_m.min() > 3.0 and err0_deg.min() > 5.0  # the loops disagree with the drifted poses...
    assert err_m.max() < 0.1 and err_deg.max() < 1.0  # ... and hardly at all after the optimisation


def test_wrong_loop_edge_is_down_weighted():
    true = _circle(60)
    est, edges = _drifted(true, yaw_bias=0.0005, scale_bias=0.002)
    good = [_loop(true, 0, 59), _loop(true, 2, 57)]
    wrong = np.eye(4)
    wrong[:3, 3] = [4.0, -3.0, 0.0]  # a place 5 m away that looks the same
    bad = _loop(true, 10, 45, error=wrong)
    ref = optimize_pose_graph(est, edges + good, loss_scale=3.0).poses
    res = optimize_pose_graph(est, edges + good + [bad], loss_scale=3.0).poses
    # the wrong edge stays violated (its residual is about its 5 m error) and barely moves the rest
    err_m, _ = edge_errors(res, [bad])
    assert err_m[0] > 3.0
    assert np.linalg.norm(res[:, :3, 3] - ref[:, :3, 3], axis=1).max() < 0.5
    # without the robust loss the same edge bends the trajectory by metres
    plain = PoseEdge(bad.i, bad.j, bad.i_from_j, bad.sigma_t_m, bad.sigma_r_rad, robust=False)
    bent = optimize_pose_graph(est, edges + good + [plain], loss_scale=3.0).poses
    assert np.linalg.norm(bent[:, :3, 3] - ref[:, :3, 3], axis=1).max() > 1.0


def test_nothing_to_do():
    true = _circle(5)
    res = optimize_pose_graph(true, [])
    assert np.array_equal(res.poses, true) and res.iterations == 0
