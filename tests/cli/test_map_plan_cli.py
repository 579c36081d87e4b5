"""End to end: ``skyrecon map`` then ``skyrecon plan`` on a rendered flight."""

import json

import numpy as np
import pytest

from skyrecon.cli.main import main
from skyrecon.io import read_ply, read_sequence
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
    # from where the drone has been, without --allow-unknown: the cameras never saw their own
    # positions, but the flown track is known free (flown_path.json), so the plan joins it
    capsys.readouterr()
    plain = ["plan", str(out), "--start", *map(str, start), "--goal", *map(str, goal), "--out", str(route)]
    assert main(plain) == 0
    doc = json.loads((route / "path.json").read_text())
    assert doc["success"] and doc["adjusted"]
    waypoints = np.array(doc["waypoints"])
    np.testing.assert_allclose(waypoints[[0, -1]], [start, goal], atol=1e-6)
    seg = np.concatenate([np.linspace(a, b, 50) for a, b in zip(waypoints[:-1], waypoints[1:])])
    assert generate_city(3).distance(seg, include_ground=True).min() > 0.35
    # without the flown track and without snapping: exit 2 and one line that says why
    (out / "flown_path.json").unlink()
    capsys.readouterr()
    assert main([*plain, "--snap-radius", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: no path") and "clearance" in err[0]


def test_plan_from_every_flown_position_to_every_other(flight, tmp_path):
    """Issue: after `skyrecon map` on a flight, `skyrecon plan` from a camera position failed
    ("the start lies in unexplored space") although the drone flew through it."""
    out = tmp_path / "map"
    assert main(["map", str(flight), "--out", str(out), "--voxel-size", "0.5", "--quiet"]) == 0
    track = np.array([p.t for p in read_sequence(flight).world_from_left])
    occ = load_map(out)
    assert np.all(occ.state_at(track) == 0)  # the flown positions are known free
    city = generate_city(3)
    for i, start in enumerate(track):
        for j, goal in enumerate(track):
            if i == j:
                continue
            route = tmp_path / f"route_{i}_{j}"
            args = [
                "plan",
                str(out),
                "--start",
                *map(str, start),
                "--goal",
                *map(str, goal),
                "--out",
                str(route),
            ]
            assert main([*args, "--quiet"]) == 0, (i, j)
            w = np.array(json.loads((route / "path.json").read_text())["waypoints"])
            seg = np.concatenate([np.linspace(a, b, 30) for a, b in zip(w[:-1], w[1:])])
            assert city.distance(seg, include_ground=True).min() > 0.35, (i, j)


def test_plan_with_a_prior_map_fills_what_today_has_not_seen(tmp_path, capsys):
    from skyrecon.mapping import MapConfig, OccupancyMap

    cfg = MapConfig(voxel_size_m=0.5)
    shape = (80, 40, 40)
    wall = np.zeros(shape, bool)
    wall[40:42, :30, :] = True  # a wall across x = 0 leaving a gap at y > 5 m
    origin = np.array([-20.0, -10.0, 0.0])
    known_today = np.zeros(shape, bool)
    known_today[:20] = True  # today's map saw only the first 10 m
    OccupancyMap.from_occupancy_grid(wall, origin, cfg, known=known_today).save(tmp_path / "today")
    OccupancyMap.from_occupancy_grid(wall, origin, cfg).save(tmp_path / "prior")
    args = ["plan", str(tmp_path / "today"), "--start", "-15", "0", "10", "--goal", "15", "0", "10"]
    assert main([*args, "--out", str(tmp_path / "r0"), "--quiet"]) != 0  # unknown space blocks the way
    assert main([*args, "--prior-map", str(tmp_path / "prior"), "--out", str(tmp_path / "r1")]) == 0
    assert "prior map filled" in capsys.readouterr().err
    path = json.loads((tmp_path / "r1" / "path.json").read_text())
    assert max(p[1] for p in path["waypoints"]) > 5.0  # through the gap the prior knows of
    OccupancyMap.from_occupancy_grid(wall, origin + 1000.0, cfg).save(tmp_path / "far")
    assert main([*args, "--prior-map", str(tmp_path / "far"), "--out", str(tmp_path / "r2"), "--quiet"]) == 2
    assert "another place" in capsys.readouterr().err
    coarse = OccupancyMap.from_occupancy_grid(wall[::2, ::2, ::2], origin, MapConfig(voxel_size_m=1.0))
    coarse.save(tmp_path / "coarse")
    assert (
        main([*args, "--prior-map", str(tmp_path / "coarse"), "--out", str(tmp_path / "r3"), "--quiet"]) == 2
    )
    assert "voxel" in capsys.readouterr().err
