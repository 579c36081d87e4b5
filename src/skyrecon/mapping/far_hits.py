"""Far hits confirmed by the frame before: a far obstacle only where two frames see it.

Stereo depth error grows with the square of the range. Far out (beyond ``min_range_m``, up to
the map's hit range) a camera's noise on a plain surface passes the texture test here and there
and matches at a random disparity: a speck of a few pixels metres in front of the true surface.
One such hit makes an unknown voxel occupied (OctoMap's ``l_hit`` 0.85 against ``l_miss``
-0.4: even a voxel seen free twice turns occupied), and when the drone never looks through that
voxel again the phantom stays, in the air beside the goal or the path (noisy plain delivery seed
11: five one-frame hits at 15-17 m, 1-3 m from the goal, each made by one frame, and the goal
"too close" to them for every plan).

A real surface is there in the next frame too; noise is not. :class:`FarHitFilter` keeps a far
pixel only where the previous frame's depth, at the pixel the point reprojects to (or one of its
eight neighbours), lies within the depth a disparity error of ``disparity_tol_px`` allows
(``range^2 * tol / (f B)``, at least ``min_tol_m``); the others only carve free space in front
of their point (``OccupancyMap.integrate_depth(carve_only=...)``): no hit. (Leaving them out
altogether took the free space in front of far plain surfaces away too: plain delivery seed 9
never saw its first metres of path free and returned.) A
real far obstacle is in the map one frame later (0.1 s at 10 Hz, 0.6 m of flight at 6 m/s,
with more than 8 m still between them). Pixels nearer than ``min_range_m`` and +inf (open air)
are kept as they are.

Frames and units: depth (h, w) float32 metres along the camera's optical axis, NaN none, +inf
open air; poses ``world_from_cam`` (world frame, z up, metres); seconds.
"""

from __future__ import annotations

import cv2
import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError
from skyrecon.mapping.rays import camera_rays

#: a previous frame older than this (seconds) confirms nothing (a gap: the sensor dropped frames)
MAX_AGE_S = 0.35


