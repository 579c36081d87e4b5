"""A sparse reconstruction: cameras, posed images with keypoints, and 3D points with tracks.

Mirrors the COLMAP data model with skyrecon conventions: poses are
``cam_from_world`` and pixel (0, 0) is the centre of the top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError


@dataclass
class Image:
    """One registered image.

    Attributes:
        image_id: unique id (>= 1 in COLMAP files).
        name: file name relative to the image directory.
        camera_id: id of its camera in ``Reconstruction.cameras``.
        cam_from_world: pose, world -> this camera.
        keypoints: (M, 2) float64 pixels (u, v).
        point3d_ids: (M,) int64 id of the 3D point each keypoint observes, -1 for none.
    """

    image_id: int
    name: str
    camera_id: int
    cam_from_world: Rigid3
    keypoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    point3d_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __post_init__(self) -> None:
        self.keypoints = np.asarray(self.keypoints, dtype=np.float64).reshape(-1, 2)
        self.point3d_ids = np.asarray(self.point3d_ids, dtype=np.int64).reshape(-1)
        if len(self.keypoints) != len(self.point3d_ids):
            raise InputError(
                f"image {self.name}: {len(self.keypoints)} keypoints but {len(self.point3d_ids)} point ids"
            )
        self.cam_from_world = self.cam_from_world.with_frames("cam", "world")

    @property
    def center_world(self) -> np.ndarray:
        """(3,) camera centre in the world frame."""
        return self.cam_from_world.center


@dataclass
class Point3D:
    """A triangulated point.

    Attributes:
        point3d_id: unique id.
        xyz: (3,) float64 world position.
        color: (3,) uint8 RGB.
        error: mean reprojection error, pixels (-1 when unknown).
        track: (K, 2) int64 rows of (image_id, keypoint index).
    """

    point3d_id: int
    xyz: np.ndarray
    color: np.ndarray = field(default_factory=lambda: np.zeros(3, dtype=np.uint8))
    error: float = -1.0
    track: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))

    def __post_init__(self) -> None:
        self.xyz = np.asarray(self.xyz, dtype=np.float64).reshape(3)
        self.color = np.asarray(self.color, dtype=np.uint8).reshape(3)
        self.track = np.asarray(self.track, dtype=np.int64).reshape(-1, 2)


@dataclass
class Reconstruction:
    """Cameras, images and 3D points keyed by id."""

    cameras: dict[int, Intrinsics] = field(default_factory=dict)
    images: dict[int, Image] = field(default_factory=dict)
    points3d: dict[int, Point3D] = field(default_factory=dict)

    def image_by_name(self, name: str) -> Image:
        for im in self.images.values():
            if im.name == name:
                return im
        raise KeyError(name)

    def points_array(self) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) float64 positions and (N, 3) uint8 colours of every 3D point, id order."""
        ids = sorted(self.points3d)
        if not ids:
            return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
        xyz = np.stack([self.points3d[i].xyz for i in ids])
        rgb = np.stack([self.points3d[i].color for i in ids])
        return xyz, rgb

    def reprojection_errors(self) -> np.ndarray:
        """(num observations,) pixel distances between keypoints and their projected 3D points."""
        errs = []
        for im in self.images.values():
            cam = self.cameras[im.camera_id]
            observed = np.nonzero(im.point3d_ids >= 0)[0]
            sel = [i for i in observed if int(im.point3d_ids[i]) in self.points3d]
            if not sel:
                continue
            xyz = np.stack([self.points3d[int(im.point3d_ids[i])].xyz for i in sel])
            uv = cam.project(im.cam_from_world.apply(xyz))
            errs.append(np.linalg.norm(uv - im.keypoints[sel], axis=1))
        return np.concatenate(errs) if errs else np.zeros(0)

    def validate(self) -> None:
        """Raise ``InputError`` if ids do not refer to each other consistently."""
        for im in self.images.values():
            if im.camera_id not in self.cameras:
                raise InputError(f"image {im.name} refers to missing camera {im.camera_id}")
        for p in self.points3d.values():
            for image_id, kp in p.track:
                seen_by = self.images.get(int(image_id))
                if seen_by is None:
                    raise InputError(f"point {p.point3d_id} refers to missing image {image_id}")
                if not 0 <= kp < len(seen_by.keypoints):
                    raise InputError(
                        f"point {p.point3d_id} refers to keypoint {kp} of {seen_by.name}, out of range"
                    )
