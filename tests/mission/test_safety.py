"""The stopping rule: formulas, the speed limit's parts, the rig's supported speed, and the rule
holding in every cycle of missions flown faster than the rig supports."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.mission import MissionConfig, make_scenario, run_mission
from skyrecon.mission.guidance import guide, unobserved_binds
from skyrecon.mission.metrics import mission_metrics, stop_rule_holds
from skyrecon.mission.perception import hit_range_m
from skyrecon.mission.safety import (
    rig_supported_speed,
    speed_limit,
    speed_warning,
    stoppable_speed_mps,
    stopping_distance_m,
)
from skyrecon.mission.vehicle import DroneState, step, turn_speed


@pytest.mark.parametrize("room", [0.5, 3.0, 12.0, 40.0])
@pytest.mark.parametrize("accel,reaction", [(3.0, 0.2), (5.0, 0.1), (8.0, 0.0)])
def test_stoppable_speed_stops_exactly_within_the_room(room, accel, reaction):
    v = stoppable_speed_mps(room, accel, reaction)
    assert stopping_distance_m(v, accel, reaction) == pytest.approx(room, rel=1e-9)
    assert stopping_distance_m(v * 1.01, accel, reaction) > room
    assert (
        stoppable_speed_mps(0.0, accel, reaction) == 0.0 and stoppable_speed_mps(-1.0, accel, reaction) == 0.0
    )


def test_braking_in_the_simulated_vehicle_fits_the_formula():
    """A drone at speed v told to brake stops within stopping_distance_m(v, a, dt)."""
    cfg = MissionConfig(cruise_speed_mps=15.0)
    s = DroneState(np.zeros(3), np.array([12.0, 0.0, 0.0]), 0.0, 0.0)
    start = s.position.copy()
    for _ in range(100):
        s = step(s, s.position + [5.0, 0, 0], 15.0, cfg, brake=True)
        if s.speed == 0.0:
            break
    assert s.speed == 0.0
    assert np.linalg.norm(s.position - start) <= stopping_distance_m(12.0, cfg.max_accel_mps2, cfg.dt) + 1e-9


def test_speed_limit_takes_the_tightest_part_and_says_which():
    cfg = MissionConfig(cruise_speed_mps=15.0)
    free = speed_limit(cfg, verified_m=100.0, momentum_room_m=math.inf, to_go_m=500.0, turns_mps=99.0)
    # the path is never trusted beyond the rig's range: the rig's supported speed binds
    assert free.value_mps == pytest.approx(rig_supported_speed(cfg)) and free.reason == "rig"
    assert free.path_room_m == pytest.approx(hit_range_m(cfg) - cfg.verify_buffer_m) and free.stop_limited
    slow = speed_limit(cfg, 100.0, momentum_room_m=4.0, to_go_m=500.0, turns_mps=99.0)
    assert slow.reason == "momentum" and slow.stop_mps == slow.value_mps
    assert slow.value_mps == pytest.approx(
        stoppable_speed_mps(4.0 - cfg.verify_buffer_m, 5.0, cfg.reaction_s)
    )
    turn = speed_limit(cfg, 100.0, math.inf, 500.0, turns_mps=2.0)
    assert turn.reason == "turns" and turn.value_mps == 2.0 and not turn.stop_limited
    assert turn.stop_mps > 2.0  # the stopping rule's own part is kept for the log
    cruise = speed_limit(MissionConfig(), 100.0, math.inf, 500.0, 99.0)
    assert cruise.reason == "cruise" and cruise.value_mps == 6.0


def test_a_cruise_speed_the_rig_cannot_stop_from_is_warned_about():
    assert speed_warning(MissionConfig(cruise_speed_mps=6.0)) == ""
    cfg = MissionConfig(cruise_speed_mps=15.0)
    v = rig_supported_speed(cfg)
    assert 6.0 < v < 15.0
    text = speed_warning(cfg)
    assert "15 m/s" in text and f"{v:.1f} m/s" in text
    # harder braking supports more; a shorter range than the rig's trusted one supports less
    assert rig_supported_speed(MissionConfig(max_accel_mps2=8.0)) > v
    assert rig_supported_speed(MissionConfig(max_range_m=12.0)) < v


def test_the_speed_cap_comes_from_the_maps_range_not_the_depth_range():
    # the map ends where a quarter pixel of disparity moves depth 1.5 m (17 m for the default rig):
    # space beyond it is never verified, so the rig cannot stop from a speed that needs it
    cfg = MissionConfig()
    trusted = hit_range_m(cfg)
    assert trusted == pytest.approx(16.97, abs=0.01) and trusted < cfg.max_range_m
    v = rig_supported_speed(cfg)
    assert stopping_distance_m(v, cfg.max_accel_mps2, cfg.reaction_s) == pytest.approx(
        trusted - cfg.verify_buffer_m
    )
    far = speed_limit(cfg, cfg.max_range_m, math.inf, 500.0, 99.0)
    assert far.path_room_m == pytest.approx(trusted - cfg.verify_buffer_m) and not far.unobserved_in_range
    near = speed_limit(cfg, 0.9 * trusted, math.inf, 500.0, 99.0)
    assert near.unobserved_in_range


def test_a_longer_baseline_trusts_depth_farther_and_supports_more_speed():
    base = MissionConfig()
    wide = base.with_baseline(0.6)
    # same depth error at the end of the range: Z^2 / B constant; same nearest depth searched
    assert wide.max_range_m**2 / wide.baseline_m == pytest.approx(base.max_range_m**2 / base.baseline_m)
    assert wide.min_depth_m <= base.min_depth_m + 1e-9 and wide.max_disparity % 16 == 0
    assert hit_range_m(wide) == pytest.approx(24.0, abs=0.05) and hit_range_m(wide) > hit_range_m(base)
    assert rig_supported_speed(wide) > 13.5 > 12.0 > rig_supported_speed(base)
    assert speed_warning(wide.with_overrides(cruise_speed_mps=13.5)) == ""
    assert base.with_baseline(0.6, keep_range=True).max_range_m == base.max_range_m
    with pytest.raises(InputError):
        base.with_baseline(0.0)


def test_turn_speed_falls_with_the_angle_and_grows_with_the_braking_limit():
    cfg = MissionConfig()
    speeds = [turn_speed(math.radians(a), cfg) for a in (0, 15, 30, 60, 90, 150)]
    assert speeds[0] == math.inf and all(a > b for a, b in zip(speeds[1:], speeds[2:]))
    assert speeds[-1] >= 1.0
    assert turn_speed(0.5, MissionConfig(max_accel_mps2=8.0)) > turn_speed(0.5, cfg)


def test_stop_rule_holds_flags_a_cycle_faster_than_it_may_be():
    from skyrecon.mission.loop import CycleRecord

    def rec(speed, stop):
        return CycleRecord(
            0, 0.0, np.zeros(3), 0.0, 0.0, speed, {}, 9.0, False, True, True, 9.0, 9.0, 1.0, 9.0, stop
        )

    assert stop_rule_holds([rec(1.0, 2.0), rec(1.5, 2.0)], 5.0, 0.1) == [True, True]
    # above the limit but braking at full deceleration: allowed; above it and not braking: flagged
    assert stop_rule_holds([rec(4.0, 9.0), rec(3.5, 1.0), rec(3.4, 1.0)], 5.0, 0.1) == [True, True, False]


@pytest.mark.parametrize("seed", [1, 2])
def test_missions_faster_than_the_rig_supports_keep_the_stopping_rule_every_cycle(tiny_config, seed):
    cfg = tiny_config.with_overrides(cruise_speed_mps=15.0)
    assert speed_warning(cfg)
    result = run_mission(make_scenario(seed, cfg), cfg)
    m = mission_metrics(result)
    assert m["collisions"] == 0 and m["success"], m["message"]
    assert m["stop_rule_ok"] and all(stop_rule_holds(result.records, cfg.max_accel_mps2, cfg.dt))
    assert m["min_clearance_m"] > cfg.safety_margin_m
    assert max(r.speed_mps for r in result.records) <= rig_supported_speed(cfg) + 1e-6
    assert m["warnings"] and m["loop_ms_p99"] is not None


def test_a_stalled_drone_looks_around_the_point_it_must_see():
    from skyrecon.mission.guidance import scan_look_at

    p, look = np.zeros(3), np.array([2.0, 0.0, 0.0])
    assert np.array_equal(scan_look_at(look, p, 0.5), look)  # not yet: one second first
    seen = {tuple(np.round(scan_look_at(look, p, t), 3)) for t in np.arange(1.0, 7.0, 1.0)}
    assert len(seen) >= 5  # a different view every second
    for t in np.arange(1.0, 7.0, 0.5):  # always about the same distance away, within 30 degrees
        q = scan_look_at(look, p, t)
        assert abs(np.linalg.norm(q[:2]) - 2.0) < 1e-9 and np.degrees(np.arctan2(q[1], q[0])) <= 30.0 + 1e-9


def _guided_steps(rest, yaw_deg, verified_m, cfg, cycles=20):
    state = DroneState(rest[0].copy(), np.zeros(3), math.radians(yaw_deg), 0.0)
    for _ in range(cycles):
        g = guide(rest - rest[0] + state.position, state, verified_m, cfg)
        state = step(
            state, g.carrot, g.speed_limit, cfg, look_at=g.look_at, look_within_rad=g.look_within_rad
        )
    return state, g


def test_an_unobserved_point_that_costs_no_speed_does_not_hold_the_drone_still():
    # Seen at 15 m/s (seed 10): the path bends left, the first unobserved point lies 19.75 m along
    # it, 49 degrees off the direction of motion, and the turns set the limit. Looking straight
    # at that point turned the camera beyond max_heading_error_deg and the drone stood still.
    cfg = MissionConfig().with_overrides(cruise_speed_mps=15.0)
    rest = np.array(
        [[0, 0, 15], [3.93, 2.17, 15.1], [4.43, 4.9, 15.6], [4.43, 11.9, 15.9], [4.0, 16.5, 16.7]]
    )
    rest = np.vstack([rest, [[-27.4, 38.2, 14.4]]]).astype(float)
    g = guide(rest, DroneState(rest[0].copy(), np.zeros(3), math.radians(78.0), 0.0), 19.75, cfg)
    assert g.limit is not None and not unobserved_binds(g.limit)
    assert g.look_within_rad is not None  # the look is kept within reach of the motion
    state, _ = _guided_steps(rest, 78.0, 19.75, cfg)
    assert state.speed > 1.0 and np.linalg.norm(state.position - rest[0]) > 2.0


def test_an_unobserved_point_beyond_the_trusted_range_never_binds():
    # Seen at 15 m/s (seed 1): the first unobserved point 21.5 m along the path, beyond the
    # range the rig maps, so no look can verify it; the turns set the limit just below the rig's.
    cfg = MissionConfig().with_overrides(cruise_speed_mps=15.0)
    room = hit_range_m(cfg) - cfg.verify_buffer_m
    turns = 0.95 * rig_supported_speed(cfg)
    limit = speed_limit(cfg, 21.5, math.inf, 60.0, turns)
    assert limit.reason == "turns" and limit.path_room_m == pytest.approx(room)
    assert not unobserved_binds(limit)
    near = speed_limit(cfg, 10.0, math.inf, 60.0, turns)  # within range and setting the limit
    assert near.reason == "path_seen" and unobserved_binds(near)


def test_an_unobserved_point_that_sets_the_speed_is_looked_at_freely():
    cfg = MissionConfig()
    rest = np.array([[0.0, 0, 15], [5.0, 0, 15], [5.0, 30.0, 15]])
    g = guide(rest, DroneState(rest[0].copy(), np.zeros(3), 0.0, 0.0), 6.0, cfg)
    assert g.limit is not None and g.limit.reason == "path_seen" and unobserved_binds(g.limit)
    assert g.look_within_rad is None and np.allclose(g.look_at, [5.0, 1.0, 15.0])


def test_fine_depth_is_opt_in_for_the_tracker():
    from skyrecon.mission.perception import FINE_MAX_DISPARITY, flight_perception

    assert flight_perception(MissionConfig()).fine_max_disparity == 0
    assert flight_perception(MissionConfig(mover_fine_depth=True)).fine_max_disparity == FINE_MAX_DISPARITY
    assert flight_perception(MissionConfig(mover_fine_depth=True, track_movers=False)).fine_max_disparity == 0


def test_a_path_whose_unobserved_end_lies_within_the_arrival_tolerance_is_cut_short():
    """Held by unobserved space beside the goal, the drone need not fly its last metre: the path
    ends half the arrival tolerance short of the goal, inside the arrival sphere."""
    from skyrecon.mission.loop import ARRIVAL_CUT_SHARE, arrival_cut

    cfg = MissionConfig()
    goal = np.array([10.0, 0.0, 15.0])
    rest = np.array([[8.1, 0.0, 15.0], [9.0, 0.0, 15.0], goal])  # 1.9 m to go
    cut = arrival_cut(rest, 1.5, goal, cfg)  # observed free for 1.5 m: the last 0.4 m is not
    assert cut is not None
    end = 1.9 - ARRIVAL_CUT_SHARE * cfg.arrival_tolerance_m
    np.testing.assert_allclose(cut[-1], [8.1 + end, 0.0, 15.0])
    np.testing.assert_allclose(cut[:2], rest[:2])
    assert np.linalg.norm(cut[-1] - goal) < cfg.arrival_tolerance_m
    # whole horizon observed, unobserved space farther than the tolerance from the end, a path
    # ending elsewhere (an escape point): left as it is
    assert arrival_cut(rest, cfg.verify_horizon_m, goal, cfg) is None
    far = np.array([[0.0, 0.0, 15.0], goal])
    assert arrival_cut(far, 5.0, goal, cfg) is None
    assert arrival_cut(rest, 1.5, goal + np.array([0.0, 3.0, 0.0]), cfg) is None
    # nothing left to cut from
    assert arrival_cut(np.array([[9.6, 0.0, 15.0], goal]), 0.0, goal, cfg) is None
