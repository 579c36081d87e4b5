"""A city that moves, in closed loop: movers, a stale prior map, and what the mission reports."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from skyrecon.cli import demo as demo_cli
from skyrecon.cli.main import main
from skyrecon.errors import InputError
from skyrecon.mapping import MapConfig, OccupancyMap
from skyrecon.mission.loop import run_mission
from skyrecon.mission.metrics import mission_metrics
from skyrecon.mission.outputs import write_mission_outputs
from skyrecon.mission.scenario import make_scenario


@pytest.fixture(scope="module")
def moving_flight(tiny_config, tmp_path_factory):
    cfg = tiny_config.with_overrides(movers=True, city_changes=True, prior_map="earlier", pose_source="truth")
    sc = make_scenario(4, cfg)
    result = run_mission(sc, cfg)
    out = tmp_path_factory.mktemp("moving")
    doc = write_mission_outputs(result, out, cloud_format="las")
    return sc, result, doc, out


def test_movers_are_judged_against_true_geometry_at_true_time(moving_flight):
    sc, result, m, _ = moving_flight
    assert sc.movers is not None and m["moving_obstacles"] == len(sc.movers.movers) >= 3
    assert m["collisions"] == 0
    # recompute the clearance to the movers along the flown track, each point at its own time
    pos = np.array([r.position for r in result.records] + [result.final_position])
    t = np.array([r.time_s for r in result.records] + [result.records[-1].time_s + result.config.dt])
    fine = np.linspace(0, 1, 6)[:, None]
    pts = np.concatenate([a + (b - a) * fine for a, b in zip(pos[:-1], pos[1:])])
    ts = np.concatenate([a + (b - a) * fine[:, 0] for a, b in zip(t[:-1], t[1:])])
    truth = sc.movers.mover_distance(pts, ts).min()
    assert m["min_clearance_moving_m"] == pytest.approx(truth, abs=0.15)
    assert m["min_clearance_moving_m"] > result.config.drone_radius_m


def test_mission_reports_the_dynamic_figures(moving_flight):
    sc, result, m, out = moving_flight
    for key in ("moving_obstacles", "min_clearance_static_m", "min_clearance_moving_m", "loop_ms_p99"):
        assert key in m
    assert "movers" in m["stage_ms"] and "movers" in m["loop_stages"]
    dyn = m["dynamic"]
    assert {"mover_detection_recall", "phantom_trail", "vacated_free_s", "changes_seen"} <= set(dyn)
    kinds = sorted(c["kind"] for c in dyn["changes_seen"])
    assert "removed" in kinds
    assert m["prior_map"]["known_fraction"] == 1.0
    doc = json.loads((out / "mission.json").read_text())
    assert doc["scenario"]["movers"] and doc["scenario"]["changes"]
    html = (out / "report.html").read_text()
    assert "A city that moves" in html and "Closest approach" in html


def test_the_map_cloud_takes_the_chosen_format(moving_flight):
    _, result, m, out = moving_flight
    laspy = pytest.importorskip("laspy")
    assert m["files"]["occupied"] == "map/occupied.las" and not (out / "map" / "occupied.ply").exists()
    las = laspy.read(out / "map" / "occupied.las")
    xyz = np.column_stack([las.x, las.y, las.z])
    truth = result.occ_map.occupied_centers()
    assert len(xyz) == len(truth)
    np.testing.assert_allclose(np.sort(xyz, axis=0), np.sort(truth, axis=0), atol=6e-4)


def test_same_seed_same_movers_same_flight(moving_flight, tiny_config):
    sc, result, _, _ = moving_flight
    again = make_scenario(4, result.config)
    assert again.movers.to_dict() == sc.movers.to_dict()
    a = again.movers.snapshot(12.3).boxes
    assert np.array_equal(a, sc.movers.snapshot(12.3).boxes)


def test_a_plain_world_is_painted_plain(tiny_config):
    """``--plain`` (MissionConfig.plain): a city of plain surfaces and plain movers, by seed."""
    from skyrecon.sim.texture import MAT_PLAIN

    parser = argparse.ArgumentParser()
    demo_cli.add_parser(parser.add_subparsers())
    assert demo_cli._config(parser.parse_args(["demo", "--plain"])).plain
    assert not demo_cli._config(parser.parse_args(["demo"])).plain
    cfg = tiny_config.with_overrides(movers=True, pose_source="truth")
    usual, plain = make_scenario(4, cfg), make_scenario(4, cfg.with_overrides(plain=True))
    assert np.count_nonzero(plain.city.box_material == MAT_PLAIN) > np.count_nonzero(
        usual.city.box_material == MAT_PLAIN
    )
    assert plain.movers.movers and {m.material for m in plain.movers.movers} == {MAT_PLAIN}
    assert MAT_PLAIN not in {m.material for m in usual.movers.movers}
    again = make_scenario(4, cfg.with_overrides(plain=True))
    assert again.movers.to_dict() == plain.movers.to_dict()
    np.testing.assert_array_equal(again.city.boxes, plain.city.boxes)


def test_camera_noise_is_measured_by_the_drone(tiny_config):
    """``--camera-noise`` (MissionConfig.camera_noise): the simulated cameras add steady noise;
    the health check measures it on every frame (the texture tests stand above it) and
    ``mission.json`` reports its median; a noise-free render reads almost none."""
    parser = argparse.ArgumentParser()
    demo_cli.add_parser(parser.add_subparsers())
    assert demo_cli._config(parser.parse_args(["demo", "--camera-noise", "1.5"])).camera_noise == 1.5
    with pytest.raises(InputError, match="camera_noise"):
        tiny_config.with_overrides(camera_noise=-1.0)
    base = tiny_config.with_overrides(movers=True, pose_source="truth", time_limit_s=3.0)
    measured = {}
    for sigma in (0.0, 2.0):
        cfg = base.with_overrides(camera_noise=sigma)
        r = run_mission(make_scenario(2, cfg), cfg)
        assert all(rec.image_noise is not None for rec in r.records)
        measured[sigma] = mission_metrics(r)["image_noise_median"]
        # grainy images (noise above 1 grey level): the depth is used, the drone flies slower
        grainy = ["grainy" in rec.health.split(",") for rec in r.records]
        assert all(grainy) if sigma else not any(grainy)
        if sigma:
            assert max(rec.speed_limit_mps for rec in r.records) <= cfg.grainy_speed_mps
    assert measured[0.0] < 0.2
    assert measured[2.0] == pytest.approx(2.0, abs=0.3)


def test_tracking_keeps_movers_out_of_the_map(tiny_config):
    """The same moving city flown with tracking on and off: off, the movers leave trails."""
    base = tiny_config.with_overrides(movers=True, pose_source="truth", time_limit_s=25.0)
    trail = {}
    for on in (True, False):
        cfg = base.with_overrides(track_movers=on)
        r = run_mission(make_scenario(2, cfg), cfg)
        trail[on] = mission_metrics(r)["dynamic"]["phantom_trail"]["occupied_voxels"]
    assert trail[True] <= trail[False]


def test_bad_prior_maps_give_one_clear_line(tmp_path, capsys):
    args = [
        "demo",
        "--seed",
        "0",
        "--city-size",
        "60",
        "--width",
        "160",
        "--quiet",
        "--out",
        str(tmp_path / "o"),
    ]
    assert main([*args, "--prior-map", str(tmp_path / "missing")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing" in err[0]
    far = OccupancyMap.from_occupancy_grid(
        np.ones((8, 8, 8), bool), np.array([9000.0, 9000.0, 0.0]), MapConfig(voxel_size_m=0.5)
    )
    far.save(tmp_path / "far")
    assert main([*args, "--prior-map", str(tmp_path / "far")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "another city" in err[0]


def test_user_movers_inside_a_building_or_on_the_start_are_refused(tmp_path, capsys):
    args = ["demo", "--seed", "0", "--city-size", "60", "--width", "160", "--quiet", "--movers", "off"]
    parser = argparse.ArgumentParser()
    demo_cli.add_parser(parser.add_subparsers())
    sc = make_scenario(0, demo_cli._config(parser.parse_args(args)))  # what the command will fly
    b = sc.city.boxes[int(np.argmax(sc.city.boxes[:, 5]))]  # the tallest building
    inside = [(b[0] + b[3]) / 2, (b[1] + b[4]) / 2, min(b[5] - 1.0, 14.0)]
    drone = {
        "name": "intruder",
        "kind": "drone",
        "motion": {
            "type": "polyline",
            "points": [inside, [inside[0] + 0.5, inside[1], inside[2]]],
            "speed_mps": 1.0,
        },
        "size_m": [1.0, 1.0, 0.4],
    }
    args = args[:-2]
    f = tmp_path / "movers.json"
    f.write_text(json.dumps([drone]))
    assert main([*args, "--movers", str(f), "--out", str(tmp_path / "a")]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(err) == 1 and "movers.json" in err[0] and "intruder" in err[0], err
    s = sc.start.tolist()
    drone["motion"]["points"] = [s, [s[0] + 0.5, s[1], s[2]]]
    f.write_text(json.dumps({"movers": [drone]}))
    assert main([*args, "--movers", str(f), "--out", str(tmp_path / "b")]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(err) == 1 and "start" in err[0], err
    f.write_text("{not json")
    assert main([*args, "--movers", str(f), "--out", str(tmp_path / "c")]) == 2
    assert "JSON" in capsys.readouterr().err
