"""Union-find, track building (conflicts split or dropped), pair selection, multi-view
triangulation and the SfM metrics."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Rigid3, rotvec_to_matrix
from skyrecon.core.rigid import rotation_angle_deg
from skyrecon.errors import InputError
from skyrecon.eval.sfm_metrics import evaluate_sfm_poses, scene_extent
from skyrecon.sfm.align import Sim3
from skyrecon.sfm.matching import PairGeometry
from skyrecon.sfm.pairs import (
    exhaustive_pairs,
    resolve_pair_mode,
    retrieval_pairs,
    select_pairs,
    sequential_pairs,
)
from skyrecon.sfm.settings import PairingSettings
from skyrecon.sfm.tracks import UnionFind, build_tracks
from skyrecon.sfm.triangulation import max_triangulation_angles_deg, triangulate_tracks
from skyrecon.sfm.viewgraph import chained_rotations, rotation_inconsistent_pairs


def test_union_find_joins_sets():
    uf = UnionFind(6)
    uf.union([0, 2], [1, 3])
    uf.union(1, 3)
    r = uf.find(np.arange(6))
    assert r[0] == r[1] == r[2] == r[3]
    assert len({r[0], r[4], r[5]}) == 3
    with pytest.raises(InputError):
        uf.union(0, 6)


def test_consistent_union_refuses_two_nodes_of_one_image():
    uf = UnionFind(4)
    image = np.array([0, 1, 0, 2])
    refused = uf.union_consistent(np.array([0, 1, 3]), np.array([1, 2, 2]), image)
    assert refused == 1  # 1-2 would put nodes 0 and 2 (both image 0) together
    r = uf.find(np.arange(4))
    assert r[0] == r[1] and r[2] == r[3] and r[0] != r[2]


def test_tracks_chain_matches_across_images():
    # a point seen in images 0, 1, 2 (keypoints 5, 7, 1) and another in 1, 2 (0, 3)
    tracks = build_tracks([10, 10, 10], [(0, 1, np.array([[5, 7]])), (1, 2, np.array([[7, 1], [0, 3]]))])
    assert tracks.num_tracks == 2
    assert sorted(tracks.lengths.tolist()) == [2, 3]
    long = int(np.argmax(tracks.lengths))
    assert tracks.track(long).tolist() == [[0, 5], [1, 7], [2, 1]]
    assert tracks.kp_track[0][5] == long and tracks.kp_track[2][1] == long
    assert tracks.kp_track[0][0] == -1
    o = tracks.kp_obs[1][7]
    assert tracks.obs_image[o] == 1 and tracks.obs_kp[o] == 7


def test_inconsistent_tracks_are_dropped_or_split():
    # image 0 keypoints 1 and 2 both end up linked through image 1 and 2
    pairs = [(0, 1, np.array([[1, 4]])), (1, 2, np.array([[4, 6]])), (0, 2, np.array([[2, 6]]))]
    kp = [np.array([[0, 0], [10, 10], [50, 50]], float), np.zeros((5, 2)), np.zeros((7, 2))]
    dropped = build_tracks([3, 5, 7], pairs, kp, conflicts="drop")
    assert dropped.num_tracks == 0 and dropped.num_inconsistent == 1
    split = build_tracks([3, 5, 7], pairs, kp, conflicts="split")
    assert split.num_inconsistent == 1  # one match refused
    assert all(len(set(split.track(k)[:, 0])) == split.lengths[k] for k in range(split.num_tracks))
    assert split.num_observations == 4
    # co-located duplicates (same point detected twice) are merged rather than dropped
    kp_close = [np.array([[0, 0], [10, 10], [10.3, 10.2]], float), np.zeros((5, 2)), np.zeros((7, 2))]
    merged = build_tracks([3, 5, 7], pairs, kp_close, conflicts="drop")
    assert merged.num_tracks == 1 and merged.lengths[0] == 3


def test_pair_selection_modes():
    assert len(exhaustive_pairs(5)) == 10
    seq = sequential_pairs(100, window=3, exponential=True, max_offset=12)
    offsets = set((seq[:, 1] - seq[:, 0]).tolist())
    assert offsets == {1, 2, 3, 6, 12}
    assert len(seq) < 5 * 100  # linear in the number of frames
    S = -np.ones((6, 6))
    S[0, 5] = S[5, 0] = 0.9
    np.fill_diagonal(S, -np.inf)
    loops = retrieval_pairs(S, 1, exclude_within=2, min_similarity=0.5)
    assert loops.tolist() == [[0, 5]]
    sel = select_pairs(
        40,
        "sequential",
        PairingSettings(window=2, max_offset=8, loop_candidates=1),
        lambda: np.eye(40)[np.r_[np.arange(20), np.arange(20)]],
    )
    assert sel.mode == "sequential" and sel.num_loop_pairs > 0
    assert select_pairs(6, "auto", PairingSettings()).mode == "exhaustive"
    with pytest.raises(InputError):
        select_pairs(1, "auto", PairingSettings())


def test_one_auto_pairing_rule():
    settings = PairingSettings()
    frames = [f"frame_{k:05d}.png" for k in range(0, 2 * 60, 2)]
    photos = [f"{name}_{k}.jpg" for k in range(20) for name in ("tower", "gate", "wall")]
    assert resolve_pair_mode("auto", frames[:50], settings) == "exhaustive"
    assert resolve_pair_mode("auto", frames, settings) == "sequential"
    assert resolve_pair_mode("auto", photos, settings) == "retrieval"
    assert resolve_pair_mode("retrieval", frames, settings) == "retrieval"
    descriptors = lambda: np.eye(60)  # noqa: E731
    assert select_pairs(60, "auto", settings, descriptors, names=frames).mode == "sequential"
    assert select_pairs(60, "auto", settings, descriptors).mode == "retrieval"  # no names: not numbered


def _cams(n: int = 4):
    R, t = [], []
    for k in range(n):
        T = Rigid3.look_at([-3 + 2 * k, -10, 1.0], [0, 0, 0])
        R.append(T.R)
        t.append(T.t)
    return np.array(R), np.array(t)


def test_multiview_triangulation_rejects_outlier_observations():
    R, t = _cams(4)
    rng = np.random.default_rng(0)
    X = rng.uniform(-1, 1, (50, 3))
    obs_img = np.tile(np.arange(4), 50)
    P = np.einsum("nij,nj->ni", R[obs_img], np.repeat(X, 4, axis=0)) + t[obs_img]
    xn = P[:, :2] / P[:, 2:]
    xn += rng.normal(0, 0.2 / 800, xn.shape)
    xn[1::20] += 0.05  # one observation of every 5th track is wrong
    ptr = np.arange(0, 201, 4)
    res = triangulate_tracks(ptr, xn, obs_img, R, t, np.full(4, 800.0), max_error_px=2.0, min_angle_deg=1.0)
    assert res.ok.all()
    assert np.abs(res.points - X).max() < 0.03  # 0.2 px noise, 10 m away
    assert not res.inliers[1::20].any()
    assert res.inliers.sum() == 200 - 10
    ang = max_triangulation_angles_deg(ptr, res.points, obs_img, -np.einsum("kji,kj->ki", R, t), res.inliers)
    assert np.all(ang >= 1.0) and np.all(res.angles_deg >= 1.0)  # exact, and bounds on the same side
    # too small an angle: rejected
    res2 = triangulate_tracks(ptr, xn, obs_img, R, t, np.full(4, 800.0), min_angle_deg=60.0)
    assert not res2.ok.any()


def test_max_angles_are_exact_and_their_bounds_decide_like_the_exact_ones():
    """Long tracks (a camera moving along a line, points near and far): with a threshold the
    O(L) cone bounds may stand in for the O(L^2) search, always on the same side of it."""
    rng = np.random.default_rng(3)
    n_cams = 120
    centers = np.stack([np.linspace(0, 30, n_cams), rng.normal(0, 0.2, n_cams), np.zeros(n_cams)], axis=1)
    n_pts = 400
    X = np.stack(
        [
            rng.uniform(0, 30, n_pts),
            rng.uniform(-10, 10, n_pts),
            np.exp(rng.uniform(np.log(2), np.log(5000), n_pts)),
        ],
        axis=1,
    )
    lens = rng.integers(2, n_cams, n_pts)
    ptr = np.concatenate([[0], np.cumsum(lens)]).astype(np.int64)
    obs_img = np.concatenate([np.sort(rng.choice(n_cams, k, replace=False)) for k in lens])
    active = rng.random(len(obs_img)) > 0.1
    exact = max_triangulation_angles_deg(ptr, X, obs_img, centers, active)
    naive = np.zeros(n_pts)
    for k in range(n_pts):
        sel = np.arange(ptr[k], ptr[k + 1])[active[ptr[k] : ptr[k + 1]]]
        d = X[k] - centers[obs_img[sel]]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        naive[k] = np.degrees(np.arccos(np.clip((d @ d.T).min(), -1, 1))) if len(sel) >= 2 else 0.0
    np.testing.assert_allclose(exact, naive, atol=1e-6)
    assert 0.2 < np.mean(exact >= 1.5) < 0.9  # both sides of the threshold are exercised
    for threshold in (0.3, 1.5, 5.0, 20.0):
        bounded = max_triangulation_angles_deg(ptr, X, obs_img, centers, active, threshold)
        np.testing.assert_array_equal(bounded >= threshold, exact >= threshold)


def test_sfm_metrics_are_invariant_to_a_similarity():
    R, t = _cams(5)
    gt = {f"{k}": Rigid3(R[k], t[k]) for k in range(5)}
    S = Sim3(rotvec_to_matrix([0.3, -0.2, 1.0]), [5, 6, 7], 0.25)
    est = {k: S.transform_pose(v) for k, v in gt.items()}
    ev = evaluate_sfm_poses(est, gt)
    assert ev.rotation_errors_deg.max() < 1e-6
    assert ev.center_errors_m.max() < 1e-9
    assert abs(ev.scale - 4.0) < 1e-9
    C = np.stack([v.center for v in gt.values()])
    assert ev.extent_m == pytest.approx(scene_extent(C))
    assert scene_extent(C, "bbox_diagonal") >= ev.extent_m - 1e-9
    del est["3"]
    assert evaluate_sfm_poses(est, gt).missing == ["3"]


def test_view_graph_rejects_pairs_with_inconsistent_rotations():
    rng = np.random.default_rng(0)
    R = [rotvec_to_matrix(rng.normal(0, 0.3, 3)) for _ in range(8)]
    pairs = []
    for i in range(8):
        for j in range(i + 1, min(8, i + 3)):
            Rij = R[j] @ R[i].T @ rotvec_to_matrix(rng.normal(0, 0.002, 3))
            pairs.append(
                PairGeometry(i, j, "ok", 300, np.zeros((300 - 10 * (j - i), 2), np.int32), Rij, np.ones(3))
            )
    # a repeated-structure pair: many matches, rotation off by 90 degrees
    wrong = R[7] @ R[1].T @ rotvec_to_matrix([0, 0, np.pi / 2])
    pairs.append(PairGeometry(1, 7, "ok", 250, np.zeros((250, 2), np.int32), wrong, np.ones(3)))
    bad, err = rotation_inconsistent_pairs(pairs, 8, 5.0)
    assert bad == [len(pairs) - 1]
    assert err[-1] == pytest.approx(90.0, abs=1.0)
    assert np.nanmax(err[:-1]) < 1.0


def test_a_long_flight_keeps_its_true_loops_despite_a_few_wrong_neighbour_pairs():
    """600 frames: neighbour pairs (up to 3 apart) accurate to 0.02 deg except every 25th
    adjacent pair, which is 1.5 deg off (and has the most matches, as in a small-baseline
    ambiguity); the flight comes back to its start. Chained along the strongest pairs these
    add up to about 8 deg and every true loop would be rejected; averaged over all neighbour
    pairs they are outvoted: the true loops stay and a look-alike loop 20 deg off goes."""
    rng = np.random.default_rng(3)
    n = 600
    yaw = np.linspace(0, 2 * np.pi, n, endpoint=False)
    R = [rotvec_to_matrix([0.0, 0.0, a]) @ rotvec_to_matrix(rng.normal(0, 0.05, 3)) for a in yaw]
    pairs, trusted = [], []

    def add(i, j, noise_rad, inliers, ok):
        Rij = R[j] @ R[i].T @ rotvec_to_matrix(rng.normal(0, noise_rad, 3))
        pairs.append(PairGeometry(i, j, "ok", inliers, np.zeros((inliers, 2), np.int32), Rij, np.ones(3)))
        trusted.append(ok)

    for i in range(n):
        for d in (1, 2, 3):
            if i + d < n:
                wrong = d == 1 and i % 25 == 7
                noise = np.radians(1.5 / np.sqrt(3) if wrong else 0.02)
                add(i, i + d, noise, 500 - 20 * d + 50 * wrong, True)
    loops = list(range(len(pairs), len(pairs) + 10))
    for k in range(10):
        add(k, n - 10 + k, np.radians(0.05), 200, False)
    look_alike = R[300] @ R[40].T @ rotvec_to_matrix([0.0, 0.0, np.radians(20)])
    pairs.append(PairGeometry(40, 300, "ok", 60, np.zeros((60, 2), np.int32), look_alike, np.ones(3)))
    trusted.append(False)
    chained, _ = chained_rotations([p for p, ok in zip(pairs, trusted) if ok], n)
    chained_loop_err = [
        rotation_angle_deg(pairs[k].R.T @ chained[pairs[k].j] @ chained[pairs[k].i].T) for k in loops
    ]
    assert min(chained_loop_err) > 5.0  # the case at stake: the chain has drifted
    bad, err = rotation_inconsistent_pairs(pairs, n, 5.0, np.array(trusted))
    assert bad == [len(pairs) - 1]
    assert np.nanmax(err[loops]) < 1.0
