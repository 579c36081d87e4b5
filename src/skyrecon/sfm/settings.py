"""Settings of the structure-from-motion pipeline (frozen dataclasses, validated on construction).

Thresholds marked *working pixels* are pixels of the feature-detection resolution (the images
downscaled to ``max_image_size``); the pipeline converts them to input-image pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

from skyrecon.errors import InputError
from skyrecon.features.detect import FeatureSettings
from skyrecon.features.match import MatchSettings
from skyrecon.sfm.bundle import LossName

__all__ = [
    "PairMode",
    "PairingSettings",
    "VerificationSettings",
    "MapperSettings",
    "BundleSettings",
    "SfMSettings",
]

PairMode = Literal["auto", "exhaustive", "sequential", "retrieval"]


@dataclass(frozen=True)
class PairingSettings:
    """Which image pairs are matched.

    Attributes:
        mode: ``"exhaustive"`` (every pair), ``"sequential"`` (frames of a flight: a window of
            following frames, a few frames further ahead, and loop candidates found by image
            retrieval), ``"retrieval"`` (unordered sets: each image with its most similar images)
            or ``"auto"`` (exhaustive up to ``exhaustive_max_images`` images, else sequential
            when the image names are numbered frames, else retrieval; see
            :func:`skyrecon.sfm.pairs.resolve_pair_mode`).
        exhaustive_max_images: the ``auto`` limit for exhaustive matching.
        window: sequential: match each frame with the next ``window`` frames.
        exponential: sequential: also match frames ``2 window, 4 window, ...`` ahead, up to
            ``max_offset``.
        max_offset: sequential: farthest frame offset of the exponential pairs.
        loop_candidates: sequential: per frame, the most similar frames beyond ``max_offset``
            (by global descriptor) that are also matched; 0 disables loop detection.
        loop_min_similarity: sequential: global-descriptor cosine similarity a loop candidate
            must reach.
        retrieval_neighbors: retrieval: most similar images matched with each image.
        retrieval_clusters: visual words of the VLAD global descriptor (learnt on the set).
    """

    mode: PairMode = "auto"
    exhaustive_max_images: int = 50
    window: int = 6
    exponential: bool = True
    max_offset: int = 24
    loop_candidates: int = 2
    loop_min_similarity: float = 0.25
    retrieval_neighbors: int = 20
    retrieval_clusters: int = 64

    def __post_init__(self) -> None:
        if self.mode not in ("auto", "exhaustive", "sequential", "retrieval"):
            raise InputError(
                f"unknown pairing mode {self.mode!r}; use auto, exhaustive, sequential or retrieval"
            )
        if self.window < 1 or self.max_offset < 1 or self.retrieval_neighbors < 1:
            raise InputError("pairing window, max_offset and retrieval_neighbors must be >= 1")
        if self.loop_candidates < 0 or self.exhaustive_max_images < 2 or self.retrieval_clusters < 2:
            raise InputError(
                "loop_candidates must be >= 0, exhaustive_max_images and retrieval_clusters >= 2"
            )


@dataclass(frozen=True)
class VerificationSettings:
    """Matching and geometric verification of a pair.

    A pair is first matched on its ``coarse_features`` strongest features per image and verified
    (5-point LO-RANSAC on the essential matrix); with ``guided`` on, all features are then
    matched along the epipolar lines of that pose (band ``guided_band_px``), and the pose is
    refined on the result and its inliers selected.

    Attributes:
        coarse_features: strongest keypoints per image (by detector response) used for the
            first, exhaustive descriptor match (0: all).
        guided: match all features along epipolar lines after the coarse verification.
        guided_band_px: half-width of the epipolar band, working pixels.
        threshold_px: inlier threshold on the Sampson distance, working pixels.
        min_matches: pairs with fewer putative matches are not verified.
        min_inliers: pairs with fewer inliers are declared unrelated.
        confidence, max_iterations: RANSAC stopping.
        local_optimization: LO-RANSAC (polish every new best model); off by default: the pose of
            a verified pair is refined on all its (guided) matches afterwards anyway, and the
            mapper re-estimates everything by bundle adjustment.
        rotation_support: a pair whose matches are explained this well (share of the E inliers) by
            a rotation alone has no usable translation (pure rotation or identical images).
        homography_iterations: RANSAC samples of a homography test of every verified pair
            (planarity indicator); 0 (default): the mapper tests only its initial-pair candidates.
        max_rotation_inconsistency_deg: a verified pair whose relative rotation differs by more
            than this from the rotations chained along the strongest pairs is rejected (repeated
            structure, e.g. identical facades); 0 disables the check.
    """

    coarse_features: int = 2048
    guided: bool = True
    guided_band_px: float = 2.0
    threshold_px: float = 1.5
    min_matches: int = 20
    min_inliers: int = 15
    confidence: float = 0.999
    max_iterations: int = 1000
    local_optimization: bool = False
    rotation_support: float = 0.8
    homography_iterations: int = 0
    max_rotation_inconsistency_deg: float = 5.0

    def __post_init__(self) -> None:
        if not self.threshold_px > 0 or not self.guided_band_px > 0:
            raise InputError("verification threshold_px and guided_band_px must be positive")
        if self.coarse_features < 0:
            raise InputError(f"coarse_features must be >= 0, got {self.coarse_features}")
        if self.min_inliers < 5 or self.min_matches < self.min_inliers:
            raise InputError("verification needs min_inliers >= 5 and min_matches >= min_inliers")
        if not 0 < self.confidence < 1:
            raise InputError(f"verification confidence must be in (0, 1), got {self.confidence}")


@dataclass(frozen=True)
class MapperSettings:
    """The incremental mapper.

    Attributes:
        init_min_inliers: verified matches an initial pair needs.
        init_min_parallax_deg: median triangulation angle an initial pair needs (relaxed step by
            step when no pair reaches it).
        init_max_homography_ratio: initial pairs whose E inliers a homography explains above this
            share are avoided (planar scenes or rotation: the pose is ill-conditioned).
        init_max_trials: initial pairs tried before giving up.
        init_min_points: 3D points a successful initialisation keeps after its adjustment.
        pnp_threshold_px: inlier threshold of the absolute pose, working pixels.
        pnp_min_inliers, pnp_min_inlier_ratio: acceptance of a registration.
        max_registration_trials: failed attempts before an image is given up (it is tried again
            when the model has grown since its last attempt).
        triangulation_max_error_px: reprojection error of an observation a new point may have,
            working pixels.
        triangulation_min_angle_deg: smallest largest-triangulation-angle of a new point.
        filter_max_error_px: observations above this reprojection error after an adjustment are
            removed, working pixels.
        filter_min_angle_deg: points whose largest triangulation angle falls below this after a
            global adjustment are removed.
        local_ba_images: images adjusted in a local adjustment (the new one and its most
            connected neighbours).
        global_ba_ratio: a global adjustment runs whenever the registered images (or points) grew
            by this factor since the last one.
        final_refinements: rounds of (global adjustment, filtering, re-triangulation) at the end.
        focal_check_tolerance: when the focal length is held fixed, a trial adjustment with it
            free runs at the end; a best-fit focal length off by more than this fraction gives a
            warning (K seems wrong). 0 disables the check.
        focal_check_images: the check adjusts at most about this many images (every k-th
            registered one, with the points they see at least 3 times), so its cost stays flat
            on long flights.
        loop_min_gap: a registered image closes a loop when it sees at least ``loop_min_points``
            points also seen by images registered at least this many registrations earlier
            (and none of the images in between); 0 disables loop handling.
        loop_min_points: points shared with the far past that make a loop.
        loop_max_error_ratio: the global adjustment run on a loop is undone (and the loop's new
            observations dropped) when it raises the RMS reprojection error of the observations
            the model had before the loop by more than this factor.
        loop_consistent_error_ratio: a loop whose points already fit all their views (the RMS
            reprojection error of their observations at most this factor times the model's)
            carries no drift to spread: its global adjustment is skipped (recorded with
            ``"adjusted": false``). 0 adjusts every loop.
    """

    init_min_inliers: int = 100
    init_min_parallax_deg: float = 4.0
    init_max_homography_ratio: float = 0.8
    init_max_trials: int = 12
    init_min_points: int = 50
    pnp_threshold_px: float = 4.0
    pnp_min_inliers: int = 20
    pnp_min_inlier_ratio: float = 0.2
    max_registration_trials: int = 3
    triangulation_max_error_px: float = 4.0
    triangulation_min_angle_deg: float = 1.5
    filter_max_error_px: float = 1.5
    filter_min_angle_deg: float = 1.5
    local_ba_images: int = 6
    global_ba_ratio: float = 1.1
    final_refinements: int = 3
    focal_check_tolerance: float = 0.03
    focal_check_images: int = 200
    loop_min_gap: int = 50
    loop_min_points: int = 30
    loop_max_error_ratio: float = 1.25
    loop_consistent_error_ratio: float = 1.5

    def __post_init__(self) -> None:
        if self.init_min_inliers < 8 or self.pnp_min_inliers < 4 or self.init_min_points < 8:
            raise InputError(
                "mapper: init_min_inliers >= 8, init_min_points >= 8 and pnp_min_inliers >= 4 are needed"
            )
        if not self.global_ba_ratio > 1.0:
            raise InputError(f"mapper: global_ba_ratio must be > 1, got {self.global_ba_ratio}")
        if self.local_ba_images < 1:
            raise InputError("mapper: local_ba_images must be >= 1")
        if self.loop_min_gap < 0 or self.loop_min_points < 1 or not self.loop_max_error_ratio >= 1.0:
            raise InputError(
                "mapper: loop_min_gap >= 0, loop_min_points >= 1 and loop_max_error_ratio >= 1 are needed"
            )
        if not self.loop_consistent_error_ratio >= 0.0:
            raise InputError(
                f"mapper: loop_consistent_error_ratio must be >= 0, got {self.loop_consistent_error_ratio}"
            )


@dataclass(frozen=True)
class BundleSettings:
    """Bundle adjustment inside the mapper: the user-facing policy (which loss, how long local and
    global runs go, which intrinsics to refine). The mapper turns it into the solver's
    :class:`~skyrecon.sfm.bundle.BundleSolverOptions` for each local or global run.

    Attributes:
        loss: robust loss (``"cauchy"``, ``"huber"`` or ``"trivial"``).
        loss_scale_px: scale of the loss, working pixels (divided by the observation sigma when
            ``scale_weighting`` is on); the mapper raises it to the model's measured keypoint
            noise when that is larger (noisier images), never lowers it.
        local_max_iterations, global_max_iterations: LM iterations of local and global runs.
        local_function_tolerance, global_function_tolerance: relative cost decrease below which
            local / intermediate-global runs (loop closures, every final round but the last) stop.
        periodic_function_tolerance: the same for the global runs each 10 % of growth (they keep
            the model consistent for the next registrations; the final runs converge it).
        final_function_tolerance: the same for the last round of the final global run.
        refine_focal_length: estimate the focal length (shared camera) in global adjustments.
        refine_distortion: estimate radial ``k1``, ``k2`` in global adjustments (only for
            intrinsics without tangential or ``k3`` terms).
        scale_weighting: weigh each observation by its keypoint scale (coarse keypoints are
            located less precisely): sigma = keypoint size / median keypoint size, clipped to
            [0.5, 4].
    """

    loss: LossName = "cauchy"
    loss_scale_px: float = 0.25
    local_max_iterations: int = 25
    global_max_iterations: int = 50
    local_function_tolerance: float = 1e-3
    global_function_tolerance: float = 1e-4
    periodic_function_tolerance: float = 1e-3
    final_function_tolerance: float = 1e-6
    refine_focal_length: bool = False
    refine_distortion: bool = False
    scale_weighting: bool = True

    def __post_init__(self) -> None:
        if self.loss not in ("cauchy", "huber", "trivial"):
            raise InputError(f"unknown loss {self.loss!r}; use cauchy, huber or trivial")
        if not self.loss_scale_px > 0:
            raise InputError(f"loss_scale_px must be positive, got {self.loss_scale_px}")


def _default_features() -> FeatureSettings:
    # contrast threshold 0.04 = COLMAP's SIFT peak threshold (0.04 / 3 octave layers / 2)
    return FeatureSettings(
        method="rootsift", max_image_size=1600, max_features=8192, sift_contrast_threshold=0.04
    )


@dataclass(frozen=True)
class SfMSettings:
    """Everything the structure-from-motion pipeline can be told.

    Attributes:
        max_image_size: longer side of the images used for features, pixels (None or 0: the
            input size). Overrides ``features.max_image_size``. Results (intrinsics, keypoints)
            are always in input-image pixels.
        sequential: the images are frames of one flight in order: use sequential pairing
            (a shortcut for ``pairing.mode = "sequential"``).
        features, matching: detector/descriptor and descriptor matching.
        pairing, verification, mapper, bundle: see their classes.
        min_features: images with fewer keypoints are left out (too little texture).
        target_features: SIFT detections with fewer keypoints are repeated with half the contrast
            threshold (at most twice), so small images still get enough features (0: never).
    """

    max_image_size: int | None = 1600
    sequential: bool = False
    features: FeatureSettings = field(default_factory=_default_features)
    matching: MatchSettings = field(default_factory=MatchSettings)
    pairing: PairingSettings = field(default_factory=PairingSettings)
    verification: VerificationSettings = field(default_factory=VerificationSettings)
    mapper: MapperSettings = field(default_factory=MapperSettings)
    bundle: BundleSettings = field(default_factory=BundleSettings)
    min_features: int = 64
    target_features: int = 800

    def __post_init__(self) -> None:
        if self.target_features < 0:
            raise InputError(f"target_features must be >= 0, got {self.target_features}")
        if self.max_image_size is not None and self.max_image_size < 0:
            raise InputError(
                f"max_image_size must be positive (or 0/None for the input size), got {self.max_image_size}"
            )
        if self.max_image_size and self.max_image_size < 64:
            raise InputError(f"max_image_size must be at least 64 pixels, got {self.max_image_size}")
        if self.min_features < 8:
            raise InputError(f"min_features must be at least 8, got {self.min_features}")

    @property
    def feature_settings(self) -> FeatureSettings:
        """The feature settings with ``max_image_size`` applied."""
        return replace(self.features, max_image_size=self.max_image_size or None)

    @property
    def pair_mode(self) -> PairMode:
        """The pairing mode with ``sequential`` applied."""
        return "sequential" if self.sequential else self.pairing.mode
