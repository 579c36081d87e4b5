"""Settings of the two-view pipeline (one frozen dataclass, validated on construction)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from skyrecon.errors import InputError
from skyrecon.features.detect import FeatureSettings
from skyrecon.features.match import MatchSettings
from skyrecon.geometry.fundamental import FundamentalMethod

__all__ = ["TwoViewSettings", "PoseMethod", "DenseMethod"]

PoseMethod = Literal["essential", "fundamental"]
DenseMethod = Literal["stereo", "epipolar"]


@dataclass(frozen=True)
class TwoViewSettings:
    """Everything the two-view pipeline can be told.

    Attributes:
        features: detector/descriptor and working resolution (default RootSIFT at 1536 px).
        matching: ratio test (0.8), mutual check.
        pose_method: ``"essential"`` (5-point LO-RANSAC with known K; default) or
            ``"fundamental"`` (estimate F with ``fundamental_method``, then ``E = K2^T F K1``).
        fundamental_method: ``"ransac"``, ``"lmeds"``, ``"magsac"``, ``"8point"`` or ``"7point"``;
            also used for the F that diagnoses wrong intrinsics.
        threshold_px: inlier threshold on the Sampson distance, pixels *of the working
            (detection) resolution*.
        confidence, max_iterations, min_iterations: RANSAC stopping.
        refine: final robust (Cauchy) refinement of (R, t) on all inliers.
        refine_loss_scale_px: scale of that loss, working pixels.
        scale_weighting: in that refinement, weigh each match by the inverse of its expected
            localisation error (proportional to the keypoint sizes): fine-scale keypoints are
            located more precisely than coarse ones.
        scale_noise_floor: localisation noise that does not shrink with the keypoint size, as a
            fraction of the median match's noise: ``sigma ~ sqrt(floor^2 + (size / median)^2)``.
        min_inliers: fewer pose inliers than this -> the pair is declared unrelated (no pose).
        min_inlier_ratio: a smaller share of the matches agreeing on the pose -> unrelated too.
        triangulation: ``"optimal"``, ``"midpoint"``, ``"dlt"`` or ``"pinv"`` (write-up's method).
        max_reprojection_px: sparse points with a larger reprojection error (working pixels)
            are dropped.
        min_parallax_deg: sparse points with a smaller triangulation angle are dropped.
        dense: compute the dense model.
        dense_method: ``"stereo"`` (rectify + disparity matcher; default) or ``"epipolar"``
            (direct NCC window search along epipolar lines on a pixel grid).
        dense_fallback: when stereo is impossible (forward motion: the epipole is in the image;
            a disparity range too wide), use the epipolar search instead of giving up.
        stereo_matcher: matcher name for the stereo engine (``"sgbm"`` uses OpenCV when the
            engine is not installed).
        rectification: ``"calibrated"`` (ours, from R, t), ``"opencv"`` (cv2.stereoRectify) or
            ``"uncalibrated"`` (Hartley, from F).
        dense_max_image_size: longer side of the rectified images, pixels.
        dense_step: keep every ``dense_step``-th row and column of the disparity as points.
        epipolar_window, epipolar_step, epipolar_min_ncc: window side, grid step (working pixels)
            and acceptance NCC of the ``"epipolar"`` dense method.
        baseline_m: metric distance between the camera centres when known; points are then in
            metres, otherwise in units of the baseline (|t| = 1).
        parallel_features: detect features of both images in two threads.
    """

    features: FeatureSettings = field(default_factory=FeatureSettings)
    matching: MatchSettings = field(default_factory=MatchSettings)
    pose_method: PoseMethod = "essential"
    fundamental_method: FundamentalMethod = "ransac"
    threshold_px: float = 1.0
    confidence: float = 0.9999
    max_iterations: int = 2000
    min_iterations: int = 64
    refine: bool = True
    refine_loss_scale_px: float = 0.35
    scale_weighting: bool = True
    scale_noise_floor: float = 0.5
    min_inliers: int = 15
    min_inlier_ratio: float = 0.15
    triangulation: str = "optimal"
    max_reprojection_px: float = 2.0
    min_parallax_deg: float = 0.25
    dense: bool = True
    dense_method: DenseMethod = "stereo"
    dense_fallback: bool = True
    stereo_matcher: str = "sgbm"
    rectification: str = "calibrated"
    dense_max_image_size: int = 1536
    dense_step: int = 1
    epipolar_window: int = 7
    epipolar_step: int = 4
    epipolar_min_ncc: float = 0.9
    baseline_m: float | None = None
    parallel_features: bool = True

    def __post_init__(self) -> None:
        if self.pose_method not in ("essential", "fundamental"):
            raise InputError(f"unknown pose method {self.pose_method!r}; use essential or fundamental")
        if self.fundamental_method not in ("ransac", "lmeds", "magsac", "8point", "7point"):
            raise InputError(
                f"unknown fundamental method {self.fundamental_method!r}; use ransac, lmeds, magsac, 8point or 7point"
            )
        if not self.threshold_px > 0:
            raise InputError(f"threshold_px must be positive, got {self.threshold_px}")
        if not (0 < self.confidence < 1):
            raise InputError(f"confidence must be in (0, 1), got {self.confidence}")
        if self.triangulation not in ("optimal", "midpoint", "dlt", "pinv"):
            raise InputError(
                f"unknown triangulation {self.triangulation!r}; use optimal, midpoint, dlt or pinv"
            )
        if self.dense_method not in ("stereo", "epipolar"):
            raise InputError(f"unknown dense method {self.dense_method!r}; use stereo or epipolar")
        if self.rectification not in ("calibrated", "opencv", "uncalibrated"):
            raise InputError(
                f"unknown rectification {self.rectification!r}; use calibrated, opencv or uncalibrated"
            )
        if self.baseline_m is not None and not (self.baseline_m > 0):
            raise InputError(f"baseline_m must be positive, got {self.baseline_m}")
        if self.dense_max_image_size < 64:
            raise InputError(f"dense_max_image_size must be at least 64, got {self.dense_max_image_size}")
        if self.dense_step < 1 or self.epipolar_step < 1:
            raise InputError("dense_step and epipolar_step must be >= 1")
        if self.min_inliers < 5:
            raise InputError(f"min_inliers must be at least 5, got {self.min_inliers}")
