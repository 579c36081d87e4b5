"""The cleanup step of MVS: outlier and floater removal, oriented normals, optional voxel averaging."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from skyrecon.core import PointCloud
from skyrecon.mvs.cloud_ops import (
    knn_mean_distance_and_normals,
    orient_normals,
    small_component_mask,
    statistical_outlier_mask,
    voxel_downsample_indices,
)
from skyrecon.mvs.frames import WorkingView
from skyrecon.mvs.fusion import FusedCloud
from skyrecon.mvs.settings import MVSSettings

__all__ = ["CleanCloud", "clean_fused_cloud"]


@dataclass
class CleanCloud:
    """What :func:`clean_fused_cloud` returns.

    Attributes:
        cloud: world-frame points (N, 3) float32 metres, colours (N, 3) uint8 RGB, normals
            (N, 3) float32 unit, facing the cameras that saw them.
        support: (N,) int32 views that agreed on each point (with voxels: the most in the voxel).
        counts: points left after each filter, in order: ``points_fused``,
            ``points_after_outlier_removal``, ``points_after_component_filter`` (when that
            filter is on), ``points_after_voxel`` (with voxels).
    """

    cloud: PointCloud
    support: np.ndarray
    counts: dict[str, int] = field(default_factory=dict)


def _voxel_average(cloud: PointCloud, support: np.ndarray, voxel_m: float) -> tuple[PointCloud, np.ndarray]:
    """Points, colours and normals averaged per voxel of side ``voxel_m`` metres (normals renormalised);
    support is the largest in each voxel."""
    inv, counts = voxel_downsample_indices(cloud.points, voxel_m)
    m = len(counts)
    w = 1.0 / counts[:, None]

    def avg(a: np.ndarray) -> np.ndarray:
        out = np.zeros((m, a.shape[1]))
        np.add.at(out, inv, a.astype(np.float64))
        return out * w

    normals = np.zeros((len(cloud), 3)) if cloud.normals is None else cloud.normals
    nrm = avg(normals)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    sup = np.zeros(m, np.int64)
    np.maximum.at(sup, inv, support)
    colors = None if cloud.colors is None else avg(cloud.colors.astype(np.float64))
    averaged = PointCloud(avg(cloud.points).astype(np.float32), colors, nrm.astype(np.float32))
    return averaged, sup.astype(np.int32)


def clean_fused_cloud(fused: FusedCloud, views: Sequence[WorkingView], settings: MVSSettings) -> CleanCloud:
    """Statistical outlier removal, small-component removal, oriented normals, voxel averaging.

    Args:
        fused: the fused cloud (world frame) and the reference view of each point.
        views: the working views (``fused.view_index`` refers to them); normals are turned to
            face the camera centre of the view that emitted each point.
        settings: ``outlier_k``, ``outlier_std``, ``component_min_fraction``,
            ``component_radius_factor`` and ``voxel_size_m``.
    Returns:
        CleanCloud in the world frame.
    """
    cloud, vid, support = fused.cloud, fused.view_index, fused.support
    counts = {"points_fused": len(cloud)}
    if len(cloud) == 0:
        return CleanCloud(
            PointCloud(cloud.points, cloud.colors, np.zeros((0, 3), np.float32)), support, counts
        )
    mean_d, normals = knn_mean_distance_and_normals(cloud.points, settings.outlier_k)
    if settings.outlier_std > 0 and len(cloud) > settings.outlier_k:
        keep = statistical_outlier_mask(mean_d, settings.outlier_std)
        cloud, vid, support, normals = cloud.select(keep), vid[keep], support[keep], normals[keep]
    counts["points_after_outlier_removal"] = len(cloud)
    if settings.component_min_fraction > 0 and len(cloud) > settings.outlier_k:
        radius = settings.component_radius_factor * float(np.median(mean_d))
        keep = small_component_mask(cloud.points, radius, settings.component_min_fraction, settings.outlier_k)
        cloud, vid, support, normals = cloud.select(keep), vid[keep], support[keep], normals[keep]
        counts["points_after_component_filter"] = len(cloud)
    centers = np.stack([v.center_world for v in views])
    cloud = PointCloud(cloud.points, cloud.colors, orient_normals(cloud.points, normals, centers, vid))
    if settings.voxel_size_m:
        cloud, support = _voxel_average(cloud, support, settings.voxel_size_m)
        counts["points_after_voxel"] = len(cloud)
    return CleanCloud(cloud, support, counts)
