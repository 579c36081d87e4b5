"""The ground as a plane in the camera's frame, and its disparity in a rectified rig.

A drone knows which way is up (its attitude) and, once it has measured some of the ground,
how high the ground lies (:class:`skyrecon.mapping.ground_level.GroundLevel`). That fixes the ground as a
plane in the left camera's frame, and in a rectified rig a plane's disparity is an affine
function of the pixel, ``d(u, v) = a u + b v + c``. The stereo stage uses it as a prior plane
for plain ground that its own border does not fix (a field or a road running out of the image
and up to the horizon; see :func:`skyrecon.stereo.plane_supported_fill`).

Frames and units: camera frame x right, y down, z forward (optical axis); metres; disparity
``d = f B / Z - doffs`` pixels, ``x_right = x_left - d``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from skyrecon.core.rigid import Rigid3
from skyrecon.core.stereo_rig import StereoRig

_UP = np.array([0.0, 0.0, 1.0])  # world z up


@dataclass(frozen=True)
class GroundPlane:
    """The ground seen from one camera pose.

    Attributes:
        up_cam: (3,) unit vector of the world's up direction in the camera frame.
        height_m: the camera's height above the ground, metres (> 0).
    """

    up_cam: np.ndarray
    height_m: float

    @classmethod
    def from_pose(cls, world_from_cam: Rigid3, ground_z_m: float) -> GroundPlane | None:
        """The ground at world height ``ground_z_m`` (metres) seen from ``world_from_cam``
        (``p_world = R p_cam + t``); None when the camera is not above it."""
        pose = world_from_cam
        height = float(pose.t[2]) - float(ground_z_m)
        if not height > 0:
            return None
        return cls(pose.R.T @ _UP, height)

    def disparity_coefficients(self, rig: StereoRig, stride: int = 1) -> tuple[float, float, float]:
        """``(a, b, c)`` of the ground's disparity ``d = a u + b v + c`` on the pixel grid
        ``[::stride, ::stride]`` of the left image, in pixels of that grid (full-resolution
        disparity divided by ``stride``): ``u, v`` are that grid's column and row. Positive
        below the ground's horizon; above it the ground is not in view.

        From ``Z = -h / (up . r)`` along the ray ``r = ((u - cx) / fx, (v - cy) / fy, 1)``
        (skew ignored) and ``d = f B / Z - doffs``."""
        K = rig.left
        nx, ny, nz = (float(x) for x in self.up_cam)
        fb = K.fx * rig.baseline_m / self.height_m  # f B / h, pixels
        a = -fb * nx / K.fx
        b = -fb * ny / K.fy
        c = -fb * (nz - nx * K.cx / K.fx - ny * K.cy / K.fy) - rig.doffs_px
        k = int(stride)
        return a, b, c / k


@njit(cache=True, nogil=True)
def _runs_below(seed, inside, out):  # pragma: no cover - compiled
    """Down each column: ``out`` True on the pixels of ``inside`` whose run (the unbroken
    stretch of ``inside`` pixels in the column) has a ``seed`` pixel at or above them, the run's
    first pixel included when the pixel just above the run is a seed."""
    H, W = inside.shape
    for c in range(W):
        on = False
        for r in range(H):
            if inside[r, c]:
                on = on or seed[r, c]
                out[r, c] = on
            else:
                on = seed[r, c]


def below_raised(raised: np.ndarray, inside: np.ndarray, holes_px: int = 0, aside_px: int = 0) -> np.ndarray:
    """(H, W) bool: the pixels of ``inside`` ((H, W) bool: the pixels taken for the ground)
    that lie straight below a pixel of ``raised`` ((H, W) bool: measured nearer than the ground)
    in the same column, with nothing but ``inside`` pixels between them.

    A plain roof or platform whose edge with the ground beyond it vanished under noise joins
    the ground's segment; seen from above, its top lies below (nearer than) its far edge in
    the image, and that edge, where measured, is nearer than the ground there. Everything of
    the segment straight below it is then possibly that top, not ground. Below a building's
    roof line its facade (not ground) stops the run; beside a wall's vertical edge only a
    strip of its own width is lost. ``holes_px``: gaps in ``inside`` up to this wide (a
    morphological closing; the specks a noisy matcher measures inside a plain segment) do not
    break a run. ``aside_px``: the pixels of ``inside`` up to this far beside those along the
    same row are taken too (a top's far edge is measured in pieces, least near its corners,
    and its sides not at all: they border ground beyond, as the ground would)."""
    seed = np.ascontiguousarray(raised, dtype=np.bool_)
    ins = np.ascontiguousarray(inside, dtype=np.bool_)
    runs = ins
    if holes_px > 0:
        kernel = np.ones((holes_px + 1, holes_px + 1), np.uint8)
        runs = cv2.morphologyEx(ins.view(np.uint8), cv2.MORPH_CLOSE, kernel).view(np.bool_)
    out = np.zeros(ins.shape, np.bool_)
    _runs_below(seed, runs, out)
    if aside_px > 0:
        out = cv2.dilate(out.view(np.uint8), np.ones((1, 2 * aside_px + 1), np.uint8)).view(np.bool_)
    return out & ins


def warm_kernels() -> None:
    """Compile (or load from the cache) :func:`below_raised`'s kernels on a tiny input, so the
    first noisy frame of a flight does not."""
    tiny = np.zeros((4, 4), np.bool_)
    tiny[1:, 1:3] = True
    below_raised(tiny[::-1].copy(), tiny, holes_px=2)
