"""Stereo rectification of two views: from the recovered pose (ours, or OpenCV's
``stereoRectify``) or from F alone (Hartley's method via ``stereoRectifyUncalibrated``).

Every method produces a :class:`Rectification`: for each rectified image a (3, 3) matrix ``M``
mapping *normalised, undistorted* camera coordinates of its source camera to rectified pixels
(homogeneous), so that one remapping routine (with lens distortion) and one triangulation routine
serve all methods. Rectified rows are epipolar lines; a left pixel ``(x, y)`` matches the right
pixel ``(x - d, y)`` for disparity ``d`` (DESIGN.md). The rectified *left* image is image 1 unless
``swapped`` (camera 2 lies to the left of camera 1), in which case it is image 2.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.errors import EstimationError, InputError
from skyrecon.geometry.epipolar import homogeneous
from skyrecon.geometry.triangulation import triangulate_midpoint

__all__ = [
    "RectificationMethod",
    "Rectification",
    "rectify_calibrated",
    "rectify_opencv",
    "rectify_uncalibrated",
    "rectify",
    "warp_images",
    "triangulate_disparity",
    "epipole_in_image",
]

RectificationMethod = Literal["calibrated", "opencv", "uncalibrated"]


@dataclass
class Rectification:
    """How two views map onto a rectified pair.

    Attributes:
        method: ``"calibrated"``, ``"opencv"`` or ``"uncalibrated"``.
        size: (width, height) of the rectified images, pixels.
        M_left, M_right: (3, 3) normalised source-camera coordinates -> rectified pixels.
        swapped: the rectified left image comes from image 2 (and the right from image 1).
        K: (3, 3) intrinsics of the rectified left camera (calibrated methods; None otherwise).
        doffs: ``cx_right - cx_left`` of the rectified cameras, pixels (calibrated methods).
        baseline: distance between the camera centres, in the units of t (calibrated methods).
        min_disparity, num_disparities: suggested disparity search range (pixels) from the
            sparse matches, or None when none were given.
    """

    method: str
    size: tuple[int, int]
    M_left: np.ndarray
    M_right: np.ndarray
    swapped: bool
    K: np.ndarray | None = None
    doffs: float = 0.0
    baseline: float | None = None
    min_disparity: int | None = None
    num_disparities: int | None = None

    def to_rectified(self, x1n: np.ndarray, x2n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised coordinates (N, 2) of images 1 and 2 -> rectified left and right pixels (N, 2)."""
        left, right = (x2n, x1n) if self.swapped else (x1n, x2n)
        return _apply(self.M_left, left), _apply(self.M_right, right)

    def from_rectified(self, q: np.ndarray, side: Literal["left", "right"]) -> np.ndarray:
        """Rectified pixels (N, 2) -> normalised coordinates (N, 2) of the source camera."""
        M = self.M_left if side == "left" else self.M_right
        return _apply(np.linalg.inv(M), q)


