"""What the sequence commands log: a map built frame by frame (``skyrecon map``), a visual
odometry run (``skyrecon odometry``).

Names (see :mod:`skyrecon.record.recorder`); ``frame`` is the frame index and ``time`` its
timestamp in seconds (the index times 0.1 s when the sequence has none):

* ``camera``: the left camera at the frame's pose, every frame, with its image every
  ``image_every`` frames; its depth (and disparity for stereo) every ``depth_every`` frames;
* ``map/occupied``: the map's occupied voxels every ``map_every`` frames and at the end;
* ``path/camera``: the camera track so far (at each voxel snapshot and at the end);
* odometry: ``camera`` at each frame's online estimate (as above, no depth);
  ``path/odometry`` the online track every ``map_every`` frames, then the refined one at the end;
  ``path/fused`` with GPS; ``path/truth`` the ground truth when the sequence has one.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.record.recorder import Recorder

TRACK_RGB = (0, 200, 255)
TRUTH_RGB = (120, 255, 120)


def frame_time(timestamps_s: Sequence[float] | np.ndarray | None, i: int) -> float:
    """Seconds of frame ``i``: its timestamp, or ``0.1 * i`` when there is none."""
    if timestamps_s is not None and i < len(timestamps_s) and np.isfinite(timestamps_s[i]):
        return float(timestamps_s[i])
    return 0.1 * i


class MapRecording:
    """An ``on_frame`` observer of :func:`~skyrecon.mapping.map_stereo_sequence` and
    :func:`~skyrecon.mapping.map_depth_sequence` that logs to ``recorder``.

    Args:
        recorder: where to log.
        timestamps_s: the frames' timestamps, seconds (None: 10 frames a second).
        max_disparity: the disparity colour scale's top, pixels (None: per image).
        image_of: for frames without an image at hand (depth maps), ``image_of(i)`` gives frame
            ``i``'s (H, W, 3) uint8 left image; called only for the frames whose image is logged.
    """

    def __init__(
        self,
        recorder: Recorder,
        timestamps_s: Sequence[float] | np.ndarray | None = None,
        max_disparity: float | None = None,
        image_of: Callable[[int], np.ndarray] | None = None,
    ):
        self.r = recorder
        self.image_of = image_of
        self.timestamps_s = timestamps_s
        self.max_disparity = max_disparity
        self.track: list[np.ndarray] = []
        self.last: tuple[float, int] = (0.0, 0)

    def __call__(self, frame: Any) -> None:
        """Log one :class:`~skyrecon.mapping.MappedFrame`."""
        r, s = self.r, self.r.settings
        i = int(frame.index)
        self.last = (frame_time(self.timestamps_s, i), i)
        r.set_time(*self.last)
        image = None
        if i % s.image_every == 0:
            image = frame.image if frame.image is not None or self.image_of is None else self.image_of(i)
        camera: Intrinsics = frame.camera
        if image is not None and image.shape[:2] != camera.shape:  # strided depth: the image's camera
            camera = camera.scaled(image.shape[1] / camera.width)
        r.log_camera("camera", camera, frame.world_from_cam, image)
        if i % s.depth_every == 0:
            r.log_depth("camera", frame.depth_m, frame.camera)
            if frame.disparity is not None:
                r.log_disparity("camera", frame.disparity, self.max_disparity)
        self.track.append(np.asarray(frame.world_from_cam.t, float).copy())
        if i % s.map_every == 0:
            self._snapshot(frame.map)

    def _snapshot(self, occ_map: Any) -> None:
        if len(self.track) >= 2:
            self.r.log_path("path/camera", np.array(self.track), TRACK_RGB)
        self.r.log_voxels("map/occupied", occ_map.occupied_centers(), occ_map.voxel_size)

    def finish(self, occ_map: Any) -> None:
        """Log the final map (after e.g. the flown track is marked free) and the whole track."""
        self.r.set_time(*self.last)
        self._snapshot(occ_map)


def log_trajectory(
    recorder: Recorder,
    name: str,
    world_from_cam: Sequence[Rigid3 | None],
    timestamps_s: Sequence[float] | np.ndarray | None = None,
    color: tuple[int, int, int] = TRACK_RGB,
) -> None:
    """The track of a trajectory (missing poses skipped) as one path, at its last frame's time."""
    pts = np.array([p.t for p in world_from_cam if p is not None], dtype=float).reshape(-1, 3)
    if len(pts) >= 2:
        n = len(world_from_cam) - 1
        recorder.set_time(frame_time(timestamps_s, n), n)
        recorder.log_path(name, pts, color)


class OdometryRecording:
    """An ``on_frame`` observer of :func:`~skyrecon.odometry.run.run_odometry` that logs to
    ``recorder``: the left camera at each frame's online estimate, its image every
    ``image_every`` frames, the online track every ``map_every`` frames.

    Args:
        recorder: where to log.
        camera: the left camera of the rig.
    """

    def __init__(self, recorder: Recorder, camera: Intrinsics):
        self.r = recorder
        self.camera = camera
        self.track: list[np.ndarray] = []

    def __call__(self, estimate: Any, left: np.ndarray) -> None:
        """Log one :class:`~skyrecon.odometry.types.FrameEstimate` and its left image."""
        r, s = self.r, self.r.settings
        i = int(estimate.index)
        r.set_time(float(estimate.timestamp_s), i)
        image = left if i % s.image_every == 0 else None
        r.log_camera("camera", self.camera, estimate.world_from_left, image)
        self.track.append(np.asarray(estimate.world_from_left.t, float).copy())
        if i % s.map_every == 0 and len(self.track) >= 2:
            r.log_path("path/odometry", np.array(self.track), TRACK_RGB)

    def finish(
        self,
        odometry: Sequence[Rigid3],
        timestamps_s: Sequence[float] | np.ndarray,
        fused: Sequence[Rigid3] | None = None,
        truth: Sequence[Rigid3 | None] | None = None,
    ) -> None:
        """The refined odometry track, the GPS-fused one and the ground truth, at the last frame."""
        log_trajectory(self.r, "path/odometry", list(odometry), timestamps_s, TRACK_RGB)
        if fused is not None:
            log_trajectory(self.r, "path/fused", list(fused), timestamps_s, (255, 160, 0))
        if truth is not None:
            log_trajectory(self.r, "path/truth", list(truth), timestamps_s, TRUTH_RGB)
