"""Stereo visual odometry: the pose of a rectified stereo camera, frame by frame.

    vo = StereoOdometry(rig)                                   # rectified skyrecon.core.StereoRig
    for left, right, t in frames:
        est = vo.track(left, right, t)                         # FrameEstimate (pose, state, reason)
    poses = vo.trajectory()                                    # refined world_from_left of every frame

Pipeline per frame: KLT tracking (forward-backward checked) of the previous frame's features,
predicted by a constant-velocity motion prior; 3D-2D matches of the tracked features that carry a
map point; PnP in RANSAC (:func:`skyrecon.sfm.pnp.estimate_absolute_pose`, AP3P + robust
refinement); plausibility against the elapsed time. A frame whose pose fails or has few inliers
(a sudden pitch or yaw the prior missed) is tracked again with two more pyramid levels and a
wider window, then seeded by the rotation read off the image's dominant shift (phase
correlation); a re-initialisation after lost frames measures the rotation since the last
trusted image the same way (fresh corners, pure-rotation RANSAC) rather than chaining the
prior through the jerk. Then the keyframe decision. On a keyframe: new corners
fill the empty grid cells, sparse stereo (seeded by the given dense disparity, if any, or that
disparity as it is with ``refine_disparity=False``) turns features into map points, and a sliding-window bundle adjustment (:mod:`skyrecon.odometry.window`) refines the last
keyframes and their points. Non-keyframe poses are kept relative to their reference keyframe, so
the window's refinements reach them in :meth:`StereoOdometry.trajectory`.

Loop closure (``loop_closure``, on by default; :mod:`skyrecon.odometry.loops`): each keyframe is
described (thumbnail, ORB descriptors at its corners with their stereo points) and searched among
the old keyframes near the current estimate; a loop that passes the two-way PnP check, the drift
gate and a confirmation by the next keyframe goes into an SE(3) pose graph over the keyframes
(:mod:`skyrecon.odometry.pose_graph`). The corrected keyframes carry their frames with them, and the
map points in use and the motion prior move with the newest keyframe, so tracking continues from
the corrected pose. :meth:`StereoOdometry.loop_report` says what was found, applied and rejected.

Frames: ``world`` is the left camera of the first frame unless ``init_world_from_left`` says
otherwise; ``left`` is the current left camera (OpenCV axes). Metres, seconds, pixels.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skyrecon.core import StereoRig
from skyrecon.core.image_noise import corner_noise_quantile, excess_noise_sigma, image_noise_sigma
from skyrecon.core.rigid import Rigid3, matrix_to_rotvec, rotation_angle, rotvec_to_matrix
from skyrecon.errors import EstimationError, InputError
from skyrecon.odometry.checks import blank_reason, check_pair, is_frozen, to_grey
from skyrecon.odometry.frontend import (
    Pyramid,
    build_pyramid,
    detect_corners,
    disparity_lookup,
    global_shift,
    grid_coverage,
    refine_to_anchor,
    stereo_match,
    track_points,
)
from skyrecon.odometry.loops import LoopCloser
from skyrecon.odometry.pnp import fast_absolute_pose
from skyrecon.odometry.types import FrameEstimate, TrackingState
from skyrecon.odometry.window import window_bundle_adjust
from skyrecon.sfm.pnp import (
    AbsolutePose,
    estimate_absolute_pose,
    refine_absolute_pose,
    reprojection_errors_px,
)

__all__ = ["OdometrySettings", "StereoOdometry"]


@dataclass(frozen=True)
class OdometrySettings:
    """How the odometry runs.

    Attributes:
        max_features: features kept per frame (corners are topped up on keyframes). More
            features, spread finer, average the tracks' sub-pixel errors (the drift is mostly a
            slow heading error): on the six flights of ``benchmarks/odometry`` (no loop closure)
            the worst drift is 0.350 % (mean 0.305) with 300 on an 8x6 grid, 0.309 with 500,
            0.298 with 700, 0.280 with 1000, 0.291 (mean 0.244) with 700 on 10x8. With
            ``track_threshold_px`` on thirteen flights (seven routes, four circuits, two routes in
            cities with 60 % plain facades): worst 0.311 % (a plain city; mean 0.23) with 700 on
            10x8, worst 0.282 % (mean 0.22; plain 0.258, 0.259) with 1000 on 12x9.
        grid: (columns, rows) of the detection grid that keeps features spread.
        min_corner_distance_px: minimum distance between corners, pixels.
        corner_noise_factor: a new corner must be at least this many times as strong as the
            strongest corners pure noise makes (1 in 1000,
            :func:`skyrecon.core.image_noise.corner_noise_quantile`, times the image's measured
            noise variance beyond what a noise-free image reads); the noise is measured on the
            image at each detection (about 1 ms, keyframes only). Each grid cell keeps its best
            corners relative to its own strongest, so on a noisy camera a plain cell (sky, a
            plain wall) filled up with noise "corners" whose tracks follow the noise: in the
            delivery demo at 1.5 grey levels, a turn with the camera raised to the sky moved the
            odometry's position 9 m off in 2 s while it said "ok" (it missed its goal by 14 m).
            A 640x480 view of plain sky at 1.5 grey levels keeps 1080 corners with no floor,
            138 at a factor of 1 (the rarest noise peaks are stronger than the 1-in-1000
            quantile) and none at 1.5. Flown at 1.5 grey levels with the odometry pose: the
            demo delivered (drift 0.76 m at factor 1, 0.90 m at 1.5); delivery seeds 6 and 7
            slipped 0.2-1.1 m in 0.3 s at factor 1 (drift at the goal 0.90, 2.35 m) and 0.45,
            0.80 m at 1.5; at 2, corners grew scarce (seed 6: 106 cycles with too few inliers).
            200 m routes of ``benchmarks/odometry`` (seeds 1-3): worst drift 0.40 % with no
            floor, 0.30 at 1, 0.32 at 2. No effect on noise-free images; 0 turns it off.
        klt_window_px: KLT window side, pixels.
        klt_levels: KLT pyramid levels above the base (one more after a dropped frame).
        fb_threshold_px: forward-backward tracking check, pixels.
        retry_levels: a frame whose pose fails or has fewer than ``good_inliers`` inliers is
            tracked again with this many more pyramid levels and a wider window (a sudden pitch
            or yaw that the constant-velocity prior missed); 0 turns the retry off.
        anchor_tracks: re-align every tracked feature on its patch in the last keyframe (one
            finest-level KLT from the keyframe image, started at the frame-to-frame result), so
            the sub-pixel errors of chained frame-to-frame tracking do not add up between
            keyframes (:func:`skyrecon.odometry.frontend.refine_to_anchor`). Off by default:
            measured against the true projections it does not shrink the track error (what
            grows over 5-10 frames is not chaining noise), and on the loop's flights it made the
            drift slightly worse (0.24 -> 0.28 %, 0.17 -> 0.22 %).
        anchor_max_move_px: ... a re-alignment moving a feature farther than this is refused.
        refine_disparity: with a given dense disparity, use it only as the starting guess of the
            sub-pixel sparse stereo at each feature (the dense map of a fast matcher is
            pixel-locked; its bias is a scale error), falling back to the dense value nowhere.
        min_disparity_px: a feature becomes a map point only with at least this disparity
            (sets the farthest usable depth, ``fx * baseline / min_disparity_px``).
        stereo_row_tolerance_px: sparse stereo: the right match must stay within this many
            pixels of the left feature's row.
        ransac_threshold_px: PnP RANSAC and inlier threshold on the reprojection error, pixels.
        track_threshold_px: a tracked feature whose map point reprojects farther than this from it
            after the pose is dropped (None: only PnP outliers are), when at least ``good_inliers``
            stay. About a fifth of the KLT tracks err by more than 0.5 px after one frame (corners
            on occlusion boundaries and aliased silhouettes, measured against the true projections
            on a synthetic flight); left in, they bias the next poses. On ten synthetic 500-560 m
            flights (no loop closure, 700 features on 10x8) the drift is worst 0.265 % (mean
            0.225) with 1 px, 0.344 (mean 0.256) without; tightening the RANSAC threshold itself
            to 1 px instead lost accuracy after sudden jerks at 320x240.
        ransac_iterations: PnP RANSAC iteration cap.
        pnp_refinement: ``"robust"`` (Cauchy refinement through the bundle adjuster,
            :func:`skyrecon.sfm.pnp.estimate_absolute_pose`) or ``"lm"`` (OpenCV's
            Levenberg-Marquardt on the RANSAC inliers, :func:`skyrecon.odometry.pnp.fast_absolute_pose`:
            about 2 ms less a frame, but a third more error per frame).
        min_inliers: fewer PnP inliers lose the frame.
        good_inliers: fewer inliers (but at least ``min_inliers``) degrade the frame.
        min_inlier_coverage: inliers covering less than this fraction of a 4x4 image grid
            degrade the frame (poor spread makes the pose ill-conditioned).
        min_stereo_points: a (re)initialisation needs at least this many features with depth.
        keyframe_tracked_ratio: a new keyframe when fewer than this fraction of the reference
            keyframe's map points are still tracked.
        keyframe_max_distance_m: ... or when the camera moved this far from it, metres.
        keyframe_max_rotation_deg: ... or turned this much, degrees.
        keyframe_max_frames: ... or after this many frames.
        window_keyframes: keyframes in the sliding-window bundle adjustment (0, the default,
            turns it off). Off by default because on the synthetic flights it lowers the
            per-frame error but biases the scale by 0.5-1 % (the KLT tracks it adjusts drift
            radially by a few tenths of a pixel over 5-10 frames, which a monocular window
            reads as motion), tripling the drift; see :mod:`skyrecon.odometry.window`.
            Re-measured on the delivery loop's flights with the retry and the refined disparity:
            0.33 % against 0.24-0.28 % without it at 640x480, no consistent gain at 320x240.
        window_fixed_keyframes: oldest window keyframes held fixed (gauge and scale). When it is
            at least ``window_keyframes`` every keyframe is held and only the points are refined,
            from the left and right observations of every keyframe (a stereo-consistent
            multi-view triangulation; measured: a third less error per frame, but the same
            tracking bias shows as drift, 0.39-0.42 % against 0.24-0.27 % with the window off).
        window_iterations: Levenberg-Marquardt iterations of the window adjustment.
        max_speed_mps: a pose implying a faster motion since the last trusted one is rejected.
        max_rotation_rate_dps: ... or a faster rotation, degrees per second.
        gap_factor: a timestamp step larger than this many times the usual frame interval is a
            dropped frame: the search is widened and the frame flagged.
        detect_frozen: a frame byte-identical to the previous one is lost ("frozen"): a stuck
            camera or driver on real hardware. In a noise-free simulator a perfectly still drone
            also repeats its frames; turn this off there if it hovers.
        seed: seeds the RANSAC (frame ``i`` uses ``seed + i``).
        max_acceleration_mps2: when set (a vehicle whose acceleration is known: the delivery loop sets
            it), a pose farther than ``prediction_tolerance_m + a dt^2 / 2`` from the constant-velocity
            prediction is not trusted: it is refitted from the prediction on the tracks that agree
            with it, or the frame fails ("rejected a pose ... from the motion prediction").
        prediction_tolerance_m: the part of that bound that does not grow with time, metres.
        refresh_points: at each keyframe a map point measured again by stereo becomes the
            inverse-variance mean of its measurements (weights disparity^4), instead of keeping
            the depth of its first, usually farthest and least precise, measurement.
        loop_closure: place recognition on keyframes, a geometric check and a pose-graph
            optimisation (:mod:`skyrecon.odometry.loops`): when the flight comes back to a place it
            saw, the keyframe poses are corrected and tracking continues from the corrected pose.
            A loop that fails any check is dropped (and reported in :meth:`StereoOdometry.loop_report`),
            never applied.
        loop_min_inliers: a loop needs at least this many PnP inliers, both ways (and as many
            descriptor matches to be tried).
        loop_min_path_m: candidates are at least this many metres of flight back.
        loop_gate_m, loop_gate_fraction: candidates lie within ``loop_gate_m + loop_gate_fraction *
            path`` of the current estimate, and the correction a loop implies must be as small
            (``path``: metres flown since the candidate; the drift is a fraction of a percent).
        loop_confirmations: a loop is applied once this many keyframes in a row (the current one
            included) found loops implying the same correction (1: no confirmation).
    """

    max_features: int = 1000
    grid: tuple[int, int] = (12, 9)
    min_corner_distance_px: float = 8.0
    corner_noise_factor: float = 1.5
    klt_window_px: int = 15
    klt_levels: int = 3
    retry_levels: int = 2
    anchor_tracks: bool = False
    anchor_max_move_px: float = 1.5
    refine_disparity: bool = True
    fb_threshold_px: float = 0.7
    min_disparity_px: float = 0.5
    refresh_points: bool = True
    stereo_row_tolerance_px: float = 0.7
    ransac_threshold_px: float = 2.0
    track_threshold_px: float | None = 1.0
    ransac_iterations: int = 300
    pnp_refinement: str = "robust"
    min_inliers: int = 20
    good_inliers: int = 50
    min_inlier_coverage: float = 0.25
    min_stereo_points: int = 30
    keyframe_tracked_ratio: float = 0.6
    keyframe_max_distance_m: float = 2.0
    keyframe_max_rotation_deg: float = 10.0
    keyframe_max_frames: int = 10
    window_keyframes: int = 0
    window_fixed_keyframes: int = 2
    window_iterations: int = 8
    max_speed_mps: float = 40.0
    max_rotation_rate_dps: float = 360.0
    max_acceleration_mps2: float | None = None
    prediction_tolerance_m: float = 0.3
    gap_factor: float = 1.8
    detect_frozen: bool = True
    seed: int = 0
    loop_closure: bool = True
    loop_min_inliers: int = 40
    loop_min_path_m: float = 40.0
    loop_gate_m: float = 3.0
    loop_gate_fraction: float = 0.03
    loop_confirmations: int = 2

    def __post_init__(self) -> None:
        if self.max_features < 10:
            raise InputError(f"max_features must be at least 10, got {self.max_features}")
        if self.min_inliers < 4:
            raise InputError(f"min_inliers must be at least 4, got {self.min_inliers}")
        if not self.ransac_threshold_px > 0:
            raise InputError(f"ransac_threshold_px must be positive, got {self.ransac_threshold_px}")
        if self.track_threshold_px is not None and not self.track_threshold_px > 0:
            raise InputError(f"track_threshold_px must be positive or None, got {self.track_threshold_px}")
        if self.window_keyframes and self.window_fixed_keyframes < 1:
            raise InputError("window_fixed_keyframes must be at least 1 (the gauge)")
        if self.klt_window_px < 5 or self.klt_levels < 0:
            raise InputError("klt_window_px must be at least 5 and klt_levels non-negative")
        if self.pnp_refinement not in ("lm", "robust"):
            raise InputError(f"pnp_refinement must be 'lm' or 'robust', got {self.pnp_refinement!r}")
        if self.loop_min_inliers < 8 or self.loop_confirmations < 1:
            raise InputError("loop_min_inliers must be at least 8 and loop_confirmations at least 1")


@dataclass
class _Keyframe:
    """A keyframe: its pose and what it observed (left pixels of map points, right pixels)."""

    frame: int
    world_from_left: np.ndarray  # (4, 4)
    n_points: int
    obs_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    obs_uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    right_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    right_uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    reinit: bool = False  # started a new track (its pose chained by the motion prior)
    path_m: float = 0.0  # distance flown from the first keyframe, metres (estimate at creation)


@dataclass
class _Attempt:
    """One tracking and pose attempt on a frame."""

    pyr: Pyramid
    pts: np.ndarray
    ok: np.ndarray
    use: np.ndarray
    pose: Any
    T: np.ndarray | None
    failure: str
    n_inliers: int


@dataclass
class _FrameRecord:
    keyframe: int  # index into the keyframe list (-1: before any keyframe)
    kf_from_frame: np.ndarray  # (4, 4) left_kf_from_left_frame (or world_from_left when keyframe == -1)


def _inv(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def _rigid(T: np.ndarray) -> Rigid3:
    return Rigid3(T[:3, :3], T[:3, 3], "world", "left")


_KERNELS_LOADED = False


def _load_kernels() -> None:
    """Run the robust PnP once on a tiny exact problem, so that loading its compiled kernels
    (a few hundred milliseconds, once per process) happens at construction, not in a frame."""
    global _KERNELS_LOADED
    if _KERNELS_LOADED:
        return
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(-5, 5, 30), rng.uniform(-5, 5, 30), rng.uniform(5, 20, 30)])
    estimate_absolute_pose(X[:, :2] / X[:, 2:3], X, 500.0, min_inliers=10)
    _KERNELS_LOADED = True


class StereoOdometry:
    """Stereo visual odometry on a rectified rig (see the module docstring).

    Args:
        rig: rectified :class:`~skyrecon.core.StereoRig` (``x_right = x_left - d``).
        settings: :class:`OdometrySettings`.
        init_world_from_left: pose of the first frame's left camera in the world (default:
            identity, the world is the first left camera).
    Raises:
        InputError: the rig is not rectified.
    """

    def __init__(
        self,
        rig: StereoRig,
        settings: OdometrySettings = OdometrySettings(),  # noqa: B008 (frozen dataclass)
        init_world_from_left: Rigid3 | None = None,
    ) -> None:
        if not rig.is_rectified:
            raise InputError("stereo odometry needs a rectified rig (rectify the images first)")
        self.rig = rig
        self.settings = settings
        if settings.pnp_refinement == "robust" or settings.window_keyframes:
            _load_kernels()
        L = rig.left
        self._f = np.array([L.fx, L.fy])
        self._c = np.array([L.cx, L.cy])
        self._fb = L.fx * rig.baseline_m
        self._doffs = rig.doffs_px
        self._size = (L.width, L.height)
        self._init = np.eye(4) if init_world_from_left is None else init_world_from_left.matrix
        self._frames: list[_FrameRecord] = []
        self._estimates: list[FrameEstimate] = []
        self._kfs: list[_Keyframe] = []
        self._points: dict[int, np.ndarray] = {}
        self._point_weight: dict[int, float] = {}
        self._motion_rejections = 0
        self._next_id = 0
        self._pyr: Pyramid | None = None
        self._pts = np.zeros((0, 2), np.float32)
        self._ids = np.zeros(0, np.int64)
        # the keyframe the tracks are anchored on: its grey image, frame index, feature pixels
        self._anchor_img: np.ndarray | None = None
        self._anchor_frame = -1
        self._anchor_pts = np.zeros((0, 2), np.float32)
        self._last_input: np.ndarray | None = None
        self._last_time: float | None = None
        self._dts: list[float] = []
        # the trusted poses behind the motion prior: (timestamp, world_from_left 4x4)
        self._trusted: list[tuple[float, np.ndarray]] = []
        self._velocity_measured = True  # the prior's velocity comes from measured poses (see _trust)
        # the gyro's rotation since the last trusted frame, left_trusted_from_left_now (None: no gyro)
        self._gyro_since_trusted: np.ndarray | None = None
        self._gyro_active = False  # this frame came with a gyro rotation
        self._lost_count = 0
        # poses measured but refused by the motion check, by frame (see _confirm_refused)
        self._refused: dict[int, tuple[float, np.ndarray]] = {}
        self._refused_note = ""
        self._place_ms = 0.0
        self._loops: LoopCloser | None = None
        if settings.loop_closure:
            self._loops = LoopCloser(
                (L.fx, L.fy),
                (L.cx, L.cy),
                self._size,
                min_inliers=settings.loop_min_inliers,
                min_path_m=settings.loop_min_path_m,
                gate_m=settings.loop_gate_m,
                gate_fraction=settings.loop_gate_fraction,
                confirmations=settings.loop_confirmations,
                threshold_px=settings.ransac_threshold_px,
                seed=settings.seed,
            )

    # ----- public ------------------------------------------------------------------------
    @property
    def estimates(self) -> list[FrameEstimate]:
        """The per-frame answers as given by :meth:`track` (poses as estimated then)."""
        return list(self._estimates)

    def trajectory(self) -> list[Rigid3]:
        """The best current ``world_from_left`` of every frame given so far (window refinements and
        loop-closure corrections included; loops found since the last pose-graph solve are solved first)."""
        if self._loops is not None:
            poses = self._loops.finish([kf.world_from_left for kf in self._kfs])
            if poses is not None:
                self._apply_correction(poses)
        out = []
        for rec in self._frames:
            T = (
                rec.kf_from_frame
                if rec.keyframe < 0
                else self._kfs[rec.keyframe].world_from_left @ rec.kf_from_frame
            )
            out.append(_rigid(T))
        return out

    def loop_report(self) -> dict:
        """Loop-closure diagnostics: searches, loops accepted and rejected (with reasons), pose-graph
        solves and the largest correction (see :meth:`skyrecon.odometry.loops.LoopCloser.report`)."""
        if self._loops is None:
            return {"enabled": False}
        return self._loops.report()

    def track(
        self,
        left: np.ndarray,
        right: np.ndarray,
        timestamp_s: float,
        disparity_px: np.ndarray | None = None,
        gyro_prev_from_cur: np.ndarray | None = None,
    ) -> FrameEstimate:
        """Estimate the pose of one stereo frame.

        Args:
            left, right: (H, W, 3) uint8 RGB or (H, W) uint8 grey rectified images of the rig's size.
            timestamp_s: the frame's time, seconds, increasing from frame to frame.
            disparity_px: optional (H, W) float32 left disparity (``x_right = x_left - d``, NaN
                invalid); when given it supplies the features' depth instead of sparse stereo.
            gyro_prev_from_cur: optional (3, 3) rotation of the left camera since the previous
                frame given (``left_prev_from_left_cur``) as a gyro measures it (the IMU's rates
                integrated and turned into the camera's axes). When given with every frame it
                replaces the constant-angular-velocity guess of the motion prior: the search for the
                tracks starts where the turn put them, and across lost frames (and the new track a
                loss ends in) the rotation is the gyro's, not an extrapolation. The position comes
                from the cameras alone.
        Returns:
            :class:`FrameEstimate` (also appended to :attr:`estimates`).
        Raises:
            InputError: wrong image size or type, a disparity of the wrong shape, or a timestamp
                that is not finite or does not increase.
        """
        t_start = time.perf_counter()
        W, H = self._size
        check_pair(left, right, W, H)
        if disparity_px is not None:
            disparity_px = np.asarray(disparity_px)
            if disparity_px.shape != (H, W):
                raise InputError(f"the disparity must be ({H}, {W}), got {disparity_px.shape}")
        ts = float(timestamp_s)
        if not math.isfinite(ts):
            raise InputError(f"the timestamp must be finite, got {timestamp_s}")
        if self._last_time is not None and ts <= self._last_time:
            raise InputError(f"timestamps must increase: {ts} after {self._last_time}")
        index = len(self._frames)
        timings: dict[str, float] = {}
        self._gyro_active = gyro_prev_from_cur is not None
        if gyro_prev_from_cur is None:
            self._gyro_since_trusted = None  # a gap in the gyro: extrapolate until the next trusted frame
        else:
            g = np.asarray(gyro_prev_from_cur, dtype=np.float64)
            if (
                g.shape != (3, 3)
                or not np.all(np.isfinite(g))
                or not np.allclose(g @ g.T, np.eye(3), atol=1e-6)
            ):
                raise InputError("the gyro rotation must be a finite (3, 3) rotation matrix")
            if self._gyro_since_trusted is not None:
                self._gyro_since_trusted = self._gyro_since_trusted @ g
        grey = to_grey(left)
        frozen = self.settings.detect_frozen and is_frozen(grey, self._last_input)
        self._last_input = grey
        blank = blank_reason(grey)
        gap = ""
        if self._last_time is not None:
            dt = ts - self._last_time
            expected = float(np.median(self._dts[-20:])) if self._dts else None
            if expected is not None and dt > self.settings.gap_factor * expected:
                gap = f"frame gap {dt:.3f} s (usual {expected:.3f} s): search widened"
            elif not blank and not frozen:
                self._dts.append(dt)
        self._last_time = ts
        timings["checks"] = (time.perf_counter() - t_start) * 1e3

        if blank or frozen:
            reason = blank or "frozen frame (identical to the previous one)"
            est = self._lost(index, ts, reason, timings)
        elif not self._kfs:
            est = self._initialise(index, ts, grey, right, disparity_px, self._init, timings, reinit=False)
        else:
            est = self._track_frame(index, ts, grey, right, disparity_px, gap, timings)
        est.timings_ms["total"] = (time.perf_counter() - t_start) * 1e3
        self._estimates.append(est)
        return est

    # ----- motion prior -----------------------------------------------------------------------
    def _predict(self, ts: float) -> np.ndarray:
        """Constant-velocity ``world_from_left`` at time ``ts`` from the last two trusted poses;
        its rotation is the gyro's since the last trusted frame when the gyro is given."""
        if not self._trusted:
            return self._init.copy()
        t1, T1 = self._trusted[-1]
        if len(self._trusted) < 2:
            out = T1.copy()
        else:
            t0, T0 = self._trusted[-2]
            rel = _inv(T0) @ T1
            s = (ts - t1) / max(t1 - t0, 1e-6)
            step = np.eye(4)
            step[:3, :3] = rotvec_to_matrix(matrix_to_rotvec(rel[:3, :3]) * s)
            step[:3, 3] = rel[:3, 3] * s
            out = T1 @ step
        if self._gyro_since_trusted is not None:
            out[:3, :3] = T1[:3, :3] @ self._gyro_since_trusted
        return out

    def _trust(self, ts: float, T: np.ndarray, measured: bool = True) -> None:
        """Add a pose to the motion prior. ``measured`` False: a guess (a re-initialisation chains
        the last trusted pose at the old velocity), so the next pose is not held to that velocity
        (the vehicle may have braked while the frames were lost: a hovering drone whose every
        measured pose was rejected as "far from the prediction" re-initialised at the old speed,
        frame after frame, and its estimate ran away by 90 m in mission seed 0)."""
        self._trusted.append((ts, T.copy()))
        del self._trusted[:-2]
        self._velocity_measured = measured
        self._gyro_since_trusted = np.eye(3) if self._gyro_active else None

    # ----- outcomes ---------------------------------------------------------------------------
    def _record(self, T: np.ndarray, keyframe: int) -> None:
        if keyframe < 0:
            self._frames.append(_FrameRecord(-1, T.copy()))
        else:
            self._frames.append(_FrameRecord(keyframe, _inv(self._kfs[keyframe].world_from_left) @ T))

    def _lost(self, index: int, ts: float, reason: str, timings: dict[str, float]) -> FrameEstimate:
        """A frame without a pose: the constant-velocity prediction, flagged lost."""
        T = self._predict(ts)
        self._lost_count += 1
        self._record(T, len(self._kfs) - 1)
        return FrameEstimate(
            index=index,
            timestamp_s=ts,
            world_from_left=_rigid(T),
            state=TrackingState.LOST,
            reason=reason,
            n_features=len(self._pts),
            timings_ms=timings,
        )

    # ----- stereo ------------------------------------------------------------------------------
    def _disparities(
        self,
        left: Pyramid,
        right_image: np.ndarray,
        disparity_px: np.ndarray | None,
        pts: np.ndarray,
        guess: np.ndarray | None,
    ) -> np.ndarray:
        """(N,) disparities of left features: from the given dense map, else sparse KLT stereo."""
        if disparity_px is not None:
            d = disparity_lookup(disparity_px, pts)
            with np.errstate(invalid="ignore"):
                d[~(d >= self.settings.min_disparity_px)] = np.nan
            if not self.settings.refine_disparity:
                return d
            if guess is None:
                guess = d
            else:
                guess = np.where(np.isfinite(d), d, guess)
        right = build_pyramid(to_grey(right_image), self.settings.klt_window_px, 2)
        return stereo_match(
            left,
            right,
            pts,
            guess,
            max_row_error_px=self.settings.stereo_row_tolerance_px,
            min_disparity_px=self.settings.min_disparity_px,
        )

    def _backproject(self, pts: np.ndarray, d: np.ndarray) -> np.ndarray:
        """(N, 3) left-camera points from pixels (N, 2) and disparities (N,)."""
        z = self._fb / (d + self._doffs)
        xy = (pts.astype(np.float64) - self._c) / self._f * z[:, None]
        return np.column_stack([xy, z])

    # ----- initialisation and keyframes -------------------------------------------------------
    def _initialise(
        self,
        index: int,
        ts: float,
        grey: np.ndarray,
        right: np.ndarray,
        disparity_px: np.ndarray | None,
        T: np.ndarray,
        timings: dict[str, float],
        reinit: bool,
        why: str = "",
    ) -> FrameEstimate:
        """Start a new track at this frame with pose ``T`` (``world_from_left``)."""
        s = self.settings
        t0 = time.perf_counter()
        pyr = build_pyramid(grey, s.klt_window_px, s.klt_levels)
        pts = self._detect(grey, np.zeros((0, 2), np.float32))
        timings["detect"] = (time.perf_counter() - t0) * 1e3
        t0 = time.perf_counter()
        d = self._disparities(pyr, right, disparity_px, pts, None)
        timings["stereo"] = (time.perf_counter() - t0) * 1e3
        n_stereo = int(np.count_nonzero(np.isfinite(d)))
        if n_stereo < s.min_stereo_points:
            if len(pts) < s.min_stereo_points:
                reason = f"{len(pts)} features (< {s.min_stereo_points}): too little texture or sky"
            else:
                reason = (
                    f"no stereo depth in view: {n_stereo} of {len(pts)} features with depth "
                    f"(< {s.min_stereo_points}); pure rotation or distant scene"
                )
            prefix = "cannot initialise: " if not self._kfs else "cannot re-initialise: "
            est = self._lost(index, ts, prefix + reason + (f" ({why})" if why else ""), timings)
            est.n_features, est.n_stereo = len(pts), n_stereo
            return est
        ids = np.arange(self._next_id, self._next_id + len(pts), dtype=np.int64)
        self._next_id += len(pts)
        how = "the gyro's rotation" if self._gyro_since_trusted is not None else "constant velocity"
        self._pyr, self._pts, self._ids = pyr, pts, ids
        self._add_keyframe(index, T, pts, ids, d, grey, reinit)
        self._set_anchor(index, grey)
        self._record(T, len(self._kfs) - 1)
        self._trust(ts, T, measured=not reinit)  # after a loss: chained to the last trusted pose
        lost_before = self._lost_count
        self._lost_count = 0
        state, reason = TrackingState.OK, ""
        if reinit:
            state = TrackingState.DEGRADED
            reason = (
                f"re-initialised after {lost_before} lost frame(s): pose chained to the last trusted one "
                f"by {how}" + (f" ({why})" if why else "")
            )
        return FrameEstimate(
            index=index,
            timestamp_s=ts,
            world_from_left=_rigid(T),
            state=state,
            reason=reason,
            keyframe=True,
            reinitialised=reinit,
            n_features=len(pts),
            n_stereo=n_stereo,
            timings_ms=timings,
        )

    def _detect(self, grey: np.ndarray, existing_px: np.ndarray) -> np.ndarray:
        """New corners in ``grey`` ((H, W) uint8) away from ``existing_px`` ((M, 2) pixels), above
        the image's noise floor (``settings.corner_noise_factor``); (K, 2) float32 pixels."""
        s = self.settings
        floor = 0.0
        if s.corner_noise_factor > 0:
            excess = excess_noise_sigma(image_noise_sigma(grey))
            floor = s.corner_noise_factor * corner_noise_quantile(5) * excess * excess
        return detect_corners(
            grey, existing_px, s.max_features, s.grid, s.min_corner_distance_px, min_strength=floor
        )

    def _set_anchor(self, index: int, grey: np.ndarray) -> None:
        self._anchor_img, self._anchor_frame = grey, index
        self._anchor_pts = self._pts.copy()

    def _add_keyframe(
        self,
        index: int,
        T: np.ndarray,
        pts: np.ndarray,
        ids: np.ndarray,
        d: np.ndarray,
        grey: np.ndarray | None = None,
        reinit: bool = False,
    ) -> None:
        """Create map points for features with depth and no point yet; store the keyframe's observations
        (and, with loop closure and the keyframe's ``grey`` image, its place: descriptors at ``pts``
        with their stereo points; ``reinit``: the keyframe starts a new track)."""
        has_d = np.isfinite(d)
        known = np.array([i in self._points for i in ids.tolist()], bool)
        new = has_d & ~known
        if np.any(new):
            Xw = self._backproject(pts[new], d[new]) @ T[:3, :3].T + T[:3, 3]
            for i, X, di in zip(ids[new].tolist(), Xw, d[new].tolist()):
                self._points[i] = X
                self._point_weight[i] = di**4
        again = has_d & known
        if self.settings.refresh_points and np.any(again):
            # a point measured again (usually nearer, so far more precisely: the depth's variance
            # grows as 1 / disparity^4) is the inverse-variance mean of its measurements; a point
            # first seen far away would otherwise keep that far, biased depth while the drone closes in
            Xw = self._backproject(pts[again], d[again]) @ T[:3, :3].T + T[:3, 3]
            for i, X, di in zip(ids[again].tolist(), Xw, d[again].tolist()):
                w_old = self._point_weight.get(i, 0.0)
                w_new = di**4
                self._points[i] = (w_old * self._points[i] + w_new * X) / (w_old + w_new)
                self._point_weight[i] = w_old + w_new
        has_pt = np.array([i in self._points for i in ids.tolist()], bool)
        right_uv = pts[has_pt & has_d].astype(np.float64).copy()
        right_uv[:, 0] -= d[has_pt & has_d]
        self._kfs.append(
            _Keyframe(
                index,
                T.copy(),
                int(np.count_nonzero(has_pt)),
                ids[has_pt].copy(),
                pts[has_pt].astype(np.float64),
                ids[has_pt & has_d].copy(),
                right_uv,
                reinit,
            )
        )
        if self._loops is not None and grey is not None:
            t0 = time.perf_counter()
            cam = np.full((len(pts), 3), np.nan)
            if np.any(has_d):
                cam[has_d] = self._backproject(pts[has_d], d[has_d])
            self._loops.add_keyframe(
                len(self._kfs) - 1,
                index,
                grey,
                pts.astype(np.float64),
                cam,
                [k.world_from_left for k in self._kfs],
                reinit,
            )
            self._place_ms = (time.perf_counter() - t0) * 1e3

    # ----- tracking ------------------------------------------------------------------------------
    def _guess(self, T_pred: np.ndarray, T_last: np.ndarray, has_pt: np.ndarray) -> np.ndarray:
        """Predicted pixels of the tracked features in the new frame (motion prior)."""
        pts = self._pts.astype(np.float64)
        guess = pts.copy()
        # rotation-only prediction for every feature (points at infinity)
        R_rel = T_pred[:3, :3].T @ T_last[:3, :3]  # cur_from_last
        rays = np.column_stack([(pts - self._c) / self._f, np.ones(len(pts))]) @ R_rel.T
        front = rays[:, 2] > 1e-3
        guess[front] = rays[front, :2] / rays[front, 2:3] * self._f + self._c
        # full projection for features with a map point
        if np.any(has_pt):
            X = np.stack([self._points[i] for i in self._ids[has_pt].tolist()])
            cam_from_world = _inv(T_pred)
            P = X @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
            ok = P[:, 2] > 0.1
            g = guess[has_pt]
            g[ok] = P[ok, :2] / P[ok, 2:3] * self._f + self._c
            guess[has_pt] = g
        W, H = self._size
        bad = ~np.isfinite(guess).all(axis=1) | (guess[:, 0] < -W) | (guess[:, 0] > 2 * W)
        bad |= (guess[:, 1] < -H) | (guess[:, 1] > 2 * H)
        guess[bad] = pts[bad]
        return guess.astype(np.float32)

    def _rotation_from_shift(
        self, shift: tuple[float, float, float], T_pred: np.ndarray, T_last: np.ndarray
    ) -> np.ndarray:
        """A predicted pose whose rotation from the last trusted one turns the image centre by
        the measured dominant shift (its translation from the motion prior)."""
        dx, dy, _ = shift
        r = np.array([dx / self._f[0], dy / self._f[1], 1.0])
        r /= np.linalg.norm(r)
        z = np.array([0.0, 0.0, 1.0])
        axis = np.cross(z, r)
        sin = float(np.linalg.norm(axis))
        R_rel = np.eye(3)  # cur_from_last: the old optical axis is seen along r
        if sin > 1e-9:
            R_rel = rotvec_to_matrix(axis / sin * math.atan2(sin, float(z @ r)))
        out = T_pred.copy()
        out[:3, :3] = T_last[:3, :3] @ R_rel.T
        return out

    def _relocate_rotation(self, grey: np.ndarray, T_pred: np.ndarray, T_last: np.ndarray) -> np.ndarray:
        """``T_pred`` with its rotation measured from the last trusted image to ``grey``: fresh
        corners tracked (seeded by the dominant image shift) and a pure-rotation fit in RANSAC
        (the translation over a frame or two is small against the depths). ``T_pred`` unchanged
        when the fit fails or explains less than a third of the tracks: the image shift alone is
        no measurement (two views that barely overlap gave rotations 60-100 degrees off)."""
        assert self._pyr is not None
        prev = self._pyr.image
        s = self.settings
        T_rot = self._rotation_from_shift(global_shift(prev, grey), T_pred, T_last)
        R_rel = T_rot[:3, :3].T @ T_last[:3, :3]  # cur_from_last
        pts = self._detect(prev, np.zeros((0, 2), np.float32))
        if len(pts) < s.min_inliers:
            return T_pred
        rays0 = np.column_stack([(pts - self._c) / self._f, np.ones(len(pts))])
        g = rays0 @ R_rel.T
        front = g[:, 2] > 1e-3
        guess = pts.astype(np.float64).copy()
        guess[front] = g[front, :2] / g[front, 2:3] * self._f + self._c
        win, levels = s.klt_window_px + 10, s.klt_levels + max(s.retry_levels, 1)
        cur, ok = track_points(
            build_pyramid(prev, win, levels),
            build_pyramid(grey, win, levels),
            pts,
            guess.astype(np.float32),
            s.fb_threshold_px,
        )
        if np.count_nonzero(ok) < s.min_inliers:
            return T_pred
        a = rays0[ok] / np.linalg.norm(rays0[ok], axis=1, keepdims=True)
        b = np.column_stack(
            [(cur[ok].astype(np.float64) - self._c) / self._f, np.ones(int(np.count_nonzero(ok)))]
        )
        b /= np.linalg.norm(b, axis=1, keepdims=True)

        def fit(idx: np.ndarray) -> np.ndarray:  # R with b ~ R a (Kabsch)
            U, _, Vt = np.linalg.svd(b[idx].T @ a[idx])
            D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)))])
            return U @ D @ Vt

        rng = np.random.default_rng(s.seed)
        tol = 3.0 * s.ransac_threshold_px / float(self._f[0])
        best = np.zeros(len(a), bool)
        for _ in range(100):
            R = fit(rng.choice(len(a), 2, replace=False))
            inl = np.linalg.norm(a @ R.T - b, axis=1) < tol
            if inl.sum() > best.sum():
                best = inl
        if best.sum() < max(s.min_inliers, len(a) / 3):
            return T_pred
        R = fit(np.flatnonzero(best))
        out = T_pred.copy()
        out[:3, :3] = T_last[:3, :3] @ R.T
        return out

    def _attempt(
        self,
        index: int,
        ts: float,
        grey: np.ndarray,
        win: int,
        levels: int,
        T_pred: np.ndarray,
        t_last: float,
        T_last: np.ndarray,
        has_pt: np.ndarray,
        timings: dict[str, float],
    ) -> _Attempt:
        """Track the features into ``grey`` (KLT ``win`` x ``win``, ``levels`` pyramid levels) and
        estimate the pose from the tracked map points."""
        s = self.settings
        t0 = time.perf_counter()
        pyr = build_pyramid(grey, win, levels)
        assert self._pyr is not None
        prev = self._pyr
        if prev.win != win or prev.max_level != pyr.max_level:
            prev = build_pyramid(prev.image, win, pyr.max_level)
        guess = self._guess(T_pred, T_last, has_pt)
        pts, ok = track_points(prev, pyr, self._pts, guess, s.fb_threshold_px)
        if s.anchor_tracks and self._anchor_img is not None and self._anchor_frame != index - 1:
            pts, _ = refine_to_anchor(
                self._anchor_img, grey, self._anchor_pts, pts, win, s.anchor_max_move_px
            )
        timings["track"] = timings.get("track", 0.0) + (time.perf_counter() - t0) * 1e3
        use = ok & has_pt
        n_use = int(np.count_nonzero(use))

        failure = ""
        T = None
        pose = None
        if n_use < s.min_inliers:
            failure = f"{n_use} tracked features with a 3D point (< {s.min_inliers})"
        else:
            t0 = time.perf_counter()
            ids_use = self._ids[use]
            X = np.stack([self._points[i] for i in ids_use.tolist()])
            xn = (pts[use].astype(np.float64) - self._c) / self._f
            try:
                solver = fast_absolute_pose if s.pnp_refinement == "lm" else estimate_absolute_pose
                pose = solver(
                    xn,
                    X,
                    float(self._f[0]),
                    threshold_px=s.ransac_threshold_px,
                    seed=s.seed + index,
                    max_iterations=s.ransac_iterations,
                    confidence=0.999,
                    min_inliers=s.min_inliers,
                )
            except EstimationError as exc:
                failure = str(exc)
            timings["pnp"] = timings.get("pnp", 0.0) + (time.perf_counter() - t0) * 1e3
            if pose is not None:
                T = np.eye(4)
                T[:3, :3] = pose.R.T
                T[:3, 3] = -pose.R.T @ pose.t
                elapsed = max(ts - t_last, 1e-6)
                speed = float(np.linalg.norm(T[:3, 3] - T_last[:3, 3])) / elapsed
                rate = math.degrees(rotation_angle(T_last[:3, :3].T @ T[:3, :3])) / elapsed
                if speed > s.max_speed_mps or rate > s.max_rotation_rate_dps:
                    failure = (
                        f"rejected an implausible pose: {speed:.1f} m/s, {rate:.0f} deg/s since the last "
                        f"trusted frame (limits {s.max_speed_mps:g} m/s, {s.max_rotation_rate_dps:g} deg/s)"
                    )
                    T = None
                elif (
                    s.max_acceleration_mps2 is not None
                    and len(self._trusted) >= 2
                    and self._velocity_measured
                ):
                    T_measured, pose_measured = T, pose
                    T, pose, failure = self._check_motion(T, pose, T_pred, elapsed, xn, X)
                    if T is None:
                        T, pose, failure = self._confirm_refused(
                            index, ts, T_measured, pose_measured, T_pred, elapsed, failure
                        )

        n_inl = pose.num_inliers if (pose is not None and T is not None) else 0
        return _Attempt(pyr, pts, ok, use, pose, T, failure, n_inl)

    def _motion_limit(self, dt: float) -> float:
        """How far, metres, a pose may leave the constant-velocity prediction ``dt`` seconds
        ahead: ``prediction_tolerance_m + max_acceleration_mps2 * dt^2 / 2``."""
        s = self.settings
        assert s.max_acceleration_mps2 is not None
        return s.prediction_tolerance_m + 0.5 * s.max_acceleration_mps2 * dt**2

    def _confirm_refused(
        self,
        index: int,
        ts: float,
        T: np.ndarray,
        pose: AbsolutePose,
        T_pred: np.ndarray,
        elapsed: float,
        why: str,
    ) -> tuple[np.ndarray | None, AbsolutePose | None, str]:
        """A measured pose the motion check refused (:meth:`_check_motion`) is accepted after all
        when the pose measured and refused in the frame before leads to it within the same
        tolerance: two consecutive measurements agree, so the prediction is what went wrong (a
        poor pose accepted within the tolerance bent the velocity, and refitting each later frame
        onto the bent prediction held mission seed 9's estimate 1.5 m off until it re-initialised
        there). Refused means the prediction explains too few tracks to be refitted on them; the
        measurement must have at least ``good_inliers``. The frame is flagged degraded and the
        velocity is measured afresh from it."""
        s = self.settings
        before = self._refused.get(index - 1)
        self._refused = {k: v for k, v in self._refused.items() if k == index - 1}
        self._refused.setdefault(index, (ts, T.copy()))
        if before is None or not self._trusted or pose.num_inliers < s.good_inliers:
            return None, None, why
        t_before, T_before = before
        dt = max(ts - t_before, 1e-6)
        v = (T_pred[:3, 3] - self._trusted[-1][1][:3, 3]) / max(elapsed, 1e-6)  # the prior's velocity
        limit = self._motion_limit(dt)
        dev = float(np.linalg.norm(T[:3, 3] - (T_before[:3, 3] + v * dt)))
        turn = math.degrees(rotation_angle(T_before[:3, :3].T @ T[:3, :3]))
        if dev > limit or turn > s.max_rotation_rate_dps * dt:
            return None, None, why
        self._refused_note = (
            f"accepted a pose {float(np.linalg.norm(T[:3, 3] - T_pred[:3, 3])):.2f} m from the motion "
            "prediction: it agrees with the one measured in the frame before"
        )
        return T, pose, ""

    def _check_motion(
        self,
        T: np.ndarray,
        pose: AbsolutePose,
        T_pred: np.ndarray,
        elapsed: float,
        xn: np.ndarray,
        X: np.ndarray,
    ) -> tuple[np.ndarray | None, AbsolutePose | None, str]:
        """Hold a pose to the vehicle's dynamics: its position may leave the constant-velocity
        prediction by at most ``prediction_tolerance_m + a_max * dt^2 / 2``. A pose beyond that
        (RANSAC locked onto a wrong consensus: a rotation read as a slide near a wall, a passing
        vehicle) is replaced by the pose refined from the prediction on the tracks the prediction
        explains, when they are enough; else the frame fails with the reason."""
        s = self.settings
        limit = self._motion_limit(elapsed)
        dev = float(np.linalg.norm(T[:3, 3] - T_pred[:3, 3]))
        if dev <= limit:
            return T, pose, ""
        R0 = T_pred[:3, :3].T
        t0 = -R0 @ T_pred[:3, 3]
        err = reprojection_errors_px(R0, t0, xn, X, float(self._f[0]))
        near = err < 4.0 * s.ransac_threshold_px
        why = f"rejected a pose {dev:.2f} m from the motion prediction (limit {limit:.2f} m)"
        if int(np.count_nonzero(near)) < s.min_inliers:
            return None, None, why
        R, t = refine_absolute_pose(R0, t0, xn[near], X[near], float(self._f[0]), s.ransac_threshold_px / 2)
        errors = reprojection_errors_px(R, t, xn, X, float(self._f[0]))
        inliers = errors < s.ransac_threshold_px
        T_new = np.eye(4)
        T_new[:3, :3] = R.T
        T_new[:3, 3] = -R.T @ t
        if (
            int(np.count_nonzero(inliers)) < s.min_inliers
            or float(np.linalg.norm(T_new[:3, 3] - T_pred[:3, 3])) > limit
        ):
            return None, None, why
        self._motion_rejections += 1
        return T_new, AbsolutePose(R, t, inliers, errors, len(xn)), ""

    def _track_frame(
        self,
        index: int,
        ts: float,
        grey: np.ndarray,
        right: np.ndarray,
        disparity_px: np.ndarray | None,
        gap: str,
        timings: dict[str, float],
    ) -> FrameEstimate:
        s = self.settings
        loop_message = ""
        self._refused_note = ""
        T_pred = self._predict(ts)
        t_last, T_last = self._trusted[-1]
        widen = bool(gap) or self._lost_count > 0
        has_pt = np.array([i in self._points for i in self._ids.tolist()], bool)
        extra = 10 if widen else 0
        att = self._attempt(
            index,
            ts,
            grey,
            s.klt_window_px + extra,
            s.klt_levels + (1 if widen else 0),
            T_pred,
            t_last,
            T_last,
            has_pt,
            timings,
        )
        if s.retry_levels and (att.T is None or att.n_inliers < s.good_inliers):
            # a jerk the motion prior missed (a sudden pitch or yaw): search again, coarser and wider
            wide = self._attempt(
                index,
                ts,
                grey,
                s.klt_window_px + 10,
                s.klt_levels + s.retry_levels,
                T_pred,
                t_last,
                T_last,
                has_pt,
                timings,
            )
            if wide.T is not None and (att.T is None or wide.n_inliers > att.n_inliers):
                att = wide
            if (att.T is None or att.n_inliers < s.good_inliers) and self._gyro_since_trusted is None:
                # still not found: seed the search with the rotation read off the image's dominant shift
                # (with a gyro the prediction already holds the measured rotation)
                assert self._pyr is not None
                T_rot = self._rotation_from_shift(global_shift(self._pyr.image, grey), T_pred, T_last)
                wide = self._attempt(
                    index,
                    ts,
                    grey,
                    s.klt_window_px + 10,
                    s.klt_levels + s.retry_levels,
                    T_rot,
                    t_last,
                    T_last,
                    has_pt,
                    timings,
                )
                if wide.T is not None and (att.T is None or wide.n_inliers > att.n_inliers):
                    att = wide
        pyr, pts, ok, use, pose, T, failure = att.pyr, att.pts, att.ok, att.use, att.pose, att.T, att.failure
        n_tracked = int(np.count_nonzero(ok))

        if T is None or pose is None:
            if self._lost_count > 0:
                # the map could not be found again: start a new track here, chained by the prior,
                # its rotation the gyro's or else measured against the last trusted image (a jerk
                # breaks the constant-velocity prior)
                T_re = T_pred
                if self._gyro_since_trusted is None:
                    T_re = self._relocate_rotation(grey, T_pred, T_last)
                return self._initialise(
                    index, ts, grey, right, disparity_px, T_re, timings, reinit=True, why=failure
                )
            est = self._lost(index, ts, failure, timings)
            est.n_tracked = n_tracked
            return est

        # keep the tracked features, minus PnP outliers and (when enough stay) tracks that strayed
        # more than track_threshold_px from their map point
        inl_full = np.zeros(len(self._ids), bool)
        kept = pose.inliers
        if s.track_threshold_px is not None:
            tight = pose.inliers & (pose.errors_px < s.track_threshold_px)
            if np.count_nonzero(tight) >= s.good_inliers:
                kept = tight
        inl_full[np.flatnonzero(use)[kept]] = True
        outlier = use & ~inl_full
        keep = ok & ~outlier
        n_inl = pose.num_inliers
        inl_px = pts[inl_full]
        err = pose.errors_px[pose.inliers]
        rms = float(np.sqrt(np.mean(err**2))) if len(err) else float("nan")
        self._pts, self._ids, self._pyr = pts[keep], self._ids[keep], pyr
        self._anchor_pts = self._anchor_pts[keep]

        reasons = []
        if n_inl < s.good_inliers:
            reasons.append(f"{n_inl} inliers (< {s.good_inliers})")
        cover = grid_coverage(inl_px, *self._size)
        if cover < s.min_inlier_coverage:
            reasons.append(f"poor inlier spread ({cover:.0%} of the image grid)")
        if gap:
            reasons.append(gap)
        confirmed = self._refused_note
        if confirmed:
            reasons.append(confirmed)
            self._refused_note = ""
        recovered = self._lost_count
        self._lost_count = 0
        self._trust(ts, T, measured=not confirmed)  # after a confirmed jump the old velocity is void

        # keyframe decision
        kf = self._kfs[-1]
        n_pts_now = int(np.count_nonzero(inl_full))
        rel = _inv(kf.world_from_left) @ T
        make_kf = (
            n_pts_now < s.keyframe_tracked_ratio * kf.n_points
            or float(np.linalg.norm(rel[:3, 3])) > s.keyframe_max_distance_m
            or math.degrees(rotation_angle(rel[:3, :3])) > s.keyframe_max_rotation_deg
            or index - kf.frame >= s.keyframe_max_frames
            or bool(recovered)
        )
        n_stereo = n_pts_now
        if make_kf:
            t0 = time.perf_counter()
            new = self._detect(grey, self._pts)
            timings["detect"] = (time.perf_counter() - t0) * 1e3
            if len(new):
                self._pts = np.concatenate([self._pts, new])
                self._ids = np.concatenate(
                    [self._ids, np.arange(self._next_id, self._next_id + len(new), dtype=np.int64)]
                )
                self._next_id += len(new)
            t0 = time.perf_counter()
            guess_d = self._predicted_disparity(T)
            d = self._disparities(pyr, right, disparity_px, self._pts, guess_d)
            timings["stereo"] = (time.perf_counter() - t0) * 1e3
            self._add_keyframe(index, T, self._pts, self._ids, d, grey, False)
            self._set_anchor(index, grey)
            n_stereo = self._kfs[-1].n_points
            if s.window_keyframes >= 3 and len(self._kfs) >= 3:
                t0 = time.perf_counter()
                self._window_adjust()
                timings["window_ba"] = (time.perf_counter() - t0) * 1e3
                T = self._kfs[-1].world_from_left
                self._trusted[-1] = (ts, T.copy())
            if self._loops is not None:
                t0 = time.perf_counter()
                outcome = self._loops.search([kf.world_from_left for kf in self._kfs])
                if outcome.poses is not None:
                    self._apply_correction(outcome.poses)
                    T = self._kfs[-1].world_from_left
                loop_message = outcome.message
                timings["loop"] = (time.perf_counter() - t0) * 1e3 + self._place_ms
        self._record(T, len(self._kfs) - 1)
        depth_med = self._median_depth(T, self._ids)
        sigma = rms / float(self._f[0]) * depth_med / math.sqrt(max(n_inl, 1)) * 3.0
        return FrameEstimate(
            index=index,
            timestamp_s=ts,
            world_from_left=_rigid(T),
            state=TrackingState.DEGRADED if reasons else TrackingState.OK,
            reason="; ".join(reasons),
            keyframe=make_kf,
            n_features=len(self._pts),
            n_stereo=n_stereo,
            n_tracked=n_tracked,
            n_inliers=n_inl,
            reprojection_rms_px=rms,
            timings_ms=timings,
            position_sigma_m=sigma,
            loop=loop_message,
        )

    def _apply_correction(self, poses: np.ndarray) -> None:
        """Move every keyframe to its pose-graph pose (``poses`` (K, 4, 4) ``world_from_left``); the
        map points still in use and the motion prior's poses move with the newest keyframe, so that
        tracking continues from the corrected pose."""
        last = self._kfs[-1]
        C = poses[-1] @ _inv(last.world_from_left)  # world_from_world correction of the newest keyframe
        for kf, P in zip(self._kfs, poses):
            kf.world_from_left = P.copy()
        ids = set(self._ids.tolist())
        for kf in self._kfs[-max(self.settings.window_keyframes, 1) :]:
            ids.update(kf.obs_ids.tolist())
        for i in ids:
            X = self._points.get(i)
            if X is not None:
                self._points[i] = C[:3, :3] @ X + C[:3, 3]
        self._trusted = [(t, C @ T) for t, T in self._trusted]

    def _median_depth(self, T: np.ndarray, ids: np.ndarray) -> float:
        pts = [self._points[i] for i in ids.tolist() if i in self._points]
        if not pts:
            return float("nan")
        cam = _inv(T)
        z = (np.stack(pts) @ cam[:3, :3].T + cam[:3, 3])[:, 2]
        return float(np.median(z))

    def _predicted_disparity(self, T: np.ndarray) -> np.ndarray:
        """(N,) disparity of the current features predicted from their map points (NaN: none)."""
        out = np.full(len(self._ids), np.nan)
        cam = _inv(T)
        for k, i in enumerate(self._ids.tolist()):
            X = self._points.get(i)
            if X is not None:
                z = float(cam[2, :3] @ X + cam[2, 3])
                if z > 0:
                    out[k] = self._fb / z - self._doffs
        return out

    # ----- sliding window ---------------------------------------------------------------------
    def _window_adjust(self) -> None:
        """Bundle-adjust the last ``window_keyframes`` keyframes (oldest ones fixed) and their points."""
        s = self.settings
        win = self._kfs[-s.window_keyframes :]
        K = len(win)
        # at least one free keyframe, unless every keyframe is held (points-only refinement)
        n_fixed = (
            K if s.window_fixed_keyframes >= s.window_keyframes else min(s.window_fixed_keyframes, K - 1)
        )
        seen: dict[int, int] = {}
        for kf in win:
            for i in kf.obs_ids.tolist():
                if i in self._points:
                    seen[i] = seen.get(i, 0) + 1
        pids = [i for i, c in seen.items() if c >= 2]
        if len(pids) < 10:
            return
        col = {i: k for k, i in enumerate(pids)}
        points = np.stack([self._points[i] for i in pids])
        obs_kf, obs_pt, obs_uv = [], [], []
        r_kf, r_pt, r_uv = [], [], []
        for k, kf in enumerate(win):
            for i, uv in zip(kf.obs_ids.tolist(), kf.obs_uv):
                c = col.get(i)
                if c is not None:
                    obs_kf.append(k)
                    obs_pt.append(c)
                    obs_uv.append(uv)
            if k < n_fixed:
                for i, uv in zip(kf.right_ids.tolist(), kf.right_uv):
                    c = col.get(i)
                    if c is not None:
                        r_kf.append(k)
                        r_pt.append(c)
                        r_uv.append(uv)
        Ts = [_inv(kf.world_from_left) for kf in win]
        fixed = np.zeros(K, bool)
        fixed[:n_fixed] = True
        res = window_bundle_adjust(
            self.rig,
            np.stack([T[:3, :3] for T in Ts]),
            np.stack([T[:3, 3] for T in Ts]),
            fixed,
            points,
            np.array(obs_kf, np.int64),
            np.array(obs_pt, np.int64),
            np.array(obs_uv, np.float64).reshape(-1, 2),
            np.array(r_kf, np.int64),
            np.array(r_pt, np.int64),
            np.array(r_uv, np.float64).reshape(-1, 2),
            max_iterations=s.window_iterations,
        )
        if not (res.rms_after_px <= res.rms_before_px * 1.05 + 0.05):
            return  # the adjustment made things worse: keep the previous estimate
        # points seen by a single window keyframe were not adjusted: they move with that keyframe
        single: dict[int, int] = {}
        for k, kf in enumerate(win):
            for i in kf.obs_ids.tolist():
                if seen.get(i) == 1:
                    single[i] = k
        moves = {}
        for k in range(n_fixed, K):
            T = np.eye(4)
            T[:3, :3] = res.R[k].T
            T[:3, 3] = -res.R[k].T @ res.t[k]
            moves[k] = T @ _inv(win[k].world_from_left)
            win[k].world_from_left = T
        for i, k in single.items():
            C = moves.get(k)
            if C is not None and i in self._points:
                self._points[i] = C[:3, :3] @ self._points[i] + C[:3, 3]
        bad = res.point_error_px > 3.0 * s.ransac_threshold_px
        for i, X, b in zip(pids, res.points, bad):
            if b:
                del self._points[i]
            else:
                self._points[i] = X
