"""A picture of a point cloud seen from a camera, for a person to look at.

Points are projected with the camera's intrinsics and pose and splatted as small squares with a
z-buffer (nearest point wins); colours are the points' own, optionally shaded by their normals.
"""

from __future__ import annotations

import numpy as np

from skyrecon.core import Intrinsics, PointCloud, Rigid3

__all__ = ["render_cloud"]


def render_cloud(
    cloud: PointCloud,
    intrinsics: Intrinsics,
    cam_from_world: Rigid3,
    point_px: int = 2,
    background: tuple[int, int, int] = (255, 255, 255),
    shade: bool = True,
) -> np.ndarray:
    """Render ``cloud`` (world frame) from a camera.

    Args:
        cloud: points (N, 3) metres with optional colours and normals.
        intrinsics: the virtual camera (image size, focal lengths).
        cam_from_world: its pose.
        point_px: splat size, pixels.
        background: RGB of empty pixels.
        shade: modulate colours by the angle between normal and viewing ray (when normals exist).
    Returns:
        (H, W, 3) uint8 RGB image.
    """
    H, W = intrinsics.height, intrinsics.width
    img = np.empty((H, W, 3), np.uint8)
    img[:] = background
    if len(cloud) == 0:
        return img
    pc = cam_from_world.apply(cloud.points.astype(np.float64))
    z = pc[:, 2]
    front = z > 1e-9
    uv = intrinsics.project(pc[front])
    z = z[front]
    cols = (
        np.full((len(cloud), 3), 128, np.float64) if cloud.colors is None else cloud.colors.astype(np.float64)
    )[front]
    if shade and cloud.normals is not None:
        n = cam_from_world.rotate(cloud.normals[front].astype(np.float64))
        ray = pc[front] / np.linalg.norm(pc[front], axis=1, keepdims=True)
        lam = np.clip(-np.sum(n * ray, axis=1), 0.0, 1.0)
        cols = cols * (0.35 + 0.65 * lam[:, None])
    u0 = np.rint(uv[:, 0]).astype(np.int64)
    v0 = np.rint(uv[:, 1]).astype(np.int64)
    half = point_px // 2
    offs = [(du, dv) for dv in range(-half, point_px - half) for du in range(-half, point_px - half)]
    u = np.concatenate([u0 + du for du, _ in offs])
    v = np.concatenate([v0 + dv for _, dv in offs])
    zz = np.tile(z, len(offs))
    idx = np.tile(np.arange(len(z)), len(offs))
    ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    u, v, zz, idx = u[ok], v[ok], zz[ok], idx[ok]
    order = np.argsort(-zz, kind="stable")  # far first: the nearest point is written last and wins
    img[v[order], u[order]] = np.clip(cols[idx[order]], 0, 255).astype(np.uint8)
    return img
