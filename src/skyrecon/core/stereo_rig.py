"""A calibrated stereo pair of cameras.

``right_from_left`` maps points from the left camera frame to the right one.
For a rectified rig it is a pure translation ``(-baseline, 0, 0)``, the two
cameras share fx = fy and cy, and a left pixel x matches right pixel
``x - d`` (disparity d).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError


@dataclass(frozen=True)
class StereoRig:
    """Two cameras and the transform between them.

    Attributes:
        left, right: intrinsics of each camera (same image size for a rectified rig).
        right_from_left: pose of the left frame in the right frame, metres.
    """

    left: Intrinsics
    right: Intrinsics
    right_from_left: Rigid3

    def __post_init__(self) -> None:
        object.__setattr__(self, "right_from_left", self.right_from_left.with_frames("right", "left"))

    # ----- construction -------------------------------------------------
    @classmethod
    def rectified(cls, left: Intrinsics, baseline_m: float, doffs_px: float = 0.0) -> StereoRig:
        """A rectified rig: the right camera sits ``baseline_m`` to the right of the left one.

        Args:
            left: intrinsics of the left camera (no distortion).
            baseline_m: distance between the optical centres, metres, > 0.
            doffs_px: ``cx_right - cx_left`` in pixels (Middlebury's doffs).
        """
        if not np.isfinite(baseline_m) or baseline_m <= 0:
            raise InputError(f"the stereo baseline must be positive, got {baseline_m}")
        right = Intrinsics(
            left.fx, left.fy, left.cx + doffs_px, left.cy, left.width, left.height, skew=left.skew
        )
        return cls(left, right, Rigid3(np.eye(3), np.array([-baseline_m, 0.0, 0.0])))

    @classmethod
    def from_projections(cls, P_left: np.ndarray, P_right: np.ndarray, width: int, height: int) -> StereoRig:
        """From two 3x4 projection matrices ``K [I | t]`` of a rectified pair (KITTI P2/P3).

        Both matrices map a common reference frame (KITTI's cam0) into each image;
        the rig keeps only the left-to-right transform.
        """
        P_left = np.asarray(P_left, dtype=np.float64).reshape(3, 4)
        P_right = np.asarray(P_right, dtype=np.float64).reshape(3, 4)
        K_left, K_right = P_left[:, :3], P_right[:, :3]
        t_left = np.linalg.solve(K_left, P_left[:, 3])
        t_right = np.linalg.solve(K_right, P_right[:, 3])
        left = Intrinsics.from_K(K_left, width, height)
        right = Intrinsics.from_K(K_right, width, height)
        return cls(left, right, Rigid3(np.eye(3), t_right - t_left))

    # ----- properties ----------------------------------------------------
    @property
    def baseline_m(self) -> float:
        """Distance between the two optical centres, metres."""
        return float(np.linalg.norm(self.right_from_left.t))

    @cached_property
    def is_rectified(self) -> bool:
        """True when the rig is row-aligned: no rotation, translation along x, same fy and cy
        (computed once: the rig is frozen, and every disparity-to-depth conversion asks)."""
        t = self.right_from_left.t
        return bool(
            np.allclose(self.right_from_left.R, np.eye(3), atol=1e-9)
            and abs(t[1]) < 1e-9 * max(1.0, abs(t[0])) + 1e-12
            and abs(t[2]) < 1e-9 * max(1.0, abs(t[0])) + 1e-12
            and t[0] < 0
            and abs(self.left.fy - self.right.fy) < 1e-6
            and abs(self.left.fx - self.right.fx) < 1e-6
            and abs(self.left.cy - self.right.cy) < 1e-6
            and not self.left.has_distortion
            and not self.right.has_distortion
        )

    @property
    def doffs_px(self) -> float:
        """``cx_right - cx_left``, pixels: added to disparity before converting to depth."""
        return self.right.cx - self.left.cx

    @property
    def Q(self) -> np.ndarray:
        """(4, 4) disparity-to-depth matrix: ``[X Y Z W]^T = Q [u v d 1]^T`` in the left frame."""
        self._require_rectified()
        f, B = self.left.fx, self.baseline_m
        return np.array(
            [
                [1.0, 0.0, 0.0, -self.left.cx],
                [0.0, self.left.fx / self.left.fy, 0.0, -self.left.cy * self.left.fx / self.left.fy],
                [0.0, 0.0, 0.0, f],
                [0.0, 0.0, 1.0 / B, self.doffs_px / B],
            ]
        )

    def _require_rectified(self) -> None:
        if not self.is_rectified:
            raise InputError("this stereo rig is not rectified; rectify it first")

    # ----- conversions -------------------------------------------------------
    def disparity_to_depth(self, disparity_px: np.ndarray) -> np.ndarray:
        """Depth along the left optical axis from left disparity.

        Args:
            disparity_px: (H, W) float disparity, pixels, NaN where invalid.
        Returns:
            (H, W) float32 depth in metres, NaN where the disparity is invalid or
            ``d + doffs <= 0``.
        """
        self._require_rectified()
        d = np.asarray(disparity_px, dtype=np.float32) + np.float32(self.doffs_px)  # float32 throughout
        bad = ~(d > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.divide(np.float32(self.left.fx * self.baseline_m), d, out=d)
        depth[bad] = np.nan
        return depth

    def depth_to_disparity(self, depth_m: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`disparity_to_depth`: (H, W) metres -> (H, W) float32 pixels."""
        self._require_rectified()
        z = np.asarray(depth_m, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = self.left.fx * self.baseline_m / z - self.doffs_px
        d[~(z > 0)] = np.nan
        return d.astype(np.float32)
