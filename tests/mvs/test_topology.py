"""Named topologies (the write-up's pair lists) and automatic neighbour selection."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import DepthMap
from skyrecon.errors import InputError
from skyrecon.mvs import MVSSettings, neighbors_from_pairs, select_neighbors, topology_pairs
from skyrecon.mvs.frames import make_working_view
from skyrecon.mvs.topology import angle_weight
from tests.mvs.synthetic import make_ring

# The write-up's lists for its 12 cameras, verbatim.
WRITEUP = {
    "360": tuple(zip((0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11), (1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 0))),
    "overlapping": tuple(zip((0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10), (1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11))),
    "adjacent": tuple(zip((0, 2, 4, 6, 8, 10), (1, 3, 5, 7, 9, 11))),
    "skipping_1": tuple(zip((0, 3, 6, 9), (1, 4, 7, 10))),
    "skipping_2": tuple(zip((0, 4, 8), (1, 5, 9))),
}


@pytest.mark.parametrize("name", sorted(WRITEUP))
def test_topologies_match_the_writeup_for_12_views(name: str) -> None:
    assert tuple(topology_pairs(name, 12)) == WRITEUP[name]


def test_topologies_generalise_to_other_counts() -> None:
    assert topology_pairs("360", 5) == [(0, 1), (1, 2), (2, 3), (3, 4), (4, 0)]
    assert topology_pairs("overlapping", 4) == [(0, 1), (1, 2), (2, 3)]
    assert topology_pairs("adjacent", 7) == [(0, 1), (2, 3), (4, 5)]
    assert topology_pairs("skipping_1", 16) == [(0, 1), (3, 4), (6, 7), (9, 10), (12, 13)]
    assert topology_pairs("skipping_2", 16) == [(0, 1), (4, 5), (8, 9), (12, 13)]
    assert topology_pairs("360", 2) == [(0, 1)]
    for name in WRITEUP:
        for n in range(2, 20):
            pairs = topology_pairs(name, n)
            assert pairs and all(0 <= a < n and 0 <= b < n and a != b for a, b in pairs)


def test_bad_topology_names_and_counts() -> None:
    with pytest.raises(InputError, match="unknown topology"):
        topology_pairs("ring", 12)
    with pytest.raises(InputError, match="auto"):
        topology_pairs("auto", 12)
    with pytest.raises(InputError, match="at least 2"):
        topology_pairs("360", 1)


def test_neighbors_from_pairs() -> None:
    pairs = topology_pairs("360", 4)
    assert neighbors_from_pairs(pairs, 4) == [[1, 3], [0, 2], [1, 3], [2, 0]]
    assert neighbors_from_pairs(pairs, 4, symmetric=False) == [[1], [2], [3], [0]]


def test_angle_weight_prefers_moderate_angles() -> None:
    w = angle_weight(np.array([1.0, 5.0, 7.5, 20.0, 37.5, 45.0, 70.0]), 5.0, 45.0, (10.0, 30.0))
    np.testing.assert_allclose(w, [0, 0, 0.5, 1, 0.5, 0, 0])


def test_auto_selection_picks_ring_neighbours() -> None:
    ring = make_ring()
    n = len(ring.views)
    wv = [make_working_view(v, im, None, None) for v, im in zip(ring.views, ring.images)]
    # sparse points: the exact surface seen by view 0 and others, no images needed
    pts = []
    for v, d in zip(ring.views, ring.depths):
        pts.append(DepthMap(d, v.intrinsics, v.cam_from_world).to_points_world().points[::97])
    P = np.concatenate(pts).astype(np.float64)
    nb, scores = select_neighbors(wv, 4, P, max_angle_deg=65.0)
    for r in range(n):
        assert len(nb[r]) == 4
        ring_dist = sorted(min((s - r) % n, (r - s) % n) for s in nb[r])
        assert ring_dist == [1, 1, 2, 2], (r, nb[r])
        assert scores[r] == sorted(scores[r], reverse=True)
    # frustum fallback without sparse points gives the same kind of answer
    nb2, _ = select_neighbors(wv, 2, None, [(6.0, 14.0)] * n)
    assert all(sorted(min((s - r) % n, (r - s) % n) for s in nb2[r]) == [1, 1] for r in range(n))


def _reference_scores(wv, P, r, lo, hi, min_shared):  # type: ignore[no-untyped-def]
    """The per-source loop the selection computes, written out plainly (one view at a time)."""

    def visible(view, X):  # type: ignore[no-untyped-def]
        uv, z = view.posed().project(X)
        return view.intrinsics.in_image(uv) & (z > 0)

    centers = np.stack([v.center_world for v in wv])
    X = P[visible(wv[r], P)]
    dr = (X - centers[r]) / np.linalg.norm(X - centers[r], axis=1, keepdims=True)
    out = {}
    for s in range(len(wv)):
        m = visible(wv[s], X)
        if s == r or m.sum() < min_shared:
            continue
        ds = (X[m] - centers[s]) / np.linalg.norm(X[m] - centers[s], axis=1, keepdims=True)
        w = angle_weight(np.degrees(np.arccos(np.clip(np.sum(dr[m] * ds, axis=1), -1, 1))), lo, hi)
        if np.count_nonzero(w) >= min_shared:
            out[s] = float(w.sum())
    return out


def test_auto_selection_scores_every_source_like_the_plain_loop() -> None:
    ring = make_ring()
    wv = [make_working_view(v, im, None, None) for v, im in zip(ring.views, ring.images)]
    rng = np.random.default_rng(3)
    P = rng.uniform(-3.0, 3.0, (4000, 3))  # points around the ring's centre, seen by some views
    nb, scores = select_neighbors(wv, len(wv), P, min_angle_deg=5.0, max_angle_deg=65.0, min_shared=10)
    checked = 0
    for r in range(len(wv)):
        ref = _reference_scores(wv, P, r, 5.0, 65.0, 10)
        assert sorted(nb[r]) == sorted(ref), r
        for s, sc in zip(nb[r], scores[r]):
            assert sc == pytest.approx(ref[s], rel=1e-9)
            checked += 1
    assert checked > len(wv)


def test_settings_from_command_line_names() -> None:
    s = MVSSettings.from_names()
    assert (s.topology, s.depth_method, s.fusion) == ("auto", "patchmatch", "consistency")
    s = MVSSettings.from_names("adjacent", "concat", mesh=True)
    assert (s.topology, s.depth_method, s.fusion, s.mesh) == ("adjacent", "pairwise", "concat", True)
    assert MVSSettings.from_names(None, "concat").topology == "360"
    assert MVSSettings.from_names("360").depth_method == "patchmatch"
    with pytest.raises(InputError, match="unknown fusion"):
        MVSSettings.from_names(None, "average")
    with pytest.raises(InputError, match="unknown topology"):
        MVSSettings.from_names("ring")
