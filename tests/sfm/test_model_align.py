"""skyrecon.sfm.model_align: camera-centre fits and ICP with scale against known similarities."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from skyrecon.core import Image, Intrinsics, Point3D, PointCloud, Reconstruction, Rigid3
from skyrecon.core.rigid import rotvec_to_matrix
from skyrecon.errors import InputError
from skyrecon.sfm.align import Sim3, estimate_normals
from skyrecon.sfm.model_align import (
    AlignOptions,
    align_model,
    align_to_positions,
    centroid_init,
    check_spread,
    fit_camera_centres,
    icp_plane_with_scale,
    icp_refine,
    match_names,
    merged_cloud,
)


def _box_surface(n: int, seed: int) -> np.ndarray:
    """Points on the faces of a 4 x 3 x 2 m box plus a ground patch (a shape that fixes all 7 unknowns)."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-2, -1.5, 0], [2, 1.5, 2], (n, 3))
    face = rng.integers(0, 5, n)
    pts[face == 0, 0] = -2
    pts[face == 1, 0] = 2
    pts[face == 2, 1] = -1.5
    pts[face == 3, 1] = 1.5
    pts[face == 4, 2] = 2
    ground = np.column_stack([rng.uniform(-5, 5, n // 2), rng.uniform(-5, 5, n // 2), np.zeros(n // 2)])
    return np.vstack([pts, ground])


TRUE = Sim3(rotvec_to_matrix(np.array([0.03, -0.02, 0.05])), np.array([0.2, -0.1, 0.15]), 1.04)


def test_point_to_plane_icp_recovers_scale():
    target = _box_surface(6000, 0)
    source = TRUE.inverse().apply(_box_surface(4000, 1))  # other samples of the same surfaces
    tree = cKDTree(target)
    normals = estimate_normals(target, 12, tree)
    T, iterations, converged, rmse, fitness, n = icp_plane_with_scale(
        source, Sim3(np.eye(3), np.zeros(3), 1.0), target, normals, tree, 1.0, 100, 10.0
    )
    assert converged and fitness > 0.9
    assert abs(T.scale - TRUE.scale) < 2e-3
    assert np.degrees(np.arccos(np.clip((np.trace(T.R @ TRUE.R.T) - 1) / 2, -1, 1))) < 0.1
    assert np.linalg.norm(T.t - TRUE.t) < 0.01


def test_icp_refine_from_centroid_start():
    target = _box_surface(6000, 2)
    source = TRUE.inverse().apply(_box_surface(4000, 3))
    T0 = centroid_init(source, target, with_scale=True)
    T, stats = icp_refine(source, PointCloud(target.astype(np.float32)), T0, True, None, 60, seed=0)
    assert stats["converged"]
    assert abs(T.scale - TRUE.scale) < 5e-3
    assert np.linalg.norm(T.apply(source) - TRUE.apply(source), axis=1).max() < 0.03


def test_camera_centre_fit_and_degenerate_layouts():
    rng = np.random.default_rng(4)
    src = rng.uniform(-10, 10, (12, 3))
    dst = TRUE.apply(src)
    dst[3] += 5.0  # one GPS glitch
    fit, thr = fit_camera_centres(src, dst, [f"im{k}" for k in range(12)], True, None, 0, "positions")
    assert abs(fit.transform.scale - TRUE.scale) < 1e-6
    assert not fit.inliers[3] and fit.inliers.sum() == 11  # the glitch is set aside
    line = np.outer(np.arange(5.0), [1.0, 2.0, 0.5])
    with pytest.raises(InputError, match="line"):
        check_spread(line, "positions", ["a", "b", "c", "d", "e"])


def _model(points: np.ndarray, centres: np.ndarray, names: list[str]) -> Reconstruction:
    """A model with cameras at ``centres`` (looking along +z) and ``points`` (no tracks)."""
    rec = Reconstruction({1: Intrinsics.from_fov(64, 48, 60)})
    for k, (c, name) in enumerate(zip(centres, names), start=1):
        pose = Rigid3(np.eye(3), -np.asarray(c, float), "cam", "world")
        rec.images[k] = Image(k, name, 1, pose, np.zeros((0, 2)), np.zeros(0, np.int64))
    for k, p in enumerate(points, start=1):
        rec.points3d[k] = Point3D(k, p, np.array([200, 100, 50], np.uint8), 0.0, np.zeros((0, 2), np.int64))
    return rec


CENTRES = np.array([[0, 0, 5], [3, 0, 5], [6, 1, 5.5], [6, 4, 5], [3, 5, 4.5], [0, 4, 5], [-2, 2, 5]], float)
NAMES = [f"img_{k:02d}.jpg" for k in range(len(CENTRES))]


def test_align_to_positions_sets_a_glitch_aside():
    model_from_world = TRUE.inverse()
    rec = _model(model_from_world.apply(_box_surface(200, 4)), model_from_world.apply(CENTRES), NAMES)
    positions = {n: c.copy() for n, c in zip(NAMES, CENTRES)}
    positions[NAMES[3]] += [3.0, -2.0, 1.0]  # a GPS glitch
    positions["not_here.jpg"] = np.zeros(3)
    result = align_model(rec, positions, AlignOptions(max_distance=0.5), reference_label="gps.txt")
    assert result.method == "positions" and result.reference == "gps.txt"
    assert result.outliers == [NAMES[3]] and result.num_inliers == len(NAMES) - 1
    assert result.residuals_m is not None and result.residuals_m[NAMES[3]] == pytest.approx(
        np.sqrt(14), rel=1e-3
    )
    assert result.residual_rms_m < 1e-9 and result.world_from_model.scale == pytest.approx(TRUE.scale)
    assert result.positions_without_image == ["not_here.jpg"] and result.images_without_position == []
    assert any("do not fit the others" in w for w in result.warnings)
    summary = result.to_json_dict()
    assert list(summary)[:8] == [
        "method",
        "world_from_model",
        "scale",
        "R",
        "t",
        "rotation_deg",
        "model",
        "reference",
    ]
    assert (
        summary["inlier_threshold_m"] == 0.5 and "icp" not in summary and summary["num_images"] == len(NAMES)
    )


def test_align_to_positions_needs_three_matches():
    rec = _model(_box_surface(50, 5), CENTRES, NAMES)
    with pytest.raises(InputError, match="at least 3"):
        align_to_positions(rec, {NAMES[0]: CENTRES[0], NAMES[1]: CENTRES[1]}, reference="gps.txt")
    with pytest.raises(InputError, match="none of the 1 names"):
        align_to_positions(rec, {"other.jpg": CENTRES[0]}, reference="gps.txt")


def test_align_to_model_by_common_images_then_icp():
    world_pts = _box_surface(3000, 6)
    ref = _model(world_pts, CENTRES, NAMES)
    model_from_world = TRUE.inverse()
    rec = _model(
        model_from_world.apply(_box_surface(2000, 7)), model_from_world.apply(CENTRES[1:]), NAMES[1:]
    )
    result = align_model(rec, ref, AlignOptions(seed=1), model_label="m", reference_label="r")
    assert result.method == "model" and result.init == "camera centres" and result.icp is not None
    assert result.num_correspondences == len(NAMES) - 1 and result.outliers == []
    assert np.allclose(result.world_from_model.matrix, TRUE.matrix, atol=1e-3)
    assert result.reference_points is not None and len(result.reference_points) == len(world_pts)
    aligned = result.world_from_model.transform_reconstruction(rec)
    merged = merged_cloud(aligned, result.reference_points)
    assert len(merged) == len(rec.points3d) + len(world_pts)


def test_align_to_cloud_from_centroids_and_the_icp_residuals():
    target = PointCloud(_box_surface(6000, 8).astype(np.float32))
    rec = _model(TRUE.inverse().apply(_box_surface(3000, 9)), CENTRES, NAMES)
    result = align_model(rec, target, AlignOptions(max_iterations=60), reference_label="scan.ply")
    assert result.method == "cloud" and result.icp is not None and result.icp["converged"]
    assert result.residuals_of.startswith("point-to-plane") and result.residual_median_m < 0.01
    assert result.num_correspondences == result.icp["num_correspondences"]
    assert abs(result.world_from_model.scale - TRUE.scale) < 5e-3
    with pytest.raises(InputError, match="only 5 points"):
        align_model(rec, PointCloud(np.zeros((5, 3), np.float32)), reference_label="scan.ply")


def test_match_names_by_name_file_name_and_stem():
    m = match_names(["images/a.png", "images/b.png", "c.png"], ["a.png", "b", "c.png", "z.png"])
    assert m == {"c.png": "c.png", "images/a.png": "a.png", "images/b.png": "b"}


def test_align_to_model_without_common_names_and_without_icp_keeps_the_init():
    ref = _model(_box_surface(500, 10), CENTRES, NAMES)
    rec = _model(TRUE.inverse().apply(_box_surface(300, 11)), CENTRES[:2], ["a.jpg", "b.jpg"])
    options = AlignOptions(init=TRUE, refine_with_icp=False)
    result = align_model(rec, ref, options)
    assert result.world_from_model is TRUE and result.icp is None
    assert result.residuals_of.startswith("none") and np.isnan(result.residual_rms_m)
    assert result.to_json_dict()["icp"] is None
    with pytest.raises(InputError, match="no image names in common"):
        align_model(rec, ref, AlignOptions())
