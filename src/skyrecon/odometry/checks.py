"""Input sanity for the odometry: image shapes and types, and frames that carry no information
(black or near-constant, frozen: identical to the previous frame).
"""

from __future__ import annotations

import cv2
import numpy as np

from skyrecon.errors import InputError

__all__ = ["to_grey", "check_pair", "blank_reason", "is_frozen"]


def to_grey(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 grey from a (H, W) or (H, W, 3) uint8 RGB image (the same array when grey)."""
    if image.ndim == 2:
        return np.ascontiguousarray(image)
    return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)


def check_pair(left: np.ndarray, right: np.ndarray, width: int, height: int) -> None:
    """Raise :class:`InputError` unless ``left`` and ``right`` are uint8 images of the rig's size.

    Args:
        left, right: (H, W) grey or (H, W, 3) RGB uint8 images.
        width, height: the rig's image size, pixels.
    """
    for name, im in (("left", left), ("right", right)):
        if not isinstance(im, np.ndarray):
            raise InputError(f"the {name} image must be a numpy array, got {type(im).__name__}")
        if im.dtype != np.uint8:
            raise InputError(f"the {name} image must be uint8, got {im.dtype}")
        if not (im.ndim == 2 or (im.ndim == 3 and im.shape[2] == 3)):
            raise InputError(f"the {name} image must be (H, W) or (H, W, 3), got shape {im.shape}")
        if im.shape[:2] != (height, width):
            raise InputError(
                f"the {name} image is {im.shape[1]}x{im.shape[0]} but the rig is {width}x{height}"
            )


def blank_reason(grey: np.ndarray, min_std: float = 2.0, dark_mean: float = 10.0) -> str:
    """Why a grey frame carries no usable texture, or "" when it looks usable.

    Statistics on a 4x subsample (cheap): a frame darker than ``dark_mean`` with a standard
    deviation under ``min_std`` is black, any other frame under ``min_std`` is near-constant.
    """
    sub = grey[::4, ::4]
    mean, std = cv2.meanStdDev(sub)
    m, s = float(mean[0, 0]), float(std[0, 0])
    if s >= min_std:
        return ""
    if m < dark_mean:
        return f"black frame (mean {m:.1f}, std {s:.2f})"
    return f"near-constant frame (mean {m:.1f}, std {s:.2f})"


def is_frozen(grey: np.ndarray, previous: np.ndarray | None) -> bool:
    """True when ``grey`` is byte-identical to the previous (H, W) uint8 frame given."""
    return previous is not None and previous.shape == grey.shape and bool(np.array_equal(grey, previous))
