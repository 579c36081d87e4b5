"""Simulated delivery missions: a drone with a stereo camera flies through a city it has never
seen, mapping as it goes (stereo -> occupancy map -> distance field -> planner, in closed loop).

    cfg = MissionConfig()                              # every setting, in one place
    scenario = make_scenario(seed=3, cfg=cfg)          # city, start, goal, shortest feasible path
    result = run_mission(scenario, cfg)                # the closed loop (MissionResult)
    metrics = mission_metrics(result)                  # success, clearance, length ratio, loop rate...
    write_mission_outputs(result, out_dir)             # mission.json, path.json, cycles.json, map/, report.html
    run_missions(range(20), out_dir, cfg)              # many seeds in parallel, summary.json/.md/.html

Modules: :mod:`~skyrecon.mission.config` (settings), :mod:`~skyrecon.mission.scenario` (city,
endpoints, truth), :mod:`~skyrecon.mission.perception` (the rig and its stereo-depth rules),
:mod:`~skyrecon.mission.navigator` (map, planner, and how unknown space is handled),
:mod:`~skyrecon.mission.vehicle` (dynamics and guidance), :mod:`~skyrecon.mission.loop` (the
loop), :mod:`~skyrecon.mission.metrics`, :mod:`~skyrecon.mission.outputs`,
:mod:`~skyrecon.mission.batch`. World frame z up, metres.
"""

from skyrecon.mission.batch import fly_and_write, run_missions
from skyrecon.mission.config import MissionConfig, small_test_config
from skyrecon.mission.loop import LOOP_STAGES, STAGES, CycleRecord, MissionResult, PlanEvent, run_mission
from skyrecon.mission.metrics import mission_metrics
from skyrecon.mission.outputs import write_mission_outputs, write_refused_outputs
from skyrecon.mission.scenario import ImpossibleMission, Scenario, make_scenario

__all__ = [
    "MissionConfig",
    "small_test_config",
    "run_mission",
    "MissionResult",
    "CycleRecord",
    "PlanEvent",
    "LOOP_STAGES",
    "STAGES",
    "Scenario",
    "make_scenario",
    "ImpossibleMission",
    "mission_metrics",
    "write_mission_outputs",
    "write_refused_outputs",
    "fly_and_write",
    "run_missions",
]
