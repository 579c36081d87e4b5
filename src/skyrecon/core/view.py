"""A posed view: one image with its camera and pose (multi-view sets, rings, flights)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3


@dataclass
class PosedView:
    """One image of a multi-view set.

    Attributes:
        name: the image's name (file name for sets read from disk).
        intrinsics: its camera.
        cam_from_world: its pose, world -> camera, metres.
        image_path: where the image file is, when it came from disk.
    """

    name: str
    intrinsics: Intrinsics
    cam_from_world: Rigid3
    image_path: Path | None = None

    def __post_init__(self) -> None:
        self.cam_from_world = self.cam_from_world.with_frames("cam", "world")

    @property
    def center_world(self) -> np.ndarray:
        """(3,) camera centre in the world frame, metres."""
        return self.cam_from_world.center

    @property
    def P(self) -> np.ndarray:
        """(3, 4) projection matrix ``K [R | t]`` (ignores distortion)."""
        return self.intrinsics.K @ self.cam_from_world.matrix3x4

    def project(self, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points (N, 3) to pixels (N, 2); also returns (N,) depth in metres."""
        p_cam = self.cam_from_world.apply(np.asarray(points_world, dtype=np.float64))
        return self.intrinsics.project(p_cam), p_cam[:, 2]
