"""Where the drone believes it is: the pose source of the delivery loop.

A real drone in a street canyon does not know its exact pose; it estimates it from its cameras
(visual odometry), optionally anchored by a GPS with urban-canyon errors. The loop flies on that
belief: the map is built, the path planned and the vehicle steered in the drone's *estimated*
world, while the simulator renders and judges collisions at the TRUE pose.

The two worlds differ by ``est_from_true`` (a rigid transform, frames ``("est", "world")``): the
estimated camera pose is ``est_world_from_left = est_from_true @ true_world_from_left``. Each cycle
the loop reads a pose (:meth:`PoseSource.read`), turns the true state into the believed one
(:func:`believed_state`), plans and steps the vehicle in the believed world, and carries the step
back to the true world (:func:`true_step`): the displacement, velocity and turn the controller
commanded happen physically, wherever the drone really is.

Sources (``MissionConfig.pose_source``, ``skyrecon demo --pose-source``):

* ``truth``: the simulator's exact pose (what the first wave flew on);
* ``odometry``: :class:`skyrecon.odometry.StereoOdometry` on the loop's stereo frames, reusing the
  loop's dense disparity for the features' depth; the first pose is the true start (the drone
  knows where it takes off); its position is checked against the flight controller's
  accelerometer (:mod:`skyrecon.mission.inertial`): a slip is reported, degraded;
* ``gps+odometry``: the odometry anchored by a simulated urban-canyon GPS
  (:mod:`skyrecon.odometry.gps`).

Every reading carries a :class:`~skyrecon.odometry.TrackingState`; the loop slows down when the
pose is degraded and hovers (without mapping) while it is lost.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from skyrecon.core import Rigid3, StereoRig
from skyrecon.io.gps import GpsFix
from skyrecon.mission.inertial import InertialCheck, InertialCheckSettings
from skyrecon.mission.vehicle import DroneState, wrap_angle
from skyrecon.odometry.engine import OdometrySettings, StereoOdometry
from skyrecon.odometry.gps import GpsFusion, GpsFusionSettings
from skyrecon.odometry.types import TrackingState
from skyrecon.sim.accelerometer import SimulatedAccelerometer
from skyrecon.sim.gps import UrbanCanyonGps
from skyrecon.sim.gyro import SimulatedGyro

POSE_SOURCES = ("odometry", "truth", "gps+odometry")


@dataclass
class PoseReading:
    """What a pose source says about one frame.

    Attributes:
        world_from_left: estimated pose of the left camera, frames ``("world", "left")``, metres
            (the estimated world).
        state: how far it can be trusted (:class:`~skyrecon.odometry.TrackingState`).
        reason: why it is not ``ok`` ("" when it is).
        ms: wall-clock milliseconds the estimate took.
    """

    world_from_left: Rigid3
    state: TrackingState
    reason: str = ""
    ms: float = 0.0


class PoseSource(Protocol):
    """A pose source of the loop (see the module docstring)."""

    name: str

    def read(
        self,
        left: np.ndarray,
        right: np.ndarray,
        time_s: float,
        disparity_px: np.ndarray | None,
        true_world_from_left: Rigid3,
    ) -> PoseReading:
        """The pose of this frame.

        Args:
            left, right: (H, W, 3) uint8 RGB rectified stereo frame.
            time_s: simulated time of the frame, seconds.
            disparity_px: (H, W) float32 left disparity the loop computed, pixels, NaN invalid.
            true_world_from_left: the exact pose: used by ``truth`` and by the simulated GPS
                only, never by the odometry.
        """
        ...


class TruthPose:
    """The simulator's exact pose."""

    name = "truth"

    def read(self, left, right, time_s, disparity_px, true_world_from_left) -> PoseReading:
        return PoseReading(true_world_from_left.with_frames("world", "left"), TrackingState.OK)


