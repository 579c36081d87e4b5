"""The result of a structure-from-motion run."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skyrecon.core.reconstruction import Reconstruction
from skyrecon.io.jsonio import to_jsonable

__all__ = ["ImageStatus", "SfMResult"]


@dataclass
class ImageStatus:
    """What happened to one input image.

    Attributes:
        name: the image's name (path relative to the common image directory).
        path: the file.
        registered: the image has a pose in the reconstruction.
        reason: why it was left out ("" when registered).
        image_id: its id in ``SfMResult.reconstruction.images`` (registered images), else -1.
        num_features: keypoints detected (0 when unreadable).
        num_points: 3D points it observes.
        mean_error_px: mean reprojection error of those observations, input pixels (NaN if none).
    """

    name: str
    path: str
    registered: bool
    reason: str = ""
    image_id: int = -1
    num_features: int = 0
    num_points: int = 0
    mean_error_px: float = float("nan")


@dataclass
class SfMResult:
    """Cameras, poses and sparse points of the registered images, and why the others are missing.

    Attributes:
        reconstruction: COLMAP-ready model: cameras (intrinsics at the input image size; ids
            from 1), registered images (``cam_from_world``, all their keypoints in input pixels,
            ``point3d_ids``), coloured 3D points with tracks. The world frame is the
            reconstruction's own gauge (first image of the initial pair at the origin, unit
            initial baseline) until aligned (:func:`skyrecon.sfm.align.umeyama`).
        images: one entry per input image, in input order.
        diagnostics: numbers about every stage (features, pairs, tracks, mapper, adjustments).
        timings: seconds per stage (``features``, ``pairs``, ``matching``, ``tracks``,
            ``mapping``, ``total``).
        warnings: human-readable warnings, most important first.
        seed: the seed of the run.
    """

    reconstruction: Reconstruction
    images: list[ImageStatus]
    diagnostics: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    seed: int = 0

    @property
    def registered(self) -> list[str]:
        """Names of the registered images, input order."""
        return [im.name for im in self.images if im.registered]

    @property
    def unregistered(self) -> dict[str, str]:
        """Name -> reason of every image left out."""
        return {im.name: im.reason for im in self.images if not im.registered}

    @property
    def num_registered(self) -> int:
        return sum(1 for im in self.images if im.registered)

    @property
    def complete(self) -> bool:
        """Every input image is registered."""
        return all(im.registered for im in self.images)

    @property
    def note(self) -> str:
        """One paragraph for people: how many images are in the model and which were left out."""
        n, k = len(self.images), self.num_registered
        head = f"{k} of {n} images registered, {len(self.reconstruction.points3d)} 3D points."
        if k == n:
            return head
        lines = [head, "Left out:"]
        lines += [f"  {name}: {why}" for name, why in self.unregistered.items()]
        return "\n".join(lines)

    def mean_reprojection_error_px(self) -> float:
        e = self.reconstruction.reprojection_errors()
        return float(np.mean(e)) if len(e) else float("nan")

    def to_json_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (no keypoints or points)."""

        return to_jsonable(
            {
                "num_images": len(self.images),
                "num_registered": self.num_registered,
                "num_points": len(self.reconstruction.points3d),
                "mean_reprojection_error_px": self.mean_reprojection_error_px(),
                "registered": self.registered,
                "left_out": self.unregistered,
                "images": [vars(im) for im in self.images],
                "warnings": self.warnings,
                "diagnostics": self.diagnostics,
                "timings_s": self.timings,
                "seed": self.seed,
            }
        )
