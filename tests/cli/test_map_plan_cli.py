"""End to end: ``skyrecon map`` then ``skyrecon plan`` on a rendered flight."""

import json

import numpy as np
import pytest

from skyrecon.cli.main import main
from skyrecon.core import PointCloud
from skyrecon.io import read_ply, read_sequence, write_ply
from skyrecon.mapping import load_map
from skyrecon.sim import generate_city

SMALL = ["--width", "320", "--height", "240", "--seed", "3", "--quiet"]


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    out = tmp_path_factory.mktemp("flight")
    assert main(["render", "sequence", "--frames", "6", "--out", str(out), *SMALL]) == 0
    return out


@pytest.mark.parametrize("depth", [None, "depth_2"])
def test_map_from_sequence(flight, tmp_path, depth):
    out = tmp_path / "map"
    args = ["map", str(flight), "--out", str(out), "--voxel-size", "0.5", "--quiet"]
    if depth:
        args += ["--depth", depth]
    assert main(args) == 0
    occ = load_map(out)
    centres = occ.occupied_centers()
    assert len(centres) > (100 if depth else 20) and len(read_ply(out / "occupied.ply")) == len(centres)
    # occupied voxels lie on the true city surfaces (ground included)
    dist = generate_city(3).distance(centres, include_ground=True)
    precision = np.mean(dist <= 0.5 * np.sqrt(3))
    assert precision > (0.98 if depth else 0.6), precision
    summary = json.loads((out / "map_summary.json").read_text())
    assert summary["frames"] == 6


def test_plan_on_map(flight, tmp_path, capsys):
    out = tmp_path / "map"
    assert (
        main(["map", str(flight), "--depth", "depth_2", "--out", str(out), "--voxel-size", "0.5", "--quiet"])
        == 0
    )
    track = np.array([p.t for p in read_sequence(flight).world_from_left])
    start, goal = track[0], track[-1]
    route = tmp_path / "route"
    args = [
        "plan",
        str(out),
        "--start",
        *map(str, start),
        "--goal",
        *map(str, goal),
        "--clearance",
        "1.0",
        "--allow-unknown",
        "--out",
        str(route),
        "--origin",
        "47.3769",
        "8.5417",
        "408",
        "--quiet",
    ]
    assert main(args) == 0
    doc = json.loads((route / "path.json").read_text())
    waypoints = np.array(doc["waypoints"])
    np.testing.assert_allclose(waypoints[0], start, atol=1e-6)
    np.testing.assert_allclose(waypoints[-1], goal, atol=1e-6)
    # checked against the true geometry, not the map
    seg = np.concatenate([np.linspace(a, b, 50) for a, b in zip(waypoints[:-1], waypoints[1:])])
    assert generate_city(3).distance(seg, include_ground=True).min() > 0.5
    assert json.loads((route / "mission.plan").read_text())["fileType"] == "Plan"
    # no path: exit 2 and one line that says why (the cameras never saw their own positions)
    capsys.readouterr()
    bad = ["plan", str(out), "--start", *map(str, start), "--goal", *map(str, goal), "--out", str(route)]
    assert main(bad) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: no path") and "unknown" in err[0]


def test_map_bad_inputs(tmp_path, capsys):
    assert main(["map", str(tmp_path / "nothing"), "--out", str(tmp_path / "m")]) == 2
    assert "not found" in capsys.readouterr().err
    ply = tmp_path / "c.ply"
    write_ply(ply, PointCloud(np.random.default_rng(0).normal(size=(100, 3))))
    assert main(["map", str(ply), "--out", str(tmp_path / "m")]) == 2
    assert "--origin" in capsys.readouterr().err
    assert main(["map", str(ply), "--origin", "0", "0", "10", "--out", str(tmp_path / "m"), "--quiet"]) == 0
