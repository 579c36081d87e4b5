"""``skyrecon map SEQ1 SEQ2 ...``: several flights mapped on the executor, then merged."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skyrecon.cli.main import main
from skyrecon.mapping import load_map
from skyrecon.mapping.merge import merge_maps
from skyrecon.mapping.tiles import is_tiled_map

SMALL = ["--width", "160", "--height", "120", "--quiet"]


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    out = []
    for seed in (3, 4):
        d = tmp_path_factory.mktemp(f"flight{seed}")
        assert (
            main(["render", "sequence", "--frames", "5", "--seed", str(seed), "--out", str(d), *SMALL]) == 0
        )
        out.append(d)
    return out


def _values(occ):
    B = occ.block_size
    order = np.lexsort(occ.grid.block_coords.T[::-1])
    return occ.grid.block_coords[order], occ.grid.blocks.reshape(-1, B**3)[order]


def test_several_flights_make_the_merge_of_their_maps(flights, tmp_path, monkeypatch):
    monkeypatch.setenv("SKYRECON_EXECUTOR", "serial")
    common = ["--depth", "depth_2", "--voxel-size", "0.5", "--quiet"]
    singles = []
    for k, f in enumerate(flights):
        assert main(["map", str(f), "--out", str(tmp_path / f"single{k}"), *common]) == 0
        singles.append(load_map(tmp_path / f"single{k}"))
    out = tmp_path / "both"
    assert main(["map", *map(str, flights), "--out", str(out), *common]) == 0
    got, want = _values(load_map(out)), _values(merge_maps(singles))
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    summary = json.loads((out / "map_summary.json").read_text())
    assert [f["source"] for f in summary["flights"]] == [str(f) for f in flights]
    assert not (out / "workspace").exists()
    # tiled output, flights mapped by worker processes: the same evidence
    tiled = tmp_path / "tiled"
    monkeypatch.setenv("SKYRECON_EXECUTOR", "process")
    monkeypatch.setenv("SKYRECON_WORKERS", "2")
    assert main(["map", *map(str, flights), "--out", str(tiled), "--tile-size", "16", *common]) == 0
    assert is_tiled_map(tiled)
    again = _values(load_map(tiled))
    np.testing.assert_array_equal(again[0], want[0])
    np.testing.assert_array_equal(again[1], want[1])


def test_a_finished_flight_is_reused_when_rerun(flights, tmp_path, monkeypatch):
    monkeypatch.setenv("SKYRECON_EXECUTOR", "serial")
    ws = tmp_path / "ws"
    common = ["--depth", "depth_2", "--voxel-size", "0.5", "--workspace", str(ws)]
    # a first run that stops after mapping the flights: simulate by mapping, then keeping the workspace
    from skyrecon.cli import map as map_cli

    real_merge = map_cli.merge_maps

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(map_cli, "merge_maps", boom)
    with pytest.raises(KeyboardInterrupt):
        map_cli.run(_parse(["map", *map(str, flights), "--out", str(tmp_path / "m"), *common, "--quiet"]))
    assert (ws / "flights" / "000" / "flight_done.json").is_file()
    monkeypatch.setattr(map_cli, "merge_maps", real_merge)
    calls = []
    real_map_sequence = map_cli._map_sequence
    monkeypatch.setattr(
        map_cli, "_map_sequence", lambda *a, **k: calls.append(1) or real_map_sequence(*a, **k)
    )
    assert main(["map", *map(str, flights), "--out", str(tmp_path / "m"), *common, "--quiet"]) == 0
    assert calls == []  # both flights came from the workspace
    assert not ws.exists()


def test_bad_combinations_are_one_line(flights, tmp_path, capsys):
    assert main(["map", str(flights[0]), "--out", str(tmp_path / "x"), "--tile-size", "8"]) == 2
    assert main(["map", str(flights[0]), str(tmp_path / "missing"), "--out", str(tmp_path / "x")]) == 2
    assert (
        main(["map", *map(str, flights), "--out", str(tmp_path / "x"), "--record", str(tmp_path / "r.rrd")])
        == 2
    )
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.count("error:") == 3


def _parse(argv):
    from skyrecon.cli.main import build_parser

    return build_parser().parse_args(argv)
