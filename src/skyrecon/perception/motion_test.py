"""The motion test: depth points whose image patch the previous frame does not show where a
static point would have been.

The mover detector's free-space test (:func:`skyrecon.perception.movers.detect_movers`) needs
the static map to have seen a point's space free; beyond the map's hit range (17 m for the
flight rig) it has seen nothing, and inside it an undetected mover paints its own voxels
occupied before it is found (``benchmarks/dynamic/probe_free_space.py``: no mover found beyond
14 m). This test needs no map, only the previous frame and the camera's own motion:

Every pixel of this frame with a depth (and the sky, at infinity) is carried back into the
previous image as if it stood still: back-projected with its depth, moved into the previous
camera, projected (one ``cv2.remap`` of the previous image). Where the world stood still the
carried image is this one, up to the depth's error. A mover's pixels are not: the previous
image shows, where a static point would have been, what lay there before the mover came.
Around each point, the ``patch_px`` square of this image is compared with the carried one,
each with its own mean removed (brightness), shifted by up to ``slack_px`` (the depth's error
and the interpolation), as the mean absolute difference relative to the patch's own contrast
(its mean absolute deviation): near 0 it is the same patch, near 1 or above another. Each pixel
of a patch is carried with its own depth, so the background around a small far drone lines up
and only the drone does not.

Not compared: pixels the previous view could not have seen (carried out of its image, or its
depth there, the 3x3 nearest, nearer than the pixel's by the see-through margin: hidden then,
or newly uncovered now), pixels without depth, and patches with fewer than a third of their
pixels left or of too little contrast (a plain surface looks the same anywhere).

Frames and units: images grey 0-255 on the depth grid (the depth's (H, W)), pixels (u, v) =
(column, row); poses ``world_from_cam`` (OpenCV camera: x right, y down, z forward); metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError
from skyrecon.stereo.base import to_grey


def grid_scale(image: np.ndarray, depth_shape: tuple[int, int], what: str) -> int:
    """The whole number k with ``image`` ((kH, kW) grey or (kH, kW, 3) RGB) k times the depth
    grid ``depth_shape`` (H, W) on each side.

    Raises:
        InputError: it is not (named by ``what``, the stage that was given it).
    """
    H, W = depth_shape
    k = image.shape[0] // H
    if image.ndim not in (2, 3) or k < 1 or image.shape[0] != k * H or image.shape[1] != k * W:
        raise InputError(
            f"{what}: image {image.shape[:2]} must be a whole multiple of the depth {depth_shape}"
        )
    return k


#: the grey images are blurred by this much (Gaussian sigma, depth-grid pixels) before they are
#: compared: what is left of a static patch's misplacement after the shifts (up to half a
#: pixel) then changes it little, while a mover's several pixels still do
BLUR_SIGMA_PX = 1.0


@dataclass(frozen=True)
class MotionView:
    """One frame as the motion test needs it.

    Attributes:
        time_s: its time, seconds.
        grey: (H, W) float32 grey image (0-255) on the depth grid, blurred (:data:`BLUR_SIGMA_PX`).
        depth_m: (H, W) float32 depth, metres (NaN invalid, inf no return).
        nearest_m: (H, W) float32, per pixel the nearest valid depth in its 3x3 neighbourhood,
            metres (inf where none: nothing known to be nearer).
        intrinsics: the depth grid's camera (pinhole).
        world_from_cam: its pose.
    """

    time_s: float
    grey: np.ndarray
    depth_m: np.ndarray
    nearest_m: np.ndarray
    intrinsics: Intrinsics
    world_from_cam: Rigid3

    @classmethod
    def of(
        cls,
        time_s: float,
        image: np.ndarray,
        depth_m: np.ndarray,
        intrinsics: Intrinsics,
        world_from_cam: Rigid3,
    ) -> MotionView:
        """From the left image ((kH, kW) grey or (kH, kW, 3) uint8 RGB, k a whole number) and the
        depth (H, W) metres (NaN invalid, inf no return) matched from it."""
        d = np.ascontiguousarray(depth_m, np.float32)
        H, W = d.shape
        img = np.asarray(image)
        k = grid_scale(img, (H, W), "motion test")
        grey: np.ndarray = to_grey(img).astype(np.float32)
        if k > 1:
            grey = cv2.resize(grey, (W, H), interpolation=cv2.INTER_AREA)
        grey = cv2.GaussianBlur(grey, (0, 0), BLUR_SIGMA_PX)
        seen = np.where(np.isnan(d) | (d <= 0), np.float32(np.inf), d)
        nearest = cv2.erode(seen, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE)
        return cls(float(time_s), np.ascontiguousarray(grey), d, nearest, intrinsics, world_from_cam)


def mismatch_ratio(
    now: MotionView,
    previous: MotionView,
    behind_m: float,
    noise_frac: float,
    min_contrast: float,
    patch_px: int = 5,
    slack_px: int = 1,
) -> np.ndarray:
    """(H, W) float32 on ``now``'s depth grid: per pixel, the smallest mean absolute difference
    between its ``patch_px`` square of ``now.grey`` and of the previous image carried to this
    frame as a still world (each with its mean removed; the carried one shifted by up to
    ``slack_px``), over the patch's mean absolute deviation; NaN where not compared (see the
    module's docstring; ``min_contrast`` grey levels: the least deviation compared). A pixel is
    hidden from the previous view when that view's depth where it lands is nearer than the
    pixel's by more than ``behind_m + noise_frac * depth``, metres."""
    d = now.depth_m
    H, W = d.shape
    cam = now.intrinsics
    with np.errstate(invalid="ignore"):
        finite = np.isfinite(d) & (d > 0)
        sky = np.isinf(d) & (d > 0)
    u = (np.arange(W, dtype=np.float32) - np.float32(cam.cx)) / np.float32(cam.fx)
    v = (np.arange(H, dtype=np.float32) - np.float32(cam.cy)) / np.float32(cam.fy)
    rel = previous.world_from_cam.inverse() @ now.world_from_cam  # previous camera from this one
    R = rel.R.astype(np.float32)
    t = rel.t.astype(np.float32)
    scale = np.where(finite, d, np.float32(1.0))
    ray = (u[None, :, None] * R[:, 0] + v[:, None, None] * R[:, 1] + R[:, 2]).astype(np.float32)  # (H, W, 3)
    q = ray * scale[..., None] + np.where(finite, np.float32(1.0), np.float32(0.0))[..., None] * t
    z = q[..., 2]
    ok = (finite | sky) & (z > 0.1)
    with np.errstate(invalid="ignore", divide="ignore"):
        map_x = np.where(
            ok, np.float32(previous.intrinsics.fx) * q[..., 0] / z + np.float32(previous.intrinsics.cx), -10
        )
        map_y = np.where(
            ok, np.float32(previous.intrinsics.fy) * q[..., 1] / z + np.float32(previous.intrinsics.cy), -10
        )
    map_x = map_x.astype(np.float32)
    map_y = map_y.astype(np.float32)
    h, w = previous.grey.shape
    inb = ok & (map_x >= 0) & (map_x <= w - 1) & (map_y >= 0) & (map_y <= h - 1)
    carried = cv2.remap(previous.grey, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    seen = cv2.remap(previous.nearest_m, map_x, map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    with np.errstate(invalid="ignore"):
        hidden = np.where(finite, seen < z - (behind_m + noise_frac * d), np.isfinite(seen))
    weight = (inb & ~hidden).astype(np.float32)
    n = int(patch_px)
    box = (n, n)

    def local_sum(x: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(x, -1, box, normalize=False, borderType=cv2.BORDER_CONSTANT)

    count = local_sum(weight)
    inv_count = 1.0 / np.maximum(count, 1)  # sums over nothing: 0, not NaN (it would spread)
    cur = now.grey
    zm_now = cur - local_sum(weight * cur) * inv_count  # this patch less its mean
    contrast = local_sum(weight * np.abs(zm_now)) * inv_count
    zm_carried = carried - local_sum(weight * carried) * inv_count
    best = np.full((H, W), np.inf, np.float32)
    s = int(slack_px)
    for dy in range(-s, s + 1):
        for dx in range(-s, s + 1):
            w2 = weight * _shift(weight, dy, dx)
            c2 = local_sum(w2)
            sad = local_sum(w2 * np.abs(zm_now - _shift(zm_carried, dy, dx))) / np.maximum(c2, 1)
            best = np.minimum(best, np.where(3 * c2 >= n * n, sad, np.float32(np.inf)))
    tested = (3 * count >= n * n) & (contrast >= min_contrast) & np.isfinite(best)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(tested, best / contrast, np.float32(np.nan)).astype(np.float32)


def _shift(img: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """``img`` (H, W) moved by (dy, dx) pixels (out[r, c] = img[r + dy, c + dx]; 0 beyond)."""
    if dy == 0 and dx == 0:
        return img
    out = np.zeros_like(img)
    H, W = img.shape
    out[max(0, -dy) : H - max(0, dy), max(0, -dx) : W - max(0, dx)] = img[
        max(0, dy) : H - max(0, -dy), max(0, dx) : W - max(0, -dx)
    ]
    return out


def moved(
    now: MotionView,
    previous: MotionView,
    rows: np.ndarray,
    cols: np.ndarray,
    min_ratio: float,
    min_contrast: float,
    behind_m: float,
    noise_frac: float,
    patch_px: int = 5,
    slack_px: int = 1,
) -> np.ndarray:
    """(N,) bool: the pixels ``rows``, ``cols`` (N,) of ``now``'s depth grid whose
    :func:`mismatch_ratio` is at least ``min_ratio`` (the previous image does not show their
    patch where a static point would have been)."""
    if len(rows) == 0:
        return np.zeros(0, bool)
    ratio = mismatch_ratio(now, previous, behind_m, noise_frac, min_contrast, patch_px, slack_px)
    with np.errstate(invalid="ignore"):
        return ratio[np.asarray(rows, np.intp), np.asarray(cols, np.intp)] >= min_ratio
