"""MVS cloud metrics on hand-made clouds."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import DepthMap, Intrinsics, Rigid3
from skyrecon.errors import InputError
from skyrecon.eval.mvs_metrics import (
    evaluate_cloud,
    fraction_outside_box,
    reference_from_depth_maps,
    voxel_subsample,
)


def grid_plane(step: float = 0.01, size: float = 1.0) -> np.ndarray:
    g = np.arange(0.0, size + 1e-9, step)
    x, y = np.meshgrid(g, g)
    return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)


def test_perfect_reconstruction_scores_one() -> None:
    ref = grid_plane()
    m = evaluate_cloud(ref, ref, [0.001, 0.01])
    assert m.precision == [1.0, 1.0] and m.recall == [1.0, 1.0] and m.fscore == [1.0, 1.0]
    assert m.accuracy_mean == 0 and m.completeness_median == 0


def test_offset_and_outliers() -> None:
    ref = grid_plane()
    rec = ref + [0, 0, 0.005]  # 5 mm above the plane
    out = np.array([[0.5, 0.5, 1.0]] * 100)  # 100 outliers 1 m away
    m = evaluate_cloud(np.vstack([rec, out]), ref, [0.002, 0.01])
    n = len(rec)
    assert m.precision[0] == 0.0 and m.recall[0] == 0.0
    assert m.precision[1] == pytest.approx(n / (n + 100))
    assert m.recall[1] == 1.0
    f = 2 * m.precision[1] / (1 + m.precision[1])
    assert m.fscore[1] == pytest.approx(f)
    assert m.accuracy_median == pytest.approx(0.005)
    assert m.accuracy_90 == pytest.approx(0.005)
    assert m.at(0.009) == (m.precision[1], m.recall[1], m.fscore[1])


def test_half_missing_reconstruction_has_half_recall() -> None:
    ref = grid_plane()
    rec = ref[ref[:, 0] < 0.495]
    m = evaluate_cloud(rec, ref, [0.001])
    assert m.precision[0] == 1.0
    assert m.recall[0] == pytest.approx(0.5, abs=0.02)


def test_exact_distance_function_and_crop() -> None:
    ref = grid_plane()
    rng = np.random.default_rng(1)
    rec = np.c_[rng.uniform(0, 1, (1000, 2)), rng.normal(0, 0.002, 1000)]
    far = np.array([[5.0, 5.0, 0.5]])
    m = evaluate_cloud(
        np.vstack([rec, far]),
        ref,
        [0.004],
        reference_distance=lambda p: np.abs(p[:, 2]),
        crop=([-0.1, -0.1, -1], [1.1, 1.1, 1]),
    )
    assert m.num_cropped_out == 1 and m.num_reconstructed == 1000
    assert m.precision[0] == pytest.approx(np.mean(np.abs(rec[:, 2]) <= 0.004))


def test_empty_reconstruction_and_bad_input() -> None:
    ref = grid_plane()
    m = evaluate_cloud(np.zeros((0, 3)), ref, [0.01])
    assert m.fscore == [0.0] and m.accuracy_mean == float("inf")
    with pytest.raises(InputError):
        evaluate_cloud(ref, np.zeros((0, 3)), [0.01])
    with pytest.raises(InputError):
        evaluate_cloud(ref, ref, [])
    with pytest.raises(InputError):
        evaluate_cloud(ref[:, :2], ref, [0.01])


def test_fraction_outside_box() -> None:
    pts = np.array([[0, 0, 0], [0.5, 0.5, 0.5], [2, 0, 0], [0, 0, -0.05]], float)
    assert fraction_outside_box(pts, [0, 0, 0], [1, 1, 1]) == pytest.approx(0.5)
    assert fraction_outside_box(pts, [0, 0, 0], [1, 1, 1], margin=0.1) == pytest.approx(0.25)
    assert fraction_outside_box(np.zeros((0, 3)), [0, 0, 0], [1, 1, 1]) == 0.0


def test_voxel_subsample_evens_density() -> None:
    dense = np.vstack([grid_plane(0.001, 0.1), grid_plane(0.02, 1.0)])
    sub = voxel_subsample(dense, 0.02)
    assert len(sub) < len(dense) / 5


def test_reference_from_depth_maps_keeps_covisible_surface() -> None:
    intr = Intrinsics.from_fov(40, 30, 60.0)
    maps = []
    for x in (-0.5, 0.5):
        pose = Rigid3.look_at([x, 0, 3.0], [x, 0, 0], up_world=(0, 1, 0))
        depth = np.full((30, 40), 3.0, np.float32)  # fronto-parallel plane z = 0 at 3 m
        maps.append(DepthMap(depth, intr, pose))
    one = reference_from_depth_maps(maps, min_views=1)
    both = reference_from_depth_maps(maps, min_views=2)
    assert len(one) == 2 * 40 * 30
    assert 0 < len(both) < len(one)
    assert np.abs(both[:, 2]).max() < 1e-5
    assert np.abs(both[:, 0]).max() < 1.7  # only the overlap of the two footprints