class OdometryPose:
    """Stereo visual odometry on the loop's frames.

    The loop's dense disparity (a fast matcher at half resolution, pixel-locked) only seeds the
    odometry's sub-pixel sparse stereo at each feature (``refine_disparity``): used as depth
    directly its bias is a scale error. The frozen-frame check is off: the noise-free simulator
    repeats identical frames while the drone hovers.

    The camera's rotation between frames comes from the flight controller's gyro (and the
    gimbal's angles), simulated with a consumer MEMS gyro's errors (:mod:`skyrecon.sim.gyro`): it is
    the odometry's rotation prior, so a quick turn or a tilt of the gimbal does not lose the tracks,
    and a track restarted after a loss keeps the right heading. The position comes from the
    cameras alone. Without the gyro (``gyro=False``) a restart after a turn in the dark carried
    the extrapolated rotation, tens of degrees off, into the rest of the flight.

    The odometry is checked against the flight controller's accelerometer
    (:class:`~skyrecon.mission.inertial.InertialCheck`, simulated with a consumer MEMS
    accelerometer's errors: :mod:`skyrecon.sim.accelerometer`): when its change of velocity over a
    second disagrees with the accelerometer's, the pose is reported degraded (the loop slows
    down) until they agree again for a second. The pose itself is always the odometry's.

    Args:
        rig: the loop's rectified rig.
        init_world_from_left: the pose at take-off (the first frame), frames ``("world", "left")``.
        settings: odometry settings (None: :meth:`loop_settings`).
        seed: seeds the simulated gyro and accelerometer.
        gyro: feed the gyro's rotation to the odometry.
        inertial: check the odometry against the accelerometer.
        inertial_settings: how (None: :class:`~skyrecon.mission.inertial.InertialCheckSettings`).
    """

    name = "odometry"

    def __init__(
        self,
        rig: StereoRig,
        init_world_from_left: Rigid3,
        settings=None,
        max_accel_mps2: float = 5.0,
        seed: int = 0,
        gyro: bool = True,
        inertial: bool = True,
        inertial_settings: InertialCheckSettings | None = None,
    ) -> None:
        self.odometry = StereoOdometry(
            rig, settings or self.loop_settings(max_accel_mps2), init_world_from_left
        )
        self.gyro = SimulatedGyro(seed=seed) if gyro else None
        self.accelerometer = SimulatedAccelerometer(seed=seed) if inertial else None
        self.inertial = InertialCheck(inertial_settings) if inertial else None

    @staticmethod
    def loop_settings(max_accel_mps2: float = 5.0) -> OdometrySettings:
        """The odometry settings the delivery loop flies on. The vehicle's acceleration limit bounds
        how far a pose may leave the motion prediction (twice the limit: the prediction is itself
        estimated), so a wrong consensus (a turn read as a slide) is refitted or refused, never flown.
        Loop closure is off: its pose-graph solves would add latency spikes to the control loop, and
        a delivery rarely comes back to where it has been. 300 features on an 8x6 grid (the
        standalone default is 1000 on 12x9, which lowers the drift of long flights by a fifth): the
        loop's cycle is judged by its p99, and its missions are short and re-planned every cycle."""
        return OdometrySettings(
            max_features=300,
            grid=(8, 6),
            detect_frozen=False,
            refine_disparity=True,
            max_acceleration_mps2=2.0 * max_accel_mps2,
            loop_closure=False,
        )

    def read(self, left, right, time_s, disparity_px, true_world_from_left) -> PoseReading:
        turn = None if self.gyro is None else self.gyro.measure(time_s, true_world_from_left)
        dv = (
            None
            if self.accelerometer is None
            else self.accelerometer.velocity_change(time_s, true_world_from_left)
        )
        t0 = time.perf_counter()
        est = self.odometry.track(left, right, time_s, disparity_px, turn)
        pose, state, reason = est.world_from_left.with_frames("world", "left"), est.state, est.reason
        if self.inertial is not None:
            if dv is not None:  # into the odometry's world, as the flight controller's attitude has it
                dv = (pose.R @ np.asarray(true_world_from_left.R).T) @ dv
            verdict = self.inertial.update(time_s, pose.t, dv)
            if verdict.slipping and state == TrackingState.OK:
                state, reason = TrackingState.DEGRADED, verdict.reason
        ms = 1e3 * (time.perf_counter() - t0)
        return PoseReading(pose, state, reason, ms)


