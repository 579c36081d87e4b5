"""Saving, loading and exporting maps: round trips, atomic writes, corrupt files."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.io.ply import read_ply
from skyrecon.mapping import OccupancyMap, export_occupied_ply, load_map, write_octomap_bt


@pytest.fixture()
def mapped():
    rng = np.random.default_rng(5)
    m = OccupancyMap(voxel_size_m=0.5, prob_hit=0.75, max_range_m=30.0)
    for _ in range(3):
        pts = rng.uniform([-10, -10, 0], [10, 10, 6], size=(300, 3))
        m.integrate_points(pts, np.array([0.3, 0.2, 3.1]))
    return m


def test_save_load_round_trip(tmp_path, mapped):
    mapped.save(tmp_path / "map")
    back = OccupancyMap.load(tmp_path / "map")
    assert back.config == mapped.config
    assert back.grid.count == mapped.grid.count
    a = {tuple(c): mapped.grid.blocks[i] for i, c in enumerate(mapped.grid.block_coords.tolist())}
    for i, c in enumerate(back.grid.block_coords.tolist()):
        np.testing.assert_array_equal(back.grid.blocks[i], a[tuple(c)])
    q = np.random.default_rng(0).uniform([-10, -10, 0], [10, 10, 6], size=(500, 3))
    np.testing.assert_array_equal(back.log_odds_at(q), mapped.log_odds_at(q))
    header = json.loads((tmp_path / "map" / "map.json").read_text())
    assert header["format"] == "skyrecon.occupancy" and header["num_blocks"] == mapped.grid.count


def test_save_is_atomic(tmp_path, mapped, monkeypatch):
    d = tmp_path / "map"
    mapped.save(d)
    before = {p.name: p.read_bytes() for p in d.iterdir()}

    def broken(f, **arrays):
        f.write(b"PK\x03\x04 half a file")
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez", broken)
    with pytest.raises(OSError, match="disk full"):
        mapped.save(d)
    after = {p.name: p.read_bytes() for p in d.iterdir()}
    assert after == before  # the old map is intact, no temporary file is left behind
    monkeypatch.undo()
    empty = tmp_path / "fresh"
    monkeypatch.setattr(np, "savez", broken)
    with pytest.raises(OSError):
        mapped.save(empty)
    assert not any(p.name in ("blocks.npz", "map.json") for p in empty.iterdir())
    assert [p for p in os.listdir(empty)] == []


def test_load_reports_bad_directories(tmp_path, mapped):
    with pytest.raises(InputError, match="map.json"):
        load_map(tmp_path / "nothing")
    d = tmp_path / "map"
    mapped.save(d)
    (d / "map.json").write_text("{not json")
    with pytest.raises(InputError, match="corrupt map header"):
        load_map(d)
    mapped.save(d)
    (d / "blocks.npz").write_bytes(b"garbage")
    with pytest.raises(InputError, match="corrupt block file"):
        load_map(d)
    mapped.save(d)
    h = json.loads((d / "map.json").read_text())
    h["num_blocks"] += 1
    (d / "map.json").write_text(json.dumps(h))
    with pytest.raises(InputError, match="do not belong together"):
        load_map(d)


def test_export_occupied_ply(tmp_path, mapped):
    n = export_occupied_ply(mapped, tmp_path / "occupied.ply")
    cloud = read_ply(tmp_path / "occupied.ply")
    assert len(cloud) == n == mapped.counts()["occupied"]
    np.testing.assert_allclose(
        np.sort(cloud.points, axis=0), np.sort(mapped.occupied_centers().astype(np.float32), axis=0)
    )


def test_octomap_bt_export(tmp_path):
    rng = np.random.default_rng(0)
    occ = rng.random((20, 17, 9)) < 0.1
    known = rng.random((20, 17, 9)) < 0.7
    known[:8, :8, :8] = True
    occ[:8, :8, :8] = False  # a uniform free cube that the tree prunes
    origin = np.array([-2.0, 1.0, -1.5])
    m = OccupancyMap.from_occupancy_grid(occ, origin, known=known, voxel_size_m=0.5)
    n = write_octomap_bt(m, tmp_path / "map.bt")
    data = (tmp_path / "map.bt").read_bytes()
    assert data.startswith(b"# Octomap OcTree binary file\n")
    assert f"\nsize {n}\nres 0.5\ndata\n".encode() in data
    octomap = pytest.importorskip("octomap")
    tree = octomap.OcTree(0.1)
    assert tree.readBinary(str(tmp_path / "map.bt").encode())
    assert tree.size() == n and tree.getResolution() == 0.5
    idx = np.argwhere(np.ones(occ.shape, bool))
    for i in idx[::7]:
        p = origin + (i + 0.5) * 0.5
        node = tree.search(p)
        if known[tuple(i)]:
            assert tree.isNodeOccupied(node) == occ[tuple(i)]
        else:
            with pytest.raises(Exception):  # noqa: B017  (octomap-python raises its own base class)
                tree.isNodeOccupied(node)
