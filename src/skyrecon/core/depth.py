"""Depth maps and coloured point clouds."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError


@dataclass
class PointCloud:
    """A point cloud with optional colours and normals.

    Attributes:
        points: (N, 3) float32 positions, metres, in the frame the producer states.
        colors: (N, 3) uint8 RGB, or None.
        normals: (N, 3) float32 unit normals, or None.
    """

    points: np.ndarray
    colors: np.ndarray | None = None
    normals: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.points = np.ascontiguousarray(np.asarray(self.points, dtype=np.float32).reshape(-1, 3))
        n = len(self.points)
        if self.colors is not None:
            c = np.asarray(self.colors)
            if c.dtype != np.uint8:
                c = np.clip(np.rint(c), 0, 255).astype(np.uint8)
            self.colors = np.ascontiguousarray(c.reshape(-1, 3))
            if len(self.colors) != n:
                raise InputError(f"{len(self.colors)} colours for {n} points")
        if self.normals is not None:
            self.normals = np.ascontiguousarray(np.asarray(self.normals, dtype=np.float32).reshape(-1, 3))
            if len(self.normals) != n:
                raise InputError(f"{len(self.normals)} normals for {n} points")

    def __len__(self) -> int:
        return len(self.points)

    def select(self, mask_or_index: np.ndarray) -> PointCloud:
        """Subset by boolean mask (N,) or index array."""
        return PointCloud(
            self.points[mask_or_index],
            None if self.colors is None else self.colors[mask_or_index],
            None if self.normals is None else self.normals[mask_or_index],
        )

    def transformed(self, b_from_a: Rigid3) -> PointCloud:
        """The cloud mapped from frame a to frame b (normals rotated)."""
        return PointCloud(
            b_from_a.apply(self.points).astype(np.float32),
            self.colors,
            None if self.normals is None else b_from_a.rotate(self.normals).astype(np.float32),
        )

    @staticmethod
    def concatenate(clouds: list[PointCloud]) -> PointCloud:
        """Join clouds; colours/normals are kept only if every cloud has them."""
        if not clouds:
            return PointCloud(np.zeros((0, 3), np.float32))
        pts = np.concatenate([c.points for c in clouds])
        cols = (
            np.concatenate([c.colors for c in clouds]) if all(c.colors is not None for c in clouds) else None
        )
        nrm = (
            np.concatenate([c.normals for c in clouds])
            if all(c.normals is not None for c in clouds)
            else None
        )
        return PointCloud(pts, cols, nrm)


@dataclass
class DepthMap:
    """Depth along the optical axis for every pixel of one camera.

    Attributes:
        depth_m: (H, W) float32 metres, NaN where unknown.
        intrinsics: the camera (size must match ``depth_m``).
        cam_from_world: the camera pose, or None when only camera-frame use is needed.
    """

    depth_m: np.ndarray
    intrinsics: Intrinsics
    cam_from_world: Rigid3 | None = None

    def __post_init__(self) -> None:
        self.depth_m = np.asarray(self.depth_m, dtype=np.float32)
        if self.depth_m.ndim != 2:
            raise InputError(f"a depth map must be 2-D (H, W), got shape {self.depth_m.shape}")
        self.intrinsics.check_image(self.depth_m, "depth map")

    @property
    def valid(self) -> np.ndarray:
        """(H, W) bool: finite, positive depth."""
        with np.errstate(invalid="ignore"):
            return np.isfinite(self.depth_m) & (self.depth_m > 0)

    def to_points_cam(
        self, image: np.ndarray | None = None, min_depth_m: float = 0.0, max_depth_m: float = np.inf
    ) -> PointCloud:
        """Back-project valid pixels to a cloud in the camera frame.

        Args:
            image: optional (H, W, 3) uint8 RGB or (H, W) grey for colours.
            min_depth_m, max_depth_m: keep depths within this range, metres.
        Returns:
            PointCloud in this camera's frame, points in row-major pixel order.
        """
        mask = self.valid & (self.depth_m >= min_depth_m) & (self.depth_m <= max_depth_m)
        v, u = np.nonzero(mask)
        pts = self.intrinsics.unproject(np.stack([u, v], axis=1).astype(np.float64), self.depth_m[v, u])
        colors = None
        if image is not None:
            self.intrinsics.check_image(image, "colour image")
            c = image[v, u]
            colors = np.repeat(c[:, None], 3, axis=1) if c.ndim == 1 else c[:, :3]
        return PointCloud(pts.astype(np.float32), colors)

    def to_points_world(self, image: np.ndarray | None = None, **kw) -> PointCloud:
        """As :meth:`to_points_cam`, then mapped to the world frame (needs ``cam_from_world``)."""
        if self.cam_from_world is None:
            raise InputError("this depth map has no camera pose; cannot place it in the world")
        return self.to_points_cam(image, **kw).transformed(self.cam_from_world.inverse())
