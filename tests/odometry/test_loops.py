"""The loop closer on synthetic keyframes: a camera circling inside a ring of landmarks (each with its
own ORB-like descriptor), its odometry drifting in yaw; exact geometry, no rendering."""

import math

import numpy as np
import pytest

from skyrecon.odometry.loops import LoopCloser
from skyrecon.odometry.places import Place

F, C, SIZE = 300.0, (160.0, 120.0), (320, 240)
RADIUS, STEP = 30.0, 3.0


def _inv(T):
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


@pytest.fixture(scope="module")
def world():
    rng = np.random.default_rng(0)
    n = 4000
    a = rng.uniform(0, 2 * np.pi, n)
    r = rng.uniform(42.0, 50.0, n)
    landmarks = np.column_stack([r * np.cos(a), r * np.sin(a), rng.uniform(-8.0, 12.0, n)])
    descriptors = rng.integers(0, 256, (n, 32), dtype=np.uint8)
    return landmarks, descriptors


def _pose(s):
    """world_from_cam at arc length s on the circle, looking along it (OpenCV axes, z up world)."""
    a = s / RADIUS
    z = np.array([-math.sin(a), math.cos(a), 0.0])
    y = np.array([0.0, 0.0, -1.0])
    T = np.eye(4)
    T[:3, :3] = np.column_stack([np.cross(y, z), y, z])
    T[:3, 3] = [RADIUS * math.cos(a), RADIUS * math.sin(a), 0.0]
    return T


def _place(world, k, T_true, path, seed):
    landmarks, descriptors = world
    rng = np.random.default_rng(seed)
    cam = _inv(T_true)
    P = landmarks @ cam[:3, :3].T + cam[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = P[:, :2] / P[:, 2:3] * F + np.array(C)
    vis = (
        (P[:, 2] > 3) & (P[:, 2] < 40) & (uv[:, 0] > 5) & (uv[:, 0] < 315) & (uv[:, 1] > 5) & (uv[:, 1] < 235)
    )
    idx = np.flatnonzero(vis)[:150]
    desc = descriptors[idx].copy()
    flip = rng.integers(0, 32, len(idx))
    desc[np.arange(len(idx)), flip] ^= np.uint8(1)  # a bit of descriptor noise
    return Place(
        k,
        10 * k,
        np.ones(8, np.float32) / np.sqrt(8),
        uv[idx] + rng.normal(0, 0.3, (len(idx), 2)),
        desc,
        P[idx] * (1 + rng.normal(0, 0.002, (len(idx), 1))),
        path,
    )


def _fly(world, laps=1.3, yaw_bias_rad=0.0006, lookalike_at=None):
    """Fly the circle with a drifting odometry; returns (closer, true poses, corrected poses, raw odometry)."""
    n = int(laps * 2 * math.pi * RADIUS / STEP)
    true = [_pose(k * STEP) for k in range(n)]
    drift = np.eye(4)
    drift[:3, :3] = np.array(
        [
            [math.cos(yaw_bias_rad), 0, math.sin(yaw_bias_rad)],
            [0, 1, 0],
            [-math.sin(yaw_bias_rad), 0, math.cos(yaw_bias_rad)],
        ]
    )  # a yaw bias about the camera's vertical (-y) axis, every step
    closer = LoopCloser((F, F), C, SIZE, min_inliers=30, min_path_m=40.0)
    poses, raw = [true[0]], [true[0]]
    for k in range(n):
        if k:
            Z = _inv(true[k - 1]) @ true[k] @ drift
            poses.append(poses[-1] @ Z)
            raw.append(raw[-1] @ Z)
        src = true[k]
        if lookalike_at is not None and k == lookalike_at:
            src = _pose((k + 2) * STEP)  # a place 6 m ahead that looks exactly like this one
        closer.add_place(_place(world, k, src, k * STEP, seed=k))
        out = closer.search(poses)
        if out.poses is not None:
            poses = list(out.poses)
    final = closer.finish(poses)
    if final is not None:
        poses = list(final)
    return closer, true, poses, raw


def _max_error(a, b):
    return max(float(np.linalg.norm(p[:3, 3] - q[:3, 3])) for p, q in zip(a, b))


def test_revisit_closes_the_loop_and_removes_the_drift(world):
    closer, true, poses, raw = _fly(world)
    rep = closer.report()
    assert rep["accepted"] >= 5, rep
    assert rep["pose_graph_solves"] >= 1
    before, after = _max_error(raw, true), _max_error(poses, true)
    assert before > 1.0  # metres of drift without loop closure
    assert after < 0.35 * before, (before, after)
    # the first loop is only found on the second lap (old enough, far enough back)
    assert min(e["frame"] for e in rep["log"] if e["status"] == "accepted") >= 10 * int(40 / STEP)


def test_no_revisit_no_loop(world):
    closer, true, poses, raw = _fly(world, laps=0.9)
    rep = closer.report()
    assert rep["accepted"] == 0 and rep["pose_graph_solves"] == 0
    assert all(np.array_equal(p, q) for p, q in zip(poses, raw))


def test_a_lookalike_place_is_not_applied(world):
    n_lap = int(2 * math.pi * RADIUS / STEP)
    ref = _fly(world)
    closer, true, poses, raw = _fly(world, lookalike_at=n_lap + 10)
    rep = closer.report()
    wrong = [e for e in rep["log"] if e["frame"] == 10 * (n_lap + 10)]
    assert wrong and all(e["status"] == "rejected" for e in wrong), wrong
    assert rep["accepted"] >= 5
    # the trajectory is the one without the look-alike, within centimetres
    assert _max_error(poses, ref[2]) < 0.1
