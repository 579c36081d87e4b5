"""District-scale tiled maps (:mod:`skyrecon.mapping.tiles`) and planning across tiles
(:mod:`skyrecon.planning.tiled`)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skyrecon.cli.main import main
from skyrecon.errors import InputError
from skyrecon.mapping import MapConfig, OccupancyMap, load_map, save_map
from skyrecon.mapping.config import logit
from skyrecon.mapping.merge import merge_maps
from skyrecon.mapping.tiles import TiledMap, is_tiled_map
from skyrecon.planning.tiled import plan_on_tiles

VOXEL = 0.5
FREE, OCC = logit(0.2), logit(0.9)


def _dense_map(values: np.ndarray, lo_voxel=(0, 0, 0), voxel: float = VOXEL) -> OccupancyMap:
    """A map holding a dense (X, Y, Z) log-odds array (NaN unknown) whose first voxel is ``lo_voxel``."""
    cfg = MapConfig(voxel_size_m=voxel)
    B = cfg.block_size
    idx = np.argwhere(np.isfinite(values))
    v = idx + np.asarray(lo_voxel)
    bc = np.floor_divide(v, B)
    uniq, inv = np.unique(bc, axis=0, return_inverse=True)
    data = np.full((len(uniq), B, B, B), np.nan, np.float32)
    loc = v - bc * B
    data[inv.ravel(), loc[:, 0], loc[:, 1], loc[:, 2]] = values[tuple(idx.T)]
    return OccupancyMap.from_blocks(cfg, uniq.astype(np.int32), data)


def _yard() -> np.ndarray:
    """A 60 x 32 x 10 m yard (0.5 m voxels), all free but a wall across x = 30 m with a 12 m gap at its
    far end, and the ground (z < 0.5 m) occupied."""
    vals = np.full((120, 64, 20), FREE, np.float32)
    vals[:, :, 0] = OCC
    vals[59:61, :40, :] = OCC  # wall from y = 0 to 20 m; the gap is y in [20, 32) m
    return vals


def _two_flights() -> tuple[OccupancyMap, OccupancyMap]:
    vals = _yard()
    west, east = vals.copy(), vals.copy()
    west[70:] = np.nan  # the west flight saw x < 35 m
    east[:50] = np.nan  # the east flight saw x >= 25 m (they overlap on 25..35 m)
    return _dense_map(west), _dense_map(east)


def test_tiles_hold_the_same_evidence_as_one_merged_map(tmp_path):
    a, b = _two_flights()
    tiled = TiledMap.create(tmp_path / "t", a.config, tile_size_m=8.0)
    assert tiled.add_map(a, "west") > 1
    tiled.add_map(b, "east")
    merged = merge_maps([a, b])
    rng = np.random.default_rng(0)
    pts = rng.uniform([-2, -2, -1], [62, 34, 11], (5000, 3))
    reopened = TiledMap.open(tmp_path / "t", cache_mb=0.002)  # a tiny cache: tiles are read again
    want = merged.grid.lookup(np.floor(pts / VOXEL).astype(np.int64), fill=np.nan)
    got = reopened.log_odds_at(pts)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got[np.isfinite(got)], want[np.isfinite(want)], atol=1e-6)
    assert reopened.sources == ["west", "east"]
    assert len(reopened._cache) < len(reopened.tile_ids()) and reopened.tiles_read == len(reopened.tile_ids())
    reopened.log_odds_at(pts)  # the cache holds few tiles: the others are read again
    assert reopened.tiles_read > len(reopened.tile_ids()) + 10
    # overlap: evidence added (25..35 m seen twice), so the wall there is more certain than in one flight
    wall = np.array([[30.2, 5.0, 5.0]])
    assert reopened.log_odds_at(wall)[0] == pytest.approx(min(2 * OCC, logit(a.config.clamp_max)), abs=1e-5)
    whole = load_map(tmp_path / "t")  # load_map assembles a tiled map
    assert len(whole.occupied_centers()) == len(merged.occupied_centers())
    assert is_tiled_map(tmp_path / "t") and not is_tiled_map(tmp_path)


def test_an_interrupted_addition_leaves_the_map_as_it_was(tmp_path, monkeypatch):
    a, b = _two_flights()
    tiled = TiledMap.create(tmp_path / "t", a.config, tile_size_m=8.0)
    tiled.add_map(a, "west")
    pts = np.random.default_rng(1).uniform([0, 0, 0], [60, 32, 10], (2000, 3))
    before = tiled.log_odds_at(pts)
    import skyrecon.mapping.tiles as tiles_mod

    calls = {"n": 0}
    real = tiles_mod.atomic_write

    def failing(path, mode="wb"):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return real(path, mode)

    monkeypatch.setattr(tiles_mod, "atomic_write", failing)
    with pytest.raises(KeyboardInterrupt):
        tiled.add_map(b, "east")
    monkeypatch.undo()
    again = TiledMap.open(tmp_path / "t")
    np.testing.assert_array_equal(again.log_odds_at(pts), before)
    assert again.sources == ["west"]
    live = {
        f"{k}.g{v['generation']}.{part}.npy"
        for k, v in json.loads((tmp_path / "t" / "map.json").read_text())["tiles"].items()
        for part in ("coords", "log_odds")
    }
    assert {p.name for p in (tmp_path / "t" / "tiles").iterdir()} == live


def test_coarse_map_never_thins_obstacles(tmp_path):
    a, b = _two_flights()
    tiled = TiledMap.create(tmp_path / "t", a.config, tile_size_m=8.0)
    tiled.add_map(merge_maps([a, b]))
    coarse = tiled.coarse(4)
    assert coarse.voxel_size == pytest.approx(2.0)
    fine_occ = merge_maps([a, b]).occupied_centers()
    cidx = {tuple(v) for v in np.floor(coarse.occupied_centers() / 2.0).astype(int).tolist()}
    assert all(tuple(v) in cidx for v in np.floor(fine_occ / 2.0).astype(int).tolist())
    with pytest.raises(InputError):
        tiled.coarse(3)


def _clearance_along(path: np.ndarray, occupied: np.ndarray) -> float:
    from scipy.spatial import cKDTree

    seg = np.concatenate([np.linspace(p, q, 20) for p, q in zip(path[:-1], path[1:], strict=True)])
    return float(cKDTree(occupied).query(seg)[0].min())


@pytest.mark.parametrize("direct", [True, False])
def test_planning_across_tiles_keeps_the_clearance(tmp_path, direct):
    a, b = _two_flights()
    tiled = TiledMap.create(tmp_path / "t", a.config, tile_size_m=8.0)
    tiled.add_map(a)
    tiled.add_map(b)
    start, goal = np.array([5.0, 5.0, 5.0]), np.array([55.0, 5.0, 5.0])
    res = plan_on_tiles(
        tiled, start, goal, 1.5, segment_m=20.0, pad_m=6.0, max_direct_cells=10**9 if direct else 1000
    )
    assert res.success, res.message
    assert (res.adjusted.get("route") == "tiled") is not direct
    path = np.asarray(res.waypoints)
    np.testing.assert_allclose(path[0], start)
    np.testing.assert_allclose(path[-1], goal)
    occupied = merge_maps([a, b]).occupied_centers()
    assert _clearance_along(path, occupied) >= 1.5  # measured to voxel centres
    assert path[:, 1].max() > 20.0  # it went through the gap
    assert res.length_m < 1.4 * (50 + 2 * 17)


def test_cli_merges_into_tiles_and_plans_on_them(tmp_path):
    a, b = _two_flights()
    save_map(a, tmp_path / "west")
    save_map(b, tmp_path / "east")
    out = tmp_path / "district"
    argv = ["map", "--merge", str(tmp_path / "west"), str(tmp_path / "east"), "--out", str(out)]
    assert main([*argv, "--tile-size", "8", "--quiet"]) == 0
    assert is_tiled_map(out)
    summary = json.loads((out / "map_summary.json").read_text())
    assert summary["tiles"] > 4 and summary["merged_from"][0].endswith("west")
    plan_out = tmp_path / "plan"
    rc = main(
        [
            "plan",
            str(out),
            "--start",
            "5",
            "5",
            "5",
            "--goal",
            "55",
            "5",
            "5",
            "--clearance",
            "1.5",
            "--out",
            str(plan_out),
            "--quiet",
        ]
    )
    assert rc == 0
    doc = json.loads((plan_out / "path.json").read_text())
    assert doc["success"] if "success" in doc else doc["result"]["success"]
    # a tiled map merges again (tile by tile) and --tile-size needs --merge
    assert (
        main(["map", "--merge", str(out), "--out", str(tmp_path / "again"), "--tile-size", "16", "--quiet"])
        == 0
    )
    assert len(load_map(tmp_path / "again").occupied_centers()) == len(load_map(out).occupied_centers())
    assert main(["map", str(tmp_path / "west"), "--out", str(tmp_path / "x"), "--tile-size", "8"]) == 2
