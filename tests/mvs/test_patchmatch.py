"""PatchMatch depth of one view against exact ground truth; determinism; settings checks."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.mvs import PatchMatchSettings, patchmatch_depth
from skyrecon.mvs.frames import make_working_view
from skyrecon.mvs.patchmatch import texture_mask
from tests.mvs.synthetic import make_ring


@pytest.fixture(scope="module")
def views():
    ring = make_ring()
    return [make_working_view(v, im, None, None) for v, im in zip(ring.views, ring.images)], ring.depths


def test_depth_matches_ground_truth(views) -> None:
    wv, gts = views
    res = patchmatch_depth(wv[0], [wv[1], wv[9], wv[2], wv[8]], (5.0, 40.0), seed=3)
    gt = gts[0]
    inside = np.isfinite(gt) & (gt < 30.0)  # the monument and the plaza (not the far horizon)
    ok = np.isfinite(res.depth) & inside
    assert ok.sum() > 0.6 * inside.sum()
    rel = np.abs(res.depth[ok] - gt[ok]) / gt[ok]
    assert np.median(rel) < 0.005 and np.mean(rel < 0.05) > 0.7  # raw, before fusion, at 192x144
    valid = np.isfinite(res.depth)
    n = res.normal[valid]
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-4)
    rays = wv[0].intrinsics.ray_directions()[valid]
    assert np.all(np.sum(n * rays, axis=1) < 0)  # facing the camera
    assert np.all(res.cost[np.isfinite(res.depth)] <= PatchMatchSettings().max_cost)


def test_same_seed_same_result_for_any_thread_count(views) -> None:
    wv, _ = views
    s = PatchMatchSettings(iterations=2)
    a = patchmatch_depth(wv[0], [wv[1], wv[9]], (5.0, 40.0), s, seed=7)
    b = patchmatch_depth(wv[0], [wv[1], wv[9]], (5.0, 40.0), replace(s, threads=2), seed=7)
    np.testing.assert_array_equal(a.depth, b.depth)
    c = patchmatch_depth(wv[0], [wv[1], wv[9]], (5.0, 40.0), s, seed=8)
    assert not np.array_equal(np.nan_to_num(a.depth), np.nan_to_num(c.depth))


def test_flat_images_give_no_depth(views) -> None:
    wv, _ = views
    flat = replace(wv[0], grey=np.full_like(wv[0].grey, 90.0))
    res = patchmatch_depth(flat, [wv[1]], (5.0, 40.0), PatchMatchSettings(iterations=1))
    assert not np.isfinite(res.depth).any()
    mask = texture_mask(wv[0].grey, np.ones(wv[0].shape, bool), 4, 1.5)
    assert mask.any() and not mask[:4].any() and not mask[:, -4:].any()


def test_bad_arguments(views) -> None:
    wv, _ = views
    with pytest.raises(InputError, match="source"):
        patchmatch_depth(wv[0], [], (5.0, 40.0))
    with pytest.raises(InputError, match="depth range"):
        patchmatch_depth(wv[0], [wv[1]], (5.0, 1.0))
    with pytest.raises(InputError):
        PatchMatchSettings(window_radius=1, window_step=2)
    with pytest.raises(InputError):
        PatchMatchSettings(candidates=9)
