"""A pose that leaves the vehicle's dynamics is refitted from the motion prediction or refused."""

from __future__ import annotations

import dataclasses

import numpy as np

from skyrecon.core import Rigid3
from skyrecon.odometry.engine import OdometrySettings, StereoOdometry
from skyrecon.sfm.pnp import reprojection_errors_px
from skyrecon.sim import default_rig


def _setup(seed: int = 0):
    rig = default_rig(640, 480, 90.0, 0.3)
    eng = StereoOdometry(
        rig, dataclasses.replace(OdometrySettings(), max_acceleration_mps2=10.0), Rigid3.identity()
    )
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(-8, 8, 200), rng.uniform(-4, 4, 200), rng.uniform(4, 30, 200)])
    T_true = np.eye(4)
    T_true[:3, 3] = [0.05, 0.0, 0.5]  # world_from_left: half a metre forward
    R, t = T_true[:3, :3].T, -T_true[:3, :3].T @ T_true[:3, 3]
    P = X @ R.T + t
    xn = P[:, :2] / P[:, 2:] + rng.normal(0, 0.2 / 320, (200, 2))
    return eng, X, xn, T_true


def test_a_slide_the_vehicle_cannot_make_is_refitted_from_the_prediction():
    eng, X, xn, T_true = _setup()
    T_wrong = T_true.copy()
    T_wrong[:3, 3] += [2.7, 0.0, 0.0]  # 27 m/s sideways within one frame
    T, pose, why = eng._check_motion(T_wrong, None, T_true, 0.1, xn, X)
    assert why == "" and T is not None and pose is not None
    assert np.linalg.norm(T[:3, 3] - T_true[:3, 3]) < 0.05
    assert pose.num_inliers > 150
    errors = reprojection_errors_px(pose.R, pose.t, xn, X, 320.0)
    assert np.median(errors) < 0.5


def test_a_pose_within_the_dynamics_passes_unchanged():
    eng, X, xn, T_true = _setup()
    T_pred = T_true.copy()
    T_pred[:3, 3] += [0.1, 0.0, 0.0]  # 10 cm off the prediction: within 0.3 m + a dt^2 / 2
    T, _, why = eng._check_motion(T_true, None, T_pred, 0.1, xn, X)
    assert why == "" and T is T_true


def test_when_the_prediction_explains_nothing_the_frame_fails_with_the_reason():
    eng, X, xn, T_true = _setup()
    T_pred = T_true.copy()
    T_pred[:3, 3] += [0.0, 0.0, 5.0]  # the prediction itself is far off: no track agrees with it
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    T_pred[:3, :3] = R
    T, pose, why = eng._check_motion(T_true, None, T_pred, 0.1, xn, X)
    assert T is None and pose is None
    assert "from the motion prediction" in why


def test_a_drone_that_stopped_while_its_frames_were_lost_is_not_held_to_its_old_speed(flight):
    """5 m/s for 10 frames, 3 black frames, then hovering where the frames stopped: the pose
    re-initialised after the loss is chained at the old speed (a guess), and the measured poses that
    follow say the drone stands still. They must be believed; held to the old speed they were
    rejected one after another, each rejection re-initialising at that speed again, and the estimate
    ran away (90 m in one mission)."""
    from tests.odometry.test_engine import _run

    frames = list(range(10)) + [10] * 20
    hover = dataclasses.replace(
        flight,
        left=[flight.left[k] for k in frames],
        right=[flight.right[k] for k in frames],
        disparity=[flight.disparity[k] for k in frames],
        world_from_left=[flight.world_from_left[k] for k in frames],
    )
    black = np.zeros_like(flight.left[0])
    # as the delivery loop flies it: a hovering drone's frames may repeat exactly (no frozen check)
    settings = dataclasses.replace(OdometrySettings(), max_acceleration_mps2=10.0, detect_frozen=False)
    vo, est = _run(hover, settings, replace={k: (lambda k: (black, black)) for k in (10, 11, 12)})
    reinit = next(k for k, e in enumerate(est) if e.reinitialised)
    assert reinit == 13
    after = [e.state.value for e in est[reinit + 1 :]]
    assert after.count("lost") == 0, [e.reason for e in est[reinit + 1 :]]
    drift = [np.linalg.norm(e.world_from_left.t - hover.world_from_left[k].t) for k, e in enumerate(est)]
    assert drift[-1] - drift[reinit + 1] < 0.3, drift[reinit:]


def test_a_refused_pose_is_accepted_when_the_next_frame_measures_the_same_motion():
    """The prediction itself can be what is wrong (a poor pose let through bent the velocity):
    a pose refused in one frame and one that follows on from it in the next are two measurements
    that agree; the second is accepted (flagged, velocity measured afresh). One that does not
    follow on from it stays refused."""
    from skyrecon.sfm.pnp import estimate_absolute_pose

    eng, X, xn, T_true = _setup()
    pose = estimate_absolute_pose(xn, X, 320.0, min_inliers=20)
    T_last = np.eye(4)
    eng._trusted = [(0.0, T_last.copy()), (0.1, T_last)]
    T_pred = T_last.copy()
    T_pred[:3, 3] = [0.0, 0.0, 0.5]  # 5 m/s forward, as the prior believes
    T_first = T_pred.copy()
    T_first[:3, 3] += [1.0, 0.0, 0.0]  # measured 1 m to the side of the prediction
    T, p, why = eng._confirm_refused(7, 0.2, T_first, pose, T_pred, 0.1, "refused")
    assert T is None and p is None and why == "refused"  # one measurement alone is not enough
    T_next = T_first.copy()
    T_next[:3, 3] += [0.0, 0.0, 0.5]  # the next frame: the same 5 m/s on from the refused pose
    T_pred_next = T_pred.copy()
    T_pred_next[:3, 3] += [0.0, 0.0, 0.5]
    T, p, why = eng._confirm_refused(8, 0.3, T_next, pose, T_pred_next, 0.2, "refused")
    assert T is T_next and p is pose and why == ""
    assert "agrees with the one measured in the frame before" in eng._refused_note
    # a measurement that does not follow on from the refused one stays refused
    eng2, *_ = _setup()
    eng2._trusted = eng._trusted
    eng2._confirm_refused(7, 0.2, T_first, pose, T_pred, 0.1, "refused")
    T_far = T_next.copy()
    T_far[:3, 3] += [0.0, 1.5, 0.0]
    assert eng2._confirm_refused(8, 0.3, T_far, pose, T_pred_next, 0.2, "refused")[0] is None
