"""Array preparation shared by the recording backends (no backend library needed).

Downscaling, JPEG encoding, disparity colouring, deterministic subsets, height colours and
camera frusta; every function is pure and works on NumPy arrays.
"""

from __future__ import annotations

import cv2
import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3, matrix_to_quaternion
from skyrecon.errors import InputError


def quaternion_xyzw(world_from_body: Rigid3) -> np.ndarray:
    """(4,) float64 unit quaternion (x, y, z, w) of the pose's rotation (Rerun / Foxglove order)."""
    w, x, y, z = matrix_to_quaternion(world_from_body.R)
    return np.array([x, y, z, w])


def as_rgb8(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB from (H, W, 3) / (H, W, 4) / (H, W) uint8 (grey is repeated)."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise InputError(f"images to record must be uint8, got {img.dtype}")
    if img.ndim == 2:
        return np.repeat(img[:, :, None], 3, axis=2)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        return np.ascontiguousarray(img[:, :, :3])
    raise InputError(f"images to record must be (H, W), (H, W, 3) or (H, W, 4), got {img.shape}")


def downscale_factor(width: int, max_width: int) -> float:
    """Factor (<= 1) that brings ``width`` to at most ``max_width`` pixels."""
    return min(1.0, max_width / max(1, width))


def downscale(image: np.ndarray, factor: float, nearest: bool = False) -> np.ndarray:
    """``image`` resized by ``factor`` (area-averaged; ``nearest`` for depth, where averaging
    across edges would invent surfaces)."""
    if factor >= 1.0:
        return image
    h, w = image.shape[:2]
    size = (max(1, int(round(w * factor))), max(1, int(round(h * factor))))
    return cv2.resize(image, size, interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)


def encode_jpeg(rgb: np.ndarray, quality: int) -> bytes:
    """JPEG bytes of an (H, W, 3) uint8 RGB image."""
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 RGB image
        raise InputError("could not JPEG-encode an image for the recording")
    return buf.tobytes()


def clean_depth(depth_m: np.ndarray) -> np.ndarray:
    """(h, w) float32 depth, metres, with every invalid value (NaN, inf, <= 0) set to 0."""
    d = np.asarray(depth_m, dtype=np.float32)
    return np.where(np.isfinite(d) & (d > 0), d, np.float32(0.0)).astype(np.float32)


def depth_units(depth_m: np.ndarray) -> tuple[np.ndarray, float]:
    """Depth (0 invalid) as uint16 units and the units per metre: millimetres (1000) when the
    farthest value fits in 65.535 m, centimetres (100) to 655 m, else float32 metres (1)."""
    far = float(depth_m.max()) if depth_m.size else 0.0
    for per_m in (1000.0, 100.0):
        if far * per_m < 65535:
            return np.round(depth_m * per_m).astype(np.uint16), per_m
    return depth_m.astype(np.float32), 1.0


def colorize_disparity(disparity_px: np.ndarray, max_disparity: float | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB: disparity through the turbo colour map (near warm), invalid black."""
    d = np.asarray(disparity_px, dtype=np.float32)
    valid = np.isfinite(d) & (d > 0)
    top = (
        float(max_disparity)
        if max_disparity
        else (float(np.percentile(d[valid], 99)) if valid.any() else 1.0)
    )
    scaled = np.clip(np.where(valid, d, 0.0) / max(top, 1e-6) * 255.0, 0, 255).astype(np.uint8)
    rgb = cv2.cvtColor(cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    rgb[~valid] = 0
    return rgb


def even_subset(n: int, budget: int) -> np.ndarray | None:
    """Indices of an even, deterministic subset of ``budget`` out of ``n`` items (None: keep all)."""
    if n <= budget:
        return None
    return np.unique(np.linspace(0, n - 1, budget).round().astype(np.int64))


def cap_points(xyz: np.ndarray, rgb: np.ndarray | None, budget: int) -> tuple[np.ndarray, np.ndarray | None]:
    """(M, 3) float32 finite points and their (M, 3) uint8 colours, at most ``budget`` of them."""
    pts = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
    ok = np.isfinite(pts).all(axis=1)
    cols = None if rgb is None else np.asarray(rgb).reshape(-1, 3)
    if cols is not None and len(cols) != len(pts):
        raise InputError(f"{len(pts)} points but {len(cols)} colours")
    if not ok.all():
        pts = pts[ok]
        cols = None if cols is None else cols[ok]
    idx = even_subset(len(pts), budget)
    if idx is not None:
        pts = pts[idx]
        cols = None if cols is None else cols[idx]
    if cols is not None:
        cols = np.clip(cols, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(pts), cols


def height_colors(z: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 RGB by height: blue low, green middle, red high (as ``occupied.ply``)."""
    z = np.asarray(z, dtype=np.float64)
    if len(z) == 0:
        return np.zeros((0, 3), np.uint8)
    s = (z - z.min()) / max(float(np.ptp(z)), 1e-6)
    return np.stack([255 * s, 255 * (1 - np.abs(2 * s - 1)), 255 * (1 - s)], 1).astype(np.uint8)


def frustum_lines(intrinsics: Intrinsics, world_from_cam: Rigid3, depth: float) -> np.ndarray:
    """(16, 3) world points, 8 segments as consecutive pairs: the 4 rays from the centre to the
    image corners at ``depth`` (along the optical axis) and the far rectangle."""
    w, h = intrinsics.width, intrinsics.height
    corners_px = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    rays = np.column_stack([intrinsics.without_distortion().normalized(corners_px), np.ones(4)])
    far = rays * depth
    centre = np.zeros(3)
    cam = []
    for i in range(4):
        cam += [centre, far[i]]
    for i in range(4):
        cam += [far[i], far[(i + 1) % 4]]
    pts = np.array(cam)
    return pts @ world_from_cam.R.T + world_from_cam.t


def topic_name(name: str) -> str:
    """A name as a path: ``"map/voxels"`` -> ``"map/voxels"``; empty parts and spaces removed."""
    parts = [p.strip().replace(" ", "_") for p in str(name).split("/")]
    cleaned = "/".join(p for p in parts if p)
    if not cleaned:
        raise InputError(f"empty recording name {name!r}")
    return cleaned
