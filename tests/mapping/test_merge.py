"""Merging maps of separate flights (:mod:`skyrecon.mapping.merge` and ``skyrecon map --merge``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skyrecon.cli.main import main
from skyrecon.errors import InputError
from skyrecon.mapping import OccupancyMap, load_map, save_map
from skyrecon.mapping.merge import merge_maps


def _wall(x: float, y0: float, y1: float) -> np.ndarray:
    ys, zs = np.meshgrid(np.arange(y0, y1, 0.1), np.arange(0.0, 4.0, 0.1))
    return np.stack([np.full(ys.size, x), ys.ravel(), zs.ravel()], axis=1)


def _map(points: np.ndarray, origin=(0.0, 0.0, 2.0), voxel=0.2) -> OccupancyMap:
    m = OccupancyMap(voxel_size_m=voxel, max_range_m=40.0)
    m.integrate_points(points, np.asarray(origin, np.float64))
    return m


def _dense(m: OccupancyMap) -> dict[tuple[int, int, int], float]:
    B = m.block_size
    out = {}
    for c, block in zip(m.grid.block_coords, m.grid.blocks.reshape(-1, B, B, B), strict=True):
        for idx in np.argwhere(np.isfinite(block)):
            out[tuple((c * B + idx).tolist())] = float(block[tuple(idx)])
    return out


def test_merge_equals_one_flight_seeing_both_when_nothing_clamps():
    a_pts, b_pts = _wall(6.0, -3.0, 0.0), _wall(-6.0, 0.0, 3.0)
    a, b = _map(a_pts), _map(b_pts, origin=(0.0, 1.0, 2.0))
    both = OccupancyMap(voxel_size_m=0.2, max_range_m=40.0)
    both.integrate_points(a_pts, np.array([0.0, 0.0, 2.0]))
    both.integrate_points(b_pts, np.array([0.0, 1.0, 2.0]))
    merged = merge_maps([a, b])
    got, want = _dense(merged), _dense(both)
    assert got.keys() == want.keys()
    diff = max(abs(got[k] - want[k]) for k in want)
    # the one-flight map clamps after each ray; the merge adds then clamps: equal unless a voxel saturates
    assert diff < 1e-5 or sum(abs(got[k] - want[k]) > 1e-5 for k in want) < 0.01 * len(want)
    occ = merged.occupied_centers()
    assert (np.abs(occ[:, 0] - 6.1) < 0.3).any() and (np.abs(occ[:, 0] + 6.1) < 0.3).any()


def test_evidence_adds_and_clamps():
    a = _map(_wall(6.0, -3.0, 3.0))
    merged = merge_maps([a, a, a, a, a, a, a, a])
    hi = float(np.log(a.config.clamp_max / (1 - a.config.clamp_max)))
    vals = np.array(list(_dense(merged).values()))
    assert vals.max() <= hi + 1e-6
    # an occupied voxel of one flight is at least as occupied after merging its evidence again
    single = _dense(a)
    many = _dense(merged)
    assert all(many[k] >= v - 1e-6 for k, v in single.items() if v > 0)


def test_a_voxel_free_in_one_flight_and_occupied_in_another_is_decided_by_the_evidence():
    # flight 1 sees a wall at x=6; flight 2 saw through that place (the wall is gone) many times
    a = _map(_wall(6.0, -1.0, 1.0))
    far = _wall(12.0, -1.0, 1.0)
    b = OccupancyMap(voxel_size_m=0.2, max_range_m=40.0)
    for _ in range(4):
        b.integrate_points(far, np.array([0.0, 0.0, 2.0]))
    merged = merge_maps([a, b])
    occ = merged.occupied_centers()
    # where flight 2's rays crossed the old wall (its middle), four misses outweigh one hit
    crossed = (np.abs(occ[:, 0] - 6.1) < 0.15) & (np.abs(occ[:, 1]) < 0.3) & (np.abs(occ[:, 2] - 2.0) < 0.5)
    assert (np.abs(_map(_wall(6.0, -1.0, 1.0)).occupied_centers()[:, 1]) < 0.3).any()
    assert not crossed.any()
    assert (np.abs(occ[:, 0] - 12.1) < 0.15).any()


def test_maps_with_different_grids_are_refused():
    a = _map(_wall(6.0, -1.0, 1.0), voxel=0.2)
    b = _map(_wall(6.0, -1.0, 1.0), voxel=0.25)
    with pytest.raises(InputError, match="voxel_size_m"):
        merge_maps([a, b], ["monday", "tuesday"])


def test_cli_merge_writes_a_map_and_refuses_bad_use(tmp_path, capsys):
    a, b = _map(_wall(6.0, -3.0, 0.0)), _map(_wall(-6.0, 0.0, 3.0))
    save_map(a, tmp_path / "a")
    save_map(b, tmp_path / "b")
    out = tmp_path / "ab"
    assert (
        main(["map", "--merge", str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(out), "--quiet"]) == 0
    )
    merged = load_map(out)
    assert len(merged.occupied_centers()) == len(merge_maps([a, b]).occupied_centers())
    summary = json.loads((out / "map_summary.json").read_text())
    assert summary["merged_from"] == [str(tmp_path / "a"), str(tmp_path / "b")]
    assert (out / "occupied.ply").is_file() and (out / "preview.png").is_file()
    # both SOURCE and --merge, or neither: one line, exit 2
    assert main(["map", str(tmp_path / "a"), "--merge", str(tmp_path / "b"), "--out", str(out)]) == 2
    assert main(["map", "--out", str(out)]) == 2
    assert main(["map", "--merge", str(tmp_path / "nope"), "--out", str(out)]) == 2
    assert main(["map", "--merge", str(tmp_path / "a"), "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert all("Traceback" not in line for line in err)
