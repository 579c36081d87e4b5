"""Same arguments, same seed: byte-identical outputs, command by command.

Each command runs twice into two folders; every file must match byte for byte, except that JSON
files are compared with their timing fields left out and HTML reports (which print timings) only
need to exist in both. ``mvs`` and ``sfm`` (also across serial and process executors) and resumed
``map`` runs are checked in ``test_kill_resume.py``; the mission loop in
``tests/mission/test_faults.py::test_same_seed_same_faulty_flight``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from skyrecon.cli.main import main

TIMING = re.compile(r"(time|timing|seconds|wall|fps|per_s|_ms$|_ms_|^ms$|hz$|_s$|^s$)", re.I)


def _strip(obj):
    if isinstance(obj, dict):
        return {k: _strip(v) for k, v in obj.items() if not TIMING.search(k)}
    if isinstance(obj, list):
        return [_strip(v) for v in obj]
    return obj


def _differences(a: Path, b: Path) -> list[str]:
    files_a = {str(p.relative_to(a)) for p in a.rglob("*") if p.is_file()}
    files_b = {str(p.relative_to(b)) for p in b.rglob("*") if p.is_file()}
    diffs = sorted(files_a ^ files_b)
    for rel in sorted(files_a & files_b):
        x, y = (a / rel).read_bytes(), (b / rel).read_bytes()
        if rel.endswith(".html"):
            continue
        if rel.endswith(".json"):
            if _strip(json.loads(x)) != _strip(json.loads(y)):
                diffs.append(rel)
        elif x != y:
            diffs.append(rel)
    return diffs


def _twice(tmp_path: Path, name: str, argv_of) -> list[str]:
    outs = [tmp_path / f"{name}_a", tmp_path / f"{name}_b"]
    for out in outs:
        assert main([*argv_of(out), "--quiet"]) == 0
    return _differences(*outs)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("det_inputs")
    assert (
        main(["render", "stereo", "--width", "320", "--height", "240", "--out", str(d / "pair"), "--quiet"])
        == 0
    )
    assert main(["render", "images", "--views", "3", "--width", "480", "--height", "360", "--seed", "4",
                 "--out", str(d / "photos"), "--quiet"]) == 0  # fmt: skip
    assert main(["render", "sequence", "--frames", "12", "--out", str(d / "flight"), "--quiet"]) == 0
    return d


def test_render_stereo_twice(tmp_path):
    assert (
        _twice(
            tmp_path,
            "render",
            lambda o: ["render", "stereo", "--width", "320", "--height", "240", "--out", str(o)],
        )
        == []
    )


def test_stereo_twice(inputs, tmp_path):
    pair = inputs / "pair"
    argv = ["stereo", str(pair / "left.png"), str(pair / "right.png"), "--calib", str(pair / "calib.txt")]
    assert _twice(tmp_path, "stereo", lambda o: [*argv, "--out", str(o)]) == []


def test_two_view_twice(inputs, tmp_path):
    images = sorted((inputs / "photos" / "images").iterdir())
    argv = ["two-view", str(images[0]), str(images[1]), "--camera", str(inputs / "photos" / "K.txt")]
    assert _twice(tmp_path, "two_view", lambda o: [*argv, "--out", str(o)]) == []


def test_odometry_map_and_plan_twice(inputs, tmp_path):
    flight = inputs / "flight"
    assert _twice(tmp_path, "odometry", lambda o: ["odometry", str(flight), "--out", str(o)]) == []
    assert _twice(tmp_path, "map", lambda o: ["map", str(flight), "--out", str(o)]) == []
    track = [[float(v) for v in line.split()] for line in (flight / "poses.txt").read_text().splitlines()]
    start = [track[0][3], track[0][7], track[0][11]]
    goal = [track[-1][3], track[-1][7], track[-1][11]]
    argv = ["plan", str(tmp_path / "map_a"), "--start", *map(str, start), "--goal", *map(str, goal)]
    assert (
        _twice(tmp_path, "plan", lambda o: [*argv, "--allow-unknown", "--clearance", "0.5", "--out", str(o)])
        == []
    )
