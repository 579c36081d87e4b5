"""End to end on a small synthetic ring (exact geometry), and the pipeline's answers to bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skyrecon.core import DepthMap, Rigid3
from skyrecon.errors import InputError
from skyrecon.eval.mvs_metrics import evaluate_cloud, reference_from_depth_maps
from skyrecon.executor import SerialExecutor
from skyrecon.io import read_pfm, read_ply
from skyrecon.mvs import MVSSettings, run_mvs, save_mvs_result
from skyrecon.mvs.frames import make_working_view
from skyrecon.mvs.mesh import mesh_from_depth_maps
from skyrecon.mvs.pairwise import _rotated_clockwise, pairwise_depth
from tests.mvs.synthetic import make_ring


def reference(ring, box):
    maps = [DepthMap(d, v.intrinsics, v.cam_from_world) for v, d in zip(ring.views, ring.depths)]
    return reference_from_depth_maps(maps, min_views=2, voxel_m=0.02, crop=box)


def scene_size(ref: np.ndarray) -> float:
    return float(np.linalg.norm(ref.max(0) - ref.min(0)))


@pytest.fixture(scope="module")
def ring():
    return make_ring()


@pytest.fixture(scope="module")
def default_result(ring):
    return run_mvs(
        ring.views, ring.images, MVSSettings(max_image_size=None), executor=SerialExecutor(), progress=False
    )


def test_default_pipeline_is_accurate_and_complete(ring, default_result) -> None:
    res = default_result
    assert not res.warnings
    box = ring.eval_box
    ref = reference(ring, box)
    tau = 0.01 * scene_size(ref)
    m = evaluate_cloud(
        res.cloud.points,
        ref,
        [tau],
        crop=box,
        reference_distance=lambda p: np.abs(ring.city.distance(p, include_ground=True)),
    )
    assert m.fscore[0] >= 0.8, m
    assert m.precision[0] >= 0.9, m
    # outputs: colours, unit normals facing the cameras, depth maps keyed by stem
    c = res.cloud
    assert c.colors is not None and c.normals is not None and len(c) == len(res.support)
    np.testing.assert_allclose(np.linalg.norm(c.normals, axis=1), 1.0, atol=1e-4)
    assert set(res.depth_maps) == {v.name[:-4] for v in ring.views}
    dm = res.depth_maps["ring_000"]
    assert dm.depth_m.shape == (144, 192) and dm.depth_m.dtype == np.float32
    gt = ring.depths[0]
    ok = np.isfinite(dm.depth_m) & np.isfinite(gt)
    assert ok.mean() > 0.4
    assert np.median(np.abs(dm.depth_m[ok] - gt[ok]) / gt[ok]) < 0.01
    assert set(res.timings_s) >= {"load", "sparse", "depth", "fusion", "total"}
    assert res.neighbors["ring_000.png"] and len(res.pairs) >= len(ring.views)


def test_writeup_baseline_runs_and_is_noisier(ring, default_result) -> None:
    res = run_mvs(
        ring.views,
        ring.images,
        MVSSettings.writeup_baseline(max_image_size=None),
        executor=SerialExecutor(),
        progress=False,
    )
    assert res.pairs == [(i, (i + 1) % 10) for i in range(10)]
    assert len(res.cloud) > 0

    def dist(r):
        return np.median(np.abs(ring.city.distance(r.cloud.points.astype(np.float64), include_ground=True)))  # noqa: E731

    assert dist(default_result) < dist(res)


def test_too_few_views_and_mismatched_images(ring) -> None:
    with pytest.raises(InputError, match="at least 2"):
        run_mvs(ring.views[:1], ring.images[:1], progress=False)
    with pytest.raises(InputError, match="images for"):
        run_mvs(ring.views, ring.images[:-1], executor=SerialExecutor(), progress=False)
    small = list(ring.images)
    small[3] = small[3][::2, ::2]
    with pytest.raises(InputError, match="ring_003"):
        run_mvs(ring.views, small, executor=SerialExecutor(), progress=False)


def test_blank_images(ring) -> None:
    black = [np.zeros_like(im) for im in ring.images]
    with pytest.raises(InputError, match="blank"):
        run_mvs(
            ring.views, black, MVSSettings(max_image_size=None), executor=SerialExecutor(), progress=False
        )
    some = list(ring.images)
    some[2] = np.zeros_like(some[2])
    res = run_mvs(
        ring.views, some, MVSSettings(max_image_size=None), executor=SerialExecutor(), progress=False
    )
    assert any("ring_002" in w and "blank" in w for w in res.warnings)
    assert "ring_002" not in res.depth_maps and len(res.cloud) > 0


def test_views_that_see_nothing_in_common(ring) -> None:
    # two cameras looking away from each other at different parts of the world
    v0, v1 = ring.views[0], ring.views[5]
    away = Rigid3.look_at(v1.center_world, v1.center_world + (v1.center_world - ring.city.center))
    views = [v0, type(v1)(v1.name, v1.intrinsics, away)]
    with pytest.raises(InputError, match=r"ring_000.*in common|in common.*ring_000"):
        run_mvs(
            views,
            [ring.images[0], ring.images[5]],
            MVSSettings(max_image_size=None),
            executor=SerialExecutor(),
            progress=False,
        )


@pytest.mark.parametrize("turn", [0, 1])
def test_pairwise_depth_matches_ground_truth_on_both_sides(ring, turn: int) -> None:
    """Neighbour on the right, on the left, and (turned cameras) above/below the reference."""
    wv = [make_working_view(v, im, None, None) for v, im in zip(ring.views, ring.images)]
    gts = list(ring.depths)
    if turn:  # cameras rolled by 90 degrees: the ring's baselines become vertical in the images
        wv = [_rotated_clockwise(v) for v in wv]
        gts = [np.ascontiguousarray(np.rot90(g, -1)) for g in gts]
    for src in (1, len(wv) - 1):
        res = pairwise_depth(wv[0], wv[src], (6.0, 30.0))
        assert res.rotated == bool(turn)
        d, gt = res.depth, gts[0]
        ok = np.isfinite(d) & np.isfinite(gt)
        assert ok.mean() > 0.1
        assert np.median(np.abs(d[ok] - gt[ok]) / gt[ok]) < 0.03  # SGBM at 192x144


def test_save_result_writes_cloud_depth_and_summary(default_result, tmp_path) -> None:
    paths = save_mvs_result(default_result, tmp_path / "out", settings=MVSSettings())
    cloud = read_ply(paths["fused"])
    assert len(cloud) == len(default_result.cloud) and cloud.normals is not None
    d = read_pfm(tmp_path / "out" / "depth" / "ring_000.pfm")
    np.testing.assert_array_equal(np.isnan(d), np.isnan(default_result.depth_maps["ring_000"].depth_m))
    summary = json.loads(paths["summary"].read_text())
    assert summary["points"] == len(cloud) and "timings_s" in summary and "settings" in summary


def test_mesh_from_the_ring_depth_maps(ring, default_result) -> None:
    wv = [make_working_view(v, im, None, None) for v, im in zip(ring.views, ring.images)]
    depths = [default_result.depth_maps[v.stem].depth_m for v in wv]
    verts, faces, colors = mesh_from_depth_maps(wv, depths, default_result.cloud)
    assert len(faces) > 1000 and colors.shape == verts.shape
    lo, hi = ring.eval_box
    near = np.all((verts >= lo) & (verts <= hi), axis=1)
    d = np.abs(ring.city.distance(verts[near].astype(np.float64), include_ground=True))
    assert np.median(d) < 0.1  # metres, at 192x144 with voxels of ~1/250 of the cloud


def test_known_points_replace_the_sparse_matching(ring, default_result, monkeypatch) -> None:
    """Points on the surfaces (an SfM model's, here the true depth's) give the depth ranges and
    sources: no feature matching, and the cloud is as good as with matched points."""
    import skyrecon.mvs.pipeline as pipeline

    def no_matching(*args, **kwargs):
        raise AssertionError("the sparse step matched features although points were given")

    monkeypatch.setattr(pipeline, "sparse_scene", no_matching)
    monkeypatch.setattr(pipeline, "MAX_KNOWN_POINTS", 5000)
    surface = np.concatenate(
        [
            DepthMap(d, v.intrinsics, v.cam_from_world).to_points_world().points
            for v, d in zip(ring.views, ring.depths)
        ]
    )
    surface = np.vstack([surface, [[np.nan, 0.0, 0.0]]])  # a broken point is left out
    res = run_mvs(
        ring.views,
        ring.images,
        MVSSettings(max_image_size=None),
        executor=SerialExecutor(),
        progress=False,
        known_points=surface,
    )
    assert res.diagnostics["sparse_points_source"] == "given"
    assert 2500 < res.diagnostics["sparse_points"] <= 5000
    assert default_result.diagnostics["sparse_points_source"] == "matched"
    box = ring.eval_box
    ref = reference(ring, box)
    tau = 0.01 * scene_size(ref)
    dist = lambda p: np.abs(ring.city.distance(p, include_ground=True))  # noqa: E731
    m = evaluate_cloud(res.cloud.points, ref, [tau], crop=box, reference_distance=dist)
    m0 = evaluate_cloud(default_result.cloud.points, ref, [tau], crop=box, reference_distance=dist)
    assert m.fscore[0] >= 0.8 and m.fscore[0] >= m0.fscore[0] - 0.03, (m, m0)
