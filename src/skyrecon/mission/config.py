"""Every setting of a simulated delivery mission, in one place.

Units: metres, seconds, degrees where the name says ``_deg``. World frame: z up.
The defaults are the product's: a 640x480 stereo pair with a 90 degree horizontal field of
view and a 0.3 m baseline (good depth from about 2 m to 20 m, see :attr:`MissionConfig.max_range_m`),
0.5 m voxels, 2 m clearance, 6 m/s cruise in an altitude band of 12..30 m over a 200 m city.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

from skyrecon.errors import InputError


@dataclass(frozen=True)
class MissionConfig:
    """Settings of one mission (the sensor, the map, the planner, the vehicle, the scenario).

    Sensor (forward-looking rectified stereo rig, left camera at the drone's position):
        width, height: image size, pixels.
        hfov_deg: horizontal field of view, degrees.
        baseline_m: stereo baseline, metres. With f = 320 px and B = 0.3 m a disparity of
            1 px is 96 m away and the depth error for 0.25 px of disparity error is
            ``Z^2 / (f B) / 4``: 0.1 m at 10 m, 0.4 m at 20 m.
        matcher: stereo matcher name (``skyrecon.stereo.create_matcher``).
        max_disparity: disparity search bound, pixels (nearest depth ``f B / max_disparity``).
        camera_pitch_deg: the camera looks this far below the direction of travel, degrees.
        max_camera_pitch_deg: bound of the camera's pitch down, degrees.
        max_camera_pitch_up_deg: bound of the camera's pitch up, degrees: enough to see a climb's
            path, not so much that the sky fills the view (at 30 degrees up only the lowest few
            degrees of a 74 degree vertical field of view lie below the horizon: the odometry kept
            a handful of features, all along the bottom edge, and drifted).
        max_camera_pitch_rate_deg_s: the gimbal tilts the camera at most this fast, degrees/s
            (an unlimited tilt jumped 36-46 degrees in one frame when a climb began or ended,
            and the odometry lost every feature it tracked).
        depth_stride: the depth image is subsampled by this factor before integration (the
            fast matcher works at half resolution anyway).
    Map:
        voxel_size_m: occupancy voxel edge, metres.
        max_range_m: depth beyond this carves free space up to it only (stereo is unreliable
            farther); the map's range is the rig's trusted range, at most this
            (:func:`skyrecon.mission.perception.hit_range_m`, about 17 m by default).
        far_hit_confirm_m: depth pixels at this range or farther go into the map only where
            the frame before saw a surface at their point too (within a disparity error of
            1 px): a camera's noise on far plain surfaces leaves one-frame specks metres in
            front of them, phantom obstacles where no later ray looks
            (:class:`skyrecon.mapping.far_hits.FarHitFilter`); None: off. Not nearer: from
            5 m, a plain wall's noisy depth at 5-10 m, two frames disagreeing by more than a
            pixel, lost its hits but kept its carving, and noisy plain delivery seed 12 flew
            within 0.55 m of the wall (2.4 m at 10 m).
        map_padding_m: the map covers the city plus this much on every side, metres.
    Planner:
        clearance_m: distance the planner keeps from mapped obstacles, metres (the planner adds
            half a voxel diagonal for the discretisation).
        replan_tolerance_m: hysteresis of replanning: a path planned at ``clearance_m`` is kept
            until the map shows it more than this much inside the clearance (new observations
            nibbling at a path that hugs the clearance do not trigger a replan every cycle).
        keep_out_heuristic_weight: the heuristic weight of a replan around movers' keep-out
            volumes (1: the shortest path, as every other plan). A larger weight finds those
            paths with far fewer expansions (1.2: a thirtieth, 3 ms instead of 13 ms on 2 cores,
            paths within about 1 % of the shortest) but flew worse: in 50 dynamic missions the
            escapes from an approaching drone flipped between up and down from one replan to
            the next, the drone turned on the spot instead of moving away, and it was hit
            (seed 131, 0.30 m). Weight 1.2 on every plan made a held-out seed never take off
            (a plan from the take-off point dipped 1.2 m over ground too plain for stereo to
            show the space below the dip free). So 1 by default.
        evade_movers: a drone inside a mover's predicted sweep steps out of it even when no
            path to the goal starts from its escape point (the path is then the step alone, and
            a path on is sought every cycle), and an escape keeps its point while that stays
            usable, so that escapes do not flip sides between cycles as a mover's prediction
            shifts; when no point within reach clears the sweep (a crane boom's keep-out can be
            7 m in radius), it steps to the reachable point farthest from it (see
            :meth:`~skyrecon.mission.navigator.Navigator.replan`). On by default since session
            31. Without it, seed 115 hovered 10 s in a crane boom's sweep (its escapes found but
            unused, no path on from them) and was hit; without the farthest-point step, seed 103
            hovered inside a 7 m keep-out and was hit (session 29, with the tracker's defaults of
            today). With it and the other defaults of session 31: seeds 100-149 49/50 delivered
            (one safe hover) and the held-out 200-249 50/50, 0 collisions
            (``benchmarks/dynamic/results.json``, ``results_seeds200-249.json``).
        reach_aware_verify: steep climbs the camera cannot verify from where the drone is: a
            tube probe of the path's verification (``verify_radius_m`` beside or below it) that
            lies within ``verify_skip_m + verify_radius_m`` of the drone and out of the camera's
            vertical reach counts as known, as the path samples within ``verify_skip_m`` already
            do (held-out seed 231 with ``evade_movers``: such a probe straight above the drone kept
            its way unverified for 25 s, and the drone hovered); and the back-off along the flown
            track starts for a path point within 12 degrees of the edge of that reach instead of 5
            (seed 248: a point at 45 degrees, 7 degrees inside the 52-degree reach, stayed
            unobserved for 20 s: the top rows of the image do not carve it). On by default since
            session 31 (without it, 48/50 delivered on seeds 200-249: 231 and 248 hovered safely).
        backoff_looks_ahead: a drone backing off along its flown track to see a climb (see
            :class:`~skyrecon.mission.guidance.BackOff`) looks where it flies and holds 2 s at
            the end looking at the climb (any tracked mover ends the hold); off (the default),
            it flies back blind with the camera on the climb. Either way, backing off stops
            when the way back meets a tracked mover's predicted sweep (until session 31 only
            with this on: blind, seed 123 backed into a drone it tracked, in session 26 and
            again in session 31). Flown in session 26 with a changed tracker only (seeds
            100-149): looking where it flew, seed 129 did not see the climb and climbed to it
            three times (before the 2 s hold was added). Off until flown in the dynamic
            missions without a failure.
        min_altitude_m, max_altitude_m: flight band, world z metres. Streets are free above
            10 m (poles, trees and overhead wires stay below), so the band starts at 12 m.
        ground_z_m: the ground's world height, metres: the flight band's reference (a real
            drone's terrain model and altimeter). The stereo stage uses it as a prior plane:
            plain ground whose measured border agrees with it is open air up to the map's range
            well above it (:meth:`skyrecon.perception.StereoDepth.compute`, ``ground``). None:
            no ground prior. (Learning the level from the flight's own depth instead,
            :class:`skyrecon.mapping.ground_level.GroundLevel`, failed in a noisy plain city:
            roofs and walls outweigh the plain streets, and the level jumped to a roof.) The
            generated city's ground is at 0. Checked against the true geometry by
            ``benchmarks/mission/probe_ground_prior.py`` (``results_ground_prior.json``).
    Vehicle:
        cruise_speed_mps: top speed, m/s.
        max_accel_mps2: acceleration and braking limit, m/s^2 (5: a multirotor tilting about 27 degrees).
        max_yaw_rate_deg_s: turn-rate limit, degrees/s.
        max_heading_error_deg: the drone only moves while the camera looks within this angle of
            its direction of travel (it turns on the spot otherwise).
        drone_radius_m: a collision is the true distance to an obstacle below this, metres.
        safety_margin_m: the mission's clearance target: the true distance to every obstacle
            stays above this, metres (reported as ``clearance_ok``).
        cycle_hz: rate of the sense-plan-act loop in simulated time (one stereo frame per cycle).
        latency_budget_s: the loop's latency budget, seconds: the stopping rule reacts one cycle
            plus this late (:mod:`skyrecon.mission.safety`); cycles slower than it are counted.
        loop_threads: threads of the loop's Numba parallel kernels (depth integration, the
            distance field) and of OpenBLAS (its matrix products); 0: as many as they have. 1
            by default: each kernel does a millisecond or two per frame, and a parallel region
            waits for its slowest thread, so on a 2-core machine a descheduled worker stalls it
            by a scheduler slice (see :mod:`skyrecon.threads`). Flown on dynamic seed 102 alone,
            2 threads gave loop p99 102 / 44 ms in two flights of the same path (depth
            integration 50-57 ms on a few cycles, 1.1 ms at the median), 1 thread 35 / 33 ms at
            the same median; two missions at a time, its mover detection took 60-90 ms on 7
            cycles with OpenBLAS threaded, 11-25 ms with one thread. Over the 50 dynamic
            missions (seeds 100-149, two at a time, the same flights), the worst mission's loop
            p99 was 135.2 ms with both threaded (session 31), 111.7 ms with one Numba thread
            and 59.3 ms with one of each (median of the missions' p99 40.2 ms).
        verify_buffer_m: the drone stops this far before the first stretch of its path it has
            not yet observed free, metres.
        verify_radius_m: radius of the tube around the path that must be observed (not unknown).
        verify_skip_m: the first metres of the path ahead count as observed (the drone is there,
            and that close the tube lies outside the camera's field of view).
        arrival_tolerance_m: the mission succeeds within this distance of the goal, metres.
        time_limit_s: simulated time limit; None: ``60 s + 4 x straight distance / cruise speed``.
    Pose (:mod:`skyrecon.mission.pose_source`):
        pose_source: where the drone's pose comes from: "truth" (the simulator's exact pose),
            "odometry" (stereo visual odometry on its own frames) or "gps+odometry".
        degraded_speed_mps: speed cap while the pose estimate is degraded, m/s (the drone
            hovers, without mapping, while it is lost).
        grainy_speed_mps: speed cap while the camera's images are grainy (measured noise above
            1 grey level, :mod:`skyrecon.mission.health`), m/s: stereo sees a crossing drone
            later through the noise (delivery demo seed 0 at 1.5 grey levels and 6 m/s flew
            into one it never tracked; at 3 m/s it delivered, 3.3 m from it).
        delivery_tolerance_m: the drone ends the mission where it BELIEVES it is within
            ``arrival_tolerance_m`` of the goal; the delivery counts when it truly is within
            ``arrival_tolerance_m + delivery_tolerance_m`` (room for the odometry's drift), metres.
    Scenario:
        city_size_m: side of the generated city, metres.
        cruise_altitude_m: altitude of the start and the goal picked from a seed, metres.
        min_goal_distance_m, max_goal_distance_m: straight-line distance range of start to goal.
        endpoint_clearance_m: start and goal picked from a seed keep this far from obstacles.
    A city that moves (:mod:`skyrecon.sim.movers`, :mod:`skyrecon.mission.changes`):
        movers: the simulated city has moving obstacles (other drones, vehicles, a crane boom).
        movers_file: a JSON file describing the movers instead (a list of movers as in
            ``mission.json`` ``scenario.movers``, see :meth:`skyrecon.sim.movers.Mover.to_dict`);
            a mover inside a building or on the drone's start is refused with one clear line.
        plain: a world of plain surfaces: the city of ``generate_city(..., plain=True)``
            (plain facades and glass on a share of the buildings, plain grey streets) and plain
            movers (``make_movers(..., plain=True)``). Not the same city as without (the facade
            draws differ), so neither are its endpoints and movers.
        city_changes: today's city differs from the one the prior map was made of (a new
            scaffold tower on the way, a container stack gone).
        prior_map: "" (start with an empty map), "earlier" (the map an earlier flight over
            yesterday's city left: its true occupancy) or a map directory (``skyrecon map`` /
            ``skyrecon demo`` output); see :mod:`skyrecon.mission.prior`.
        track_movers: separate moving objects from the static map and track them
            (:mod:`skyrecon.perception.movers`); the planner keeps clear of their predicted sweep.
        tracker_settings: overrides of the tracker's :class:`~skyrecon.perception.MoverSettings`,
            ``"name=value,..."`` (e.g. ``"max_push_m=None,side_view_cos=1,reacquire_s=None"``:
            the defaults before session 31; empty: its defaults), for flying tried settings
            (``benchmarks/dynamic/run.py --tracker``).
        mover_fine_depth: also match each pair at full resolution for the tracker
            (:attr:`skyrecon.perception.PerceptionSettings.fine_max_disparity`), which finds
            drones 12-20 m away that the half-resolution matcher loses (recall within 20 m 0.17
            -> 0.32 on 24 dynamic missions). Off by default: it doubled the loop's median
            latency on 2 cores (about 24 -> 55 ms, two missions at a time), and one new scaffold
            tower took 0.8 s to be mapped (its edges passed for movers at first).
        mover_horizon_s: how far ahead a tracked mover's motion is predicted for planning, seconds.
        mover_margin_m: extra radius of a tracked mover's keep-out capsule, metres (stereo places
            a small mover at 10-20 m up to a few metres too far along the viewing ray).
    Faults (:mod:`skyrecon.sim.faults`, :mod:`skyrecon.mission.health`, :mod:`skyrecon.mission.failsafe`):
        camera_noise: steady sensor noise of both cameras, grey levels (standard deviation,
            :func:`skyrecon.sim.sensor_noise.add_sensor_noise`; 0: the renderer's noise-free
            images). A real camera has 1-2; the texture tests measure it on each frame and stand
            above it (:mod:`skyrecon.core.image_noise`). Not a fault: the health check calls an
            image noisy only above its ``max_noise`` (6).
        faults: faults injected into the simulated sensors ("" none; a specification or "random").
        failsafe: what a prolonged loss of trustworthy depth triggers: "return" (back along the
            flown track to take-off), "land" (where it is, over observed free ground) or "hover".
        failsafe_after_s: how long the depth must stay untrustworthy before that, seconds (until
            then the drone holds a hover).
        no_progress_failsafe_s: no progress towards the goal for this long (the goal or every way
            to it stays blocked in the drone's map) triggers the same action, seconds.
    """

    width: int = 640
    height: int = 480
    hfov_deg: float = 90.0
    baseline_m: float = 0.3
    matcher: str = "skyrecon-fast"
    max_disparity: int = 64
    camera_pitch_deg: float = 8.0
    max_camera_pitch_deg: float = 30.0
    max_camera_pitch_up_deg: float = 15.0
    max_camera_pitch_rate_deg_s: float = 90.0
    depth_stride: int = 2
    voxel_size_m: float = 0.5
    max_range_m: float = 20.0
    far_hit_confirm_m: float | None = 10.0
    map_padding_m: float = 25.0
    clearance_m: float = 2.0
    replan_tolerance_m: float = 0.5
    keep_out_heuristic_weight: float = 1.0
    evade_movers: bool = True
    reach_aware_verify: bool = True
    backoff_looks_ahead: bool = False
    min_altitude_m: float = 12.0
    max_altitude_m: float = 30.0
    ground_z_m: float | None = 0.0
    cruise_speed_mps: float = 6.0
    max_accel_mps2: float = 5.0
    max_yaw_rate_deg_s: float = 90.0
    max_heading_error_deg: float = 45.0
    drone_radius_m: float = 0.35
    safety_margin_m: float = 1.0
    cycle_hz: float = 10.0
    latency_budget_s: float = 0.1
    loop_threads: int = 1
    verify_buffer_m: float = 1.5
    verify_radius_m: float = 1.0
    verify_skip_m: float = 1.5
    arrival_tolerance_m: float = 1.0
    time_limit_s: float | None = None
    pose_source: str = "truth"
    degraded_speed_mps: float = 2.0
    grainy_speed_mps: float = 3.0
    delivery_tolerance_m: float = 1.0
    city_size_m: float = 200.0
    cruise_altitude_m: float = 15.0
    min_goal_distance_m: float = 100.0
    max_goal_distance_m: float = 180.0
    endpoint_clearance_m: float = 4.0
    movers: bool = False
    movers_file: str = ""
    plain: bool = False
    city_changes: bool = False
    prior_map: str = ""
    track_movers: bool = True
    tracker_settings: str = ""
    mover_fine_depth: bool = False
    mover_horizon_s: float = 3.0
    mover_margin_m: float = 1.0
    camera_noise: float = 0.0
    faults: str = ""
    failsafe: str = "return"
    failsafe_after_s: float = 3.0
    no_progress_failsafe_s: float = 30.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, float) and not math.isfinite(v):
                raise InputError(f"mission setting {f.name} must be finite, got {v}")
        positive = (
            "width",
            "height",
            "hfov_deg",
            "baseline_m",
            "max_disparity",
            "depth_stride",
            "voxel_size_m",
            "max_range_m",
            "cruise_speed_mps",
            "max_accel_mps2",
            "max_yaw_rate_deg_s",
            "max_camera_pitch_rate_deg_s",
            "drone_radius_m",
            "cycle_hz",
            "arrival_tolerance_m",
            "city_size_m",
            "max_heading_error_deg",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise InputError(f"mission setting {name} must be positive, got {getattr(self, name)}")
        if not 0 <= self.max_camera_pitch_up_deg <= 90 or not 0 <= self.max_camera_pitch_deg <= 90:
            raise InputError("the camera's pitch bounds must lie in [0, 90] degrees")
        if not self.hfov_deg < 170:
            raise InputError(f"hfov_deg must be below 170 degrees, got {self.hfov_deg}")
        if self.width < 64 or self.height < 48:
            raise InputError(f"images must be at least 64x48 pixels, got {self.width}x{self.height}")
        if self.clearance_m < self.drone_radius_m:
            raise InputError(
                f"clearance_m ({self.clearance_m}) must be at least the drone radius ({self.drone_radius_m})"
            )
        if not 0 <= self.replan_tolerance_m < self.clearance_m:
            raise InputError(
                f"replan_tolerance_m must lie in [0, clearance_m), got {self.replan_tolerance_m}"
            )
        if not self.min_altitude_m < self.max_altitude_m:
            raise InputError(
                f"need min_altitude_m < max_altitude_m, got {self.min_altitude_m}, {self.max_altitude_m}"
            )
        if not 0 < self.min_goal_distance_m <= self.max_goal_distance_m:
            raise InputError("need 0 < min_goal_distance_m <= max_goal_distance_m")
        self._check_timing()
        if self.pose_source not in ("odometry", "truth", "gps+odometry"):
            raise InputError(f"pose_source must be odometry, truth or gps+odometry, got {self.pose_source!r}")
        if not (
            self.degraded_speed_mps >= 0 and self.grainy_speed_mps >= 0 and self.delivery_tolerance_m >= 0
        ):
            raise InputError(
                "degraded_speed_mps, grainy_speed_mps and delivery_tolerance_m must be at least 0"
            )
        if not 0 <= self.camera_noise <= 64:
            raise InputError(f"camera_noise must lie in [0, 64] grey levels, got {self.camera_noise}")
        if self.failsafe not in ("return", "land", "hover"):
            raise InputError(f"failsafe must be return, land or hover, got {self.failsafe!r}")
        if not self.failsafe_after_s > 0:
            raise InputError(f"failsafe_after_s must be positive, got {self.failsafe_after_s}")
        if not self.no_progress_failsafe_s > 0:
            raise InputError(f"no_progress_failsafe_s must be positive, got {self.no_progress_failsafe_s}")
        if not (self.mover_horizon_s > 0 and self.keep_out_heuristic_weight >= 1.0):
            raise InputError(
                "mover_horizon_s must be positive and keep_out_heuristic_weight at least 1, got "
                f"{self.mover_horizon_s} and {self.keep_out_heuristic_weight}"
            )
        self._check_tracker_settings()
        self._check_optional()

    def _check_optional(self) -> None:
        """Refuse an optional setting (None: off) that is set but not positive."""
        for name in ("time_limit_s", "far_hit_confirm_m"):
            if getattr(self, name) is not None and not getattr(self, name) > 0:
                raise InputError(f"{name} must be positive or None, got {getattr(self, name)}")

    def _check_timing(self) -> None:
        """Refuse a negative latency budget and a loop thread count that is not a count."""
        if not self.latency_budget_s >= 0:
            raise InputError(f"latency_budget_s must be at least 0, got {self.latency_budget_s}")
        if (
            isinstance(self.loop_threads, bool)
            or not isinstance(self.loop_threads, int)
            or self.loop_threads < 0
        ):
            raise InputError(f"loop_threads must be a whole number >= 0, got {self.loop_threads!r}")

    def _check_tracker_settings(self) -> None:
        """Refuse ``tracker_settings`` with unknown names or values MoverSettings refuses."""
        if self.tracker_settings:
            from skyrecon.perception.movers import MoverSettings, parse_mover_overrides

            MoverSettings(**parse_mover_overrides(self.tracker_settings))

    @property
    def dt(self) -> float:
        """Simulated seconds per cycle."""
        return 1.0 / self.cycle_hz

    @property
    def focal_px(self) -> float:
        """Focal length of the cameras, pixels."""
        return 0.5 * self.width / math.tan(math.radians(self.hfov_deg) / 2)

    @property
    def min_depth_m(self) -> float:
        """Nearest depth the disparity search covers, metres."""
        return self.focal_px * self.baseline_m / self.max_disparity

    @property
    def planning_margin_m(self) -> float:
        """What the planner adds to the clearance for the voxel discretisation, metres."""
        return 0.5 * math.sqrt(3.0) * self.voxel_size_m

    @property
    def reaction_s(self) -> float:
        """Seconds from an observation to the vehicle acting on it: one cycle plus the latency budget."""
        return self.dt + self.latency_budget_s

    @property
    def stopping_distance_m(self) -> float:
        """Distance to stop from cruise speed (reaction, then braking), metres."""
        v = self.cruise_speed_mps
        return v * self.reaction_s + v**2 / (2 * self.max_accel_mps2)

    @property
    def verify_horizon_m(self) -> float:
        """How far ahead the path must be observed free for full speed: braking distance from
        cruise speed, the buffer, and 2 m, metres."""
        return self.stopping_distance_m + self.verify_buffer_m + 2.0

    def time_limit_for(self, straight_m: float) -> float:
        """Simulated time limit of a mission whose start and goal are ``straight_m`` apart, seconds."""
        if self.time_limit_s is not None:
            return float(self.time_limit_s)
        return 60.0 + 4.0 * straight_m / self.cruise_speed_mps

    def with_overrides(self, **changes) -> MissionConfig:
        """A copy with some fields changed (None values are ignored)."""
        return replace(self, **{k: v for k, v in changes.items() if v is not None})

    def with_baseline(self, baseline_m: float, keep_range: bool = False) -> MissionConfig:
        """The same drone with a stereo rig of another baseline, metres.

        Depth error grows as ``Z^2 e / (f B)`` for a disparity error ``e``, so the range with the
        same depth error at its end grows as ``sqrt(B)``: ``max_range_m`` is scaled by
        ``sqrt(baseline_m / self.baseline_m)`` (unless ``keep_range``), and ``max_disparity`` by
        the baseline ratio (rounded up to a multiple of 16), so the nearest depth searched stays
        the same. With the rig supported speed (:func:`skyrecon.mission.safety.rig_supported_speed`)
        (which uses the map's range: within ``max_range_m``, where a quarter pixel of disparity error
        moves depth by at most 1.5 m) this says what a longer baseline buys: 0.3 m maps to 17.0 m
        (11.5 m/s at 5 m/s^2), 0.6 m to 24.0 m (14.0 m/s).
        """
        if not baseline_m > 0:
            raise InputError(f"the stereo baseline must be positive, got {baseline_m} m")
        ratio = baseline_m / self.baseline_m
        max_disparity = int(16 * math.ceil(self.max_disparity * ratio / 16))
        max_range = self.max_range_m if keep_range else self.max_range_m * math.sqrt(ratio)
        return replace(self, baseline_m=float(baseline_m), max_disparity=max_disparity, max_range_m=max_range)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> MissionConfig:
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known})


#: The quick missions of the benchmarks' ``--small``: 320x240 images, a 100 m city, 50-90 m deliveries.
SMALL_BENCHMARK = dict(
    width=320,
    height=240,
    max_disparity=32,
    city_size_m=100.0,
    min_goal_distance_m=50.0,
    max_goal_distance_m=90.0,
)


def small_test_config(**changes) -> MissionConfig:
    """A quick mission for tests and smoke runs: 320x240 images, an 80 m city, 30..50 m deliveries."""
    base = MissionConfig(
        width=320,
        height=240,
        max_disparity=32,
        city_size_m=80.0,
        min_goal_distance_m=30.0,
        max_goal_distance_m=50.0,
        map_padding_m=20.0,
    )
    return base.with_overrides(**changes)
