"""Checks and conversions of the inputs to the map: poses, depth images, point clouds."""

from __future__ import annotations

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError


def as_world_from_cam(pose: Rigid3 | np.ndarray, what: str = "pose") -> Rigid3:
    """A ``world_from_cam`` pose from a :class:`Rigid3` or a (4, 4) / (3, 4) matrix.

    Raises InputError for NaN or infinite values, a non-rotation, or a Rigid3 labelled
    ``cam_from_world`` (the classic inverted pose: pass ``pose.inverse()``).
    """
    if isinstance(pose, Rigid3):
        if pose.dst == "cam" and pose.src == "world":
            raise InputError(
                f"{what} is labelled cam_from_world but the map needs world_from_cam; pass pose.inverse()"
            )
        R, t = pose.R, pose.t
    else:
        M = np.asarray(pose, dtype=np.float64)
        if M.shape not in ((4, 4), (3, 4)):
            raise InputError(f"{what} must be a Rigid3 or a 4x4 / 3x4 matrix, got shape {M.shape}")
        R, t = M[:3, :3], M[:3, 3]
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise InputError(f"{what} contains NaN or infinite values; drop the frame or fix the pose")
    try:
        return Rigid3(R, t, "world", "cam")
    except InputError as e:
        raise InputError(f"{what}: {e}") from None


def check_depth(
    depth_m: np.ndarray, intrinsics: Intrinsics, max_plausible_m: float, what: str = "depth"
) -> np.ndarray:
    """The depth image as contiguous (H, W) float32 metres, after sanity checks.

    Raises InputError when the shape does not match the camera or when the depth is not
    plausibly in metres (median valid depth above ``max_plausible_m``: millimetres by mistake).
    """
    d = np.asarray(depth_m)
    if d.ndim != 2:
        raise InputError(f"{what} must be a 2-D (H, W) image, got shape {d.shape}")
    if not np.issubdtype(d.dtype, np.number):
        raise InputError(f"{what} must be numeric, got dtype {d.dtype}")
    intrinsics.check_image(d, what)
    d = np.ascontiguousarray(d, dtype=np.float32)
    sample = d[:: max(1, d.shape[0] // 64), :: max(1, d.shape[1] // 64)]
    with np.errstate(invalid="ignore"):
        valid = sample[np.isfinite(sample) & (sample > 0)]
    if valid.size and float(np.median(valid)) > max_plausible_m:
        raise InputError(
            f"{what}: median depth {float(np.median(valid)):.0f} is implausible in metres "
            f"(> {max_plausible_m:g} m); if the depth is in millimetres divide it by 1000"
        )
    return d


def check_points(points: np.ndarray, what: str = "points") -> np.ndarray:
    """(N, 3) float64 points; rows with NaN are dropped, other shapes raise InputError."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"{what} must have shape (N, 3), got {p.shape}")
    return p[np.all(np.isfinite(p), axis=1)]


def check_point3(p: np.ndarray, what: str) -> np.ndarray:
    """A (3,) float64 point; raises InputError for other shapes, NaN or infinity."""
    a = np.asarray(p, dtype=np.float64).reshape(-1)
    if a.shape != (3,):
        raise InputError(f"{what} must have 3 coordinates (x, y, z), got {a.size}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{what} contains NaN or infinite values: {a.tolist()}")
    return a
