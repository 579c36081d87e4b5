"""Small picture builders shared by commands: contact sheets and top-down city maps."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np


def _as_rgb(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    if image.dtype != np.uint8:
        image = np.clip(image, 0, 255).astype(np.uint8)
    return image


def contact_sheet(
    images: Sequence[np.ndarray], labels: Sequence[str] | None = None, columns: int = 2, tile_width: int = 480
) -> np.ndarray:
    """Tile images (each (H, W) or (H, W, 3) uint8) into one RGB picture with optional labels.

    Returns:
        (H', W', 3) uint8 RGB.
    """
    if not images:
        return np.zeros((1, 1, 3), np.uint8)
    tiles = []
    for k, im in enumerate(images):
        im = _as_rgb(im)
        scale = tile_width / im.shape[1]
        tile = cv2.resize(
            im, (tile_width, max(1, int(round(im.shape[0] * scale)))), interpolation=cv2.INTER_AREA
        )
        if labels is not None and k < len(labels):
            cv2.putText(tile, labels[k], (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 3, cv2.LINE_AA)
            cv2.putText(
                tile, labels[k], (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA
            )
        tiles.append(tile)
    tile_h = max(t.shape[0] for t in tiles)
    rows = []
    for r in range(0, len(tiles), columns):
        row = [np.pad(t, ((0, tile_h - t.shape[0]), (0, 0), (0, 0))) for t in tiles[r : r + columns]]
        row += [np.zeros((tile_h, tile_width, 3), np.uint8)] * (columns - len(row))
        rows.append(np.concatenate(row, axis=1))
    return np.concatenate(rows, axis=0)


def top_down_map(
    boxes: np.ndarray,
    extent: tuple[float, float, float, float],
    paths: Sequence[np.ndarray] = (),
    cylinders: np.ndarray | None = None,
    px_per_m: float = 3.0,
    path_colors: Sequence[tuple[int, int, int]] = ((220, 40, 40), (40, 90, 220), (30, 160, 60)),
) -> np.ndarray:
    """A plan view of a city: buildings shaded by height, poles as dots, paths as lines.

    Args:
        boxes: (N, 6) world boxes ``[xmin, ymin, zmin, xmax, ymax, zmax]``, metres.
        extent: ``(xmin, ymin, xmax, ymax)`` of the picture, metres (world frame, z up).
        paths: each (K, 3) or (K, 2) world positions, metres.
        cylinders: (M, 5) ``[x, y, radius, zmin, zmax]`` poles.
    Returns:
        (H, W, 3) uint8 RGB, north (+y) up.
    """
    x0, y0, x1, y1 = extent
    W, H = int(np.ceil((x1 - x0) * px_per_m)), int(np.ceil((y1 - y0) * px_per_m))
    img = np.full((H, W, 3), 235, np.uint8)

    def to_px(x, y):
        return (np.asarray(x) - x0) * px_per_m, (y1 - np.asarray(y)) * px_per_m

    zmax = max(float(boxes[:, 5].max()) if len(boxes) else 1.0, 1.0)
    for b in boxes[np.argsort(boxes[:, 5])] if len(boxes) else []:
        (u0, v0), (u1, v1) = to_px(b[0], b[4]), to_px(b[3], b[1])
        shade = int(200 - 150 * min(b[5] / zmax, 1.0))
        cv2.rectangle(img, (int(u0), int(v0)), (int(u1), int(v1)), (shade, shade, shade + 20), -1)
        cv2.rectangle(img, (int(u0), int(v0)), (int(u1), int(v1)), (60, 60, 70), 1)
    if cylinders is not None:
        for c in cylinders:
            u, v = to_px(c[0], c[1])
            cv2.circle(img, (int(u), int(v)), max(1, int(c[2] * px_per_m)), (90, 60, 30), -1)
    for k, path in enumerate(paths):
        path = np.asarray(path, dtype=np.float64)
        if len(path) == 0:
            continue
        u, v = to_px(path[:, 0], path[:, 1])
        pts = np.stack([u, v], axis=1).astype(np.int32)
        color = path_colors[k % len(path_colors)]
        cv2.polylines(img, [pts], False, color, 2, cv2.LINE_AA)
        cv2.circle(img, tuple(int(a) for a in pts[0]), 4, color, -1)
        cv2.drawMarker(img, tuple(int(a) for a in pts[-1]), color, cv2.MARKER_CROSS, 10, 2)
    return img


def height_map_image(
    points_world: np.ndarray,
    extent: tuple[float, float, float, float],
    paths: Sequence[np.ndarray] = (),
    px_per_m: float = 4.0,
    path_colors: Sequence[tuple[int, int, int]] = ((220, 40, 40), (40, 90, 220), (30, 160, 60)),
) -> np.ndarray:
    """Plan view of points (e.g. occupied voxel centres): darker where higher, paths on top.

    Args:
        points_world: (N, 3) world points, metres.
        extent: ``(xmin, ymin, xmax, ymax)`` of the picture, metres.
        paths: each (K, 3) or (K, 2) world positions, metres.
    Returns:
        (H, W, 3) uint8 RGB, north (+y) up.
    """
    x0, y0, x1, y1 = extent
    W, H = max(1, int(np.ceil((x1 - x0) * px_per_m))), max(1, int(np.ceil((y1 - y0) * px_per_m)))
    img = np.full((H, W, 3), 240, np.uint8)
    p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    if len(p):
        u = ((p[:, 0] - x0) * px_per_m).astype(np.int64)
        v = ((y1 - p[:, 1]) * px_per_m).astype(np.int64)
        ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
        top = np.full(H * W, -np.inf)
        np.maximum.at(top, v[ok] * W + u[ok], p[ok, 2])
        seen = np.isfinite(top)
        zmax = max(float(top[seen].max()) if seen.any() else 1.0, 1.0)
        shade = (200 - 170 * np.clip(top[seen] / zmax, 0, 1)).astype(np.uint8)
        flat = img.reshape(-1, 3)
        flat[seen] = np.stack(
            [shade, shade, np.minimum(shade.astype(np.int32) + 25, 255).astype(np.uint8)], axis=1
        )
    for k, path in enumerate(paths):
        path = np.asarray(path, dtype=np.float64)
        if len(path) == 0:
            continue
        pts = np.stack([(path[:, 0] - x0) * px_per_m, (y1 - path[:, 1]) * px_per_m], axis=1).astype(np.int32)
        color = path_colors[k % len(path_colors)]
        cv2.polylines(img, [pts], False, color, 2, cv2.LINE_AA)
        cv2.circle(img, tuple(int(a) for a in pts[0]), 4, color, -1)
        cv2.drawMarker(img, tuple(int(a) for a in pts[-1]), color, cv2.MARKER_CROSS, 10, 2)
    return img
