"""Pictures of a two-view result: matches, epipolar lines, the rectified pair. All return RGB uint8."""

from __future__ import annotations

import cv2
import numpy as np

from skyrecon.errors import InputError
from skyrecon.geometry.epipolar import epipolar_lines

__all__ = ["draw_matches", "draw_epipolar_lines", "draw_rectified_pair"]

_GREEN = (40, 220, 60)
_RED = (230, 40, 40)


def _rgb(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] < 3:
        raise InputError(f"expected an (H, W) or (H, W, 3) image, got shape {img.shape}")
    img = img[..., :3]
    if img.dtype != np.uint8:
        mx = (
            65535.0
            if img.dtype == np.uint16
            else (1.0 if img.dtype.kind == "f" and np.nanmax(img) <= 1 else 255.0)
        )
        img = np.clip(np.nan_to_num(img.astype(np.float64)) * (255.0 / mx), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img)


def _side_by_side(a: np.ndarray, b: np.ndarray, max_width: int) -> tuple[np.ndarray, float, int]:
    """Concatenate two images horizontally, scaled so the canvas is at most ``max_width`` wide."""
    h = max(a.shape[0], b.shape[0])
    canvas = np.zeros((h, a.shape[1] + b.shape[1], 3), np.uint8)
    canvas[: a.shape[0], : a.shape[1]] = a
    canvas[: b.shape[0], a.shape[1] :] = b
    s = min(1.0, max_width / canvas.shape[1])
    if s < 1.0:
        canvas = cv2.resize(
            canvas,
            (int(round(canvas.shape[1] * s)), int(round(canvas.shape[0] * s))),
            interpolation=cv2.INTER_AREA,
        )
    return np.ascontiguousarray(canvas), s, a.shape[1]


def _pt(x: np.ndarray, s: float, dx: float = 0.0) -> tuple[int, int]:
    return int(round(((x[0] + dx) + 0.5) * s - 0.5)), int(round((x[1] + 0.5) * s - 0.5))


def draw_matches(
    image1: np.ndarray,
    image2: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
    inliers: np.ndarray | None = None,
    max_matches: int = 400,
    max_width: int = 2400,
    show_outliers: bool = True,
    seed: int = 0,
) -> np.ndarray:
    """Side-by-side picture with a line per match (inliers green, outliers red).

    Args:
        image1, image2: the two images (RGB or grey).
        x1, x2: (M, 2) matching pixels in each image.
        inliers: optional (M,) bool.
        max_matches: draw at most this many (a random subset, fixed by ``seed``).
        max_width: width of the returned picture at most, pixels.
    Returns:
        (H, W, 3) uint8 RGB picture.
    """
    x1 = np.asarray(x1, np.float64).reshape(-1, 2)
    x2 = np.asarray(x2, np.float64).reshape(-1, 2)
    inl = np.ones(len(x1), bool) if inliers is None else np.asarray(inliers, bool)
    canvas, s, off = _side_by_side(_rgb(image1), _rgb(image2), max_width)
    idx = np.arange(len(x1)) if show_outliers else np.nonzero(inl)[0]
    if len(idx) > max_matches:
        idx = np.sort(np.random.default_rng(seed).choice(idx, max_matches, replace=False))
    thick = max(1, int(round(2 * s * max(canvas.shape) / 1500)))
    for k in idx:
        c = _GREEN if inl[k] else _RED
        p, q = _pt(x1[k], s), _pt(x2[k], s, off)
        cv2.line(canvas, p, q, c, 1, cv2.LINE_AA)
        cv2.circle(canvas, p, thick + 1, c, -1, cv2.LINE_AA)
        cv2.circle(canvas, q, thick + 1, c, -1, cv2.LINE_AA)
    return canvas


def _line_ends(line: np.ndarray, w: int, h: int) -> tuple[np.ndarray, np.ndarray] | None:
    a, b, c = line
    pts = []
    if abs(b) > 1e-12:
        for u in (-0.5, w - 0.5):
            pts.append((u, -(a * u + c) / b))
    if abs(a) > 1e-12:
        for v in (-0.5, h - 0.5):
            pts.append((-(b * v + c) / a, v))
    pts = [p for p in pts if -0.51 <= p[0] <= w - 0.49 and -0.51 <= p[1] <= h - 0.49]
    if len(pts) < 2:
        return None
    return np.array(pts[0]), np.array(pts[-1])


def draw_epipolar_lines(
    image1: np.ndarray,
    image2: np.ndarray,
    F: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
    num_lines: int = 20,
    max_width: int = 2400,
    seed: int = 0,
) -> np.ndarray:
    """Side-by-side picture of epipolar lines: for each drawn match, its point and the epipolar
    line of its partner in both images (the same colour per match).

    Args:
        F: (3, 3) with ``x2^T F x1 = 0`` (pixels).
        x1, x2: (M, 2) matching pixels (e.g. the inliers).
        num_lines: matches drawn (random subset fixed by ``seed``).
    Returns:
        (H, W, 3) uint8 RGB picture.
    """
    x1 = np.asarray(x1, np.float64).reshape(-1, 2)
    x2 = np.asarray(x2, np.float64).reshape(-1, 2)
    a, b = _rgb(image1), _rgb(image2)
    canvas, s, off = _side_by_side(a, b, max_width)
    rng = np.random.default_rng(seed)
    idx = np.arange(len(x1))
    if len(idx) > num_lines:
        idx = np.sort(rng.choice(idx, num_lines, replace=False))
    l2 = epipolar_lines(F, x1[idx], which=2)
    l1 = epipolar_lines(F, x2[idx], which=1)
    thick = max(1, int(round(s * max(a.shape[:2]) / 800)))
    for k in range(len(idx)):
        hue = int(180 * k / max(1, len(idx)))
        col = cv2.cvtColor(np.array([[[hue, 220, 255]]], np.uint8), cv2.COLOR_HSV2RGB)[0, 0].tolist()
        for line, (w, h), dx in ((l1[k], a.shape[1::-1], 0.0), (l2[k], b.shape[1::-1], float(off))):
            ends = _line_ends(line, w, h)
            if ends is not None:
                cv2.line(canvas, _pt(ends[0], s, dx), _pt(ends[1], s, dx), col, thick, cv2.LINE_AA)
        cv2.circle(canvas, _pt(x1[idx[k]], s), 3 * thick, col, -1, cv2.LINE_AA)
        cv2.circle(canvas, _pt(x2[idx[k]], s, off), 3 * thick, col, -1, cv2.LINE_AA)
    return canvas


def draw_rectified_pair(
    left: np.ndarray, right: np.ndarray, num_rows: int = 16, max_width: int = 2400
) -> np.ndarray:
    """Rectified pair side by side with horizontal guide lines (rows should show the same content)."""
    canvas, s, _ = _side_by_side(_rgb(left), _rgb(right), max_width)
    for y in np.linspace(0, canvas.shape[0] - 1, num_rows + 2)[1:-1]:
        cv2.line(canvas, (0, int(y)), (canvas.shape[1] - 1, int(y)), (255, 230, 0), 1, cv2.LINE_AA)
    return canvas