def _apply(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    p = homogeneous(np.asarray(x, np.float64)) @ M.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return p[:, :2] / p[:, 2:]


def _border(intr: Intrinsics, n: int = 16) -> np.ndarray:
    """(4n, 2) normalised coordinates of points along the image border (distortion removed)."""
    w, h = intr.width - 1.0, intr.height - 1.0
    s = np.linspace(0.0, 1.0, n)
    px = np.concatenate(
        [
            np.stack([s * w, 0 * s], 1),
            np.stack([s * w, 0 * s + h], 1),
            np.stack([0 * s, s * h], 1),
            np.stack([0 * s + w, s * h], 1),
        ]
    )
    return intr.normalized(px)


def epipole_in_image(
    R: np.ndarray, t: np.ndarray, intr1: Intrinsics, intr2: Intrinsics, margin: float = 0.0
) -> bool:
    """True when the epipole of either camera lies inside its image (grown by ``margin`` x size):
    the motion is mostly along the optical axis and planar rectification is ill-posed."""
    c2_in_1 = -np.asarray(R).T @ np.asarray(t)
    for intr, c in ((intr1, c2_in_1), (intr2, np.asarray(t, np.float64))):
        if abs(c[2]) < 1e-12:
            continue
        uv = intr.project((c if c[2] > 0 else -c)[None])[0]
        mx, my = margin * intr.width, margin * intr.height
        if -mx <= uv[0] <= intr.width - 1 + mx and -my <= uv[1] <= intr.height - 1 + my:
            return True
    return False


def _out_size(intr1: Intrinsics, scale: float) -> tuple[int, int]:
    if not (scale > 0 and np.isfinite(scale)):
        raise InputError(f"the rectification scale must be positive, got {scale}")
    return max(8, int(round(intr1.width * scale))), max(8, int(round(intr1.height * scale)))


def _disparity_range(d: np.ndarray, width: int, max_fraction: float = 0.5) -> tuple[int, int]:
    """(min_disparity, num_disparities) covering robust percentiles of sparse disparities d.

    The range spans the 1st to 99th percentile plus a margin; when that is wider than
    ``max_fraction`` of the image width (a block matcher then loses that share of the image),
    the far end (small disparities) is given up step by step, down to the 20th percentile.
    """
    d = d[np.isfinite(d)]
    num_max = max(16, width // 16 * 16)
    if len(d) < 5:
        return 0, int(min(num_max, 128))
    hi = float(np.percentile(d, 99.0))
    for p_lo in (1.0, 2.0, 5.0, 10.0, 20.0):
        lo = float(np.percentile(d, p_lo))
        span = hi - lo
        lo_i = int(np.floor(lo - 0.1 * span - 8))
        num = int(np.ceil((hi + 0.1 * span + 8 - lo_i) / 16.0)) * 16
        if num <= max_fraction * width:
            break
    return lo_i, int(max(16, min(num, num_max)))


def _finish(
    method: str,
    size: tuple[int, int],
    M_left: np.ndarray,
    M_right: np.ndarray,
    swapped: bool,
    K: np.ndarray | None,
    doffs: float,
    baseline: float | None,
    x1n: np.ndarray | None,
    x2n: np.ndarray | None,
) -> Rectification:
    rect = Rectification(method, size, M_left, M_right, swapped, K, doffs, baseline)
    if x1n is not None and x2n is not None and len(x1n) > 0:
        ql, qr = rect.to_rectified(x1n, x2n)
        rect.min_disparity, rect.num_disparities = _disparity_range(ql[:, 0] - qr[:, 0], size[0])
    return rect


def rectify_calibrated(
    intr1: Intrinsics,
    intr2: Intrinsics,
    R: np.ndarray,
    t: np.ndarray,
    scale: float = 1.0,
    x1n: np.ndarray | None = None,
    x2n: np.ndarray | None = None,
) -> Rectification:
    """Rectify from the relative pose (Fusiello-style common rotation, our own).

    The rectified x axis follows the baseline from the left to the right camera centre, y is the
    mean of the two cameras' y axes made orthogonal to it; both rectified cameras share f and
    cy. Camera 2 becomes the left image when it lies to the left of camera 1 (``swapped``).

    Args:
        intr1, intr2: full-resolution intrinsics of images 1 and 2.
        R, t: cam2_from_cam1 (|t| sets the baseline unit).
        scale: rectified pixel density relative to image 1 (output size = scale x size of image 1).
        x1n, x2n: optional (N, 2) normalised coordinates of inlier matches: used to place the
            principal points so that their disparities start near 0 and to suggest a range.
    Returns:
        Rectification with ``K`` and ``doffs`` set.
    Raises:
        EstimationError: zero baseline.
    """
    R = np.asarray(R, np.float64)
    t = np.asarray(t, np.float64).reshape(3)
    b = -R.T @ t  # camera-2 centre in camera-1 frame
    nb = np.linalg.norm(b)
    if nb < 1e-12:
        raise EstimationError("cannot rectify: the two camera centres coincide (no baseline)")
    x_avg = np.array([1.0, 0.0, 0.0]) + R.T @ np.array([1.0, 0.0, 0.0])
    swapped = bool(b @ x_avg < 0)
    e1 = (-b if swapped else b) / nb
    y_avg = np.array([0.0, 1.0, 0.0]) + R.T @ np.array([0.0, 1.0, 0.0])
    e2 = y_avg - (y_avg @ e1) * e1
    if np.linalg.norm(e2) < 1e-9:
        e2 = np.cross(np.array([0.0, 0.0, 1.0]), e1)
    e2 /= np.linalg.norm(e2)
    e3 = np.cross(e1, e2)
    R_rect1 = np.stack([e1, e2, e3])  # rect_from_cam1
    R_rect2 = R_rect1 @ R.T  # rect_from_cam2
    Rl, Rr = (R_rect2, R_rect1) if swapped else (R_rect1, R_rect2)
    il, ir = (intr2, intr1) if swapped else (intr1, intr2)
    W, H = _out_size(intr1, scale)
    f = scale * float(np.mean([intr1.fx, intr1.fy, intr2.fx, intr2.fy]))

    def extent(Rm: np.ndarray, intr: Intrinsics, f_: float) -> np.ndarray:
        K0 = np.array([[f_, 0, 0], [0, f_, 0], [0, 0, 1.0]])
        q = _apply(K0 @ Rm, _border(intr))
        return np.array([q[:, 0].min(), q[:, 0].max(), q[:, 1].min(), q[:, 1].max()])

    el, er = extent(Rl, il, f), extent(Rr, ir, f)
    # fit the left image's width and the common rows into the output size
    width_l = el[1] - el[0]
    rows = min(el[3], er[3]) - max(el[2], er[2])
    fit = min(1.0, W / max(width_l, 1e-9), H / max(rows, 1e-9))
    fit = max(fit, 0.25)
    if fit < 1.0:
        f *= fit
        el, er = el * fit, er * fit
    cy = (H - 1) / 2.0 - 0.5 * (max(el[2], er[2]) + min(el[3], er[3]))
    cx_l = (W - 1) / 2.0 - 0.5 * (el[0] + el[1])
    cx_r = (W - 1) / 2.0 - 0.5 * (er[0] + er[1])
    baseline = float(nb)
    if x1n is not None and x2n is not None and len(x1n) >= 5:
        K0 = np.array([[f, 0, 0], [0, f, 0], [0, 0, 1.0]])
        left, right = (x2n, x1n) if swapped else (x1n, x2n)
        d0 = _apply(K0 @ Rl, left)[:, 0] - _apply(K0 @ Rr, right)[:, 0]
        d0 = d0[np.isfinite(d0)]
        if len(d0) >= 5:
            margin = 8.0
            cx_r = cx_l + float(np.percentile(d0, 1.0)) - margin
    Kl = np.array([[f, 0, cx_l], [0, f, cy], [0, 0, 1.0]])
    Kr = np.array([[f, 0, cx_r], [0, f, cy], [0, 0, 1.0]])
    return _finish("calibrated", (W, H), Kl @ Rl, Kr @ Rr, swapped, Kl, cx_r - cx_l, baseline, x1n, x2n)


def rectify_opencv(
    intr1: Intrinsics,
    intr2: Intrinsics,
    R: np.ndarray,
    t: np.ndarray,
    scale: float = 1.0,
    x1n: np.ndarray | None = None,
    x2n: np.ndarray | None = None,
    alpha: float = -1.0,
) -> Rectification:
    """Rectify from the relative pose with ``cv2.stereoRectify`` (Bouguet's method).

    Arguments as :func:`rectify_calibrated`; ``alpha`` is OpenCV's free-scaling parameter.
    Camera 2 becomes the left image when OpenCV places it on the left (positive ``P2[0, 3]``).

    Raises:
        EstimationError: OpenCV chose a vertical rectification (motion mostly along y): use the
            ``"calibrated"`` method instead.
    """
    W, H = _out_size(intr1, scale)
    R = np.asarray(R, np.float64)
    t = np.asarray(t, np.float64).reshape(3, 1)
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
        intr1.K,
        intr1.dist,
        intr2.K,
        intr2.dist,
        (intr1.width, intr1.height),
        R,
        t,
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=alpha,
        newImageSize=(W, H),
    )
    if abs(P2[1, 3]) > abs(P2[0, 3]):
        raise EstimationError(
            "OpenCV rectified vertically (the cameras moved mostly up/down); use the calibrated method"
        )
    K1r, K2r = P1[:, :3], P2[:, :3]
    Tx = P2[0, 3] / P2[0, 0]
    swapped = bool(Tx > 0)
    M1, M2 = K1r @ R1, K2r @ R2
    Ml, Mr = (M2, M1) if swapped else (M1, M2)
    Kl = K2r if swapped else K1r
    Kr = K1r if swapped else K2r
    return _finish(
        "opencv", (W, H), Ml, Mr, swapped, Kl.copy(), float(Kr[0, 2] - Kl[0, 2]), float(abs(Tx)), x1n, x2n
    )


def rectify_uncalibrated(
    intr1: Intrinsics,
    intr2: Intrinsics,
    F: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
    scale: float = 1.0,
) -> Rectification:
    """Hartley's uncalibrated rectification from F and inlier matches (``cv2.stereoRectifyUncalibrated``).

    Args:
        intr1, intr2: full-resolution intrinsics (only used for distortion and image size; the
            homographies are computed from F on undistorted pixels).
        F: (3, 3) with ``x2^T F x1 = 0`` on undistorted pixels.
        x1, x2: (N, 2) inlier pixels (undistorted), N >= 8.
        scale: output size relative to image 1.
    Returns:
        Rectification without metric intrinsics (``K`` is None); the two homographies are
        composed with a common similarity so that the images fit the output and disparities of
        the matches are positive.
    """
    x1 = np.asarray(x1, np.float64)
    x2 = np.asarray(x2, np.float64)
    if len(x1) < 8:
        raise EstimationError(f"uncalibrated rectification needs at least 8 inlier matches, got {len(x1)}")
    ok, H1, H2 = cv2.stereoRectifyUncalibrated(x1, x2, np.asarray(F, np.float64), (intr1.width, intr1.height))
    if not ok:
        raise EstimationError("Hartley rectification failed (degenerate epipolar geometry)")
    W, H = _out_size(intr1, scale)

    def warp(Hm: np.ndarray, x: np.ndarray) -> np.ndarray:
        return _apply(Hm, x)

    # make disparities positive: mirror both images horizontally if needed
    d = warp(H1, x1)[:, 0] - warp(H2, x2)[:, 0]
    if np.median(d) < 0:
        Fl = np.diag([-1.0, 1.0, 1.0])
        H1, H2 = Fl @ H1, Fl @ H2
    # also keep the image upright (y increasing downwards like the source)
    p = warp(H1, x1)
    if np.corrcoef(p[:, 1], x1[:, 1])[0, 1] < 0:
        Fl = np.diag([1.0, -1.0, 1.0])
        H1, H2 = Fl @ H1, Fl @ H2
    px1 = intr1.K @ homogeneous(_border(intr1)).T
    px2 = intr2.K @ homogeneous(_border(intr2)).T
    q1 = warp(H1, (px1[:2] / px1[2]).T)
    q2 = warp(H2, (px2[:2] / px2[2]).T)
    ymin, ymax = max(q1[:, 1].min(), q2[:, 1].min()), min(q1[:, 1].max(), q2[:, 1].max())
    s = min(W / (q1[:, 0].max() - q1[:, 0].min()), H / max(ymax - ymin, 1e-9))
    ty = (H - 1) / 2.0 - s * 0.5 * (ymin + ymax)
    tx1 = (W - 1) / 2.0 - s * 0.5 * (q1[:, 0].min() + q1[:, 0].max())
    dd = s * (warp(H1, x1)[:, 0] - warp(H2, x2)[:, 0])
    tx2 = tx1 + float(np.percentile(dd, 1.0)) - 8.0
    S1 = np.array([[s, 0, tx1], [0, s, ty], [0, 0, 1.0]])
    S2 = np.array([[s, 0, tx2], [0, s, ty], [0, 0, 1.0]])
    M1 = S1 @ H1 @ intr1.K
    M2 = S2 @ H2 @ intr2.K
    return _finish(
        "uncalibrated", (W, H), M1, M2, False, None, 0.0, None, intr1.normalized(x1), intr2.normalized(x2)
    )


def rectify(
    method: RectificationMethod,
    intr1: Intrinsics,
    intr2: Intrinsics,
    R: np.ndarray,
    t: np.ndarray,
    F: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
    scale: float = 1.0,
) -> Rectification:
    """Dispatch to one rectification method. x1, x2: (N, 2) inlier pixels of images 1 and 2."""
    x1n, x2n = intr1.normalized(x1), intr2.normalized(x2)
    if method == "calibrated":
        return rectify_calibrated(intr1, intr2, R, t, scale, x1n, x2n)
    if method == "opencv":
        return rectify_opencv(intr1, intr2, R, t, scale, x1n, x2n)
    if method == "uncalibrated":
        u1 = intr1.K @ homogeneous(x1n).T
        u2 = intr2.K @ homogeneous(x2n).T
        return rectify_uncalibrated(intr1, intr2, F, (u1[:2] / u1[2]).T, (u2[:2] / u2[2]).T, scale)
    raise InputError(f"unknown rectification method {method!r}; use calibrated, opencv or uncalibrated")


def warp_images(
    image1: np.ndarray, image2: np.ndarray, intr1: Intrinsics, intr2: Intrinsics, rect: Rectification
) -> tuple[np.ndarray, np.ndarray]:
    """Resample both images onto the rectified grid (bilinear; lens distortion removed).

    Args:
        image1, image2: (H, W[, 3]) images matching ``intr1`` and ``intr2``.
    Returns:
        (left, right) rectified images of size ``rect.size``, same dtype and channels.
    """
    intr1.check_image(image1, "image 1")
    intr2.check_image(image2, "image 2")
    srcs = [(image2, intr2), (image1, intr1)] if rect.swapped else [(image1, intr1), (image2, intr2)]
    out = []
    for (img, intr), M in zip(srcs, (rect.M_left, rect.M_right)):
        mx, my = cv2.initUndistortRectifyMap(intr.K, intr.dist, M, np.eye(3), rect.size, cv2.CV_32FC1)
        out.append(cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0))
    return out[0], out[1]


def triangulate_disparity(
    disparity: np.ndarray, rect: Rectification, R: np.ndarray, t: np.ndarray, step: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate every valid disparity into camera 1's frame.

    Args:
        disparity: (H, W) float disparity of the rectified left image, NaN where invalid.
        rect: the rectification it was computed on.
        R, t: cam2_from_cam1 (|t| is the baseline unit of the result).
        step: use every ``step``-th row and column.
    Returns:
        ``(points, pixels)``: (N, 3) float64 points in camera 1's frame and the (N, 2) int
        rectified-left pixels (x, y) they came from.
    """
    d = np.asarray(disparity, np.float64)[::step, ::step]
    ys, xs = np.nonzero(np.isfinite(d))
    dv = d[ys, xs]
    ys = ys * step
    xs = xs * step
    ql = np.stack([xs, ys], 1).astype(np.float64)
    qr = ql.copy()
    qr[:, 0] -= dv
    nl = rect.from_rectified(ql, "left")
    nr = rect.from_rectified(qr, "right")
    n1, n2 = (nr, nl) if rect.swapped else (nl, nr)
    X = triangulate_midpoint(R, t, n1, n2)
    return X, np.stack([xs, ys], 1)