class FarHitFilter:
    """Keeps a far depth pixel only where the frame before saw a surface there too.

    Args:
        min_range_m: pixels at this Euclidean range or farther need confirmation, metres ...
        max_range_m: ... up to this one (the map's hit range: farther depth marks no obstacle
            anyway); None: no limit.
        focal_baseline_px_m: the rig's ``f B`` (full-resolution focal length in pixels times
            the baseline in metres): the depth error of a disparity error ``e`` at range ``z``
            is ``z^2 e / (f B)``.
        disparity_tol_px: the disparity error two frames may differ by, full-resolution pixels.
        min_tol_m: the least depth tolerance, metres (a voxel: the depth that hits one voxel).
        max_age_s: a previous frame older than this confirms nothing.
    """

    def __init__(
        self,
        min_range_m: float,
        focal_baseline_px_m: float,
        max_range_m: float | None = None,
        disparity_tol_px: float = 1.0,
        min_tol_m: float = 0.5,
        max_age_s: float = MAX_AGE_S,
    ):
        if not min_range_m > 0 or not focal_baseline_px_m > 0 or not disparity_tol_px > 0:
            raise InputError(
                "the far-hit filter needs a positive range, f*B and disparity tolerance, got "
                f"{min_range_m} m, {focal_baseline_px_m} px m, {disparity_tol_px} px"
            )
        self.min_range_m = float(min_range_m)
        self.max_range_m = np.inf if max_range_m is None else float(max_range_m)
        self.fb = float(focal_baseline_px_m)
        self.disparity_tol_px = float(disparity_tol_px)
        self.min_tol_m = float(min_tol_m)
        self.max_age_s = float(max_age_s)
        self._prev: tuple[float, np.ndarray, np.ndarray, Intrinsics, Rigid3] | None = None
        self.last_dropped = 0  # far pixels the last call took out
        self.last_far = 0  # far pixels the last call looked at

    def reset(self) -> None:
        """Forget the previous frame."""
        self._prev = None

    def unconfirmed(
        self, depth_m: np.ndarray, intrinsics: Intrinsics, world_from_cam: Rigid3, time_s: float
    ) -> np.ndarray:
        """(h, w) bool: the far pixels of ``depth_m`` the previous frame does not confirm (for the
        map: free space in front of them, no hit, ``integrate_depth(carve_only=mask)``).
        ``depth_m`` is remembered, as it is, for the next frame.

        Args:
            depth_m: (h, w) float32 depth along the optical axis, metres (NaN none, +inf open air).
            intrinsics: the camera of ``depth_m``.
            world_from_cam: the camera's pose.
            time_s: the frame's time, seconds.
        """
        depth = np.asarray(depth_m)
        if depth.shape != (intrinsics.height, intrinsics.width):
            raise InputError(
                f"depth image {depth.shape} does not match the camera ({intrinsics.height}, {intrinsics.width})"
            )
        dirs, lengths = camera_rays(intrinsics)
        with np.errstate(invalid="ignore"):
            rng = depth * lengths  # Euclidean range
            far = np.isfinite(rng) & (rng >= self.min_range_m) & (rng <= self.max_range_m)
        self.last_far = int(np.count_nonzero(far))
        drop = far
        if self.last_far:
            drop = far.copy()
            drop[far] = ~self._confirmed(depth, far, dirs, world_from_cam, float(time_s))
        self.last_dropped = int(np.count_nonzero(drop))
        lo, hi = _neighbourhood_bounds(depth)
        self._prev = (float(time_s), lo, hi, intrinsics, world_from_cam)
        return drop

    def _confirmed(
        self,
        depth: np.ndarray,
        far: np.ndarray,
        dirs: np.ndarray,
        world_from_cam: Rigid3,
        time_s: float,
    ) -> np.ndarray:
        """(K,) bool for the K ``far`` pixels (their rays ``dirs`` (h, w, 3), z = 1): the previous
        frame saw a surface at their point."""
        k = int(np.count_nonzero(far))
        if self._prev is None:
            return np.zeros(k, bool)
        t_prev, lo, hi, cam_prev, pose_prev = self._prev
        if not 0.0 <= time_s - t_prev <= self.max_age_s:
            return np.zeros(k, bool)
        x_cam = dirs[far] * depth[far].astype(np.float64)[:, None]
        p = pose_prev.inverse().apply(world_from_cam.apply(x_cam))
        zp = p[:, 2]
        up, vp = np.rint(cam_prev.project(p)).T  # NaN behind the camera
        with np.errstate(invalid="ignore"):
            ok = (up >= 0) & (up < cam_prev.width) & (vp >= 0) & (vp < cam_prev.height)
        keep = np.zeros(k, bool)
        if not ok.any():
            return keep
        ui, vi = up[ok].astype(np.int64), vp[ok].astype(np.int64)
        zz = zp[ok]
        tol = np.maximum(self.min_tol_m, zz * zz * self.disparity_tol_px / self.fb)
        keep[ok] = (zz >= lo[vi, ui] - tol) & (zz <= hi[vi, ui] + tol)
        return keep


def _neighbourhood_bounds(depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((h, w), (h, w)) float32: the least and greatest finite depth in each pixel's 3 x 3
    neighbourhood (+inf / -inf where none is finite), metres."""
    d = np.asarray(depth, np.float32)
    finite = np.isfinite(d)
    kernel = np.ones((3, 3), np.uint8)
    lo = cv2.erode(np.where(finite, d, np.float32(np.inf)), kernel, borderType=cv2.BORDER_REPLICATE)
    hi = cv2.dilate(np.where(finite, d, np.float32(-np.inf)), kernel, borderType=cv2.BORDER_REPLICATE)
    return lo, hi
