"""What the 3D viewer draws: points, occupied voxels, camera frusta and paths, all in one world frame.

Every coordinate is in the world frame of the output it came from (metres, z up for maps, paths
and missions; a COLMAP model's own gauge for an unaligned SfM model). The page subtracts the scene
centre (float64) before converting to float32, so large coordinates (UTM, ECEF) keep their
precision; the offset is shown in the page.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np


@dataclass(frozen=True)
class Polyline:
    """A named line through points.

    Attributes:
        name: what it is (``flown``, ``planned``...), shown in the page's legend.
        points: (K, 3) float64 world metres, in order.
        color: RGB 0..255.
    """

    name: str
    points: np.ndarray
    color: tuple[int, int, int] = (255, 80, 60)

    def __post_init__(self) -> None:
        object.__setattr__(self, "points", np.asarray(self.points, dtype=np.float64).reshape(-1, 3))


@dataclass(frozen=True)
class ViewerScene:
    """Everything one viewer page shows.

    Attributes:
        title: shown in the page (usually the path that was opened).
        points: (N, 3) float64 (or float32) world positions, metres.
        colors: (N, 3) uint8 RGB of the points, or None (then coloured by height).
        voxel_centers: (M, 3) float64 world centres of occupied voxels, metres.
        voxel_size_m: edge of a voxel, metres (0 when there are none).
        camera_segments: (S, 2, 3) float64 line segments (start, end) of camera frusta, world.
        paths: polylines (flown track, planned path...).
        total_points: points in the source before subsampling (``len(points)`` when not subsampled).
        total_voxels: voxels in the source before subsampling.
    """

    title: str
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    colors: np.ndarray | None = None
    voxel_centers: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    voxel_size_m: float = 0.0
    camera_segments: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))
    paths: tuple[Polyline, ...] = ()
    total_points: int = -1
    total_voxels: int = -1

    def __post_init__(self) -> None:
        pts = np.asarray(self.points)
        if pts.dtype not in (np.float32, np.float64):
            pts = pts.astype(np.float64)
        object.__setattr__(self, "points", pts.reshape(-1, 3))
        if self.colors is not None:
            c = np.asarray(self.colors, dtype=np.uint8).reshape(-1, 3)
            if len(c) != len(self.points):
                raise ValueError(f"{len(c)} colours for {len(self.points)} points")
            object.__setattr__(self, "colors", c)
        object.__setattr__(
            self, "voxel_centers", np.asarray(self.voxel_centers, dtype=np.float64).reshape(-1, 3)
        )
        object.__setattr__(
            self, "camera_segments", np.asarray(self.camera_segments, dtype=np.float64).reshape(-1, 2, 3)
        )
        object.__setattr__(self, "paths", tuple(self.paths))
        if self.total_points < 0:
            object.__setattr__(self, "total_points", len(self.points))
        if self.total_voxels < 0:
            object.__setattr__(self, "total_voxels", len(self.voxel_centers))

    @property
    def is_empty(self) -> bool:
        """True when there is nothing to draw."""
        return (
            not len(self.points)
            and not len(self.voxel_centers)
            and not len(self.camera_segments)
            and not any(len(p.points) for p in self.paths)
        )

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper corners (3,) float64 world metres of everything drawn ((0, 0) when empty)."""
        parts = [
            np.asarray(self.points, dtype=np.float64),
            self.voxel_centers,
            self.camera_segments.reshape(-1, 3),
            *(p.points for p in self.paths),
        ]
        los = [p.min(axis=0) for p in parts if len(p)]
        his = [p.max(axis=0) for p in parts if len(p)]
        if not los:
            return np.zeros(3), np.zeros(3)
        lo, hi = np.min(los, axis=0), np.max(his, axis=0)
        if len(self.voxel_centers):
            lo, hi = lo - self.voxel_size_m / 2, hi + self.voxel_size_m / 2
        return lo, hi

    def subsampled(self, max_points: int, seed: int = 0) -> ViewerScene:
        """At most ``max_points`` points and ``max_points`` voxels, drawn uniformly without replacement.

        Deterministic for a given ``seed``; the kept points stay in their original order. The
        counts before subsampling stay in ``total_points`` / ``total_voxels``.
        """
        if max_points < 0 or (len(self.points) <= max_points and len(self.voxel_centers) <= max_points):
            return self
        rng = np.random.default_rng(seed)
        pts, cols, vox = self.points, self.colors, self.voxel_centers
        if len(pts) > max_points:
            keep = _sample(rng, len(pts), max_points)
            pts = pts[keep]
            cols = None if cols is None else cols[keep]
        if len(vox) > max_points:
            vox = vox[_sample(rng, len(vox), max_points)]
        return replace(
            self,
            points=pts,
            colors=cols,
            voxel_centers=vox,
            total_points=self.total_points,
            total_voxels=self.total_voxels,
        )


def _sample(rng: np.random.Generator, n: int, k: int) -> np.ndarray:
    """``k`` distinct sorted indices of ``range(n)``, uniformly (vectorised; fast for n = 10^7)."""
    return np.sort(rng.choice(n, size=k, replace=False, shuffle=False))


def frustum_segments(
    world_from_cam_R: np.ndarray,
    cam_center: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: int,
    height: int,
    depth: float,
) -> np.ndarray:
    """The 8 line segments (8, 2, 3) of a pinhole camera's frustum drawn ``depth`` in front of it.

    Args:
        world_from_cam_R: (3, 3) rotation camera -> world (camera axes OpenCV: x right, y down, z forward).
        cam_center: (3,) camera centre, world.
        fx, fy, cx, cy: intrinsics, pixels; ``width``, ``height``: image size, pixels.
        depth: distance of the drawn image plane along the optical axis, world units.
    Returns:
        Four edges from the centre to the image corners and the four edges of the image rectangle.
    """
    u = np.array([0.0, width, width, 0.0])
    v = np.array([0.0, 0.0, height, height])
    rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones(4)], axis=1) * depth
    corners = rays @ np.asarray(world_from_cam_R, dtype=np.float64).T + np.asarray(
        cam_center, dtype=np.float64
    )
    c = np.asarray(cam_center, dtype=np.float64)
    segs = [(c, corners[i]) for i in range(4)] + [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    return np.array(segs, dtype=np.float64)
