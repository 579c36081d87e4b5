"""``skyrecon demo``: a drone delivers a parcel through a synthetic city it has never seen.

It generates a city from the seed, picks a start and a delivery point far apart with buildings
in between (or takes ``--start``/``--goal``), and flies in closed loop: each cycle the stereo
camera's pair becomes depth, the depth goes into the drone's occupancy map, the distance field
and the path are checked and replanned, and the drone moves on. Collisions are judged against
the true geometry. It writes ``report.html`` (self-contained), ``mission.json`` (metrics),
``path.json`` (the flown track), ``cycles.json`` and the drone's map (``map/``).

Other things move in the city (``--movers on``, the default): other drones on their own
routes (some crossing the drone's), vehicles in the streets and a crane boom turning over a
building site. The drone tells what moves from what stands, tracks the movers, keeps them out
of its map and keeps clear of where they are going. With ``--prior-map`` it starts from an older
map of the city (``earlier``: the map a flight before a scaffold tower went up and a container
stack went away would have left) and corrects it with its own cameras.

With ``--missions N`` it flies seeds N, N+1, ... in parallel, each in ``seed_NNNN/``, and writes
``summary.json``, ``summary.md`` and ``summary.html``.

With ``--faults`` the cameras and the flight computer fail as told; the drone finds out from
its data, brakes to a hover, and after 3 s without trustworthy depth returns, lands or hovers
(``--failsafe``); ``mission.json`` says how it ended (``outcome``) and when each fault was
detected (``faults``).

Exit status: 0 delivered (every mission, with --missions); 1 a mission was not delivered
(collision, time limit, or a failsafe return, landing or hover); 2 impossible input (e.g. a goal inside a building): ``report.html``
still says why.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import deque
from dataclasses import replace

from skyrecon.cli.common import (
    add_camera_noise_option,
    add_cloud_format,
    add_command,
    add_executor_options,
    add_record_option,
    describe_executor,
    info,
    open_executor,
    output_dir,
    positive_float,
    positive_int,
    recording,
)
from skyrecon.errors import InputError
from skyrecon.mission import MissionConfig
from skyrecon.mission.batch import fly_and_write, mission_line, run_missions
from skyrecon.mission.safety import speed_warning
from skyrecon.progress import progress, progress_enabled
from skyrecon.sim.faults import GPS_FAULTS, parse_faults

EXAMPLES = """  skyrecon demo                                  # one delivery, seed 0, into ./demo_out/
  skyrecon demo --seed 7 --out mission7/
  skyrecon demo --start -57 -15 15 --goal 53 58 15 --out custom/
  skyrecon demo --missions 20 --out many/        # seeds 0..19 in parallel, summary.html
  skyrecon demo --missions 100 --executor dask --scheduler tcp://head:8786 --out /shared/many/
  skyrecon demo --width 320 --height 240 --city-size 100 --out quick/
  skyrecon demo --speed 15 --baseline 0.6 --out fast/   # a wider rig trusts depth farther: 15 m/s
  skyrecon demo --prior-map earlier --out stale/   # plans on yesterday's map; a tower is new, a stack gone
  skyrecon demo --seed 7 --prior-map mission7/map --out again/   # reuse the map of an earlier flight
  skyrecon demo --movers off --out still/         # a city where nothing moves
  skyrecon demo --faults blackout@12+2,one-eye@30 --failsafe land --out faulty/
  skyrecon demo --faults random --seed 5 --out random_faults/
  skyrecon demo --record demo.rrd                 # the flight on a timeline: 'rerun demo.rrd'
  skyrecon demo --record demo.mcap                # the same for Foxglove / Lichtblick
