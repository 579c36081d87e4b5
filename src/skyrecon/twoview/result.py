"""Result types of the two-view pipeline."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from skyrecon.core.depth import PointCloud
from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.geometry.rectification import Rectification
from skyrecon.io.jsonio import to_jsonable

__all__ = ["Status", "TwoViewGeometry", "DenseResult", "TwoViewResult"]

Status = Literal["ok", "uncertain", "no_translation", "failed"]
"""``ok``: pose estimated (warnings may still apply); ``uncertain``: a pose was estimated but a
diagnostic casts doubt on it (e.g. the intrinsics seem wrong); ``no_translation``: the matches
are explained by a rotation alone (identical images, pure rotation): R is given, t is None;
``failed``: no pose (unrelated images / too few inliers)."""


@dataclass
class TwoViewGeometry:
    """Relative geometry of two views estimated from matches.

    Attributes:
        status: see :data:`Status`.
        R: (3, 3) rotation cam2_from_cam1, or None when ``failed``.
        t: (3,) unit translation direction cam2_from_cam1 (``x_cam2 = R x_cam1 + t``), or None
            unless ``ok`` / ``uncertain``.
        E: (3, 3) essential matrix ``[t]x R`` (normalised coordinates) or None.
        F: (3, 3) fundamental matrix for full-resolution pixels (``x2^T F x1 = 0``), unit
            Frobenius norm, or None. With a pose it is ``K2^-T E K1^-1``.
        inliers: (M,) bool per match.
        errors_px: (M,) Sampson distance to the final model, full-resolution pixels (NaN
            without a model).
        warnings: human-readable warnings, most important first.
        diagnostics: numbers behind the warnings (inlier counts/ratios of E, F, H and of a
            rotation-only model, median parallax, ...).
    """

    status: Status
    R: np.ndarray | None
    t: np.ndarray | None
    E: np.ndarray | None
    F: np.ndarray | None
    inliers: np.ndarray
    errors_px: np.ndarray
    warnings: list[str] = field(default_factory=list)
    diagnostics: dict[str, float] = field(default_factory=dict)

    @property
    def num_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))

    @property
    def has_pose(self) -> bool:
        """Both R and t are known."""
        return self.R is not None and self.t is not None


@dataclass
class DenseResult:
    """Dense reconstruction of a pair.

    Attributes:
        method: ``"stereo"`` or ``"epipolar"``.
        cloud: coloured points in camera 1's frame (metres with a metric baseline, else
            baseline units).
        rectification: the rectification used (stereo method), else None.
        left, right: (H, W, 3) uint8 rectified images (stereo method), else None.
        disparity: (H, W) float32 disparity of the rectified left image, pixels, NaN where
            invalid (``x_right = x_left - d``), else None.
        matcher: name of the disparity matcher that ran.
        warnings: what happened on the way (e.g. a fallback from stereo to epipolar search).
    """

    method: str
    cloud: PointCloud
    rectification: Rectification | None = None
    left: np.ndarray | None = None
    right: np.ndarray | None = None
    disparity: np.ndarray | None = None
    matcher: str = ""
    warnings: list[str] = field(default_factory=list)


@dataclass
class TwoViewResult:
    """Everything the two-view pipeline produced for one pair.

    Attributes:
        geometry: the relative geometry (status, R, t, E, F, inliers, warnings, diagnostics).
        intrinsics1, intrinsics2: the cameras (full resolution).
        keypoints1, keypoints2: (N1, 2), (N2, 2) float64 full-resolution pixels of every
            detected keypoint.
        matches: (M, 2) int64 indices ``[i1, i2]`` into the keypoints.
        sparse: triangulated inliers, camera 1's frame, float32 with colours from image 1.
        sparse_match_index: (K,) int64 row of ``matches`` of every sparse point.
        dense: the dense model, or None (not requested or impossible; see warnings).
        timings: seconds per stage (``features``, ``matching``, ``geometry``, ``sparse``,
            ``dense`` and ``total``).
        baseline_m: the metric baseline the clouds are scaled with, or None (unit baseline).
    """

    geometry: TwoViewGeometry
    intrinsics1: Intrinsics
    intrinsics2: Intrinsics
    keypoints1: np.ndarray
    keypoints2: np.ndarray
    matches: np.ndarray
    sparse: PointCloud
    sparse_match_index: np.ndarray
    dense: DenseResult | None
    timings: dict[str, float]
    baseline_m: float | None = None

    # ----- convenience views -------------------------------------------------
    @property
    def status(self) -> Status:
        return self.geometry.status

    @property
    def R(self) -> np.ndarray | None:
        return self.geometry.R

    @property
    def t(self) -> np.ndarray | None:
        return self.geometry.t

    @property
    def E(self) -> np.ndarray | None:
        return self.geometry.E

    @property
    def F(self) -> np.ndarray | None:
        return self.geometry.F

    @property
    def inliers(self) -> np.ndarray:
        return self.geometry.inliers

    @property
    def warnings(self) -> list[str]:
        return self.geometry.warnings

    @property
    def x1(self) -> np.ndarray:
        """(M, 2) matched pixels in image 1."""
        return self.keypoints1[self.matches[:, 0]]

    @property
    def x2(self) -> np.ndarray:
        """(M, 2) matched pixels in image 2."""
        return self.keypoints2[self.matches[:, 1]]

    @property
    def num_matches(self) -> int:
        return int(len(self.matches))

    @property
    def num_inliers(self) -> int:
        return self.geometry.num_inliers

    @property
    def cam2_from_cam1(self) -> Rigid3 | None:
        """The pose as a Rigid3 (|t| = 1, or the metric baseline), or None without a full pose."""
        R, t = self.geometry.R, self.geometry.t
        if R is None or t is None:
            return None
        s = 1.0 if self.baseline_m is None else self.baseline_m
        return Rigid3(R, t * s, "cam2", "cam1")

    def to_json_dict(self) -> dict[str, Any]:
        """The ``two_view.json`` content: R, t (|t| = 1), F, E, counts, status, warnings.

        Matrices are nested lists; missing ones (no pose) and non-finite diagnostics are None,
        so ``json.dumps(..., allow_nan=False)`` works.
        """

        return to_jsonable(
            {
                "R": self.R,
                "t": self.t,
                "F": self.F,
                "E": self.E,
                "num_matches": self.num_matches,
                "num_inliers": self.num_inliers,
                "status": self.status,
                "warnings": list(self.warnings),
                "num_sparse_points": len(self.sparse),
                "num_dense_points": 0 if self.dense is None else len(self.dense.cloud),
                "baseline_m": self.baseline_m,
                "diagnostics": dict(self.geometry.diagnostics),
                "timings_s": dict(self.timings),
            }
        )
