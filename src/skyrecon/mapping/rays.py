"""Camera ray directions, computed once per camera and pixel step and shared.

The map's per-frame stages (:class:`~skyrecon.mapping.frame_support.FrameSupport`,
:class:`~skyrecon.mapping.ground_level.GroundLevel`) need the ray of every (or every k-th) pixel
of the same camera in every frame; they ask here instead of each keeping its own copy.

Frames and units: camera frame (x right, y down, z forward), directions with z = 1.
"""

from __future__ import annotations

import numpy as np

from skyrecon.core.intrinsics import Intrinsics

_CACHE: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
_MAX_CAMERAS = 8


def camera_rays(intrinsics: Intrinsics, step: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Ray directions of every ``step``-th pixel of each row and column, and their lengths.

    Args:
        intrinsics: the camera.
        step: pixel step (1: every pixel).
    Returns:
        ``(dirs, lengths)``: (H', W', 3) float64 directions with z = 1 and (H', W') float64
        their Euclidean lengths (metres of range per metre of depth); read-only, shared
        between callers.
    """
    i = intrinsics
    key = (i.width, i.height, i.fx, i.fy, i.cx, i.cy, i.skew, tuple(np.ravel(i.dist)), int(step))
    rays = _CACHE.get(key)
    if rays is None:
        dirs = np.ascontiguousarray(i.ray_directions()[::step, ::step], dtype=np.float64)
        lengths = np.linalg.norm(dirs, axis=2)
        dirs.flags.writeable = False
        lengths.flags.writeable = False
        if len(_CACHE) >= _MAX_CAMERAS:
            _CACHE.clear()
        rays = _CACHE[key] = (dirs, lengths)
    return rays