"""


def _xyz(text: list[str], name: str):
    try:
        return [float(v) for v in text]
    except ValueError:
        raise InputError(f"{name} needs three numbers X Y Z in metres, got {' '.join(text)}") from None


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = add_command(
        subparsers,
        "demo",
        help="fly a simulated delivery through a city the drone maps as it goes",
        description=__doc__.split("\n\n", 1)[1].split("\n\nExit status")[0],
        examples=EXAMPLES,
    )
    p.add_argument("--seed", type=int, default=0, help="city seed; also picks start and goal (default 0)")
    p.add_argument(
        "--out", default="demo_out", help="output directory, created if missing (default ./demo_out)"
    )
    p.add_argument("--start", nargs=3, metavar=("X", "Y", "Z"), help="start position, world metres (z up)")
    p.add_argument("--goal", nargs=3, metavar=("X", "Y", "Z"), help="delivery point, world metres (z up)")
    p.add_argument(
        "--missions", type=positive_int, default=1, help="fly this many seeds (seed, seed+1, ...) in parallel"
    )
    add_executor_options(p, "parallel missions with --missions (default: CPU count, or $SKYRECON_WORKERS)")
    add_cloud_format(p)
    p.add_argument("--city-size", type=positive_float, help="side of the city, metres (default 200)")
    p.add_argument("--width", type=positive_int, help="camera image width, pixels (default 640)")
    p.add_argument("--height", type=positive_int, help="camera image height, pixels (default 480)")
    p.add_argument("--speed", type=positive_float, help="cruise speed, m/s (default 6)")
    p.add_argument(
        "--max-accel",
        type=positive_float,
        help="the vehicle's acceleration and braking limit, m/s^2 (default 5); with the rig's trusted "
        "range it sets the highest speed the drone can stop from (a faster --speed is capped, with a warning)",
    )
    p.add_argument(
        "--baseline",
        type=positive_float,
        help="stereo baseline, metres (default 0.3); a longer one trusts depth farther (as the square root "
        "of the baseline, unless --max-range is given) and so supports a higher speed",
    )
    p.add_argument(
        "--max-range",
        type=positive_float,
        help="depth is used up to this range, metres (default 20; the map marks obstacles only as far as the rig's "
        "depth is accurate to 1.5 m, 17 m for the default rig); farther matches only carve free space",
    )
    p.add_argument(
        "--clearance", type=positive_float, help="distance kept from mapped obstacles, metres (default 2)"
    )
    p.add_argument(
        "--max-altitude",
        type=positive_float,
        help="ceiling of the flight band, metres (default 30; "
        "lower makes the drone go round more buildings instead of over them)",
    )
    p.add_argument(
        "--pose-source",
        choices=("odometry", "truth", "gps+odometry"),
        default="odometry",
        help="where the drone's pose comes from: its own stereo visual odometry (default), the "
        "simulator's exact pose, or the odometry anchored by a simulated urban-canyon GPS",
    )
    p.add_argument(
        "--movers",
        default="on",
        metavar="on|off|FILE.json",
        help="other drones, vehicles and a turning crane boom move through the city (default on); or "
        "the movers described in a JSON file (as mission.json's scenario.movers)",
    )
    p.add_argument(
        "--plain",
        action="store_true",
        help="a world of plain surfaces: plain facades, glass and plain grey streets (as 'skyrecon "
        "render --plain'), and plain movers (not the same city as without)",
    )
    p.add_argument(
        "--prior-map",
        metavar="MAP_DIR|earlier",
        help="start from an older map of this city: a map directory (e.g. the map/ of an earlier demo "
        "with the same seed) or 'earlier' (the map an earlier flight left, before a scaffold tower went "
        "up and a container stack went away); the drone plans on it and corrects it with its cameras",
    )
    p.add_argument(
        "--city-changes",
        action="store_true",
        help="today's city differs from the prior's (a new scaffold tower, a container stack gone); "
        "on with --prior-map earlier",
    )
    p.add_argument(
        "--no-tracking",
        action="store_true",
        help="do not separate and track moving objects (they go into the map like buildings); for comparison",
    )
    add_camera_noise_option(p)
    p.add_argument(
        "--ground-z",
        type=float,
        metavar="METRES",
        help="the ground's world height (a terrain model and altimeter; the generated city's is 0, the "
        "default): under camera noise, plain ground whose measured border agrees with it is seen as "
        "open air above it",
    )
    p.add_argument(
        "--no-ground-prior",
        action="store_true",
        help="fly without the ground's height (plain ground under noise then stays unknown)",
    )
    p.add_argument(
        "--faults",
        metavar="SPEC",
        help="inject sensor and computer faults: NAME@ONSET[+DURATION][:VALUE], comma-separated "
        "(blackout, freeze, drop, one-eye, latency, cpu, glare, noise; gps-jump with --pose-source "
        "gps+odometry), or 'random' (a seeded mix); e.g. blackout@12+2,latency@20+5:0.4",
    )
    p.add_argument(
        "--failsafe",
        choices=("return", "land", "hover"),
        default="return",
        help="what a prolonged loss of trustworthy depth (3 s), or 30 s without getting closer to the "
        "goal, triggers: return along the flown track to take-off (default), land where it is over "
        "ground seen free, or hover",
    )
    p.add_argument(
        "--time-limit",
        type=positive_float,
        help="simulated seconds before giving up (default: from the distance)",
    )
    add_record_option(p)
    return p


def _config(args):
    cfg = MissionConfig()
    changes = dict(
        width=args.width,
        height=args.height,
        cruise_speed_mps=args.speed,
        max_accel_mps2=args.max_accel,
        max_range_m=args.max_range,
        clearance_m=args.clearance,
        time_limit_s=args.time_limit,
        max_altitude_m=args.max_altitude,
        pose_source=args.pose_source,
        movers=args.movers != "off",
        movers_file="" if args.movers in ("on", "off") else args.movers,
        plain=args.plain,
        camera_noise=args.camera_noise,
        prior_map=args.prior_map or "",
        city_changes=bool(args.city_changes or args.prior_map == "earlier"),
        track_movers=not args.no_tracking,
        faults=args.faults or "",
        failsafe=args.failsafe,
        ground_z_m=args.ground_z,
    )
    if args.no_ground_prior and args.ground_z is not None:
        raise InputError("--ground-z and --no-ground-prior contradict each other: give one")
    if args.city_size is not None:
        scale = min(1.0, args.city_size / cfg.city_size_m)
        changes.update(
            city_size_m=args.city_size,
            min_goal_distance_m=cfg.min_goal_distance_m * scale,
            max_goal_distance_m=cfg.max_goal_distance_m * scale,
        )
    if args.width is not None and args.height is None:
        changes["height"] = max(48, round(args.width * 3 / 4))
    if args.width is not None or args.height is not None:
        w = changes.get("width") or cfg.width
        changes["max_disparity"] = max(16, int(round(cfg.max_disparity * w / cfg.width / 16)) * 16)
    try:
        cfg = cfg.with_overrides(**changes)
    except TypeError as e:  # pragma: no cover - field names are fixed above
        raise InputError(str(e)) from None
    if args.baseline is not None:
        cfg = cfg.with_baseline(args.baseline, keep_range=args.max_range is not None)
    if args.no_ground_prior:
        cfg = replace(cfg, ground_z_m=None)
    return cfg


class _Progress:
    """The live line: distance to go, loop rate (median of the last 25 cycles), replans, speed."""

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self.bar = None if quiet or not progress_enabled() else progress(desc="flying", unit=" cycles")
        self.loop: deque[float] = deque(maxlen=25)
        self.replans = 0
        self.plans = 0
        self.last_info = -1e9

    def __call__(self, rec, nav) -> None:
        self.loop.append(rec.loop_ms)
        if rec.replanned and rec.replan_ok:
            self.plans += 1
            self.replans = max(0, self.plans - 1)
        if self.quiet:
            return
        srt = sorted(self.loop)
        hz = 1000.0 / srt[len(srt) // 2] if srt and srt[len(srt) // 2] > 0 else float("nan")
        text = (
            f"t {rec.time_s:5.1f} s | to go {rec.to_go_m:6.1f} m | {rec.speed_mps:3.1f} m/s | "
            f"loop {hz:5.1f} Hz | {self.replans} replans | clearance {rec.clearance_m:5.2f} m"
        )
        if self.bar is not None:
            self.bar.set_postfix_str(text, refresh=False)
            self.bar.update(1)
        elif rec.time_s - self.last_info >= 5.0:
            self.last_info = rec.time_s
            info("  " + text)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def run(args: argparse.Namespace) -> int:
    # The loop's parallel kernels wait passively between frames; spinning OpenMP workers would
    # steal the cores the stereo threads need (and a shared machine's cores from others).
    os.environ.setdefault("OMP_WAIT_POLICY", "passive")
    cfg = _config(args)
    # a specification that cannot be parsed fails here, in one line
    if any(f.name in GPS_FAULTS for f in parse_faults(cfg.faults)) and cfg.pose_source != "gps+odometry":
        raise InputError("a gps-jump fault needs a GPS: add --pose-source gps+odometry")
    start = _xyz(args.start, "--start") if args.start else None
    goal = _xyz(args.goal, "--goal") if args.goal else None
    if (start is None) != (goal is None):
        raise InputError("give both --start and --goal, or neither (then the seed picks them)")
    out = output_dir(args.out)
    warning = speed_warning(cfg)
    if warning:  # shown even with --quiet: the user asked for a speed the drone will not fly
        info(f"warning: {warning}")
    if args.missions > 1:
        if start is not None:
            raise InputError("--start/--goal fix one mission; drop them with --missions")
        if args.record is not None:
            raise InputError("--record records one mission; drop it with --missions")
        seeds = list(range(args.seed, args.seed + args.missions))
        with open_executor(args) as executor:
            if not args.quiet:
                info(
                    f"flying {len(seeds)} missions (seeds {seeds[0]}..{seeds[-1]}) into {out}/seed_NNNN/ "
                    f"({describe_executor(executor)})"
                )
            rows, totals = run_missions(seeds, out, cfg, executor, quiet=args.quiet, cloud_format=args.format)
        if not args.quiet:
            info(
                f"{totals['succeeded']} of {totals['missions']} delivered, {totals['collisions']} collisions; "
                f"summary: {out / 'summary.html'} (and summary.json, summary.md)"
            )
        return 0 if totals["succeeded"] == totals["missions"] else 1

    t0 = time.perf_counter()
    progress = _Progress(args.quiet)

    def announce(sc) -> None:
        if not args.quiet:
            info(
                f"seed {sc.seed}: {cfg.city_size_m:g} m city with {sc.city.num_buildings} buildings; flying from "
                f"{_fmt(sc.start)} to {_fmt(sc.goal)} ({sc.straight_line_m:.0f} m apart, shortest feasible "
                f"{sc.shortest.length_m:.0f} m); the drone has no map yet"
            )

    with recording(args) as recorder:
        try:
            outcome = fly_and_write(
                args.seed,
                out,
                cfg,
                start,
                goal,
                on_cycle=progress,
                on_scenario=announce,
                cloud_format=args.format,
                recorder=recorder,
            )
        finally:
            progress.close()
    doc = outcome.doc
    report = os.path.abspath(out / "report.html")
    if outcome.refused:
        info(f"report: {report} (says why the mission is impossible)")
        raise InputError(f"impossible mission: {doc['message']}")
    if not args.quiet:
        info(mission_line(doc))
        info(f"wrote mission.json, path.json, cycles.json, map/ to {out} in {time.perf_counter() - t0:.0f} s")
    print(f"report: {report}", flush=True)
    if not doc["success"]:
        info(f"error: mission failed: {doc['message']}")
        return 1
    return 0


def _fmt(p) -> str:
    return "(" + ", ".join(f"{float(v):.1f}" for v in p) + ")"


__all__ = ["add_parser", "run"]


if __name__ == "__main__":  # pragma: no cover
    # imported here: cli.main imports every command module (this one too) to build its parser
    from skyrecon.cli.main import main

    sys.exit(main(["demo", *sys.argv[1:]]))
