"""Loose GPS fusion: drift is anchored, a 20 m multipath jump is gated, the correction moves smoothly."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core.rigid import Rigid3, rotvec_to_matrix
from skyrecon.io.gps import GpsFix, read_gps_csv, write_gps_csv
from skyrecon.odometry.gps import GpsFusion, GpsFusionSettings, fuse_trajectory


def _truth(n: int = 600, dt: float = 0.1) -> tuple[np.ndarray, list[Rigid3]]:
    """A 5 m/s flight with turns and a climb, 60 s: world_from_left (world z up)."""
    t = np.arange(n) * dt
    yaw = 0.4 * np.sin(t / 12.0) + 0.02 * t
    v = 5.0
    xy = np.cumsum(np.stack([np.cos(yaw), np.sin(yaw)], 1) * v * dt, axis=0)
    z = 15 + 3 * np.sin(t / 20)
    cam_axes = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float).T  # cam z forward = world x at yaw 0
    poses = [
        Rigid3(rotvec_to_matrix([0, 0, a]) @ cam_axes, [x, y, h], "world", "left")
        for a, (x, y), h in zip(yaw, xy, z)
    ]
    return t, poses


def _drifting_odometry(truth: list[Rigid3]) -> list[Rigid3]:
    """Odometry in its own world (the first camera frame): 3 % scale error and a slow heading drift."""
    first_inv = truth[0].inverse().with_frames(None, None)
    out, pose = [], Rigid3.identity()
    for k in range(len(truth)):
        if k:
            step = truth[k - 1].inverse().with_frames(None, None) @ truth[k].with_frames(None, None)
            drift = Rigid3(rotvec_to_matrix([0, 0.00005, 0]), 1.03 * step.t)
            pose = pose @ Rigid3(step.R, drift.t) @ Rigid3(drift.R)
        out.append(pose.with_frames("odom", "left"))
    assert first_inv is not None
    return out


def _fixes(t: np.ndarray, truth: list[Rigid3], seed: int = 0, jump=(30.0, 35.0, 20.0)) -> list[GpsFix]:
    rng = np.random.default_rng(seed)
    fixes = []
    for k in range(0, len(t), 2):  # 5 Hz
        p = truth[k].t + rng.normal(0, 1.0, 3)
        if jump[0] <= t[k] < jump[1]:
            p = p + np.array([0.0, jump[2], 0.0])
        fixes.append(GpsFix(t[k], p, 2.5))
    return fixes


def test_fusion_removes_drift_and_gates_a_20m_jump():
    t, truth = _truth()
    odom = _drifting_odometry(truth)
    fixes = _fixes(t, truth)
    fused, fusion = fuse_trajectory(t, odom, fixes)
    err = np.array([np.linalg.norm(a.t - b.t) for a, b in zip(fused, truth)])
    # unaligned odometry is nowhere near; once the flight has turned enough to align (about 17 s) the
    # fused track stays close
    assert err[t > 20].max() < 4.0, err[t > 20].max()
    assert fusion.aligned
    assert np.sqrt(np.mean(err[t > 20] ** 2)) < 2.0
    jump = [u for u in fusion.updates if 30.0 <= u.time_s < 35.0]
    assert len(jump) == 25 and not any(u.accepted for u in jump)
    assert all(u.innovation_m > 12 for u in jump)
    # the jump did not pull the fused track sideways
    assert err[(t >= 30) & (t < 36)].max() < 3.0


def test_the_correction_is_rate_limited():
    t, truth = _truth(300)
    odom = [p.with_frames("odom", "left") for p in truth]  # perfect odometry, aligned
    settings = GpsFusionSettings(max_correction_mps=1.0)
    fusion = GpsFusion(settings, Rigid3.identity("world", "odom"), estimate_rotation=False)
    fused = []
    for k in range(len(t)):
        fix = GpsFix(
            t[k], truth[k].t + (np.array([0.0, 0.0, 0.0]) if t[k] < 10 else np.array([8.0, 0, 0])), 2.5
        )
        fused.append(fusion.update(t[k], odom[k], fix))
    # a persistent 8 m offset opens the gate only slowly and then moves the track at <= 1 m/s
    shift = np.array([f.t[0] - p.t[0] for f, p in zip(fused, truth)])
    assert np.all(np.abs(np.diff(shift)) <= 1.0 * 0.1 + 1e-6)


def test_no_fix_means_pure_odometry_and_first_fix_anchors():
    fusion = GpsFusion(estimate_rotation=False)
    pose = Rigid3(np.eye(3), [1.0, 2.0, 3.0], "odom", "left")
    assert np.allclose(fusion.update(0.0, pose, None).t, [1, 2, 3])
    out = fusion.update(0.1, pose, GpsFix(0.1, [11.0, 2.0, 3.0], 3.0))
    assert np.allclose(out.t, [11, 2, 3]) and fusion.initialised


def test_gps_csv_round_trip(tmp_path):
    fixes = [GpsFix(0.2 * k, [k, -k, 10.0], 2.0 + k) for k in range(5)]
    write_gps_csv(tmp_path / "gps.csv", fixes)
    back = read_gps_csv(tmp_path / "gps.csv")
    assert [f.time_s for f in back] == pytest.approx([f.time_s for f in fixes])
    assert np.allclose([f.position for f in back], [f.position for f in fixes])
    (tmp_path / "b.csv").write_text("0, 1, 2\n")
    from skyrecon.errors import InputError

    with pytest.raises(InputError, match="b.csv: line 1"):
        read_gps_csv(tmp_path / "b.csv")
    (tmp_path / "c.csv").write_text("0,1,2,3\n1,1,2,3,4\n")
    assert read_gps_csv(tmp_path / "c.csv")[0].accuracy_m == 5.0


def test_a_wrong_correction_is_recovered_after_persistent_rejections():
    t, truth = _truth()
    odom = [p.with_frames("odom", "left") for p in truth]  # perfect odometry...
    wrong = Rigid3(rotvec_to_matrix([0, 0, np.radians(40.0)]), np.zeros(3), "world", "odom")
    fixes = _fixes(t, truth, jump=(0.0, 0.0, 0.0))
    # ... but a start told to trust a correction that is 40 degrees off
    fused, fusion = fuse_trajectory(t, odom, fixes, world_from_odom=wrong, estimate_rotation=True)
    fusion_known = GpsFusion(GpsFusionSettings(), wrong, rotation_known=True)
    out = [
        fusion_known.update(tk, p, [f for f in fixes if tk - 0.1 < f.time_s <= tk]) for tk, p in zip(t, odom)
    ]
    err = np.array([np.linalg.norm(a.t - b.t) for a, b in zip(out, truth)])
    # (gated against the latest fit, the fixes get back in as the fit turns: a re-alignment is not needed)
    assert err[t > 45].max() < 4.0, err[t > 45].max()
    assert np.linalg.norm(fused[-1].t - truth[-1].t) < 4.0


def test_a_long_jump_is_not_believed_over_an_odometry_that_tracks():
    """A 25 s multipath episode (longer than reset_after_s): with the odometry tracking through it,
    the correction stays put; without that word, the fusion re-aligns onto the jumped fixes."""
    t, truth = _truth()
    odom = [p.with_frames("odom", "left") for p in truth]
    fixes = _fixes(t, truth, jump=(20.0, 45.0, 40.0))

    def fly(tracking: bool) -> tuple[np.ndarray, GpsFusion]:
        fusion = GpsFusion(GpsFusionSettings(), Rigid3.identity("world", "odom"), rotation_known=True)
        out = [
            fusion.update(tk, p, [f for f in fixes if tk - 0.1 < f.time_s <= tk], True if tracking else None)
            for tk, p in zip(t, odom)
        ]
        return np.array([np.linalg.norm(a.t - b.t) for a, b in zip(out, truth)]), fusion

    err, fusion = fly(tracking=True)
    assert fusion.resets == 0 and err.max() < 4.0, err.max()  # the 40 m jump moved it by metres at most
    err, fusion = fly(tracking=False)
    assert fusion.resets >= 1 and err[(t > 40) & (t < 45)].max() > 5.0
    # ... but never by a jump: the re-alignment is reached under the rate limit (1.5 m/s)
    step = (
        np.linalg.norm(np.diff(np.array([e for e in err]), axis=0), axis=-1)
        if err.ndim > 1
        else np.abs(np.diff(err))
    )
    assert step.max() < 1.5 * 0.1 + 0.5, step.max()


def test_kalman_offset_trusts_a_good_odometry_over_biased_fixes():
    """Odometry with 0.5 % drift from a known take-off pose; fixes with a 3 m bias for 20 s (multipath):
    the Kalman offset stays within the odometry's drift plus a fraction of the bias, the window fit
    takes the bias on."""
    t, truth = _truth()
    good = [p.with_frames("odom", "left") for p in truth]  # a good odometry (no drift)
    rng = np.random.default_rng(2)
    fixes = [GpsFix(t[k], truth[k].t + [0, 0, 3.0 if 20 <= t[k] < 40 else 0] + rng.normal(0, 1.0, 3), 2.5)
             for k in range(0, len(t), 2)]  # fmt: skip

    def fly(settings):
        fusion = GpsFusion(
            settings, Rigid3.identity("world", "odom"), rotation_known=True, estimate_rotation=False
        )
        out = [
            fusion.update(tk, p, [f for f in fixes if tk - 0.1 < f.time_s <= tk], True)
            for tk, p in zip(t, good)
        ]
        return np.array([np.linalg.norm(a.t - b.t) for a, b in zip(out, truth)])

    kalman = fly(GpsFusionSettings(odometry_drift_fraction=0.01))
    window = fly(GpsFusionSettings())
    assert kalman[0] < 0.1  # the take-off position is kept, not moved onto the first fix
    assert kalman.max() < 0.85 * window.max() and kalman[t < 20].max() < 0.5, (kalman.max(), window.max())