class GpsOdometryPose:
    """The odometry anchored by a GPS with urban-canyon errors (:mod:`skyrecon.sim.gps`):
    :class:`skyrecon.odometry.gps.GpsFusion` leans the odometry's world onto the fixes, gated and
    rate limited, so a multipath jump cannot throw the drone through a wall.

    Args:
        rig: the loop's rectified rig.
        init_world_from_left: the pose at take-off, frames ``("world", "left")``.
        city: the simulated city (its buildings block the sky: noise, dropouts and jumps).
        seed: seeds the simulated receiver.
    """

    name = "gps+odometry"

    def __init__(
        self, rig: StereoRig, init_world_from_left: Rigid3, city, seed: int = 0, max_accel_mps2: float = 5.0
    ) -> None:
        self.odometry = OdometryPose(rig, init_world_from_left, max_accel_mps2=max_accel_mps2, seed=seed)
        # the odometry starts from the true take-off pose: its world is already level and oriented
        # the drone's attitude is known (it took off level, oriented; an IMU and compass keep it):
        # GPS corrects the position only (fitting a rotation to a few metres of noisy fixes added
        # metres of error on short flights)
        # and the odometry drifts well under 1 % of the distance: GPS fixes, metres off in a street
        # canyon, only lean on it as far as that drift allows (a Kalman offset, see GpsFusion)
        self.fusion = GpsFusion(
            # the receiver's bias wanders over tens of seconds: fixes within 30 s are not independent
            GpsFusionSettings(odometry_drift_fraction=0.01, fix_correlation_s=30.0),
            rotation_known=True,
            estimate_rotation=False,
        )
        self.receiver = UrbanCanyonGps(city, seed)
        self._next_fix_s = 0.0
        #: optional ``fix_offset(t) -> (3,)`` metres added to the fix taken at ``t`` (fault injection)
        self.fix_offset: Callable[[float], np.ndarray] | None = None
        #: the last :meth:`read` refused a GPS fix (gated out by the fusion)
        self.rejected_fix = False

    def read(self, left, right, time_s, disparity_px, true_world_from_left) -> PoseReading:
        r = self.odometry.read(left, right, time_s, disparity_px, true_world_from_left)
        t0 = time.perf_counter()
        fixes = []
        while self._next_fix_s <= time_s + 1e-9:  # the receiver's own rate
            fix = self.receiver.fix(self._next_fix_s, true_world_from_left.t)
            if fix is not None:
                if self.fix_offset is not None:
                    fix = GpsFix(fix.time_s, fix.position + self.fix_offset(fix.time_s), fix.accuracy_m)
                fixes.append(fix)
            self._next_fix_s += 1.0 / self.receiver.settings.rate_hz
        n_before = len(self.fusion.updates)
        fused = self.fusion.update(  # degraded still tracks (fewer inliers), lost does not
            time_s, r.world_from_left.with_frames("odom", "left"), fixes, r.state != TrackingState.LOST
        )
        self.rejected_fix = any(not u.accepted for u in self.fusion.updates[n_before:])
        ms = r.ms + 1e3 * (time.perf_counter() - t0)
        return PoseReading(fused.with_frames("world", "left"), r.state, r.reason, ms)


def yaw_of(R: np.ndarray) -> float:
    """The heading part of a rotation of the z-up world (radians from +x towards +y)."""
    return math.atan2(float(R[1, 0]), float(R[0, 0]))


def est_from_true(est_world_from_left: Rigid3, true_world_from_left: Rigid3) -> Rigid3:
    """The transform from the true world to the estimated one, frames ``("est", "world")``."""
    return (
        est_world_from_left.with_frames("est", "left")
        @ true_world_from_left.with_frames("world", "left").inverse()
    ).with_frames("est", "world")


def believed_state(true_state: DroneState, est_from_world: Rigid3) -> DroneState:
    """The drone's state as it believes it to be: the true state seen in the estimated world.

    Args:
        true_state: the simulator's state (world frame).
        est_from_world: :func:`est_from_true` of the current frame.
    """
    R = est_from_world.R
    return DroneState(
        est_from_world.apply(true_state.position[None])[0],
        R @ true_state.velocity,
        wrap_angle(true_state.yaw + yaw_of(R)),
        true_state.pitch_down,
        true_state.time_s,
    )


def true_step(
    true_state: DroneState, believed: DroneState, believed_next: DroneState, est_from_world: Rigid3
) -> DroneState:
    """Carry a step the controller made in the believed world back to the true world.

    The commanded displacement and velocity (rotated from the estimated into the true world),
    the turn and the camera pitch happen physically from the true state.
    """
    Rt = est_from_world.R.T
    return replace(
        true_state,
        position=true_state.position + Rt @ (believed_next.position - believed.position),
        velocity=Rt @ believed_next.velocity,
        yaw=wrap_angle(true_state.yaw + wrap_angle(believed_next.yaw - believed.yaw)),
        pitch_down=believed_next.pitch_down,
        time_s=believed_next.time_s,
    )


def make_pose_source(
    name: str,
    rig: StereoRig,
    init_world_from_left: Rigid3,
    seed: int = 0,
    city=None,
    max_accel_mps2: float = 5.0,
) -> PoseSource:
    """The pose source called ``name`` (one of :data:`POSE_SOURCES`); ``city`` (the simulated
    one) is needed by ``gps+odometry``; ``max_accel_mps2`` is the vehicle's acceleration limit."""
    if name == "truth":
        return TruthPose()
    if name == "odometry":
        return OdometryPose(rig, init_world_from_left, max_accel_mps2=max_accel_mps2, seed=seed)
    if name == "gps+odometry":
        if city is None:
            raise ValueError("the gps+odometry pose source needs the simulated city")
        return GpsOdometryPose(rig, init_world_from_left, city, seed, max_accel_mps2=max_accel_mps2)
    raise ValueError(f"unknown pose source {name!r}; expected one of {', '.join(POSE_SOURCES)}")
