"""Occupancy map from a sequence of posed depth images, streamed frame by frame.

What ``skyrecon map SEQUENCE --depth SUBDIR`` runs (the command reads the depth files lazily,
see :mod:`skyrecon.io.depth_dir`). Depth: (H, W) float32 metres along the optical axis, NaN
invalid; poses ``world_from_cam`` (world frame z up, metres).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError
from skyrecon.mapping.config import MapConfig
from skyrecon.mapping.occupancy import OccupancyMap


@dataclass
class FrameTimings:
    """Per-frame wall times of a map built frame by frame, seconds (lists in frame order).

    Attributes:
        depth_s: getting the frame's depth (stereo, or reading it).
        integrate_s: the map update.
    """

    depth_s: list[float] = field(default_factory=list)
    integrate_s: list[float] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
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


@dataclass
class MappedFrame:
    """One frame just integrated into a map, for an observer (e.g. a recording).

    Attributes:
        index: frame index from 0.
        depth_m: (h, w) float32 depth integrated, metres along the optical axis, NaN invalid.
        camera: the pinhole of ``depth_m``.
        world_from_cam: the frame's pose (``p_world = R p_cam + t``, metres).
        map: the map after this frame.
        image: (H, W, 3) uint8 RGB left image, when the frame has one at hand.
        disparity: (H, W) float32 disparity of a stereo frame, pixels, NaN invalid.
    """

    index: int
    depth_m: np.ndarray
    camera: Intrinsics
    world_from_cam: Rigid3
    map: OccupancyMap
    image: np.ndarray | None = None
    disparity: np.ndarray | None = None


def as_rigid(pose: Rigid3 | np.ndarray) -> Rigid3:
    """A pose given as :class:`Rigid3` or a (4, 4) / (3, 4) matrix, as :class:`Rigid3`."""
    return pose if isinstance(pose, Rigid3) else Rigid3.from_matrix(np.asarray(pose, dtype=np.float64))


@dataclass
class DepthSequenceMap:
    """A map built by :func:`map_depth_sequence`.

    Attributes:
        map: the occupancy map (world frame, metres).
        timings: per-frame wall times (``depth_s``: time to get each depth image from the iterable).
    """

    map: OccupancyMap
    timings: FrameTimings


def map_depth_sequence(
    depths: Iterable[np.ndarray],
    camera: Intrinsics,
    world_from_cam: Sequence[Rigid3 | np.ndarray],
    config: MapConfig | None = None,
    progress: Callable[[int, int], None] | None = None,
    *,
    resume: DepthSequenceMap | None = None,
    first_frame: int = 0,
    after_frame: Callable[[int, DepthSequenceMap], object] | None = None,
    on_frame: Callable[[MappedFrame], None] | None = None,
) -> DepthSequenceMap:
    """Build an occupancy map from depth images of one camera, one frame at a time.

    Args:
        depths: (H, W) float32 depth images, metres, in frame order (e.g. a generator reading
            them from disk: only one is held at a time).
        camera: the camera of every depth image.
        world_from_cam: one pose per frame (``p_world = R p_cam + t``, metres); frames beyond
            the poses are refused.
        config: the map's settings.
        progress: optional ``progress(i, n)`` after each frame.
        resume: go on from this (map, timings) of the frames before ``first_frame`` (e.g. from
            a checkpoint); ``config`` is then unused.
        first_frame: index of the first frame ``depths`` yields.
        after_frame: optional ``after_frame(done, built)`` after each frame (``done`` frames are
            in the map), e.g. to write a checkpoint.
        on_frame: optional observer called with each :class:`MappedFrame` (not timed).
    Raises:
        InputError: more frames than poses, no frame, bad depth or poses (the message names the frame).
    """
    built = resume if resume is not None else DepthSequenceMap(OccupancyMap(config), FrameTimings())
    occ, timings = built.map, built.timings
    n = len(world_from_cam)
    frames = iter(depths)
    i = first_frame
    while True:
        t0 = time.perf_counter()
        depth = next(frames, None)
        if depth is None:
            break
        if i >= n:
            raise InputError(f"frame {i}: there are only {n} poses; give one world_from_cam pose per frame")
        t1 = time.perf_counter()
        try:
            occ.integrate_depth(depth, camera, world_from_cam[i])
        except InputError as exc:
            raise InputError(f"frame {i}: {exc}") from None
        timings.depth_s.append(t1 - t0)
        timings.integrate_s.append(time.perf_counter() - t1)
        if on_frame is not None:
            on_frame(MappedFrame(i, depth, camera, as_rigid(world_from_cam[i]), occ))
        i += 1
        if progress is not None:
            progress(i, n)
        if after_frame is not None:
            after_frame(i, built)
    if i == 0:
        raise InputError("no depth frames to build a map from")
    return built
