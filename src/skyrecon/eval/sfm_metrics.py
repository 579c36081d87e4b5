"""Accuracy of a structure-from-motion result against ground-truth cameras.

Reconstructions live in their own gauge, so errors are measured after alignment:

* rotation error: the best global rotation ``Q`` between the two world frames is fitted to all
  camera rotations (chordal L2 mean), then each image's error is the angle between
  ``R_est Q^T`` and ``R_gt`` (both ``cam_from_world``);
* camera-centre error: a similarity (Umeyama) maps the estimated centres onto the true ones
  (for collinear centres its rotation is ``Q``); each image's error is the remaining distance, in metres and as a percentage of the scene
  extent (the largest distance between two ground-truth centres, or the diagonal of their
  bounding box: stated with the numbers).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.spatial import ConvexHull

from skyrecon.core.rigid import Rigid3, rotation_angle_deg
from skyrecon.errors import EstimationError, InputError
from skyrecon.sfm.align import umeyama

__all__ = ["ExtentKind", "scene_extent", "rotation_alignment", "SfMEvaluation", "evaluate_sfm_poses"]

ExtentKind = Literal["max_distance", "bbox_diagonal"]


def scene_extent(centers: np.ndarray, kind: ExtentKind = "max_distance") -> float:
    """Size of a camera set, metres: the largest distance between two (N, 3) centres
    (``"max_distance"``) or the diagonal of their axis-aligned bounding box (``"bbox_diagonal"``)."""
    c = np.asarray(centers, np.float64).reshape(-1, 3)
    if len(c) < 2:
        return 0.0
    if kind == "bbox_diagonal":
        return float(np.linalg.norm(c.max(axis=0) - c.min(axis=0)))
    if kind != "max_distance":
        raise InputError(f"unknown extent kind {kind!r}; use max_distance or bbox_diagonal")
    if len(c) > 2000:  # the farthest pair are vertices of the convex hull
        try:
            c = c[ConvexHull(c).vertices]
        except Exception:  # flat or degenerate sets: keep all points
            pass
    d = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=2)
    return float(d.max())


def rotation_alignment(R_est: np.ndarray, R_gt: np.ndarray) -> np.ndarray:
    """(3, 3) rotation ``Q`` (estimated world -> true world) minimising ``sum |R_est_i Q^T - R_gt_i|_F``
    for (N, 3, 3) ``cam_from_world`` rotations."""
    M = np.einsum(
        "nji,njk->ik", np.asarray(R_gt, np.float64), np.asarray(R_est, np.float64)
    )  # sum R_gt^T R_est
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


@dataclass
class SfMEvaluation:
    """Per-image errors of a reconstruction against ground truth.

    Attributes:
        names: evaluated images (registered and with ground truth), in ground-truth order.
        rotation_errors_deg: (N,) after the global rotation alignment.
        center_errors_m: (N,) after the similarity alignment, metres.
        extent_m: scene extent, metres; extent_kind: how it was measured.
        num_ground_truth: images with ground truth; missing: those not registered.
        scale: scale of the similarity (metres per reconstruction unit).
    """

    names: list[str]
    rotation_errors_deg: np.ndarray
    center_errors_m: np.ndarray
    extent_m: float
    extent_kind: str
    num_ground_truth: int
    missing: list[str] = field(default_factory=list)
    scale: float = float("nan")

    @property
    def center_errors_pct(self) -> np.ndarray:
        """(N,) centre errors as a percentage of the scene extent."""
        return (
            100.0 * self.center_errors_m / self.extent_m
            if self.extent_m > 0
            else np.full(len(self.names), np.nan)
        )

    def summary(self) -> dict[str, float]:
        """Median and maximum of each error (NaN when nothing was evaluated)."""

        def stat(a: np.ndarray, f) -> float:
            return float(f(a)) if len(a) else float("nan")

        return {
            "registered": float(len(self.names)),
            "ground_truth": float(self.num_ground_truth),
            "rotation_median_deg": stat(self.rotation_errors_deg, np.median),
            "rotation_max_deg": stat(self.rotation_errors_deg, np.max),
            "center_median_m": stat(self.center_errors_m, np.median),
            "center_max_m": stat(self.center_errors_m, np.max),
            "center_median_pct": stat(self.center_errors_pct, np.median),
            "center_max_pct": stat(self.center_errors_pct, np.max),
            "extent_m": self.extent_m,
        }


def evaluate_sfm_poses(
    estimated: Mapping[str, Rigid3],
    ground_truth: Mapping[str, Rigid3],
    extent_kind: ExtentKind = "max_distance",
) -> SfMEvaluation:
    """Compare estimated and true ``cam_from_world`` poses by image name.

    Args:
        estimated: name -> estimated pose (reconstruction gauge).
        ground_truth: name -> true pose (metres).
        extent_kind: how the scene extent is measured (from all ground-truth centres).
    Returns:
        SfMEvaluation (empty arrays when fewer than 3 images can be compared).
    """
    gt_names = list(ground_truth)
    names = [n for n in gt_names if n in estimated]
    missing = [n for n in gt_names if n not in estimated]
    extent = scene_extent(
        np.stack([ground_truth[n].center for n in gt_names]) if gt_names else np.zeros((0, 3)), extent_kind
    )
    if len(names) < 3:
        return SfMEvaluation(names, np.zeros(0), np.zeros(0), extent, extent_kind, len(gt_names), missing)
    R_est = np.stack([estimated[n].R for n in names])
    R_gt = np.stack([ground_truth[n].R for n in names])
    Q = rotation_alignment(R_est, R_gt)
    rot = np.array([rotation_angle_deg((Re @ Q.T).T @ Rg) for Re, Rg in zip(R_est, R_gt)])
    C_est = np.stack([estimated[n].center for n in names])
    C_gt = np.stack([ground_truth[n].center for n in names])
    try:
        fit = umeyama(C_est, C_gt, with_scale=True)
        res, scale = fit.residuals, fit.transform.scale
    except EstimationError:
        # collinear centres (a straight flight): the rotation comes from the camera rotations
        a = C_est - C_est.mean(axis=0)
        b = C_gt - C_gt.mean(axis=0)
        qa = a @ Q.T
        scale = float(np.sum(qa * b) / max(np.sum(a * a), 1e-300))
        res = np.linalg.norm(scale * qa - b, axis=1)
    return SfMEvaluation(names, rot, res, extent, extent_kind, len(gt_names), missing, scale)
