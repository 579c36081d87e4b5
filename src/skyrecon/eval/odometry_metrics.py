"""Trajectory metrics of visual odometry against ground truth.

Both trajectories are per-frame ``world_from_left`` poses (left camera in its world, metres),
already associated frame by frame (same length, same order). Each lives in its own world frame:
the absolute error aligns them first.

* **ATE** (absolute trajectory error): RMSE of camera-centre distances after the least-squares
  rigid (SE(3)) alignment of the estimate onto the ground truth (Umeyama; Sim(3) with
  ``with_scale=True`` for monocular estimates, whose scale is free).
* **RPE** (relative pose error): for every frame ``i`` and the first later frame ``j`` that is
  ``delta`` further along (metres of ground-truth path, or seconds), the error of the estimated
  motion ``left_i_from_left_j`` against the true one: RMSE of its translation (metres) and mean of
  its rotation (degrees). No alignment is needed.
* **Drift** the KITTI odometry way: over every sub-path that starts at a frame and is
  25, 50 or 100 m long (ground-truth path length), the translation error of the relative motion
  as a percentage of the sub-path's length, and its rotation error in degrees per 100 m; averaged
  over all sub-paths of all lengths (KITTI's devkit uses 100..800 m; drone flights here are shorter).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skyrecon.core.rigid import Rigid3, rotation_angle_deg
from skyrecon.errors import EstimationError, InputError
from skyrecon.sfm.align import Sim3, umeyama

__all__ = [
    "DRIFT_LENGTHS_M",
    "OdometryMetrics",
    "align_trajectory",
    "ate_rmse",
    "relative_pose_error",
    "kitti_drift",
    "path_length",
    "evaluate_odometry",
]

DRIFT_LENGTHS_M = (25.0, 50.0, 100.0)


def _positions(poses: Sequence[Rigid3]) -> np.ndarray:
    return np.array([p.t for p in poses], dtype=np.float64).reshape(-1, 3)


def _check(est: Sequence[Rigid3], gt: Sequence[Rigid3]) -> None:
    if len(est) != len(gt):
        raise InputError(f"{len(est)} estimated poses for {len(gt)} ground-truth poses; associate them first")
    if len(est) < 2:
        raise InputError(f"trajectory metrics need at least 2 poses, got {len(est)}")


def path_length(poses: Sequence[Rigid3]) -> np.ndarray:
    """(N,) cumulative distance travelled by the camera centre up to each frame, metres (0 at frame 0)."""
    p = _positions(poses)
    if len(p) == 0:
        return np.zeros(0)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])


def align_trajectory(est: Sequence[Rigid3], gt: Sequence[Rigid3], with_scale: bool = False) -> Sim3:
    """``gt_world_from_est_world``: the rigid (or similarity) transform that best maps the estimated
    camera centres onto the true ones (least squares, Umeyama). With fewer than 3 poses, or collinear
    centres (a straight flight), the rotation about the line is not observable from positions alone:
    then the first frames' poses fix it (``gt_0 @ est_0^-1``) and only the translation is fitted."""
    _check(est, gt)
    src, dst = _positions(est), _positions(gt)
    try:
        return umeyama(src, dst, with_scale=with_scale).transform
    except EstimationError:
        T = gt[0].with_frames(None, None) @ est[0].with_frames(None, None).inverse()
        s = 1.0
        if with_scale:
            ls, ld = path_length(est)[-1], path_length(gt)[-1]
            s = ld / ls if ls > 1e-12 else 1.0
        R = T.R
        t = dst.mean(axis=0) - s * (src.mean(axis=0) @ R.T)
        return Sim3(R, t, s)


def ate_rmse(
    est: Sequence[Rigid3], gt: Sequence[Rigid3], with_scale: bool = False
) -> tuple[float, np.ndarray, Sim3]:
    """Absolute trajectory error.

    Returns:
        (RMSE in metres, (N,) per-frame centre errors in metres, the alignment
        ``gt_world_from_est_world``).
    """
    T = align_trajectory(est, gt, with_scale)
    err = np.linalg.norm(T.apply(_positions(est)) - _positions(gt), axis=1)
    return float(np.sqrt(np.mean(err**2))), err, T


