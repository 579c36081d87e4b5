"""What a delivery mission (``skyrecon demo``) logs, cycle by cycle.

Names (see :mod:`skyrecon.record.recorder`); everything the drone knows lives in the world it
believes it is in (its pose estimate), the simulator's truth under ``truth/``:

* ``mission/start``, ``mission/goal``: (1, 3) points, at time 0;
* ``drone/camera``: the left camera at the believed pose, every cycle (frame = cycle), with its
  image every ``image_every`` cycles and its depth and disparity every ``depth_every``;
* ``map/occupied``: the map's occupied voxels every ``map_every`` cycles and at the end;
* ``path/planned``: each path the drone decided to follow, when it changes;
* ``path/flown``: the believed track so far (every 5 cycles and at the end);
* ``movers/tracked``: the centres of the moving objects the drone tracks (with tracking on);
* ``truth/drone``: the true pose of the left camera; ``truth/flown``: the true track (only when
  the pose is estimated, i.e. not ``--pose-source truth``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.record.recorder import Recorder

#: Colours (RGB) of the mission's paths.
PLANNED_RGB = (255, 160, 0)
FLOWN_RGB = (0, 200, 255)
TRUTH_RGB = (120, 255, 120)
MOVER_RGB = (255, 40, 40)
FLOWN_EVERY = 5


class MissionRecording:
    """Logs one mission to ``recorder`` (see the module docstring); does nothing (and costs
    nothing) when the recorder is not enabled (a :class:`~skyrecon.record.NullRecorder`).

    Args:
        recorder: where to log.
        camera: the drone's left camera.
        voxel_size_m: the map's voxel edge, metres.
        max_disparity: the matcher's disparity bound, pixels (the disparity colour scale).
        start, goal: (3,) world metres.
    """

    def __init__(
        self,
        recorder: Recorder,
        camera: Intrinsics,
        voxel_size_m: float,
        max_disparity: float,
        start: np.ndarray,
        goal: np.ndarray,
    ):
        self.r = recorder
        self.camera = camera
        self.voxel_size_m = float(voxel_size_m)
        self.max_disparity = float(max_disparity)
        self.plans_logged = 0
        self.flown: list[np.ndarray] = []
        self.true_flown: list[np.ndarray] = []
        self.last_time = 0.0
        self.last_cycle = 0
        self.enabled = recorder.enabled
        if not self.enabled:
            return
        recorder.set_time(0.0, 0)
        recorder.log_points("mission/start", np.asarray(start, float).reshape(1, 3), np.array([[0, 255, 0]]))
        recorder.log_points("mission/goal", np.asarray(goal, float).reshape(1, 3), np.array([[255, 0, 0]]))

    def cycle(
        self,
        cycle: int,
        time_s: float,
        world_from_left: Rigid3,
        true_world_from_left: Rigid3 | None,
        left: np.ndarray | None,
        depth: Any,
        occ_map: Any,
        plans: list[Any],
        tracks: Sequence[Any] | None = None,
    ) -> None:
        """Log one cycle.

        Args:
            cycle: index from 0; time_s: simulated seconds at its start.
            world_from_left: the believed pose of the left camera.
            true_world_from_left: its true pose (None when the pose is the truth).
            left: (H, W, 3) uint8 RGB image the drone received, or None (no frame).
            depth: the cycle's :class:`~skyrecon.perception.stereo_depth.DepthFrame`, or None.
            occ_map: the drone's :class:`~skyrecon.mapping.OccupancyMap`.
            plans: every :class:`~skyrecon.mission.loop.PlanEvent` so far.
            tracks: the mover tracker's :class:`~skyrecon.perception.movers.MoverTrack` list
                (None: no tracking); the moving ones are logged.
        """
        if not self.enabled:
            return
        r, s = self.r, self.r.settings
        self.last_time, self.last_cycle = time_s, cycle
        r.set_time(time_s, cycle)
        image = left if left is not None and cycle % s.image_every == 0 else None
        r.log_camera("drone/camera", self.camera, world_from_left, image)
        if depth is not None and cycle % s.depth_every == 0:
            r.log_depth("drone/camera", depth.depth_m, depth.intrinsics)
            r.log_disparity("drone/camera", depth.disparity, self.max_disparity)
        self.flown.append(np.asarray(world_from_left.t, float).copy())
        if true_world_from_left is not None:
            r.log_pose("truth/drone", true_world_from_left)
            self.true_flown.append(np.asarray(true_world_from_left.t, float).copy())
        if tracks is not None:
            moving = np.array([t.position for t in tracks if t.moving], float).reshape(-1, 3)
            r.log_points("movers/tracked", moving, np.tile(np.array(MOVER_RGB, np.uint8), (len(moving), 1)))
        if len(plans) > self.plans_logged:
            self.plans_logged = len(plans)
            r.log_path("path/planned", plans[-1].waypoints, PLANNED_RGB)
        if cycle % FLOWN_EVERY == 0:
            self._log_tracks()
        if cycle % s.map_every == 0:
            r.log_voxels("map/occupied", occ_map.occupied_centers(), self.voxel_size_m)

    def finish(self, occ_map: Any) -> None:
        """Log the final map and tracks at the last cycle's time."""
        if not self.enabled:
            return
        self.r.set_time(self.last_time, self.last_cycle)
        self._log_tracks()
        self.r.log_voxels("map/occupied", occ_map.occupied_centers(), self.voxel_size_m)

    def _log_tracks(self) -> None:
        if len(self.flown) >= 2:
            self.r.log_path("path/flown", np.array(self.flown), FLOWN_RGB)
        if len(self.true_flown) >= 2:
            self.r.log_path("truth/flown", np.array(self.true_flown), TRUTH_RGB)
