"""The mission's parts: vehicle limits, path helpers, the map-change filter, the look-ahead check, endpoints."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyrecon.core import Intrinsics
from skyrecon.errors import InputError
from skyrecon.mapping import OccupancyMap
from skyrecon.mission import MissionConfig, make_scenario
from skyrecon.mission.guidance import guide, hover
from skyrecon.mission.navigator import Navigator
from skyrecon.mission.scenario import MapBox, _segment_blocked
from skyrecon.mission.vehicle import (
    DroneState,
    corner_speed_limit,
    point_along,
    sample_path,
    step,
    turn_speed,
    wrap_angle,
)
from skyrecon.sim import look_from


def test_step_respects_speed_acceleration_and_turn_rate():
    cfg = MissionConfig()
    s = DroneState(np.zeros(3), np.zeros(3), 0.0, 0.0)
    carrot_ahead = np.array([100.0, 0.0, 0.0])
    speeds = []
    for _ in range(60):
        n = step(s, carrot_ahead, 99.0, cfg)
        assert np.linalg.norm(n.velocity - s.velocity) <= cfg.max_accel_mps2 * cfg.dt + 1e-9
        s = n
        speeds.append(s.speed)
    assert max(speeds) <= cfg.cruise_speed_mps + 1e-9 and speeds[-1] == np.float64(cfg.cruise_speed_mps)
    # a target behind: turn at the rate limit, and do not move while the camera looks away
    s = DroneState(np.zeros(3), np.zeros(3), 0.0, 0.0)
    n = step(s, np.array([-10.0, 0.1, 0.0]), 5.0, cfg)
    assert abs(wrap_angle(n.yaw - s.yaw)) <= math.radians(cfg.max_yaw_rate_deg_s) * cfg.dt + 1e-9
    assert n.speed == 0.0


def test_step_faces_the_way_it_goes_when_the_look_at_is_straight_below():
    """A look-at straight below has no bearing: the drone turns to its carrot and then moves
    (the heading froze before, and a carrot 90 degrees off it was never flown to: a failsafe
    return down a steep flown track hovered in place until its time limit)."""
    cfg = MissionConfig()
    s = DroneState(np.array([0.0, 0.0, 20.0]), np.zeros(3), 0.0, 0.0)
    carrot = np.array([0.0, 1.0, 19.5])  # 1 m to the left (+y), a little down
    below = np.array([0.0, 0.0, 10.0])  # what it looks at: straight below
    within = 0.5 * math.radians(cfg.max_heading_error_deg)  # as guidance.guide clamps the look
    turned = False
    for _ in range(30):
        s = step(s, carrot, 2.0, cfg, look_at=below, look_within_rad=within)
        turned = turned or abs(wrap_angle(s.yaw - math.pi / 2)) <= within + 1e-9
    assert turned and np.linalg.norm(s.position - carrot) < 0.05  # it got there


def test_step_brakes_within_its_limit_and_pitches_towards_the_target():
    cfg = MissionConfig()
    s = DroneState(np.zeros(3), np.array([6.0, 0, 0]), 0.0, 0.0)
    n = step(s, np.array([0.2, 0.0, 0.0]), 6.0, cfg)
    assert n.speed == np.float64(6.0 - cfg.max_accel_mps2 * cfg.dt)
    tilt = math.radians(cfg.max_camera_pitch_rate_deg_s) * cfg.dt  # the gimbal's slew per cycle
    still = DroneState(np.zeros(3), np.zeros(3), 0.0, 0.0)
    n = step(still, np.array([5.0, 0.0, 5.0]), 6.0, cfg)
    assert math.isclose(n.pitch_down, -tilt)  # starts to look up a climb, no faster than the gimbal
    for _ in range(10):
        n = step(DroneState(np.zeros(3), np.zeros(3), 0.0, n.pitch_down), np.array([5.0, 0.0, 5.0]), 6.0, cfg)
    assert math.isclose(n.pitch_down, -math.radians(cfg.max_camera_pitch_up_deg))  # 45 deg up, clamped
    n = still
    for _ in range(10):
        n = step(
            DroneState(np.zeros(3), np.zeros(3), 0.0, n.pitch_down), np.array([5.0, 0.0, -5.0]), 6.0, cfg
        )
    assert math.isclose(n.pitch_down, math.radians(cfg.max_camera_pitch_deg))  # down a descent


def test_path_helpers():
    path = np.array([[0.0, 0, 0], [10, 0, 0], [10, 10, 0]])
    assert np.allclose(point_along(path, 15.0), [10, 5, 0])
    assert np.allclose(point_along(path, 99.0), [10, 10, 0])
    pts, s = sample_path(path, 0.5, 12.0)
    assert s[0] == 0 and s[-1] == 12.0 and np.allclose(np.diff(s), 0.5)
    assert np.allclose(pts[-1], [10, 2, 0])
    cfg = MissionConfig()
    assert corner_speed_limit(path, cfg, 20.0) == cfg.cruise_speed_mps  # 10 m is enough to slow down
    near = np.array([[0.0, 0, 0], [3, 0, 0], [3, 10, 0]])  # a right angle 3 m ahead
    slow = MissionConfig(max_accel_mps2=2.0)  # 3 m is too short to slow from 6 m/s to the turn speed
    v_turn = turn_speed(math.pi / 2, slow)
    assert corner_speed_limit(near, slow, 20.0) == np.float64(math.sqrt(v_turn**2 + 2 * 2.0 * 3.0)) < 6.0
    assert corner_speed_limit(near[:2], cfg, 20.0) == cfg.cruise_speed_mps


def _box_navigator(cfg: MissionConfig, goal=(30.0, 4.0, 14.0)) -> Navigator:
    box = MapBox(np.array([-8.0, -8.0, 8.0]), (96, 32, 32), cfg.voxel_size_m)
    return Navigator(cfg, box, np.array(goal))


def _look(nav: Navigator, depth_m: float, times: int = 3) -> None:
    """A 64x48 camera at (0, 4, 14) looking along +x sees a flat wall at ``depth_m`` (inf: open sky)."""
    cam = Intrinsics.from_fov(64, 48, 90.0)
    pose = look_from(np.array([0.0, 4.0, 14.0]), 0.0, 0.0)
    for _ in range(times):
        nav.integrate(np.full((48, 64), depth_m, np.float32), cam, pose)


def test_only_blocks_whose_occupied_voxels_change_reach_the_distance_field():
    cfg = MissionConfig()
    nav = _box_navigator(cfg)
    occupied_changes = lambda: nav.map.pop_changed_blocks(occupied_only=True)  # noqa: E731 - what update_distance reads
    _look(nav, np.inf, 1)  # open sky: free space only
    changed = nav.map.pop_changed_blocks()
    assert len(changed) > 0 and len(occupied_changes()) == 0
    _look(nav, 6.0, 1)  # a wall: occupied voxels appear
    assert len(occupied_changes()) > 0
    _look(nav, 6.0, 1)  # seen again: nothing new for the distance field
    assert len(occupied_changes()) == 0


def test_warm_up_leaves_the_map_and_its_distance_field_alone():
    cfg = MissionConfig()
    nav = _box_navigator(cfg)
    _look(nav, 6.0, 1)
    before = nav.map.dense_log_odds(np.array([-16, -16, 16]), (96, 48, 32)).copy()
    version = nav.df.version
    nav.warm_up(Intrinsics.from_fov(64, 48, 90.0))
    after = nav.map.dense_log_odds(np.array([-16, -16, 16]), (96, 48, 32))
    np.testing.assert_array_equal(before, after)
    assert nav.df.version == version
    assert len(nav.map.pop_changed_blocks(occupied_only=True)) > 0  # the wall's changes are still pending
    grid = nav.planner._grid  # built now, patched in the cycles, not rebuilt in the first one
    assert grid is not None and grid.version == nav.df.version


def test_only_replans_around_movers_inflate_the_heuristic():
    cfg = MissionConfig(keep_out_heuristic_weight=1.2)
    nav = _box_navigator(cfg)
    _look(nav, np.inf, 2)  # open sky ahead
    nav.update_distance()
    seen: list[float] = []
    plan = nav.planner.plan

    def spy(*args, **kwargs):
        seen.append(nav.planner.weight)
        return plan(*args, **kwargs)

    nav.planner.plan = spy  # type: ignore[method-assign]
    p = np.array([2.0, 4.0, 14.0])
    assert nav.replan(p)[0].success
    mover = np.array([[12.0, -4.0, 14.0, 12.0, 12.0, 14.0, 0.5]])  # a sweep across the way
    r, _ = nav.replan(p, mover)
    assert r.success and len(r.waypoints) > 2  # around it
    assert (
        seen[0] == 1.0
        and set(seen[1:]) == {cfg.keep_out_heuristic_weight}
        and cfg.keep_out_heuristic_weight > 1
    )
    assert nav.planner.weight == 1.0  # restored
    with pytest.raises(InputError):
        MissionConfig(keep_out_heuristic_weight=0.5)


def test_look_ahead_needs_the_path_observed():
    cfg = MissionConfig()
    nav = _box_navigator(cfg)
    path = np.array([[0.0, 4.0, 14.0], [30.0, 4.0, 14.0]])
    assert nav.verified_distance(path, 9.0, 1.5) == 1.5  # nothing observed: stop before the first sample
    _look(nav, 5.0)  # a wall 5 m ahead: free up to it, occupied at it
    d = nav.verified_distance(path, 9.0, 1.5)
    assert 4.0 <= d <= 5.0
    nav2 = _box_navigator(cfg)
    _look(nav2, np.inf)  # open air as far as the range: the whole horizon is verified
    assert nav2.verified_distance(path, 9.0, 1.5) == 9.0


def test_seed_endpoints_are_far_apart_clear_and_blocked(tiny_config):
    sc = make_scenario(3, tiny_config)
    assert tiny_config.min_goal_distance_m <= sc.straight_line_m <= tiny_config.max_goal_distance_m
    d = sc.city.distance(np.stack([sc.start, sc.goal]), include_ground=True)
    assert np.all(d >= tiny_config.endpoint_clearance_m)
    assert _segment_blocked(sc.city, sc.start, sc.goal, tiny_config.clearance_m)
    assert sc.shortest.success and sc.shortest.length_m >= sc.straight_line_m
    assert sc.box.contains(sc.start) and sc.box.contains(sc.goal)
    again = make_scenario(3, tiny_config)
    assert np.array_equal(again.start, sc.start) and np.array_equal(again.goal, sc.goal)


def test_guidance_brakes_before_unobserved_space_and_looks_at_it():
    cfg = MissionConfig()
    s = DroneState(np.zeros(3), np.array([6.0, 0, 0]), 0.0, 0.0)
    rest = np.array([[0.0, 0, 15], [100, 0, 15]])
    free = guide(rest, s, cfg.verify_horizon_m, cfg)
    assert free.speed_limit == cfg.cruise_speed_mps and free.look_within_rad is not None
    g = guide(rest, s, 5.0, cfg)  # unobserved from 5 m on
    a, t = cfg.max_accel_mps2, cfg.reaction_s  # stop (after reacting) before the buffer
    assert g.speed_limit == np.float64(-a * t + math.sqrt((a * t) ** 2 + 2 * a * (5.0 - cfg.verify_buffer_m)))
    assert g.limit is not None and g.limit.reason == "path_seen"
    assert np.allclose(g.look_at, [5.0, 0, 15]) and g.look_within_rad is None
    assert guide(rest, s, 1.0, cfg).speed_limit == 0.0  # within the buffer: stop
    h = hover(np.zeros(3), np.array([10.0, 0, 0]))
    assert h.speed_limit == 0.0 and h.to_go_m == 10.0


def test_a_climb_above_the_cameras_reach_is_seen_by_backing_off_along_the_flown_track():
    from skyrecon.mission.guidance import RETREAT_MAX_M, out_of_reach, retreat_path, vertical_reach_rad

    cfg = MissionConfig()
    up, down = vertical_reach_rad(cfg)
    # 15 deg tilt up plus half of the 640x480 / 90 deg camera's vertical field of view
    assert math.degrees(up) == pytest.approx(15.0 + math.degrees(math.atan(240 / 320)))
    assert math.degrees(down) == pytest.approx(30.0 + math.degrees(math.atan(240 / 320)))
    p = np.array([0.0, 0.0, 15.0])
    steep = np.array([1.0, 0.0, 17.0])  # 63 deg up: no tilt of the gimbal shows it
    assert out_of_reach(p, steep, cfg) and not out_of_reach(p, [10.0, 0.0, 17.0], cfg)
    assert out_of_reach(p, [0.5, 0.0, 12.0], cfg)  # straight down, beyond the 67 deg of reach
    # the track it flew: level along -x; it backs off until the point is 12 deg inside the reach
    way_back = np.array([p, [-30.0, 0.0, 15.0]])
    back = retreat_path(way_back, steep, cfg)
    assert back is not None and np.allclose(back[0], p)
    end = back[-1]
    elev = math.atan2(steep[2] - end[2], steep[0] - end[0])
    assert elev <= up - math.radians(12.0) + 1e-9 and elev > up - math.radians(12.0) - math.radians(2.0)
    assert np.all(np.diff(back[:, 0]) < 0)  # along the track, no further than needed
    # a point so high that no place on the track shows it: back off the longest allowed
    far = retreat_path(way_back, np.array([1.0, 0.0, 60.0]), cfg)
    assert far is not None and np.linalg.norm(far[-1] - p) == pytest.approx(RETREAT_MAX_M, abs=0.3)
    assert retreat_path(np.array([p, p + [-0.5, 0, 0]]), steep, cfg) is None  # nowhere to go


def _held_under_a_climb(cfg: MissionConfig):
    """A drone at 15 m held still by a climb at 72 degrees just ahead that its camera cannot look
    at, with 30 m of flown track behind it: (position, path ahead, flown track, speed limit)."""
    from skyrecon.mission.safety import speed_limit

    p = np.array([0.0, 0.0, 15.0])
    rest = np.array([p, [2.0, 0.0, 21.0], [20.0, 0.0, 21.0]])
    track = np.array([p, [-30.0, 0.0, 15.0]])
    held = speed_limit(cfg, 4.0, math.inf, 30.0, 99.0)
    assert held.reason == "path_seen"
    return p, rest, track, held


@pytest.mark.parametrize("looks_ahead", [False, True])
def test_backing_off_flies_the_track_back_and_ends_with_the_climb_in_reach(looks_ahead):
    """Blind (the default), the camera stays on the climb all the way; with
    ``backoff_looks_ahead`` the camera looks the way it flies, then holds at the end looking at
    the climb before the back-off ends."""
    from skyrecon.mission.guidance import RETREAT_AFTER_S, RETREAT_SPEED_MPS, BackOff

    cfg = MissionConfig(backoff_looks_ahead=looks_ahead)
    p, rest, track, held = _held_under_a_climb(cfg)
    b = BackOff()
    # not yet held long enough, not in normal flight, or not held by the unobserved point: nothing
    assert not b.consider(rest, 4.0, RETREAT_AFTER_S - 0.5, held, p, lambda q: track, cfg)
    assert not b.consider(rest, 4.0, RETREAT_AFTER_S, held, p, lambda q: track, cfg, mode="hold")
    assert not b.consider(rest, 4.0, RETREAT_AFTER_S, None, p, lambda q: track, cfg)
    assert b.consider(rest, 4.0, RETREAT_AFTER_S, held, p, lambda q: track, cfg) and b.active
    assert b.label("fly") == "retreat" and b.label("return") == "return"
    s = DroneState(p.copy(), np.zeros(3), 0.0, 0.0)  # facing the climb, backing off behind it
    moved, held_looking = 0, 0
    for _ in range(600):
        g = b.guide(s.position, s, cfg, math.inf)
        assert g.speed_limit <= RETREAT_SPEED_MPS
        if not looks_ahead:
            assert np.allclose(g.look_at, b.look)
        s = step(s, g.carrot, g.speed_limit, cfg, look_at=g.look_at, blind_mps=g.blind_mps)
        if not looks_ahead:
            assert abs(s.yaw) < math.radians(1.0)  # the camera stays on the climb
        elif np.hypot(*s.velocity[:2]) > 0.3:  # moving back: the camera looks the way it goes (-x)
            moved += 1
            assert abs(abs(s.yaw) - math.pi) < math.radians(30.0)
        if b.looking_since_s is not None:  # at the end: holding, looking at the climb
            assert np.allclose(g.look_at, b.look) and g.speed_limit == 0.0
            held_looking += 1
        if not b.active:
            break
    if looks_ahead:
        assert moved > 10 and held_looking > 10
        assert abs(s.yaw) < math.radians(10.0)  # turned back to the climb before flying on
    assert not b.active and s.position[0] < -3.0
    assert not out_of_reach_of(s.position, b.look, cfg)


def test_backing_off_stops_when_its_way_back_meets_a_mover():
    """The way back was free when flown; a mover's predicted sweep across it ends the back-off
    (the plan and its escapes keep clear of movers); a sweep elsewhere, or none, does not."""
    from skyrecon.mission.guidance import RETREAT_AFTER_S, BackOff
    from skyrecon.planning.keep_out import path_conflict

    cfg = MissionConfig()
    p, rest, track, held = _held_under_a_climb(cfg)

    def conflict(way, keep):  # where the way back comes within a capsule's radius (no margin)
        return path_conflict(way, keep, 0.0, 0.1)

    b = BackOff()
    assert b.consider(rest, 4.0, RETREAT_AFTER_S, held, p, lambda q: track, cfg)
    away = np.array([[0.0, 30.0, 15.0, 5.0, 30.0, 15.0, 1.0]])  # a drone's sweep far to the side
    assert not b.yield_to_movers(p, away, conflict) and b.active
    assert not b.yield_to_movers(p, None, conflict) and b.active
    behind = np.array([[-2.0, -3.0, 15.0, -2.0, 3.0, 15.0, 1.0]])  # crossing the way back, 2 m behind
    assert b.yield_to_movers(p, behind, conflict) and not b.active
    # holding at the end of the way back to look: any tracked mover ends it
    assert b.consider(rest, 4.0, RETREAT_AFTER_S, held, p, lambda q: track, cfg)
    b.looking_since_s = 50.0
    assert b.yield_to_movers(p, away, conflict) and not b.active and b.looking_since_s is None


def test_a_back_off_that_never_arrives_ends_after_its_time_limit():
    """The no-progress failsafe's clock stops while backing off, so a back-off that circles the
    end of its way back (held-out dynamic seed 179, 112 s) must end on its own."""
    from skyrecon.mission.guidance import RETREAT_AFTER_S, RETREAT_SLACK_S, RETREAT_SPEED_MPS, BackOff

    cfg = MissionConfig()
    p, rest, track, held = _held_under_a_climb(cfg)
    b = BackOff()
    assert b.consider(rest, 4.0, RETREAT_AFTER_S, held, p, lambda q: track, cfg)
    limit = b.time_limit_s()
    length = float(np.sum(np.linalg.norm(np.diff(b.path, axis=0), axis=1)))
    assert limit == pytest.approx(2.0 * length / RETREAT_SPEED_MPS + RETREAT_SLACK_S)
    stuck = DroneState(p.copy(), np.array([0.5, 0.0, 0.0]), 0.0, 0.0, time_s=40.0)  # never gets there
    ended_at = None
    for k in range(int(10 * (limit + 5))):
        stuck.time_s = 40.0 + 0.1 * k
        b.guide(stuck.position, stuck, cfg, math.inf)
        if not b.active:
            ended_at = stuck.time_s - 40.0
            break
    assert ended_at == pytest.approx(limit, abs=0.11)
    assert b.started_s is None and b.count == 1


def out_of_reach_of(position, point, cfg):
    from skyrecon.mission.guidance import out_of_reach

    return out_of_reach(position, point, cfg, margin_deg=10.0)


def test_a_drone_in_a_movers_way_sidesteps_without_turning_first():
    from skyrecon.mission.loop import ESCAPE_SPEED_MPS, _follow

    cfg = MissionConfig()
    nav = _box_navigator(cfg)
    _look(nav, np.inf)  # open sky ahead: observed free
    p = np.array([2.0, 4.0, 14.0])
    # a mover's predicted sweep passes just beside the drone: the plan cannot start here
    keep = np.array([[2.0, 2.5, 10.0, 2.0, 2.5, 18.0, 0.5]])
    r, how = nav.replan(p, keep)
    assert r.success and how == "escape" and nav.escaping(p)
    assert np.linalg.norm(nav.escape_to - p) <= 6.0
    # the camera looks back (yaw 180 degrees): the drone may move at once all the same (within
    # the stopping rule: vehicle.step's blind_mps)
    s = DroneState(p.copy(), np.zeros(3), math.pi, 0.0)
    _, g = _follow(nav, nav.rest(p), s, math.inf, False, cfg)
    assert g.blind_mps == ESCAPE_SPEED_MPS
    # once there, or on another path, it is no longer escaping
    assert not nav.escaping(nav.escape_to.copy())
    r, how = nav.replan(p)  # without the mover: an ordinary plan
    assert how == "plan" and not nav.escaping(p)


def test_a_drone_in_a_movers_way_steps_out_even_when_no_path_goes_on():
    """A mover's predicted sweep covers the drone and closes the whole way to the goal (held-out
    mission 115: a crane boom). The drone steps out of the sweep all the same (a path to the
    escape point alone, followed as an escape), asks for a path to the goal every cycle while
    it does, and keeps its escape point while that stays usable as the sweep shifts (no flip
    from one side to the other); once the way is open it plans to the goal again. With
    ``evade_movers`` (the default): without it, it hovers where it is."""
    assert MissionConfig().evade_movers
    off = _box_navigator(MissionConfig(evade_movers=False))
    _look(off, np.inf)
    off.update_distance()
    p = np.array([2.0, 4.0, 14.0])
    wall = np.array([[10.0, -30.0, 16.0, 10.0, 30.0, 16.0, 10.0]])  # across the box, the drone inside
    r, how = off.replan(p, wall)
    assert not r.success and not off.evading
    cfg = MissionConfig(evade_movers=True)
    nav = _box_navigator(cfg)
    _look(nav, np.inf)  # open sky ahead: observed free
    nav.update_distance()
    r, how = nav.replan(p, wall)
    assert r.success and how == "escape" and nav.evading
    assert len(r.waypoints) == 2 and np.allclose(r.waypoints[0], p)
    esc = r.waypoints[1].copy()
    axis_gap = np.linalg.norm((esc - wall[0, :3])[[0, 2]])
    assert axis_gap >= wall[0, 6] + nav.planner.threshold  # out of the sweep by the clearance
    assert np.linalg.norm(esc - p) <= 6.0
    assert nav.escaping(p)
    out = nav.check(p, np.zeros((0, 3), np.int32))
    assert not out.clear and out.evading  # seek a way on every cycle
    # the sweep shifts a little: the escape point is kept, not re-chosen
    q = p + 0.3 * (esc - p) / np.linalg.norm(esc - p)
    shifted = wall + np.array([[0.3, 0, 0, 0.3, 0, 0, 0]])
    r, how = nav.replan(q, shifted)
    assert r.success and how == "escape" and np.allclose(r.waypoints[1], esc)
    # the way is open again: an ordinary path to the goal
    r, how = nav.replan(q)
    assert r.success and how == "plan" and not nav.evading
    assert np.allclose(r.waypoints[-1], nav.goal)


def test_with_no_point_clear_of_a_huge_sweep_the_drone_still_moves_away():
    """A keep-out capsule 12 m in radius (a crane boom tracked with a large uncertainty) covers
    everything within the 6 m escape radius: with ``evade_movers`` the drone steps to the reachable
    point farthest from it rather than hovering inside (held-out-set seed 103)."""
    from skyrecon.planning.keep_out import capsule_distance

    cfg = MissionConfig(evade_movers=True)
    nav = _box_navigator(cfg)
    _look(nav, np.inf)
    nav.update_distance()
    p = np.array([8.0, 4.0, 16.0])
    boom = np.array([[14.0, -30.0, 16.0, 14.0, 30.0, 16.0, 12.0]])
    assert nav.escape_point(p, 6.0) is not None  # without the boom there is room ...
    r, how = nav.replan(p, boom)
    assert r.success and how == "escape" and nav.evading and len(r.waypoints) == 2
    away = r.waypoints[1]
    gain = capsule_distance(away[None], boom)[0] - capsule_distance(p[None], boom)[0]
    assert gain >= 4.0 and np.linalg.norm(away - p) <= 6.0 + 1e-9
    assert nav.planner.grid_for(away, away).distance(away[None])[0] >= nav.planner.threshold
    off = _box_navigator(MissionConfig(evade_movers=False))
    _look(off, np.inf)
    off.update_distance()
    assert not off.replan(p, boom)[0].success  # without it, it hovers


@pytest.mark.parametrize("aware", [False, True])
def test_a_steep_climb_is_verified_when_its_unseen_tube_probe_lies_beyond_the_cameras_reach(aware):
    """A 70-degree climb from the drone: the path and the tube below it are observed free, the
    tube probes beside it are not (the camera cannot look that far up: held-out seed 231). With
    ``reach_aware_verify`` the probes near the drone and beyond the camera's reach count as known,
    as the path samples within ``verify_skip_m`` do; farther ones still hold the drone."""
    cfg = MissionConfig(reach_aware_verify=aware)
    nav = _box_navigator(cfg)
    p = np.array([0.0, 4.2, 14.0])
    ang = np.radians(np.linspace(-30.0, 88.0, 400))  # rays in the climb's vertical plane only
    ends = p + 12.0 * np.stack([np.cos(ang), np.zeros_like(ang), np.sin(ang)], axis=1)
    for _ in range(3):
        nav.map.integrate_points(ends, p)
    up = np.radians(70.0)
    rest = np.array([p, p + 2.4 * np.array([np.cos(up), 0.0, np.sin(up)]), [8.0, 4.2, 16.3]])
    side = np.array([0.0, 1.0, 0.0])
    first = p + 1.5 * np.array([np.cos(up), 0.0, np.sin(up)])
    assert np.isnan(nav.map.log_odds_at(np.stack([first + side, first - side]))).all()  # unknown
    seen = nav.verified_distance(rest, cfg.verify_horizon_m, cfg.verify_skip_m)
    # without: held at the first sample past the skip; with: on to the first sample whose side
    # probes are more than verify_skip_m + verify_radius_m (2.5 m) from the drone
    assert seen == (2.5 if aware else 1.5)


@pytest.mark.parametrize("aware", [False, True])
def test_the_back_off_starts_sooner_on_steep_climbs_with_reach_aware_verify(aware):
    """A path point 45 degrees up, 7 degrees inside the camera's 52-degree reach (held-out seed
    248): the back-off starts only with ``reach_aware_verify`` (12 degrees of margin, not 5)."""
    from skyrecon.mission.guidance import RETREAT_AFTER_S, BackOff
    from skyrecon.mission.safety import speed_limit

    cfg = MissionConfig(reach_aware_verify=aware)
    p = np.array([0.0, 0.0, 15.0])
    rest = np.array([p, [2.0, 0.0, 17.0], [20.0, 0.0, 17.0]])  # 45 degrees up for 2.8 m
    track = np.array([p, [-30.0, 0.0, 15.0]])
    held = speed_limit(cfg, 1.5, math.inf, 30.0, 99.0)
    assert held.reason == "path_seen"
    b = BackOff()
    assert b.consider(rest, 1.5, RETREAT_AFTER_S, held, p, lambda q: track, cfg) == aware


def test_a_resumed_benchmark_reads_back_only_flights_of_its_settings(tmp_path):
    import json

    from skyrecon.mission.batch import read_mission_json

    cfg = MissionConfig(movers=True, prior_map="earlier")
    folder = tmp_path / "seed_0001"
    folder.mkdir()
    doc = {"seed": 1, "success": True, "reason": "", "config": cfg.to_dict()}
    (folder / "mission.json").write_text(json.dumps(doc))
    assert read_mission_json(folder)["seed"] == 1
    assert read_mission_json(folder, cfg)["seed"] == 1
    assert read_mission_json(folder, cfg.with_overrides(tracker_settings="min_texture=0")) is None
    assert read_mission_json(folder, cfg.with_overrides(plain=True)) is None
    # a folder flown before a setting existed reads as flown with its default
    old = {k: v for k, v in cfg.to_dict().items() if k != "plain"}
    (folder / "mission.json").write_text(json.dumps({**doc, "config": old}))
    assert read_mission_json(folder, cfg)["seed"] == 1
    (folder / "mission.json").write_text(json.dumps({**doc, "config": None}))
    assert read_mission_json(folder) is not None and read_mission_json(folder, cfg) is None
    (folder / "mission.json").write_text(json.dumps({**doc, "reason": "error"}))
    assert read_mission_json(folder, cfg) is None


def test_a_view_over_far_fields_is_not_refused_as_millimetres():
    """The loop's depth is its own stereo's, in metres: a frame whose measured pixels are
    mostly ground kilometres away (a noisy plain city's view over the fields beyond it) carves
    free space; the map's plausibility check for users' depth images must not stop the flight
    (it did: noisy plain delivery seed 6, session 48). A user's map keeps the check."""
    nav = _box_navigator(MissionConfig())
    _look(nav, 3045.0, 1)
    assert len(nav.map.pop_changed_blocks()) > 0  # free space carved, no error
    user_map = OccupancyMap(voxel_size_m=0.5)
    with pytest.raises(InputError, match="implausible in metres"):
        user_map.integrate_depth(
            np.full((48, 64), 3045.0, np.float32), Intrinsics.from_fov(64, 48, 90.0), np.eye(4)
        )


def test_the_navigator_gives_the_cameras_ground_plane():
    """The stereo stage's ground prior: the ground at ``cfg.ground_z_m`` as the camera sees it
    (its up direction in the camera's frame and its height above the ground); none without a
    ground height or from below it."""
    pose = look_from(np.array([0.0, 4.0, 14.0]), 0.3, math.radians(40.0))
    plane = _box_navigator(MissionConfig(ground_z_m=0.5)).ground_plane(pose)
    assert plane is not None and plane.height_m == pytest.approx(13.5)
    np.testing.assert_allclose(plane.up_cam, pose.R @ np.array([0.0, 0.0, 1.0]), atol=1e-12)
    np.testing.assert_allclose(
        plane.up_cam, [0.0, -math.cos(math.radians(40)), -math.sin(math.radians(40))], atol=1e-12
    )
    assert _box_navigator(MissionConfig(ground_z_m=None)).ground_plane(pose) is None
    assert _box_navigator(MissionConfig(ground_z_m=20.0)).ground_plane(pose) is None
