"""3-D path planning over an occupancy map: any-angle grid search on the distance field,
shortening and smoothing with collision checks, replanning, and mission export.

Main entry points: :func:`plan_path` / :class:`Planner` -> :class:`PlanResult`,
:class:`Replanner`, :func:`write_path_json`, :func:`write_qgc_plan`.
"""

from skyrecon.planning.flown import plan_with_flown_path, route_along_track
from skyrecon.planning.keep_out import capsule_distance, keep_out, path_conflict
from skyrecon.planning.mission import enu_to_geodetic, qgc_plan, write_path_json, write_qgc_plan
from skyrecon.planning.planner import Planner, plan_path
from skyrecon.planning.replan import ReplanDecision, Replanner, remaining_path
from skyrecon.planning.result import REASONS, PlanResult

__all__ = [
    "Planner",
    "capsule_distance",
    "keep_out",
    "path_conflict",
    "plan_path",
    "plan_with_flown_path",
    "route_along_track",
    "PlanResult",
    "REASONS",
    "Replanner",
    "ReplanDecision",
    "remaining_path",
    "write_path_json",
    "write_qgc_plan",
    "qgc_plan",
    "enu_to_geodetic",
]
