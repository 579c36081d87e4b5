"""Occupancy map from a rectified stereo sequence: stereo -> depth -> map, frame by frame.

This is what ``skyrecon map SEQUENCE_DIR`` runs (the command only reads the files and writes
the map), as a library stage. Stereo depth comes from the perception layer
(:class:`skyrecon.perception.StereoDepth` with :meth:`~skyrecon.perception.PerceptionSettings.mapping`
rules by default). Per frame:

1. disparity of the rectified pair with a stereo matcher (full-resolution ``skyrecon`` with a
   uniqueness test and the horizontal aggregation paths, without the colour-guided fill, by
   default: a camera looking down at plain streets needs the horizontal paths, see
   :class:`skyrecon.stereo.SkyreconSettings`), kept between frames;
2. only *measured* disparities are used: pixels the matcher filled by interpolation are
   guesses, and pixels at a disparity discontinuity (their 3x3 neighbourhood spans more than
   ``max_disparity_step_px``) are dropped, because smoothing puts them in the air between the
   foreground and the background: both would become phantom obstacles. A match counts as
   measured only on texture (``min_texture``): on a plain wall or road the matcher's value is
   smoothed in from the edges, often too far, and its ray would carve free space through the
   wall;
3. a plain segment (unmeasured pixels bounded by measured ones) whose trusted measured border
   lies on one plane of disparity, all around it, takes that plane (``plane_fill``, see
   :func:`skyrecon.stereo.plane_supported_fill`): the plain wall gets hits instead of a hole,
   while an occluded strip or the sky above a roof line stays unknown;
3b. the matcher's other values (filled, or smoothed over plain surfaces) are guesses: they never
   carve free space, and they become hits only in voxels that the guesses of
   ``guess_min_frames`` frames fall into, next to an occupied voxel and not known free
   (:class:`~skyrecon.mapping.frame_support.FrameSupport`);
4. depth ``Z = f B / (d + doffs)`` and projective integration into an :class:`OccupancyMap`
   whose range is limited to the *trusted range* of the rig (:func:`stereo_hit_range_m`):
   a disparity error of ``disparity_error_px`` moves depth by at most ``max_depth_error_m``
   (2 voxels by default) up to that range. Farther measurements carve free space up to the
   trusted range and give no hit, so far-range stereo noise cannot create obstacles;
5. the map's sensor model trusts a single hit less than OctoMap's default (``prob_hit`` 0.6,
   ``prob_miss`` 0.35 instead of 0.7 / 0.4): stereo noise scatters hits into the voxels in front
   of a surface, and the misses of the other frames that see through them now clear them;
6. each surface is taken a fifth of a voxel nearer the camera than measured
   (``surface_pull_voxels``): the noise that falls behind a surface would mark voxels inside
   the obstacle that no ray can ever clear, and free space now stops short of the surface.
   Step 6 and the plane fill's check against the matcher's own values (issue #13) raise the
   share of occupied voxels on a true surface on plain cities (seeds 1, 3, 4, 7, 11) from
   0.55-0.66 to 0.63-0.71 and halve the free voxels inside obstacles.

On the synthetic city (``benchmarks/mapping/stereo_map.py``) steps 1, 2 and 5 raise the
occupied-voxel precision at 0.5 m from about 0.71 to 0.84 at the same recall within 20 m. On
cities of plain surfaces (``generate_city(..., plain=True)``, seeds 3, 7, 11) the texture rule,
step 3 and 3b cut the free voxels inside obstacles 2-10 fold (0.0099 -> 0.0009 on seed 3) and
raise the share of occupied voxels on a true surface from 0.50-0.61 to 0.62-0.67; recall within
20 m rises on seeds 3 and 7 (0.48 -> 0.55, 0.65 -> 0.73) and falls on seed 11 (0.86 -> 0.82).
On the textured city they cut free voxels inside obstacles 4 fold at a cost of 0.03 in
precision (voxels inside buildings, from depth that was too far) and 0.015 in recall.

Frames and units: images (H, W, 3) uint8 RGB of a rectified rig; poses ``world_from_left``
(world frame z up, metres); depth (H, W) float32 metres along the left optical axis, NaN invalid.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from skyrecon.core.rigid import Rigid3
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError
from skyrecon.mapping.config import STEREO_PLAUSIBLE_DEPTH_M, MapConfig
from skyrecon.mapping.depth_sequence import FrameTimings, MappedFrame, as_rigid
from skyrecon.mapping.frame_support import FrameSupport
from skyrecon.mapping.ground_level import GroundLevel, GroundSettings
from skyrecon.mapping.inputs import as_world_from_cam
from skyrecon.mapping.occupancy import IntegrationStats, OccupancyMap
from skyrecon.mapping.rays import camera_rays
from skyrecon.perception import DepthFrame, GroundPlane, PerceptionSettings, StereoDepth
from skyrecon.stereo import Matcher
from skyrecon.threads import available_cores, kernel_threads

_PERCEPTION_FIELDS = frozenset(f.name for f in fields(PerceptionSettings))

#: :meth:`StereoMapper.resume_state`: map, guesses' support, timings, ground level, ground support
ResumeState = tuple[OccupancyMap, FrameSupport | None, FrameTimings, GroundLevel | None, FrameSupport | None]


@dataclass(frozen=True)
class StereoMapSettings:
    """How stereo frames become map updates.

    Attributes:
        voxel_size_m: voxel edge, metres.
        max_range_m: measurements farther than this carve free space only, metres (the map's
            range is further limited to the trusted range of the rig, see
            :meth:`PerceptionSettings.hit_range_m`).
        perception: the stereo-to-depth rules (matcher, measured pixels, discontinuity filter,
            resolution, trusted range); default :meth:`PerceptionSettings.mapping`.
        prob_hit, prob_miss: the map's sensor model (see :class:`MapConfig`).
        surface_pull_voxels: the map takes each measured surface this many voxels nearer the
            camera (see :class:`MapConfig`): stereo noise behind a surface cannot be cleared.
        guess_min_frames: with ``perception.guesses``, the matcher's untrusted values (filled,
            or smoothed over plain surfaces) become hits, never free space, in the voxels that
            the guesses of at least this many frames fall into (:class:`FrameSupport`);
            0: not used.
        ground: with ``perception.guesses``, the guesses that agree with the ground level
            learnt over the flight become hits just under the ground plane (never free space)
            where two frames agree (:mod:`skyrecon.mapping.ground_level`): plain streets and
            squares on flat terrain. On by default (``skyrecon map --no-flat-ground`` turns it
            off; None here). It was off while the matcher's guesses over plain streets were
            1.3 px off (no horizontal paths) and the level was often missing: on plain seeds 1,
            3 and 4 of the stereo map benchmark the default map then held 0-29 % of the street
            voxels observed within 20 m, and now 16-89 %. What it risks: a level found too
            high puts a layer of hits just above the street, never above the guesses' own
            agreement with that level (a wrong level finds few guesses that agree).
        ground_plane_fill: with ``ground``, the plane fill of each frame is also given the
            ground plane of the level learnt from the frames before the previous one (``ground``
            of :meth:`~skyrecon.perception.StereoDepth.compute`; the same frames with or without
            ``overlap``): a plain segment whose measured border agrees with it (a plain street
            between its kerbs) takes it, and within the trusted range its pixels become ground
            pixels (hits half a voxel under the plane where two frames agree; never free space,
            nor the level's own evidence), whatever the matcher's values inside
            (``plane_prior_guess_check`` off in :meth:`PerceptionSettings.mapping`); beyond that
            range the matcher's values there stay guesses (the level's error of a few decimetres
            puts far hits a voxel layer off). Under a camera's noise the matcher's values on a
            plain street are the noise's (1.5 grey levels, plain seed 1 of
            ``benchmarks/mapping/stereo_map.py``: 12 % of the street pixels within 20 m agreed
            with the level, 65 % without noise), so the guesses alone left it unmapped: seed 1's
            recall within 20 m went 0.511 -> 0.643 of OctoMap+SGBM's, the other plain seeds
            within +0.01, precision unchanged. Without noise the street's guesses mostly agree
            already; plain seed 1 lost 24 of its street voxels (the plane's hits, under a level
            one frame older, stand where the guesses' stood: 1.098 -> 1.077x), the other seeds
            moved by at most 0.006.
    """

    voxel_size_m: float = 0.2
    max_range_m: float = 40.0
    perception: PerceptionSettings = field(default_factory=PerceptionSettings.mapping)
    prob_hit: float = 0.6
    prob_miss: float = 0.35
    surface_pull_voxels: float = 0.2
    guess_min_frames: int = 3
    ground: GroundSettings | None = field(default_factory=GroundSettings)
    ground_plane_fill: bool = True

    def __post_init__(self) -> None:
        if not (np.isfinite(self.voxel_size_m) and self.voxel_size_m > 0):
            raise InputError(f"voxel size must be positive, got {self.voxel_size_m} m")
        if not (np.isfinite(self.max_range_m) and self.max_range_m > 0):
            raise InputError(f"max range must be positive, got {self.max_range_m} m")
        if self.guess_min_frames != 0 and self.guess_min_frames < 2:
            raise InputError(f"guess_min_frames must be 0 (off) or at least 2, got {self.guess_min_frames}")

    def with_overrides(self, **overrides: Any) -> StereoMapSettings:
        """A copy with fields replaced; names of :class:`PerceptionSettings` fields (e.g.
        ``max_disparity=64``, ``max_depth_error_m=1.0``) go to ``perception``."""
        unknown = set(overrides) - _PERCEPTION_FIELDS - {f.name for f in fields(self)}
        if unknown:
            raise InputError(f"unknown stereo map setting(s): {', '.join(sorted(unknown))}")
        p = {k: v for k, v in overrides.items() if k in _PERCEPTION_FIELDS}
        own = {k: v for k, v in overrides.items() if k not in _PERCEPTION_FIELDS}
        perception = replace(own.pop("perception", self.perception), **p)
        return replace(self, perception=perception, **own)

    def hit_range_m(self, rig: StereoRig) -> float:
        """The map's maximum range for this rig, metres (see :meth:`PerceptionSettings.hit_range_m`)."""
        return self.perception.hit_range_m(rig, self.voxel_size_m, self.max_range_m)


@dataclass
class StereoFrameResult:
    """One frame through :meth:`StereoMapper.add_frame`.

    Attributes:
        depth_m: (H, W) float32 depth used, metres along the left optical axis (NaN: none).
        stats: what the integration did; None when it comes later (``StereoMapper.overlap``).
        depth_s, integrate_s: wall time of stereo + depth and of the map update (or of the wait
            for the previous frame's update), seconds.
        disparity: (H, W) float32 disparity of the matcher, pixels, NaN invalid.
    """

    depth_m: np.ndarray
    stats: IntegrationStats | None
    depth_s: float
    integrate_s: float
    disparity: np.ndarray | None = None


class StereoMapper:
    """Builds an occupancy map from the frames of a rectified stereo sequence, one at a time.

    Args:
        rig: the rectified rig (``rig.left`` is the camera the poses and depth refer to).
        settings: :class:`StereoMapSettings`; keyword overrides are applied on top (see
            :meth:`StereoMapSettings.with_overrides`).
        config: optional base :class:`MapConfig` of the map (its voxel size, range and
            hit / miss probabilities are replaced by the settings').
        matcher: optional matcher to use instead of building one from the settings (e.g. one
            already warmed up by another mapper).
        overlap: integrate each frame into the map on a second thread while the next frame's
            depth is finished (see :meth:`add_frame`); None: when there is more than one core.
            The map is the same either way (the frames are integrated in order).
    Attributes:
        map: the :class:`OccupancyMap` being built (range = :meth:`StereoMapSettings.hit_range_m`),
            with every frame added so far (reading it waits for a frame still being integrated).
        stereo: the :class:`StereoDepth` stage.
        ground: the :class:`GroundLevel` learnt so far, or None (as up to date as ``map``).
        timings: per-frame wall times.
    The :class:`FrameSupport` of the guesses and of the ground pixels are in
    :meth:`resume_state`.
    """

    def __init__(
        self,
        rig: StereoRig,
        settings: StereoMapSettings | None = None,
        config: MapConfig | None = None,
        matcher: Matcher | None = None,
        overlap: bool | None = None,
        **overrides: Any,
    ):
        s = settings or StereoMapSettings()
        if overrides:
            s = s.with_overrides(**overrides)
        if not rig.is_rectified:
            raise InputError("the stereo rig is not rectified; a stereo map needs a rectified sequence")
        self.rig = rig
        self.settings = s
        self.stereo = StereoDepth(rig, s.perception, matcher)
        self.hit_range_m = s.hit_range_m(rig)
        base = (config or MapConfig()).to_dict()
        base.update(
            voxel_size_m=s.voxel_size_m,
            max_range_m=self.hit_range_m,
            prob_hit=s.prob_hit,
            prob_miss=s.prob_miss,
            surface_pull_voxels=s.surface_pull_voxels,
            max_plausible_depth_m=STEREO_PLAUSIBLE_DEPTH_M,  # its own stereo: metres
        )
        self._map = OccupancyMap(MapConfig.from_dict(base))
        self._support = (
            FrameSupport(self._map, s.guess_min_frames, self.hit_range_m)
            if s.guess_min_frames and s.perception.guesses
            else None
        )
        use_ground = s.ground is not None and s.perception.guesses
        self._ground = GroundLevel(s.ground, self.hit_range_m) if use_ground else None
        ground_range_m = self.hit_range_m
        if use_ground and s.ground is not None and s.ground.beyond_trusted:
            ground_range_m = min(s.max_range_m, 2.0 * self.hit_range_m)
        self._ground_support = (
            FrameSupport(self._map, 2, ground_range_m, pixel_step=4, next_to_occupied=False)
            if use_ground
            else None
        )
        self.timings = FrameTimings()
        self.overlap = available_cores() > 1 if overlap is None else bool(overlap)
        # depth not yet in the map: the frame, its pose and the ground plane its fill was given
        self._pending: tuple[DepthFrame, Rigid3, GroundPlane | None] | None = None
        self._updater: ThreadPoolExecutor | None = None  # the thread that updates the map (overlap)

    @property
    def map(self) -> OccupancyMap:
        self.flush()
        return self._map

    @property
    def ground(self) -> GroundLevel | None:
        self.flush()
        return self._ground

    def resume_state(self) -> ResumeState:
        """What a checkpoint must hold to resume this mapper: the map, the guesses' support
        (which refers to the map), the timings, and the ground level with its support
        (picklable), with every frame added so far."""
        self.flush()
        return self._map, self._support, self.timings, self._ground, self._ground_support

    def restore(self, state: ResumeState) -> None:
        """Take back a :meth:`resume_state` (of a mapper with the same rig and settings)."""
        self._pending = None
        self._map, self._support, self.timings, self._ground, self._ground_support = state

    def flush(self) -> None:
        """Integrate the frame :meth:`add_frame` left for later, if any (its wall time is added
        to that frame's ``timings.integrate_s``)."""
        if self._pending is None:
            return
        t0 = time.perf_counter()
        waiting = self._pending
        self._pending = None
        self._integrate(*waiting)
        if self.timings.integrate_s:
            self.timings.integrate_s[-1] += time.perf_counter() - t0

    @property
    def matcher(self) -> Matcher:
        """The stereo matcher (created, and warmed up, on first use)."""
        return self.stereo.matcher

    def depth(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """(h, w) float32 depth, metres along the left optical axis, NaN where not kept
        (see :class:`skyrecon.perception.StereoDepth`).

        Args:
            left, right: (H, W, 3) uint8 RGB (or grey) rectified images of the rig.
        """
        return self.stereo.depth(left, right)

    def add_frame(
        self, left: np.ndarray, right: np.ndarray, world_from_left: Rigid3 | np.ndarray
    ) -> StereoFrameResult:
        """Stereo depth of one rectified pair, integrated at pose ``world_from_left`` (world metres).

        With ``overlap`` the frame is integrated later: while the matcher of the next frame is
        done (it uses every core), the rest of that frame's depth (single-threaded) runs beside
        this frame's map update on a second thread, which then runs its kernels on one thread.
        Reading ``map`` (or :meth:`flush`) integrates a frame still waiting. The result's
        ``stats`` are then None, its ``depth_s`` is this frame's depth (with the previous
        frame's update running beside it), ``integrate_s`` the wait for that update after it.
        On the stereo map benchmark's flights (2 cores, 640x480, 128 disparities) this takes
        a frame from about 58 to 50 ms.
        """
        t0 = time.perf_counter()
        pose = as_world_from_cam(world_from_left)  # checked now: its frame is integrated later
        waiting, self._pending = self._pending, None
        update: list[Future[IntegrationStats]] = []

        def start_update() -> None:  # once the matcher is done
            if waiting is not None:
                update.append(self._update_thread().submit(self._integrate_on_one_thread, *waiting))

        try:
            ground = self._ground_plane(pose)
            frame = self.stereo.compute(left, right, after_match=start_update, ground=ground)
        finally:
            t1 = time.perf_counter()
            if update:
                update[0].result()  # re-raises what the update raised
            elif waiting is not None:  # the matcher failed: update here
                self._integrate(*waiting)
        stats = None
        if self.overlap:
            self._pending = (frame, pose, ground)
        else:
            stats = self._integrate(frame, pose, ground)
        t2 = time.perf_counter()
        self.timings.depth_s.append(t1 - t0)
        self.timings.integrate_s.append(t2 - t1)
        return StereoFrameResult(frame.depth_m, stats, t1 - t0, t2 - t1, frame.disparity)

    def _ground_plane(self, world_from_left: Rigid3) -> GroundPlane | None:
        """The ground plane for the next frame's plane fill: the level learnt from the frames
        up to the one before the previous (the previous one may still be being integrated
        with ``overlap``; the same frames either way, so the map does not depend on it), None
        while there is none or without the ground level."""
        if self._ground is None or not self.settings.ground_plane_fill:
            return None
        z_m = self._ground.level_after(len(self.timings.depth_s) - 1)
        return None if z_m is None else GroundPlane.from_pose(world_from_left, z_m)

    def _update_thread(self) -> ThreadPoolExecutor:
        if self._updater is None:
            self._updater = ThreadPoolExecutor(max_workers=1, thread_name_prefix="skyrecon-map-update")
        return self._updater

    def _integrate_on_one_thread(
        self, frame: DepthFrame, world_from_left: Rigid3, ground: GroundPlane | None = None
    ) -> IntegrationStats:
        """:meth:`_integrate` with its Numba kernels on one thread (the other cores are the
        caller's, finishing the next frame's depth)."""
        with kernel_threads(1):
            return self._integrate(frame, world_from_left, ground)

    def _ground_segments(
        self, frame: DepthFrame, ground: GroundPlane | None
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """``(depth, guess, ground_guess, on_plane)`` of a frame whose plane fill was given
        ``ground``: the plain segments that took its plane (``frame.from_ground``) leave the
        depth (no free space, no evidence of the level); within the trusted range they are
        ``on_plane`` ((h, w) their depth, NaN elsewhere: their border's disparities, the
        evidence, are measured there; farther, the level's error puts the hits a voxel layer
        off); everywhere else the matcher's values on them are guesses, as without the plane
        (``guess`` for the guesses' support, ``ground_guess`` for the level's). Without such
        segments: the frame's depth and guesses, ``on_plane`` None."""
        depth, guess = frame.depth_m, frame.guess_depth_m
        if ground is None or frame.from_ground is None or not frame.from_ground.any():
            return depth, guess, guess, None
        v, u = np.nonzero(frame.from_ground)
        _, range_per_depth = camera_rays(self.stereo.intrinsics)
        plane = depth[v, u]
        near = plane * range_per_depth[v, u] <= self.hit_range_m
        nan = np.float32(np.nan)
        on_plane = np.full(depth.shape, nan, np.float32)
        on_plane[v[near], u[near]] = plane[near]
        depth = depth.copy()
        depth[v, u] = nan
        ground_guess = guess
        if guess is not None and frame.disparity is not None:
            guess = guess.copy()
            guess[v, u] = self.rig.disparity_to_depth(frame.disparity[v, u][None])[0]
            ground_guess = guess.copy()
            ground_guess[v[near], u[near]] = nan
        return depth, guess, ground_guess, on_plane

    def _integrate(
        self, frame: DepthFrame, world_from_left: Rigid3, ground: GroundPlane | None = None
    ) -> IntegrationStats:
        """The map update of one frame's depth: hits and misses, the guesses' support, the
        ground level and its support. ``ground``: the plane the frame's plane fill was given
        (see :meth:`_ground_plane`); the segments that took it are ground pixels."""
        depth, guess, ground_guess, on_plane = self._ground_segments(frame, ground)
        intr = self.stereo.intrinsics
        stats = self._map.integrate_depth(depth, intr, world_from_left)
        if self._support is not None and guess is not None:
            self._support.add(guess, intr, world_from_left)
        if self._ground is not None and self._ground_support is not None:
            self._ground.add(depth, intr, world_from_left, frame.from_plane)
            below = self._ground.settings.below_voxels * self._map.voxel_size
            step = self._ground_support.step  # only the pixels the support reads
            on_ground = None
            if ground_guess is not None:
                fb = self.rig.left.fx * self.rig.baseline_m
                on_ground = self._ground.ground_depth(ground_guess, intr, world_from_left, fb, below, step)
            if on_plane is not None and ground is not None:  # (set together)
                # the plane the fill took, ``below`` under it along the same rays
                deeper = on_plane[::step, ::step] * np.float32((ground.height_m + below) / ground.height_m)
                on_ground = deeper if on_ground is None else np.where(np.isfinite(deeper), deeper, on_ground)
            if on_ground is not None:
                self._ground_support.add(on_ground, intr, world_from_left, strided=True)
        return stats


def map_stereo_sequence(
    frames: Iterable[tuple[np.ndarray, np.ndarray]],
    rig: StereoRig,
    world_from_left: Sequence[Rigid3 | np.ndarray],
    settings: StereoMapSettings | None = None,
    progress: Callable[[int, int], None] | None = None,
    *,
    mapper: StereoMapper | None = None,
    first_frame: int = 0,
    after_frame: Callable[[int, StereoMapper], object] | None = None,
    on_frame: Callable[[MappedFrame], None] | None = None,
    **overrides: Any,
) -> StereoMapper:
    """Build an occupancy map from a rectified stereo sequence.

    Args:
        frames: (left, right) image pairs, (H, W, 3) uint8 RGB, in frame order (e.g. a
            generator reading them from disk).
        rig: the rectified rig.
        world_from_left: one left-camera pose per frame (``p_world = R p_left + t``, metres);
            frames beyond the poses are refused.
        settings: :class:`StereoMapSettings`; keyword overrides on top.
        progress: optional ``progress(i, n)`` after each frame.
        mapper: resume with this mapper (e.g. restored from a checkpoint, see
            :meth:`StereoMapper.resume_state`) instead of a new one; ``settings`` are then unused.
        first_frame: index of the first frame ``frames`` yields (the frames before it are
            already in ``mapper``).
        after_frame: optional ``after_frame(done, mapper)`` after each frame (``done`` frames
            are in the map), e.g. to write a checkpoint.
        on_frame: optional observer called with each :class:`MappedFrame` (image, disparity
            and depth; not timed).
    Returns:
        The :class:`StereoMapper`: ``.map`` the map, ``.timings`` the per-frame times.
    Raises:
        InputError: more frames than poses, no frame, or bad images / poses (the message names
            the frame).
    """
    if mapper is None:
        mapper = StereoMapper(rig, settings, **overrides)
    mapper.stereo.warm_up()  # the matcher and the plane fill's kernels, before the first frame is timed
    n = len(world_from_left)
    i = first_frame - 1
    for i, (left, right) in enumerate(frames, start=first_frame):
        if i >= n:
            raise InputError(f"frame {i}: there are only {n} poses; give one world_from_left pose per frame")
        try:
            result = mapper.add_frame(left, right, world_from_left[i])
        except InputError as exc:
            raise InputError(f"frame {i}: {exc}") from None
        if on_frame is not None:
            pose = as_rigid(world_from_left[i])
            depth, camera = result.depth_m, mapper.stereo.intrinsics
            on_frame(MappedFrame(i, depth, camera, pose, mapper.map, left, result.disparity))
        if progress is not None:
            progress(i + 1, n)
        if after_frame is not None:
            after_frame(i + 1, mapper)
    if i < 0:
        raise InputError("no stereo frames to build a map from")
    mapper.flush()  # the last frame, into the map and its time into the timings
    return mapper
