"""Rectification of a calibrated stereo rig (lens distortion, arbitrary relative pose).

:func:`rectify_rig` turns a :class:`~skyrecon.core.StereoRig` with intrinsics, distortion and
``right_from_left`` into remapping tables for both images (``cv2.stereoRectify`` +
``cv2.initUndistortRectifyMap``), the rectified rig and its Q matrix. After
:meth:`RigRectification.apply`, rows are epipolar lines and a left pixel ``(x, y)`` matches the
right pixel ``(x - d, y)``.

The rectified left camera is rotated with respect to the original one: points computed from
rectified disparities live in the *rectified* left frame; ``left_rect_from_left`` maps
between the two.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError

__all__ = ["RigRectification", "rectify_rig"]


@dataclass
class RigRectification:
    """Maps from an original (calibrated, possibly distorted) stereo pair to a rectified one.

    Not to be confused with :class:`skyrecon.geometry.Rectification`, the rectifying
    homographies of an arbitrary uncalibrated image pair.

    Attributes:
        rig: the rectified rig (no distortion, pure x baseline, ``rig.Q`` valid).
        original: the rig that was rectified.
        left_rect_from_left, right_rect_from_right: rotations from the original camera frames
            to the rectified ones (identity when no rectification was needed).
        map_left, map_right: ``(map1, map2)`` remap tables for ``cv2.remap`` (fixed-point
            CV_16SC2 + CV_16UC1), or None when the rig was already rectified.
        roi_left, roi_right: ``(x, y, w, h)`` of the all-valid region in each rectified image.
        Q: (4, 4) disparity-to-depth matrix of the rectified rig:
            ``[X Y Z W]^T = Q [u v d 1]^T`` in the rectified left frame.
    """

    rig: StereoRig
    original: StereoRig
    left_rect_from_left: Rigid3
    right_rect_from_right: Rigid3
    map_left: tuple[np.ndarray, np.ndarray] | None
    map_right: tuple[np.ndarray, np.ndarray] | None
    roi_left: tuple[int, int, int, int]
    roi_right: tuple[int, int, int, int]
    Q: np.ndarray

    @property
    def is_identity(self) -> bool:
        """True when the input rig was already rectified and images pass through unchanged."""
        return self.map_left is None

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the rectified images."""
        return self.rig.left.size

    def _check(self, image: np.ndarray, which: str) -> None:
        if not isinstance(image, np.ndarray) or image.ndim not in (2, 3):
            raise InputError(f"the {which} image must be an (H, W) or (H, W, C) array")
        intr = self.original.left if which == "left" else self.original.right
        intr.check_image(image, f"the {which} image")

    def apply_left(self, image: np.ndarray, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
        """Rectify a left image (H, W[, C]) of the original left camera's size."""
        self._check(image, "left")
        if self.map_left is None:
            return image
        return cv2.remap(
            image, self.map_left[0], self.map_left[1], interpolation, borderMode=cv2.BORDER_CONSTANT
        )

    def apply_right(self, image: np.ndarray, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
        """Rectify a right image (H, W[, C]) of the original right camera's size."""
        self._check(image, "right")
        if self.map_right is None:
            return image
        return cv2.remap(
            image, self.map_right[0], self.map_right[1], interpolation, borderMode=cv2.BORDER_CONSTANT
        )

    def apply(
        self, left: np.ndarray, right: np.ndarray, interpolation: int = cv2.INTER_LINEAR
    ) -> tuple[np.ndarray, np.ndarray]:
        """Rectify a pair: ``(left_rect, right_rect)``, each of :attr:`size`.

        Images keep their dtype and channels; pixels that fall outside the source are 0.
        Already-rectified rigs return the inputs unchanged.
        """
        return self.apply_left(left, interpolation), self.apply_right(right, interpolation)


def _roi(roi: Sequence[float]) -> tuple[int, int, int, int]:
    """OpenCV's ``(x, y, w, h)`` region as four ints, pixels."""
    x, y, w, h = (int(v) for v in roi)
    return x, y, w, h


def rectify_rig(
    rig: StereoRig, alpha: float = 0.0, zero_disparity: bool = True, new_size: tuple[int, int] | None = None
) -> RigRectification:
    """Rectify a calibrated stereo rig.

    Args:
        rig: both cameras' intrinsics (with distortion) and ``right_from_left``; the right
            camera must lie to the right of the left one (mostly along +x).
        alpha: OpenCV's free scaling: 0 keeps only valid pixels (zoomed in), 1 keeps every
            source pixel (black borders), -1 lets OpenCV choose.
        zero_disparity: give both rectified cameras the same principal point (points at
            infinity have disparity 0); otherwise ``doffs = cx_right - cx_left`` may be
            non-zero and is carried by the rectified rig.
        new_size: (width, height) of the rectified images; default the left image size.
    Returns:
        RigRectification; for an already-rectified rig the identity (no remapping).
    Raises:
        InputError: different image sizes, a mostly vertical baseline, or the right camera
            on the left.
    """
    if rig.is_rectified:
        eye = Rigid3(np.eye(3), np.zeros(3))
        W, H = rig.left.size
        return RigRectification(rig, rig, eye, eye, None, None, (0, 0, W, H), (0, 0, W, H), rig.Q)
    if rig.left.size != rig.right.size:
        raise InputError(
            f"the left camera is {rig.left.width}x{rig.left.height} but the right one is "
            f"{rig.right.width}x{rig.right.height}; rectification needs equal image sizes"
        )
    if not (np.isfinite(alpha) and -1.0 <= alpha <= 1.0):
        raise InputError(f"alpha must be in [-1, 1], got {alpha}")
    size = rig.left.size
    out_w, out_h = (int(v) for v in (new_size or size))
    out_size = (out_w, out_h)
    if out_size[0] <= 0 or out_size[1] <= 0:
        raise InputError(f"new_size must be positive, got {new_size}")
    R = rig.right_from_left.R
    t = rig.right_from_left.t.reshape(3, 1)
    if np.linalg.norm(t) <= 0:
        raise InputError("the stereo baseline is zero; the cameras must be apart")
    if abs(t[1, 0]) > abs(t[0, 0]):
        raise InputError(
            "the baseline is mostly vertical; only side-by-side rigs are supported (rotate the images 90 degrees)"
        )
    R1, R2, P1, P2, Q, roi1, roi2 = cv2.stereoRectify(
        rig.left.K,
        rig.left.dist,
        rig.right.K,
        rig.right.dist,
        size,
        R,
        t,
        flags=cv2.CALIB_ZERO_DISPARITY if zero_disparity else 0,
        alpha=float(alpha),
        newImageSize=out_size,
    )
    Tx = P2[0, 3] / P2[0, 0]  # = -baseline for a right camera on the right
    if Tx >= 0:
        raise InputError(
            "the right camera lies to the left of the left camera; swap the two images and cameras"
        )
    map_l = cv2.initUndistortRectifyMap(rig.left.K, rig.left.dist, R1, P1[:, :3], out_size, cv2.CV_16SC2)
    map_r = cv2.initUndistortRectifyMap(rig.right.K, rig.right.dist, R2, P2[:, :3], out_size, cv2.CV_16SC2)
    W, H = out_size
    left = Intrinsics.from_K(P1[:, :3], W, H)
    right = Intrinsics.from_K(P2[:, :3], W, H)
    rect = StereoRig(left, right, Rigid3(np.eye(3), np.array([Tx, 0.0, 0.0])))
    return RigRectification(
        rect,
        rig,
        Rigid3(R1, np.zeros(3)),
        Rigid3(R2, np.zeros(3)),
        map_l,
        map_r,
        _roi(roi1),
        _roi(roi2),
        rect.Q,
    )