def _motion(poses: Sequence[Rigid3], i: int, j: int) -> Rigid3:
    """``left_i_from_left_j``."""
    a, b = poses[i].with_frames(None, None), poses[j].with_frames(None, None)
    return a.inverse() @ b


def _pairs(axis: np.ndarray, delta: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j): j is the first frame with ``axis[j] >= axis[i] + delta``."""
    j = np.searchsorted(axis, axis + delta - 1e-9 * max(1.0, delta), side="left")
    i = np.arange(len(axis))
    ok = j < len(axis)
    return i[ok], j[ok]


def _relative_errors(
    est: Sequence[Rigid3], gt: Sequence[Rigid3], i: np.ndarray, j: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(translation errors in metres, rotation errors in degrees) of the motions i -> j."""
    t_err = np.empty(len(i))
    r_err = np.empty(len(i))
    for k, (a, b) in enumerate(zip(i, j)):
        e = _motion(gt, a, b).inverse() @ _motion(est, a, b)
        t_err[k] = np.linalg.norm(e.t)
        r_err[k] = rotation_angle_deg(e.R)
    return t_err, r_err


def relative_pose_error(
    est: Sequence[Rigid3],
    gt: Sequence[Rigid3],
    delta: float,
    unit: str = "m",
    timestamps_s: np.ndarray | None = None,
) -> dict[str, Any]:
    """Relative pose error over steps of ``delta`` metres of true path (``unit="m"``) or seconds
    (``unit="s"``, needs ``timestamps_s`` (N,)).

    Returns:
        ``{"delta", "unit", "pairs", "trans_rmse_m", "trans_mean_m", "rot_mean_deg"}``; the errors are
        None when the trajectory is shorter than ``delta`` (no pair).
    """
    _check(est, gt)
    if not delta > 0:
        raise InputError(f"the RPE step must be positive, got {delta}")
    if unit == "m":
        axis = path_length(gt)
    elif unit == "s":
        if timestamps_s is None or len(timestamps_s) != len(est):
            raise InputError("an RPE per second needs one timestamp per pose")
        axis = np.asarray(timestamps_s, dtype=np.float64)
        if np.any(np.diff(axis) < 0):
            raise InputError("timestamps must not decrease")
    else:
        raise InputError(f"unit must be 'm' or 's', got {unit!r}")
    i, j = _pairs(axis, delta)
    out: dict[str, Any] = {"delta": float(delta), "unit": unit, "pairs": int(len(i))}
    if len(i) == 0:
        out.update(trans_rmse_m=None, trans_mean_m=None, rot_mean_deg=None)
        return out
    t_err, r_err = _relative_errors(est, gt, i, j)
    out.update(
        trans_rmse_m=float(np.sqrt(np.mean(t_err**2))),
        trans_mean_m=float(np.mean(t_err)),
        rot_mean_deg=float(np.mean(r_err)),
    )
    return out


