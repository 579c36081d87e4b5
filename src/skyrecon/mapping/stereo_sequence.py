"""Occupancy map from a rectified stereo sequence: stereo -> depth -> map, frame by frame.

This is what ``skyrecon map SEQUENCE_DIR`` runs (the command only reads the files and writes
the map), as a library stage. Per frame:

1. disparity of the rectified pair with a stereo matcher (full-resolution ``skyrecon`` with a
   uniqueness test by default), kept between frames;
2. only *measured* disparities are used: pixels the matcher filled by interpolation are
   guesses, and pixels at a disparity discontinuity (their 3x3 neighbourhood spans more than
   ``max_disparity_step_px``) are dropped, because smoothing puts them in the air between the
   foreground and the background: both would become phantom obstacles;
3. depth ``Z = f B / (d + doffs)`` and projective integration into an :class:`OccupancyMap`
   whose range is limited to the *trusted range* of the rig (:func:`stereo_hit_range_m`):
   a disparity error of ``disparity_error_px`` moves depth by at most ``max_depth_error_m``
   (2 voxels by default) up to that range. Farther measurements carve free space up to the
   trusted range and give no hit, so far-range stereo noise cannot create obstacles;
4. the map's sensor model trusts a single hit less than OctoMap's default (``prob_hit`` 0.6,
   ``prob_miss`` 0.35 instead of 0.7 / 0.4): stereo noise scatters hits into the voxels in front
   of a surface, and the misses of the other frames that see through them now clear them.

On the synthetic city (``benchmarks/mapping/stereo_map.py``) steps 1, 2 and 4 raise the
occupied-voxel precision at 0.5 m from about 0.71 to 0.84 at the same recall within 20 m.

Frames and units: images (H, W, 3) uint8 RGB of a rectified rig; poses ``world_from_left``
(world frame z up, metres); depth (H, W) float32 metres along the left optical axis, NaN invalid.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from skyrecon.core.rigid import Rigid3
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError
from skyrecon.mapping.config import MapConfig
from skyrecon.mapping.occupancy import IntegrationStats, OccupancyMap


@dataclass(frozen=True)
class StereoMapSettings:
    """How stereo frames become map updates.

    Attributes:
        voxel_size_m: voxel edge, metres.
        max_range_m: measurements farther than this carve free space only, metres (the map's
            range is further limited to the trusted range of the rig).
        method: stereo matcher name (see :func:`skyrecon.stereo.available_matchers`).
        max_disparity: disparity search range, pixels.
        matcher_settings: settings of the matcher (see :func:`skyrecon.stereo.create_matcher`);
            None: ``{"uniqueness": 0.05}`` for the skyrecon matchers, nothing for the others.
        max_disparity_step_px: drop pixels whose 3x3 neighbourhood spans more disparity than
            this, pixels (depth discontinuities); None keeps them.
        max_depth_error_m: obstacles are marked only where a ``disparity_error_px`` disparity
            error moves depth by less than this, metres; None: 2 voxels.
        disparity_error_px: the disparity error assumed for the trusted range, pixels.
        use_filled: also integrate pixels the matcher filled by interpolation (off: they are
            guesses, not measurements).
        prob_hit, prob_miss: the map's sensor model (see :class:`MapConfig`).
    """

    voxel_size_m: float = 0.2
    max_range_m: float = 40.0
    method: str = "skyrecon"
    max_disparity: int = 128
    matcher_settings: dict | None = None
    max_disparity_step_px: float | None = 1.0
    max_depth_error_m: float | None = None
    disparity_error_px: float = 0.25
    use_filled: bool = False
    prob_hit: float = 0.6
    prob_miss: float = 0.35

    def __post_init__(self) -> None:
        if not (np.isfinite(self.voxel_size_m) and self.voxel_size_m > 0):
            raise InputError(f"voxel size must be positive, got {self.voxel_size_m} m")
        if not (np.isfinite(self.max_range_m) and self.max_range_m > 0):
            raise InputError(f"max range must be positive, got {self.max_range_m} m")
        if self.max_depth_error_m is not None and not self.max_depth_error_m > 0:
            raise InputError(f"max depth error must be positive, got {self.max_depth_error_m} m")
        if not self.disparity_error_px > 0:
            raise InputError(f"disparity error must be positive, got {self.disparity_error_px} px")
        if self.max_disparity_step_px is not None and not self.max_disparity_step_px > 0:
            raise InputError(f"max disparity step must be positive, got {self.max_disparity_step_px} px")

    def matcher_kwargs(self) -> dict:
        """The settings passed to :func:`skyrecon.stereo.create_matcher`."""
        if self.matcher_settings is not None:
            return dict(self.matcher_settings)
        return {"uniqueness": 0.05} if self.method in ("skyrecon", "skyrecon-fast") else {}

    def hit_range_m(self, rig: StereoRig) -> float:
        """The map's maximum range for this rig, metres (see :func:`stereo_hit_range_m`)."""
        return stereo_hit_range_m(
            rig, self.voxel_size_m, self.max_range_m, self.max_depth_error_m, self.disparity_error_px
        )


