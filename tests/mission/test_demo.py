"""``skyrecon demo`` end to end: a delivery through an unseen city, judged against the true geometry."""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re

import numpy as np
import pytest

from skyrecon.cli import demo as demo_cli
from skyrecon.cli.main import main
from skyrecon.io import read_ply
from skyrecon.mapping import load_map
from skyrecon.sim import generate_city

METRIC_KEYS = {
    "success",
    "collisions",
    "min_clearance_m",
    "path_length_m",
    "straight_line_m",
    "shortest_feasible_m",
    "replans",
    "loop_hz",
    "stage_ms",
    "seed",
    "reason",
    "length_ratio",
    "safety_margin_m",
    "cycles",
}
STAGES = {"render", "stereo", "integrate", "distance", "check", "replan", "control", "loop"}


def _run(argv):
    so, se = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
        code = main(argv)
    return code, so.getvalue(), se.getvalue()


def test_mission_delivers_without_touching_the_true_city(flight):
    assert flight.exit_code == 0, flight.stderr
    m = flight.mission
    assert m["success"] is True and m["collisions"] == 0 and m["reason"] == ""
    # judge the flown track ourselves, against the exact geometry
    path = json.loads((flight.out / "path.json").read_text())
    track = np.array(path["waypoints"])
    city = generate_city(m["seed"], m["config"]["city_size_m"])
    dense = np.concatenate(
        [a + (b - a) * np.linspace(0, 1, 12)[:, None] for a, b in zip(track[:-1], track[1:])]
    )
    clearance = city.distance(dense, include_ground=True)
    assert clearance.min() > m["config"]["drone_radius_m"]
    assert clearance.min() > m["safety_margin_m"]
    assert m["min_clearance_static_m"] == pytest.approx(clearance.min(), abs=0.1)
    # the demo's city moves: the clearance to the movers (true geometry, true time) is judged too
    assert m["moving_obstacles"] >= 1
    assert m["min_clearance_moving_m"] is None or m["min_clearance_moving_m"] > m["config"]["drone_radius_m"]
    assert m["min_clearance_m"] == pytest.approx(
        min(m["min_clearance_static_m"], m["min_clearance_moving_m"] or np.inf), abs=1e-3
    )
    # it stops where it believes the goal is: on its own odometry the truth may be off by the drift,
    # which the delivery allows up to delivery_tolerance_m (and reports as drift_m)
    allowed = m["config"]["arrival_tolerance_m"]
    if m["pose_source"] != "truth":
        allowed += m["config"]["delivery_tolerance_m"]
    assert np.linalg.norm(track[-1] - np.array(m["scenario"]["goal"])) <= allowed
    assert np.allclose(track[0], m["scenario"]["start"])
    # the straight line was blocked, and the drone did not wander
    assert m["shortest_feasible_m"] >= m["straight_line_m"]
    assert m["path_length_m"] < 1.5 * m["shortest_feasible_m"]


def test_outputs_exist_and_parse(flight):
    out = flight.out
    assert f"report: {out / 'report.html'}" in flight.stdout
    m = flight.mission
    assert METRIC_KEYS <= set(m)
    assert STAGES <= set(m["stage_ms"]) and all({"median", "p95"} <= set(v) for v in m["stage_ms"].values())
    assert m["loop_hz"] > 0 and m["cycles"] > 10
    assert m["path_length_m"] > m["straight_line_m"] * 0.95
    assert m["format"] == "skyrecon.mission" and m["config"]["width"] == 320
    cycles = json.loads((out / "cycles.json").read_text())["cycles"]
    assert len(cycles) == m["cycles"]
    assert {"position", "timings_ms", "clearance_m", "replanned", "yaw_deg"} <= set(cycles[0])
    path = json.loads((out / "path.json").read_text())
    assert path["format"] == "skyrecon.path" and len(path["waypoints"]) == m["cycles"] + 1
    occ = load_map(out / "map")
    assert occ.counts()["occupied"] > 100 and occ.voxel_size == m["config"]["voxel_size_m"]
    assert len(read_ply(out / "map" / "occupied.ply")) == occ.counts()["occupied"]
    html = (out / "report.html").read_text()
    assert html.startswith("<!DOCTYPE html>")
    assert html.count("data:image/png;base64,") >= 4  # plan view, two charts, camera frames
    assert not re.search(r"(src|href)=['\"]?(https?:|//)", html)  # nothing fetched from the network
    assert "Delivered" in html


def test_goal_inside_a_building_is_refused_with_a_report(flight, tmp_path):
    m = flight.mission
    city = generate_city(m["seed"], m["config"]["city_size_m"])
    tall = city.boxes[city.boxes[:, 5] > 16.0]
    assert len(tall), "the test city needs a building taller than 16 m"
    b = tall[0]
    goal = [(b[0] + b[3]) / 2, (b[1] + b[4]) / 2, 15.0]
    start = m["scenario"]["start"]
    out = tmp_path / "refused"
    code, stdout, stderr = _run(
        [
            "demo",
            "--seed",
            "0",
            "--city-size",
            "80",
            "--width",
            "320",
            "--out",
            str(out),
            "--start",
            *map(str, start),
            "--goal",
            *map(str, goal),
        ]
    )
    assert code == 2
    errors = [line for line in stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "inside a building" in errors[0] and "goal" in errors[0]
    assert "report.html" in stderr
    doc = json.loads((out / "mission.json").read_text())
    assert doc["success"] is False and doc["reason"] == "goal_in_obstacle" and doc["collisions"] == 0
    html = (out / "report.html").read_text()
    assert "impossible" in html and "inside a building" in html


@pytest.mark.parametrize(
    "argv, text",
    [
        (["--start", "0", "0", "15"], "both --start and --goal"),
        (["--goal", "0", "0", "15", "--start", "0", "0", "abc"], "three numbers"),
        (["--missions", "2", "--start", "0", "0", "15", "--goal", "5", "5", "15"], "--missions"),
        (["--ground-z", "1", "--no-ground-prior"], "--no-ground-prior"),
    ],
)
def test_bad_options_give_one_error_line(tmp_path, argv, text):
    code, _, stderr = _run(["demo", "--out", str(tmp_path / "x"), *argv])
    assert code == 2
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and text in lines[0]


def test_baseline_option_sets_the_rig_and_its_trusted_range():
    def config(*argv):
        parser = argparse.ArgumentParser()
        demo_cli.add_parser(parser.add_subparsers())
        return demo_cli._config(parser.parse_args(["demo", *argv]))

    cfg = config("--baseline", "0.6", "--speed", "15")
    assert (
        cfg.baseline_m == 0.6 and cfg.max_range_m == pytest.approx(20.0 * 2**0.5) and cfg.max_disparity == 128
    )
    assert config("--baseline", "0.6", "--max-range", "22").max_range_m == 22.0


def test_ground_options_set_the_ground_prior():
    parser = argparse.ArgumentParser()
    demo_cli.add_parser(parser.add_subparsers())

    def ground(*argv):
        return demo_cli._config(parser.parse_args(["demo", *argv])).ground_z_m

    assert ground() == 0.0 and ground("--ground-z", "2.5") == 2.5 and ground("--no-ground-prior") is None


def test_help_has_an_example():
    with pytest.raises(SystemExit):
        with contextlib.redirect_stdout(io.StringIO()) as so:
            main(["demo", "--help"])
    assert "skyrecon demo --missions" in so.getvalue()
