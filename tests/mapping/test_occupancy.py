"""Occupancy map: log-odds updates, free-space carving, ranges, sparse storage, accuracy, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import DepthMap, Intrinsics, Rigid3
from skyrecon.errors import InputError
from skyrecon.mapping import FREE, OCCUPIED, UNKNOWN, MapConfig, OccupancyMap, build_map_from_depth_frames
from skyrecon.mapping.config import logit


def look(eye, target) -> Rigid3:
    """``world_from_cam`` of a camera at ``eye`` looking at ``target`` (world metres)."""
    return (
        Rigid3.look_at(np.asarray(eye, float), np.asarray(target, float))
        .inverse()
        .with_frames("world", "cam")
    )


CAM = Intrinsics.from_fov(64, 48, 60.0)
# camera at the origin looking along +x: a wall 10 m ahead fills the image
POSE = look([0.05, 0.05, 0.05], [10.05, 0.05, 0.05])


def wall_depth(d: float = 10.0) -> np.ndarray:
    """Depth image of a plane perpendicular to the optical axis at distance d (z-depth is constant)."""
    return np.full((CAM.height, CAM.width), d, np.float32)


def test_log_odds_hits_misses_and_clamping():
    cfg = MapConfig(voxel_size_m=0.5)
    m = OccupancyMap(cfg)
    origin = np.array([0.25, 0.25, 0.25])
    end = np.array([5.25, 0.25, 0.25])
    l_hit, l_miss, lo, hi = logit(0.7), logit(0.4), logit(cfg.clamp_min), logit(cfg.clamp_max)
    for k in range(1, 9):
        m.integrate_points(end[None], origin)
        assert m.log_odds_at(end[None])[0] == pytest.approx(min(k * l_hit, hi), abs=1e-5)
        assert m.log_odds_at(np.array([[2.25, 0.25, 0.25]]))[0] == pytest.approx(
            max(k * l_miss, lo), abs=1e-5
        )
    assert m.state_at(np.array([end, [2.25, 0.25, 0.25], [0.25, 3.25, 0.25]])).tolist() == [
        OCCUPIED,
        FREE,
        UNKNOWN,
    ]
    # clamping keeps the map able to change its mind: a few misses free the voxel again
    for _ in range(10):  # 3.51 / 0.405 > 8 misses from the upper clamp
        m.integrate_points(np.array([[9.25, 0.25, 0.25]]), origin)
    assert m.state_at(end[None])[0] == FREE


def test_occupied_wins_within_one_scan():
    m = OccupancyMap(voxel_size_m=0.5)
    origin = np.array([0.25, 0.25, 0.25])
    pts = np.array([[3.25, 0.25, 0.25], [6.25, 0.25, 0.25]])  # the second ray crosses the first end point
    st = m.integrate_points(pts, origin)
    assert m.state_at(pts[:1])[0] == OCCUPIED
    assert st.hit_updates == 2
    assert m.log_odds_at(pts[:1])[0] == pytest.approx(logit(0.7), abs=1e-6)  # updated once, not twice


def test_depth_carves_free_space_and_marks_the_wall():
    m = OccupancyMap(voxel_size_m=0.25, max_range_m=30.0)
    st = m.integrate_depth(wall_depth(10.0), CAM, POSE)
    assert st.hit_updates > 0 and st.free_updates > 0
    along = np.array([[x, 0.05, 0.05] for x in np.arange(1.0, 9.5, 0.5)])
    assert np.all(m.state_at(along) == FREE)
    assert m.state_at(np.array([[10.1, 0.05, 0.05]]))[0] == OCCUPIED  # the voxel holding the wall
    assert m.state_at(np.array([[11.5, 0.05, 0.05]]))[0] == UNKNOWN  # behind the wall
    assert m.state_at(np.array([[5.0, 8.0, 0.05]]))[0] == UNKNOWN  # outside the field of view


def test_surface_pull_takes_the_surface_nearer_the_sensor():
    # a wall measured 5 cm into the voxel [10.5, 11.0) along x: by default that voxel holds it
    # and the one in front is free; pulled back 0.2 voxel (10 cm), the hit goes to the voxel in
    # front and the one behind stays unknown (stereo noise behind a surface cannot be cleared)
    front, behind = np.array([[10.25, 0.05, 0.05]]), np.array([[10.75, 0.05, 0.05]])
    plain = OccupancyMap(voxel_size_m=0.5, max_range_m=30.0)
    plain.integrate_depth(wall_depth(10.5), CAM, POSE)
    assert (plain.state_at(front)[0], plain.state_at(behind)[0]) == (FREE, OCCUPIED)
    pulled = OccupancyMap(voxel_size_m=0.5, max_range_m=30.0, surface_pull_voxels=0.2)
    pulled.integrate_depth(wall_depth(10.5), CAM, POSE)
    assert (pulled.state_at(front)[0], pulled.state_at(behind)[0]) == (OCCUPIED, UNKNOWN)
    assert pulled.state_at(np.array([[9.25, 0.05, 0.05]]))[0] == FREE
    # the same for points cast as rays
    origin = np.array([0.25, 0.25, 0.25])
    rays = OccupancyMap(voxel_size_m=0.5, surface_pull_voxels=0.2)
    rays.integrate_points(np.array([[10.55, 0.25, 0.25]]), origin)
    assert rays.state_at(np.array([[10.25, 0.25, 0.25], [10.75, 0.25, 0.25]])).tolist() == [OCCUPIED, UNKNOWN]
    for bad in (-0.1, 0.6):
        with pytest.raises(InputError, match="surface_pull_voxels"):
            MapConfig(surface_pull_voxels=bad)


def test_a_stale_prior_belief_is_freed_by_its_first_miss():
    """``stale_log_odds``: voxels seeded with yesterday's "occupied" (exactly that value) are
    freed by the first miss of today's measurements, by depth (whole octants carved free and
    voxels tested one by one) and by rays; a voxel hit first takes ``logit(prob_hit)`` as an
    unknown one would (today's first measurement replaces yesterday's belief) and then misses as
    usual; with the setting off, the same miss only lowers it."""
    stale = 1.0
    box = np.full((40, 8, 8), np.nan, np.float32)  # x 0..20 m, y, z -2..2 m at 0.5 m
    box[4:36] = stale  # a prior "block" the camera now sees through up to the wall at 19 m
    origin = np.array([0.0, -2.0, -2.0])
    l_miss = logit(0.4)
    probes = np.array([[3.25, 0.25, 0.25], [9.75, -0.25, 0.25], [17.25, 0.75, -0.25]])
    on = OccupancyMap.from_dense_log_odds(box, origin, MapConfig(voxel_size_m=0.5, stale_log_odds=stale))
    off = OccupancyMap.from_dense_log_odds(box, origin, MapConfig(voxel_size_m=0.5))
    for m in (on, off):
        assert np.all(m.state_at(probes) == OCCUPIED)
        m.integrate_depth(wall_depth(19.0), CAM, POSE)
    assert on.log_odds_at(probes) == pytest.approx([l_miss] * 3, abs=1e-6)
    assert np.all(on.state_at(probes) == FREE)
    assert off.log_odds_at(probes) == pytest.approx([stale + l_miss] * 3, abs=1e-6)
    assert np.all(off.state_at(probes) == OCCUPIED)
    # rays: a voxel hit first starts from a fresh hit, not from yesterday's belief; one miss
    # does not free it, three do (as for a voxel first seen today); an untouched one is freed
    origin_ray = np.array([0.25, 0.25, 0.25])
    rays = OccupancyMap.from_dense_log_odds(box, origin, MapConfig(voxel_size_m=0.5, stale_log_odds=stale))
    hit, seen_through = np.array([[6.25, 0.25, 0.25]]), np.array([[4.25, 0.25, 0.25]])
    rays.integrate_points(hit, origin_ray)  # seen through the nearer voxel, hit at 6.25
    assert rays.log_odds_at(seen_through)[0] == pytest.approx(l_miss, abs=1e-6)
    assert rays.log_odds_at(hit)[0] == pytest.approx(logit(0.7), abs=1e-6)
    rays.integrate_points(np.array([[12.25, 0.25, 0.25]]), origin_ray)  # now through both
    assert rays.log_odds_at(hit)[0] == pytest.approx(logit(0.7) + l_miss, abs=1e-5)
    assert rays.state_at(hit)[0] == OCCUPIED
    assert rays.log_odds_at(seen_through)[0] == pytest.approx(2 * l_miss, abs=1e-6)
    for _ in range(2):
        rays.integrate_points(np.array([[12.25, 0.25, 0.25]]), origin_ray)
    assert rays.state_at(hit)[0] == FREE
    # depth integration and add_hits: a stale voxel hit takes logit(prob_hit); a voxel hit before
    # adds to what it holds
    depth_map = OccupancyMap.from_dense_log_odds(
        box, origin, MapConfig(voxel_size_m=0.5, stale_log_odds=stale)
    )
    depth_map.integrate_depth(wall_depth(9.0), CAM, POSE)
    wall_voxel = np.array([[9.25, 0.25, 0.25]])
    assert depth_map.log_odds_at(wall_voxel)[0] == pytest.approx(logit(0.7), abs=1e-6)
    added = OccupancyMap.from_dense_log_odds(box, origin, MapConfig(voxel_size_m=0.5, stale_log_odds=stale))
    added.add_hits(np.array([[10, 0, 0]]))  # the voxel at x 5..5.5, y 0..0.5 (index from origin 0)
    hit_twice = np.array([[5.25, 0.25, 0.25]])
    assert added.log_odds_at(hit_twice)[0] == pytest.approx(logit(0.7), abs=1e-6)
    added.add_hits(np.array([[10, 0, 0]]))
    assert added.log_odds_at(hit_twice)[0] == pytest.approx(2 * logit(0.7), abs=1e-5)
    with pytest.raises(InputError, match="stale_log_odds"):
        MapConfig(stale_log_odds=float("inf"))


def test_max_range_carves_up_to_the_range_without_hits():
    m = OccupancyMap(voxel_size_m=0.25, max_range_m=6.0)
    st = m.integrate_depth(wall_depth(20.0), CAM, POSE)
    assert st.hit_updates == 0
    assert np.all(m.state_at(np.array([[x, 0.05, 0.05] for x in (1.0, 3.0, 5.5)])) == FREE)
    assert np.all(m.state_at(np.array([[x, 0.05, 0.05] for x in (7.0, 12.0, 20.1)])) == UNKNOWN)
    assert m.counts()["occupied"] == 0


def test_invalid_depth_is_ignored_and_inf_means_nothing_within_range():
    m = OccupancyMap(voxel_size_m=0.25, max_range_m=8.0)
    m.integrate_depth(np.full((CAM.height, CAM.width), np.nan, np.float32), CAM, POSE)
    assert m.counts()["free"] == 0 and m.counts()["occupied"] == 0
    m.integrate_depth(np.full((CAM.height, CAM.width), np.inf, np.float32), CAM, POSE)
    assert m.state_at(np.array([[7.0, 0.05, 0.05]]))[0] == FREE
    assert m.counts()["occupied"] == 0


def test_storage_is_sparse():
    m = OccupancyMap(voxel_size_m=0.25, max_range_m=30.0)
    m.integrate_depth(wall_depth(10.0), CAM, POSE)
    m.integrate_depth(wall_depth(10.0), CAM, look([500.05, 300.05, 20.05], [510.05, 300.05, 20.05]))
    lo, hi = m.voxel_bounds()
    dense_blocks = np.prod((hi - lo) / m.block_size)
    assert m.grid.count < 1e-3 * dense_blocks  # two frusta 500 m apart, nothing allocated between them
    assert m.memory_bytes() < 64e6


def test_map_from_depth_matches_ground_truth(small_city, city_frames):
    cam, depths, poses = city_frames
    v = 0.5
    m = build_map_from_depth_frames(depths, cam, poses, voxel_size_m=v, max_range_m=40.0)
    assert len(m.last_build_stats) == len(depths)
    lo, hi = m.voxel_bounds()
    states = m.classify(m.dense_log_odds(lo, tuple(hi - lo)))
    gt = small_city.occupancy_grid(lo * v, v, tuple(hi - lo), include_ground=True)
    occ, free = states == OCCUPIED, states == FREE
    assert occ.sum() > 500 and free.sum() > 10 * occ.sum()
    assert (occ & gt).sum() / occ.sum() > 0.95  # precision of occupied voxels
    assert (free & gt).sum() / free.sum() < 0.01  # free voxels that overlap an obstacle
    # recall on the observed surface: voxels holding a measured point
    seen = np.zeros_like(gt)
    dirs = cam.ray_directions()
    for d, p in zip(depths, poses):
        ok = np.isfinite(d) & (d * np.linalg.norm(dirs, axis=2) <= 40.0)
        pc = dirs[ok] * d[ok, None]
        idx = np.floor(p.apply(pc * (1 + 1e-4)) / v).astype(int) - lo
        inside = np.all((idx >= 0) & (idx < hi - lo), axis=1)
        seen[tuple(idx[inside].T)] = True
    assert (occ & seen).sum() / seen.sum() > 0.9


def test_depth_map_objects_and_raycast_agree(city_frames):
    cam, depths, poses = city_frames
    a = build_map_from_depth_frames(
        [DepthMap(depths[0], cam, poses[0].inverse())], None, None, voxel_size_m=0.5
    )
    b = OccupancyMap(voxel_size_m=0.5, max_range_m=60.0)
    d = depths[0]
    ok = np.isfinite(d)
    pts = poses[0].apply(cam.ray_directions()[ok] * d[ok, None])
    b.integrate_points(pts, poses[0].t)
    occ_a = {tuple(x) for x in a.occupied_voxels().tolist()}
    occ_b = {tuple(x) for x in b.occupied_voxels().tolist()}
    assert len(occ_a & occ_b) > 0.8 * len(occ_b)


def test_from_occupancy_grid_and_queries():
    occ = np.zeros((8, 8, 8), bool)
    occ[2:4, 2:4, 2:4] = True
    m = OccupancyMap.from_occupancy_grid(occ, np.array([-1.0, 0.0, 1.0]), voxel_size_m=0.5)
    assert m.counts()["occupied"] == 8
    c = m.occupied_centers()
    assert np.allclose(c.min(axis=0), [0.25, 1.25, 2.25]) and np.allclose(c.max(axis=0), [0.75, 1.75, 2.75])
    assert m.probability_at(c[:1])[0] == pytest.approx(m.config.clamp_max, abs=1e-6)
    with pytest.raises(InputError, match="multiple of the voxel size"):
        OccupancyMap.from_occupancy_grid(occ, np.array([0.1, 0.0, 0.0]), voxel_size_m=0.5)


def test_bad_inputs_raise_input_error(city_frames):
    cam, depths, poses = city_frames
    with pytest.raises(InputError, match="poses for"):
        build_map_from_depth_frames(depths[:3], cam, poses[:2], voxel_size_m=0.5)
    nan_pose = poses[1].matrix
    nan_pose[0, 3] = np.nan
    bad = [poses[0], nan_pose]
    with pytest.raises(InputError, match="NaN"):
        build_map_from_depth_frames(depths[:2], cam, bad, voxel_size_m=0.5)
    with pytest.raises(InputError, match="millimetres"):
        build_map_from_depth_frames([depths[0] * 1000.0], cam, poses[:1], voxel_size_m=0.5)
    with pytest.raises(InputError, match="cam_from_world"):
        OccupancyMap(voxel_size_m=0.5).integrate_depth(depths[0], cam, poses[0].inverse())
    with pytest.raises(InputError, match="160x120"):
        OccupancyMap(voxel_size_m=0.5).integrate_depth(depths[0][:60], cam, poses[0])
    with pytest.raises(InputError):
        MapConfig(voxel_size_m=-1.0)
    with pytest.raises(InputError):
        MapConfig(prob_hit=0.4)
    with pytest.raises(InputError, match="shape"):
        OccupancyMap().integrate_points(np.zeros((3, 2)), np.zeros(3))


def test_lens_distortion_is_honoured():
    cam = Intrinsics(64.0, 64.0, 31.5, 23.5, 64, 48, np.array([-0.2, 0.05, 0.0, 0.0, 0.0]))
    m = OccupancyMap(voxel_size_m=0.25, max_range_m=30.0)
    st = m.integrate_depth(np.full((48, 64), 10.0, np.float32), cam, POSE)
    assert st.hit_updates > 0
    assert np.all(m.state_at(np.array([[x, 0.05, 0.05] for x in np.arange(1.0, 9.5, 0.5)])) == FREE)
    assert m.state_at(np.array([[10.1, 0.05, 0.05]]))[0] == OCCUPIED
    # the corners of the distorted image see further out than a pinhole camera would
    corner = cam.unproject(np.array([[0.0, 0.0]]), 9.0)[0]
    assert m.state_at(POSE.apply(corner)[None])[0] == FREE


def test_occupied_voxels_and_counts_are_the_same_in_block_ranges(monkeypatch):
    """Both test the voxels range by range (no whole-map temporary); the answer is that of one
    test over every block, in block order."""
    m = OccupancyMap(MapConfig(voxel_size_m=0.5))
    for d in (6.0, 8.0, 10.0):
        m.integrate_depth(wall_depth(d), CAM, POSE)
    blocks = m.grid.blocks
    with np.errstate(invalid="ignore"):
        k, q = np.nonzero(blocks >= m._lodds[4])
        want_counts = (int((blocks >= m._lodds[4]).sum()), int((blocks < m._lodds[4]).sum()))
    B = m.block_size
    want = m.grid.block_coords[k].astype(np.int64) * B + np.stack([q // (B * B), (q // B) % B, q % B], 1)
    assert len(want) > 0 and m.counts()["blocks"] > 3
    whole = m.occupied_voxels()
    monkeypatch.setattr(
        OccupancyMap,
        "_block_ranges",
        lambda self: ((a, min(a + 2, len(blocks))) for a in range(0, len(blocks), 2)),
    )
    for got in (whole, m.occupied_voxels()):
        np.testing.assert_array_equal(got, want)
    c = m.counts()
    assert (c["occupied"], c["free"]) == want_counts
    assert c["unknown"] == blocks.size - sum(want_counts)
