"""Views at the working resolution: the image data every MVS stage reads.

A :class:`WorkingView` is one input view resized so that its longer side is at most
``max_image_size`` pixels, with its intrinsics scaled to match (pixel-centre convention kept)
and its pose unchanged. Depth maps, fusion and colours all live at this resolution.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from skyrecon.core import Intrinsics, PosedView, Rigid3
from skyrecon.errors import InputError

__all__ = ["WorkingView", "make_working_view", "working_scale"]


@dataclass
class WorkingView:
    """One view at the working resolution.

    Attributes:
        name: the view's name (its image file name).
        intrinsics: camera at the working resolution (no distortion).
        cam_from_world: pose, world -> camera, metres.
        rgb: (H, W, 3) uint8 RGB (grey inputs are repeated into three channels).
        grey: (H, W) float32 grey levels in 0..255 (ITU-R 601 luma of ``rgb``).
        valid: (H, W) bool, False where the image has no data (alpha 0).
        scale: working size / input size (1.0 when not resized).
    """

    name: str
    intrinsics: Intrinsics
    cam_from_world: Rigid3
    rgb: np.ndarray
    grey: np.ndarray
    valid: np.ndarray
    scale: float = 1.0

    @property
    def center_world(self) -> np.ndarray:
        """(3,) camera centre in the world frame, metres."""
        return self.cam_from_world.center

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the working images."""
        h, w = self.grey.shape
        return h, w

    @property
    def stem(self) -> str:
        """The name without its extension (``image_camera01.png`` -> ``image_camera01``)."""
        return self.name.rsplit(".", 1)[0] if "." in self.name else self.name

    def posed(self) -> PosedView:
        """This view as a :class:`PosedView` with the working-resolution intrinsics."""
        return PosedView(self.name, self.intrinsics, self.cam_from_world)


def working_scale(width: int, height: int, max_image_size: int | None) -> float:
    """Scale factor that brings the longer side to at most ``max_image_size`` (never upscales)."""
    if not max_image_size or max(width, height) <= max_image_size:
        return 1.0
    return float(max_image_size) / max(width, height)


def make_working_view(
    view: PosedView, image: np.ndarray, alpha: np.ndarray | None, max_image_size: int | None
) -> WorkingView:
    """Resize one input image (and its alpha) to the working resolution.

    Args:
        view: the camera and pose; ``view.intrinsics`` must match the image size and have no
            lens distortion (undistort first).
        image: (H, W) grey or (H, W, 3) RGB uint8 at the camera's resolution.
        alpha: (H, W) uint8/bool, 0 where there is no data, or None.
        max_image_size: longer side of the working images, pixels (None: keep the size).
    Raises:
        InputError: size mismatch, wrong dtype/shape, lens distortion.
    """
    if not isinstance(image, np.ndarray) or image.ndim not in (2, 3):
        raise InputError(f"view {view.name}: the image must be an (H, W) or (H, W, 3) array")
    if image.ndim == 3 and image.shape[2] == 4:
        if alpha is None:
            alpha = image[..., 3]
        image = image[..., :3]
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[..., 0]
    if image.ndim == 3 and image.shape[2] != 3:
        raise InputError(f"view {view.name}: image has {image.shape[2]} channels; expected 1 or 3")
    if image.dtype != np.uint8:
        raise InputError(f"view {view.name}: image dtype is {image.dtype}; expected uint8 (8-bit) images")
    intr = view.intrinsics
    h, w = image.shape[:2]
    if (w, h) != (intr.width, intr.height):
        raise InputError(
            f"view {view.name}: the image is {w}x{h} but its camera is calibrated for "
            f"{intr.width}x{intr.height}; use the images the cameras were calibrated for"
        )
    if intr.has_distortion:
        raise InputError(
            f"view {view.name}: lens distortion is not supported by MVS; undistort the images first"
        )
    s = working_scale(w, h, max_image_size)
    rgb = image if image.ndim == 3 else np.repeat(image[..., None], 3, axis=2)
    valid = np.ones((h, w), bool) if alpha is None else np.asarray(alpha) > 0
    if s != 1.0:
        k = intr.scaled(s)
        size = (k.width, k.height)
        rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
        valid = cv2.resize(valid.astype(np.uint8) * 255, size, interpolation=cv2.INTER_AREA) >= 255
        intr = k
    grey = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY).astype(np.float32)
    return WorkingView(view.name, intr, view.cam_from_world, np.ascontiguousarray(rgb), grey, valid, s)
