"""A small delivery flown once through the real command line, shared by the mission tests.

80 m city, 320x240 images, 32-58 m between start and goal: about 15 s.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
from dataclasses import dataclass
from pathlib import Path

import pytest

from skyrecon.cli.main import main
from skyrecon.mission import small_test_config

os.environ.setdefault("OMP_WAIT_POLICY", "passive")

SMALL_ARGS = ["--seed", "0", "--city-size", "80", "--width", "320", "--quiet"]


@dataclass
class Flight:
    out: Path
    exit_code: int
    stdout: str
    stderr: str
    mission: dict


@pytest.fixture(scope="session")
def flight(tmp_path_factory) -> Flight:
    out = tmp_path_factory.mktemp("demo") / "mission"
    so, se = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
        code = main(["demo", *SMALL_ARGS, "--out", str(out)])
    mission = json.loads((out / "mission.json").read_text()) if (out / "mission.json").is_file() else {}
    return Flight(out, code, so.getvalue(), se.getvalue(), mission)


@pytest.fixture(scope="session")
def tiny_config():
    """A 60 m city, 160x120 images, 20-35 m deliveries: a mission in a few seconds."""
    return small_test_config(
        width=160,
        height=120,
        max_disparity=16,
        city_size_m=60.0,
        min_goal_distance_m=20.0,
        max_goal_distance_m=35.0,
        map_padding_m=15.0,
    )
