"""Faults in flight: every fault type is detected from the data within 0.3 s and handled safely."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.cli.main import main
from skyrecon.errors import InputError
from skyrecon.mission.health import SensorHealth
from skyrecon.mission.loop import run_mission
from skyrecon.mission.metrics import mission_metrics
from skyrecon.mission.scenario import make_scenario
from skyrecon.sim.faults import FAULTS, FaultInjector, parse_faults, random_faults

ALL = "blackout@2+1,freeze@4+1,one-eye@6+1,drop@8+1,latency@10+1:0.4,glare@12+1.5,noise@14+1:12,cpu@16+1:3"


def test_specifications_parse_and_bad_ones_name_the_valid_faults():
    f = parse_faults("blackout@12+2,latency@20+5:0.4,one-eye@3:left")
    assert [x.name for x in f] == ["one-eye", "blackout", "latency"]
    assert f[0].value == "left" and np.isinf(f[0].duration_s) and f[2].value == 0.4
    assert parse_faults("none") == [] and parse_faults("") == []
    for bad in ("smoke@3", "blackout", "blackout@x", "latency@3:fast", "one-eye@3:middle", "freeze@2:1"):
        with pytest.raises(InputError) as e:
            parse_faults(bad)
        assert all(n in str(e.value) for n in FAULTS)
    assert random_faults(3) == random_faults(3) and random_faults(3) != random_faults(4)


def test_injector_does_what_the_fault_says():
    rng = np.random.default_rng(0)
    L, R = rng.integers(0, 255, (2, 48, 64, 3), dtype=np.uint8)
    inj = FaultInjector(parse_faults("freeze@1+1,blackout@3+1,one-eye@5+1:left,drop@7+1,latency@9+1:0.3"))
    assert np.array_equal(inj.deliver(0.5, L, R).left, L)
    first = inj.deliver(0.9, L, R)
    frozen = inj.deliver(1.2, R, L)
    assert np.array_equal(frozen.left, first.left)
    assert inj.deliver(3.1, L, R).left.max() == 0
    d = inj.deliver(5.1, L, R)
    assert d.left.max() == 0 and np.array_equal(d.right, R)
    assert inj.deliver(7.1, L, R).left is None
    for t in np.round(np.arange(8.0, 9.25, 0.1), 3):  # 8.0 .. 9.2
        d = inj.deliver(float(t), L, R)
    assert 9.2 - d.stamp_s == pytest.approx(0.3, abs=0.06)


def test_health_reveals_each_fault_from_the_frame():
    h = SensorHealth()
    rng = np.random.default_rng(1)
    yy, xx = np.mgrid[0:120, 0:160]
    smooth = 128 + 80 * np.sin(xx / 5.0) * np.cos(yy / 7.0)  # a textured, noise-free image
    img = np.repeat(smooth[..., None], 3, axis=2).astype(np.uint8)
    assert h.check_frame(0.0, img, img.copy(), 0.0, 10.0).trusted
    assert "frozen" in h.check_frame(0.1, img, img.copy(), 0.1, 10.0, moved=True).reasons
    assert "frozen" not in SensorHealth().check_frame(0.1, img, img, 0.1, 10.0, moved=False).reasons
    black = np.zeros_like(img)
    assert "black_right" in SensorHealth().check_frame(0, img, black, 0, 10).reasons
    assert "no_frame" in SensorHealth().check_frame(0, None, None, 0, 10).reasons
    assert "stale" in SensorHealth().check_frame(1.0, img, img, 0.6, 10).reasons
    assert "overrun" in SensorHealth().check_frame(0, img, img, 0, 150.0).reasons
    noisy = np.clip(img + rng.normal(0, 15, img.shape), 0, 255).astype(np.uint8)
    assert "noisy" in SensorHealth().check_frame(0, noisy, noisy, 0, 10).reasons


@pytest.fixture(scope="module")
def campaign(tiny_config):
    """Every fault type in one short flight, and a blackout that lasts (the failsafe acts)."""
    out = {}
    for name, spec, failsafe in (
        ("all", ALL, "return"),
        ("return", "blackout@3", "return"),
        ("land", "blackout@3", "land"),
    ):
        cfg = tiny_config.with_overrides(
            pose_source="truth", faults=spec, failsafe=failsafe, time_limit_s=40.0
        )
        r = run_mission(make_scenario(1, cfg), cfg)
        out[name] = (r, mission_metrics(r))
    return out


def test_every_fault_is_detected_within_a_cycle_or_two(campaign):
    r, m = campaign["all"]
    assert m["collisions"] == 0
    flown = [f for f in m["faults"] if f["onset_s"] < r.records[-1].time_s - 1.0]
    assert flown, "the mission ended before the faults"
    for f in flown:
        assert f["detected_s"] is not None, f
        assert f["detect_delay_s"] <= 0.3, f
    # untrusted depth is never integrated: the drone holds (or returns) while it lasts
    for rec in r.records:
        if {"black", "frozen", "no_frame", "stale", "black_right", "black_left"} & set(rec.health.split(",")):
            assert rec.mode != "fly" and rec.timings_ms["integrate"] == 0.0


def test_a_lasting_blackout_returns_or_lands_safely(campaign):
    r, m = campaign["return"]
    assert m["outcome"] == "returned" and m["collisions"] == 0
    assert np.linalg.norm(r.final_position - r.scenario.start) <= 2.0
    assert [e["decision"] for e in m["failsafe_events"]][:2] == ["hold", "return"]
    r, m = campaign["land"]
    assert m["outcome"] in ("landed", "hovering") and m["collisions"] == 0
    if m["outcome"] == "landed":
        assert r.final_position[2] < 1.0


def test_same_seed_same_faulty_flight(tiny_config):
    cfg = tiny_config.with_overrides(pose_source="truth", faults="random", time_limit_s=15.0)
    a = run_mission(make_scenario(2, cfg), cfg)
    b = run_mission(make_scenario(2, cfg), cfg)
    assert np.array_equal(a.flown_path(), b.flown_path()) and a.faults == b.faults


def test_bad_fault_spec_is_one_line(tmp_path, capsys):
    code = main(["demo", "--faults", "smoke@3", "--quiet", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "blackout" in err[0]


def test_report_shows_faults_and_decisions(campaign, tmp_path):
    from skyrecon.mission.outputs import write_mission_outputs

    r, _ = campaign["return"]
    doc = write_mission_outputs(r, tmp_path / "m", save_the_map=False)
    html = (tmp_path / "m" / "report.html").read_text()
    assert "Faults and failsafes" in html and "back along the flown track" in html
    assert doc["outcome"] == "returned" and doc["faults"][0]["detected_s"] is not None


def test_gps_jump_shifts_the_fixes_and_needs_a_gps(tiny_config):
    f = parse_faults("gps-jump@5+3:30")
    inj = FaultInjector(f, seed=4)
    assert inj.needs_gps and not FaultInjector(parse_faults("drop@1")).needs_gps
    assert np.all(inj.gps_offset(4.9) == 0) and np.all(inj.gps_offset(8.1) == 0)
    off = inj.gps_offset(6.0)
    assert np.linalg.norm(off) == pytest.approx(30.0) and off[2] == 0
    assert np.array_equal(off, FaultInjector(f, seed=4).gps_offset(7.0))  # one direction per fault
    # random draws GPS faults only for a drone with a GPS
    assert not any(x.name == "gps-jump" for s in range(40) for x in random_faults(s))
    assert any(x.name == "gps-jump" for s in range(40) for x in random_faults(s, gps=True))
    cfg = tiny_config.with_overrides(pose_source="truth", faults="gps-jump@2+1")
    with pytest.raises(InputError, match="gps\\+odometry"):
        run_mission(make_scenario(1, cfg), cfg)


def test_gps_source_flags_a_rejected_fix(tiny_config):
    from skyrecon.core import Rigid3
    from skyrecon.mission.loop import mission_rig
    from skyrecon.mission.pose_source import GpsOdometryPose, PoseReading
    from skyrecon.odometry.types import TrackingState
    from skyrecon.sim import generate_city

    class PerfectOdometry:  # the GPS half is under test: an odometry that tracks exactly
        def read(self, left, right, time_s, disparity_px, true_world_from_left):
            return PoseReading(true_world_from_left, TrackingState.OK)

    start = Rigid3(np.eye(3), [0.0, 0.0, 30.0], "world", "left")
    src = GpsOdometryPose(mission_rig(tiny_config), start, generate_city(0, 60.0), seed=0)
    src.odometry = PerfectOdometry()  # type: ignore[assignment]
    src.fix_offset = FaultInjector(parse_faults("gps-jump@3+2:40"), seed=0).gps_offset
    flagged = []
    for k in range(60):
        t = k * 0.1
        pose = Rigid3(np.eye(3), [t * 2.0, 0.0, 30.0], "world", "left")  # high above the city
        r = src.read(None, None, t, None, pose)
        if src.rejected_fix:
            flagged.append(t)
        assert np.linalg.norm(r.world_from_left.t - pose.t) < 5.0  # the jump never moved the pose
    # (the simulated receiver has multipath of its own: fixes may be refused outside the fault too)
    assert sum(3.0 - 1e-9 <= t < 5.3 for t in flagged) >= 5


def test_a_starved_cpu_within_budget_is_reported_slow():
    h = SensorHealth(budget_ms=100.0)
    img = np.full((48, 64, 3), 128, np.uint8)
    for _ in range(10):
        assert "slow" not in h.check_frame(0, img, img, 0, 50.0, moved=False).reasons
    r = h.check_frame(0, img, img, 0, 80.0, moved=False).reasons  # 1.6x the usual, under the budget
    assert "slow" in r and "overrun" not in r
    assert "overrun" in h.check_frame(0, img, img, 0, 150.0, moved=False).reasons


def test_no_progress_to_the_goal_for_long_begins_the_failsafe(tiny_config):
    from skyrecon.mapping import OccupancyMap
    from skyrecon.mission.failsafe import Failsafe

    occ = OccupancyMap(voxel_size_m=0.5)
    p = np.array([0.0, 0.0, 10.0])
    fs = Failsafe(tiny_config.with_overrides(failsafe="return", no_progress_failsafe_s=5.0))
    assert fs.progress(0.0, 50.0, p, occ) == "fly"
    assert fs.progress(3.0, 48.5, p, occ) == "fly"  # 1.5 m closer: the clock restarts
    assert fs.progress(7.9, 48.0, p, occ) == "fly"  # dithering half a metre is not progress
    assert fs.progress(8.0, 49.0, p, occ) == "return"
    assert "no progress towards the goal" in fs.events[-1]["reason"]
    hover = Failsafe(tiny_config.with_overrides(failsafe="hover", no_progress_failsafe_s=5.0))
    assert hover.progress(0.0, 50.0, p, occ) == "fly" and hover.progress(10.0, 50.0, p, occ) == "fly"
    # backing off to see the way (paused) does not count as no progress; the time around it does
    fs = Failsafe(tiny_config.with_overrides(failsafe="return", no_progress_failsafe_s=5.0))
    assert fs.progress(0.0, 50.0, p, occ) == "fly"
    assert fs.progress(3.0, 50.0, p, occ) == "fly"
    assert fs.progress(9.0, 56.0, p, occ, paused=True) == "fly"  # 6 s backing off, farther away
    assert fs.progress(10.9, 50.5, p, occ) == "fly"  # 4.9 s not paused since the best
    assert fs.progress(11.1, 50.5, p, occ) == "return"
    # depth untrustworthy every other frame: the held frames do not count, nor restart the count
    fs = Failsafe(tiny_config.with_overrides(failsafe="return", no_progress_failsafe_s=5.0))
    modes = []
    for k in range(120):
        t = 0.1 * k
        fs.update(t, k % 2 == 0, [] if k % 2 == 0 else ["no_depth"], p, occ)
        modes.append(fs.progress(t, 50.0, p, occ))
        if modes[-1] == "return":
            break
    assert modes[-1] == "return" and 9.5 <= t <= 11.0  # 5 s of flying frames in 10 s


def test_a_fault_hidden_by_missing_frames_is_masked_not_missed(tiny_config):
    cfg = tiny_config.with_overrides(
        pose_source="truth", faults="drop@3+2,freeze@3.5+1,drop@6+1,latency@6.5+2:0.3", time_limit_s=12.0
    )
    r = run_mission(make_scenario(1, cfg), cfg)
    rows = {(f["name"], f["onset_s"]): f for f in mission_metrics(r)["faults"]}
    if r.records[-1].time_s < 9.0:
        pytest.skip("the mission ended before the faults")
    freeze = rows[("freeze", 3.5)]
    assert freeze["masked"] and freeze["detected_s"] is None  # no frame arrived while it lasted
    late = rows[("latency", 6.5)]
    assert not late["masked"] and late["visible_s"] == pytest.approx(7.0, abs=0.11)
    assert late["detected_s"] is not None and late["detect_delay_s"] <= 0.3