def kitti_drift(
    est: Sequence[Rigid3],
    gt: Sequence[Rigid3],
    lengths_m: Sequence[float] = DRIFT_LENGTHS_M,
    step_frames: int = 1,
) -> dict:
    """Drift in % of distance travelled, the KITTI odometry way.

    For every start frame (every ``step_frames``) and every length L, the sub-path to the first frame
    at least L metres further along the true path; the translation error of the estimated relative
    motion divided by L (the sub-path's nominal length, as the KITTI devkit does).

    Returns:
        ``{"translation_pct", "rotation_deg_per_100m", "segments", "per_length": {L: {...}}}``;
        the averages are None when the flight is shorter than the shortest length.
    """
    _check(est, gt)
    dist = path_length(gt)
    t_all: list[np.ndarray] = []
    r_all: list[np.ndarray] = []
    per: dict[str, dict] = {}
    for L in lengths_m:
        i, j = _pairs(dist, float(L))
        keep = (i % max(1, step_frames)) == 0
        i, j = i[keep], j[keep]
        if len(i) == 0:
            per[f"{L:g}"] = {"segments": 0, "translation_pct": None, "rotation_deg_per_100m": None}
            continue
        t_err, r_err = _relative_errors(est, gt, i, j)
        t_pct = 100.0 * t_err / L
        r_rate = 100.0 * r_err / L
        per[f"{L:g}"] = {
            "segments": int(len(i)),
            "translation_pct": float(np.mean(t_pct)),
            "rotation_deg_per_100m": float(np.mean(r_rate)),
        }
        t_all.append(t_pct)
        r_all.append(r_rate)
    n = int(sum(len(a) for a in t_all))
    return {
        "translation_pct": float(np.mean(np.concatenate(t_all))) if n else None,
        "rotation_deg_per_100m": float(np.mean(np.concatenate(r_all))) if n else None,
        "segments": n,
        "per_length": per,
    }


@dataclass
class OdometryMetrics:
    """Everything :func:`evaluate_odometry` measures (lengths in metres, angles in degrees).

    Attributes:
        frames: poses compared.
        path_length_m: true distance travelled.
        ate_rmse_m, ate_max_m: absolute trajectory error after alignment.
        ate_errors_m: (N,) per-frame centre errors after alignment.
        alignment: ``gt_world_from_est_world``.
        rpe_100m, rpe_1s: :func:`relative_pose_error` over 100 m and 1 s.
        drift: :func:`kitti_drift`.
        with_scale: the alignment was Sim(3).
    """

    frames: int
    path_length_m: float
    ate_rmse_m: float
    ate_max_m: float
    ate_errors_m: np.ndarray
    alignment: Sim3
    rpe_100m: dict
    rpe_1s: dict
    drift: dict
    with_scale: bool = False
    extra: dict = field(default_factory=dict)

    @property
    def drift_pct(self) -> float | None:
        return self.drift["translation_pct"]

    def as_json(self) -> dict:
        return {
            "frames": self.frames,
            "path_length_m": round(self.path_length_m, 3),
            "alignment": "sim3" if self.with_scale else "se3",
            "ate_rmse_m": self.ate_rmse_m,
            "ate_max_m": self.ate_max_m,
            "rpe_100m": self.rpe_100m,
            "rpe_1s": self.rpe_1s,
            "drift": self.drift,
            "gt_world_from_est_world": self.alignment.to_json_dict(),
            **self.extra,
        }


def evaluate_odometry(
    est: Sequence[Rigid3],
    gt: Sequence[Rigid3],
    timestamps_s: np.ndarray | None = None,
    with_scale: bool = False,
    lengths_m: Sequence[float] = DRIFT_LENGTHS_M,
) -> OdometryMetrics:
    """ATE, RPE per 100 m and per second (when timestamps are given) and KITTI drift of ``est``
    against ``gt`` (both per-frame ``world_from_left``, associated one to one)."""
    _check(est, gt)
    rmse, err, T = ate_rmse(est, gt, with_scale)
    rpe_s = (
        relative_pose_error(est, gt, 1.0, "s", timestamps_s)
        if timestamps_s is not None
        else {
            "delta": 1.0,
            "unit": "s",
            "pairs": 0,
            "trans_rmse_m": None,
            "trans_mean_m": None,
            "rot_mean_deg": None,
        }
    )
    return OdometryMetrics(
        frames=len(est),
        path_length_m=float(path_length(gt)[-1]),
        ate_rmse_m=rmse,
        ate_max_m=float(err.max()),
        ate_errors_m=err,
        alignment=T,
        rpe_100m=relative_pose_error(est, gt, 100.0, "m"),
        rpe_1s=rpe_s,
        drift=kitti_drift(est, gt, lengths_m),
        with_scale=with_scale,
    )
