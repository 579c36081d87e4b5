"""Many missions and refused ones, through the API (small, quick scenes)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.executor import SerialExecutor
from skyrecon.mission import ImpossibleMission, MissionConfig, make_scenario, run_mission
from skyrecon.mission.batch import run_missions
from skyrecon.sim import City


@pytest.fixture(scope="module")
def batch(tmp_path_factory, tiny_config):
    out = tmp_path_factory.mktemp("batch")
    rows, totals = run_missions([1, 2], out, tiny_config, SerialExecutor(), quiet=True)
    return out, rows, totals


def test_many_missions_write_a_summary(batch):
    tmp_path, rows, totals = batch
    assert [r["seed"] for r in rows] == [1, 2]
    assert totals["missions"] == 2 and totals["succeeded"] == 2 and totals["collisions"] == 0
    for s in (1, 2):
        doc = json.loads((tmp_path / f"seed_{s:04d}" / "mission.json").read_text())
        assert doc["seed"] == s and doc["success"]
        assert (tmp_path / f"seed_{s:04d}" / "report.html").is_file()
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["totals"]["succeeded"] == 2 and len(summary["missions"]) == 2
    assert "seed_0001/report.html" in (tmp_path / "summary.html").read_text()
    assert sum(line.startswith("| ") for line in (tmp_path / "summary.md").read_text().splitlines()) == 3


def test_same_seed_flies_the_same_path(batch, tiny_config):
    out = batch[0]
    doc = json.loads((out / "seed_0001" / "mission.json").read_text())
    cfg = MissionConfig.from_dict(doc["config"])
    assert cfg == tiny_config
    again = run_mission(make_scenario(1, cfg), cfg).flown_path()
    first = np.array(json.loads((out / "seed_0001" / "path.json").read_text())["waypoints"])
    assert again.shape == first.shape and np.array_equal(again, first)


def test_the_loop_runs_its_kernels_on_its_threads_with_the_heap_frozen(tiny_config):
    import gc
    from dataclasses import replace

    import numba

    before = numba.get_num_threads()
    seen = []
    cfg = replace(tiny_config, time_limit_s=1.0)
    run_mission(
        make_scenario(1, cfg),
        cfg,
        on_cycle=lambda rec, nav: seen.append((numba.get_num_threads(), gc.get_freeze_count())),
    )
    assert seen and all(n == 1 for n, _ in seen)  # loop_threads = 1 by default
    assert all(f > 0 for _, f in seen)  # what existed before the flight is not scanned
    assert numba.get_num_threads() == before and gc.get_freeze_count() == 0  # restored after
    with pytest.raises(InputError):
        MissionConfig(loop_threads=-1)


def _courtyard(goal_xy, half=4.0, height=40.0, wall=2.0):
    """Four walls closing a square courtyard around goal_xy, taller than the flight band."""
    x, y = goal_xy
    return np.array(
        [
            [x - half - wall, y - half - wall, 0, x + half + wall, y - half, height],
            [x - half - wall, y + half, 0, x + half + wall, y + half + wall, height],
            [x - half - wall, y - half, 0, x - half, y + half, height],
            [x + half, y - half, 0, x + half + wall, y + half, height],
        ]
    )


def test_no_way_through_is_impossible(tiny_config):
    city = City.from_obstacles(_courtyard((10.0, 0.0)), extent=np.array([-25.0, -25.0, 25.0, 25.0]))
    with pytest.raises(ImpossibleMission) as err:
        make_scenario(0, tiny_config, start=[-15.0, 0.0, 15.0], goal=[10.0, 0.0, 15.0], city=city)
    assert "no way through" in str(err.value) and "enclosed" in str(err.value)


@pytest.mark.parametrize(
    "goal, code",
    [
        ([10.0, -5.0, 15.0], "goal_in_obstacle"),
        ([10.0, -2.5, 15.0], "goal_too_close"),
        ([10.0, 0.0, 50.0], "goal_altitude"),
        ([500.0, 0.0, 15.0], "goal_outside"),
    ],
)
def test_bad_goals_say_why(tiny_config, goal, code):
    city = City.from_obstacles(_courtyard((10.0, 0.0)), extent=np.array([-25.0, -25.0, 25.0, 25.0]))
    with pytest.raises(ImpossibleMission) as err:
        make_scenario(0, tiny_config, start=[-15.0, 0.0, 15.0], goal=goal, city=city)
    assert err.value.code == code