def stereo_hit_range_m(
    rig: StereoRig,
    voxel_size_m: float,
    max_range_m: float,
    max_depth_error_m: float | None = None,
    disparity_error_px: float = 0.25,
) -> float:
    """Range up to which stereo measurements may mark obstacles, metres.

    ``min(max_range_m, trusted_range_m(rig, max_depth_error_m or 2 * voxel_size_m, disparity_error_px))``.
    """
    from skyrecon.stereo import trusted_range_m

    err = max_depth_error_m if max_depth_error_m is not None else 2.0 * voxel_size_m
    return float(min(max_range_m, trusted_range_m(rig, err, disparity_error_px)))


def disparity_discontinuities(disparity: np.ndarray, max_step_px: float) -> np.ndarray:
    """(H, W) bool: pixels whose 3x3 neighbourhood spans more than ``max_step_px`` of disparity.

    Args:
        disparity: (H, W) float32 pixels, NaN invalid (an invalid neighbour counts as 0, so the
            pixels bordering invalid ones are flagged too).
    """
    import cv2

    d = np.nan_to_num(np.asarray(disparity, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    k = np.ones((3, 3), np.uint8)
    return (cv2.dilate(d, k) - cv2.erode(d, k)) > max_step_px


@dataclass
class StereoFrameResult:
    """One frame through :meth:`StereoMapper.add_frame`.

    Attributes:
        depth_m: (H, W) float32 depth used, metres along the left optical axis (NaN: none).
        stats: what the integration did.
        depth_s, integrate_s: wall time of stereo + depth and of the map update, seconds.
    """

    depth_m: np.ndarray
    stats: IntegrationStats
    depth_s: float
    integrate_s: float


@dataclass
class StereoMapTimings:
    """Per-frame wall times, seconds (lists in frame order)."""

    depth_s: list[float] = field(default_factory=list)
    integrate_s: list[float] = field(default_factory=list)

    def summary(self) -> dict:
        """Medians in milliseconds and frames per second (of the median total)."""
        if not self.depth_s:
            return {"frames": 0}
        total = np.add(self.depth_s, self.integrate_s)
        return {
            "frames": len(total),
            "frames_per_s": round(float(1.0 / max(np.median(total), 1e-9)), 2),
            "median_ms": {
                "depth": round(1000 * float(np.median(self.depth_s)), 1),
                "integration": round(1000 * float(np.median(self.integrate_s)), 1),
            },
        }


class StereoMapper:
    """Builds an occupancy map from the frames of a rectified stereo sequence, one at a time.

    Args:
        rig: the rectified rig (``rig.left`` is the camera the poses and depth refer to).
        settings: :class:`StereoMapSettings`; keyword overrides are applied on top.
        config: optional base :class:`MapConfig` of the map (its voxel size, range and
            hit / miss probabilities are replaced by the settings').
        matcher: optional matcher to use instead of building one from the settings (e.g. one
            already warmed up by another mapper).
    Attributes:
        map: the :class:`OccupancyMap` being built (range = :meth:`StereoMapSettings.hit_range_m`).
        timings: per-frame wall times.
    """

    def __init__(
        self,
        rig: StereoRig,
        settings: StereoMapSettings | None = None,
        config: MapConfig | None = None,
        matcher=None,
        **overrides,
    ):
        s = settings or StereoMapSettings()
        if overrides:
            s = StereoMapSettings(**{**asdict(s), **overrides})
        if not rig.is_rectified:
            raise InputError("the stereo rig is not rectified; a stereo map needs a rectified sequence")
        self.rig = rig
        self.settings = s
        self.hit_range_m = s.hit_range_m(rig)
        base = (config or MapConfig()).to_dict()
        base.update(
            voxel_size_m=s.voxel_size_m,
            max_range_m=self.hit_range_m,
            prob_hit=s.prob_hit,
            prob_miss=s.prob_miss,
        )
        self.map = OccupancyMap(MapConfig.from_dict(base))
        self.timings = StereoMapTimings()
        self._matcher = matcher

    @property
    def matcher(self):
        """The stereo matcher (created, and warmed up, on first use)."""
        if self._matcher is None:
            from skyrecon.stereo import create_matcher

            self._matcher = create_matcher(
                self.settings.method, self.settings.max_disparity, **self.settings.matcher_kwargs()
            )
            if hasattr(self._matcher, "warmup"):
                self._matcher.warmup()
        return self._matcher

    def depth(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """(H, W) float32 depth, metres along the left optical axis, NaN where not measured.

        Args:
            left, right: (H, W, 3) uint8 RGB (or grey) rectified images of the rig.
        """
        from skyrecon.stereo import disparity_to_depth

        result = self.matcher.compute(left, right)
        keep = result.valid if self.settings.use_filled else result.measured
        step = self.settings.max_disparity_step_px
        if step is not None:
            keep &= ~disparity_discontinuities(result.disparity, step)
        return disparity_to_depth(np.where(keep, result.disparity, np.float32(np.nan)), self.rig)

    def add_frame(
        self, left: np.ndarray, right: np.ndarray, world_from_left: Rigid3 | np.ndarray
    ) -> StereoFrameResult:
        """Stereo depth of one rectified pair, integrated at pose ``world_from_left`` (world metres)."""
        t0 = time.perf_counter()
        depth = self.depth(left, right)
        t1 = time.perf_counter()
        stats = self.map.integrate_depth(depth, self.rig.left, world_from_left)
        t2 = time.perf_counter()
        self.timings.depth_s.append(t1 - t0)
        self.timings.integrate_s.append(t2 - t1)
        return StereoFrameResult(depth, stats, t1 - t0, t2 - t1)


def map_stereo_sequence(
    frames: Iterable[tuple[np.ndarray, np.ndarray]],
    rig: StereoRig,
    world_from_left: Sequence[Rigid3 | np.ndarray],
    settings: StereoMapSettings | None = None,
    progress: Callable[[int, int], None] | None = None,
    **overrides,
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
    Returns:
        The :class:`StereoMapper`: ``.map`` the map, ``.timings`` the per-frame times.
    Raises:
        InputError: more frames than poses, no frame, or bad images / poses (the message names
            the frame).
    """
    mapper = StereoMapper(rig, settings, **overrides)
    n = len(world_from_left)
    i = -1
    for i, (left, right) in enumerate(frames):
        if i >= n:
            raise InputError(f"frame {i}: there are only {n} poses; give one world_from_left pose per frame")
        try:
            mapper.add_frame(left, right, world_from_left[i])
        except InputError as exc:
            raise InputError(f"frame {i}: {exc}") from None
        if progress is not None:
            progress(i + 1, n)
    if i < 0:
        raise InputError("no stereo frames to build a map from")
    return mapper
