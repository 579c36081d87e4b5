"""Test helper: how far the rays of depth-grid pixels reach in the true city."""

from __future__ import annotations

import numpy as np

from skyrecon.core import Rigid3, StereoRig
from skyrecon.sim import City


def true_reach(
    city: City, rig: StereoRig, cam_from_world: Rigid3, v: np.ndarray, u: np.ndarray, stride: int = 2
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For pixels (v, u) of the depth grid ``[::stride, ::stride]`` of ``rig.left`` seen from
    ``cam_from_world``: (N,) metres to the first true surface along each ray (inf: none), the
    camera's world position (3,) and the (N, 3) world ray directions (z = 1 in the camera)."""
    K = rig.left
    rays = np.stack([(stride * u - K.cx) / K.fx, (stride * v - K.cy) / K.fy, np.ones(len(u))], axis=1)
    world_from_cam = cam_from_world.inverse()
    dirs = rays @ world_from_cam.R.T
    return city.raycast(world_from_cam.t[None], dirs), world_from_cam.t, dirs
