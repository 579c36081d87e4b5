"""What stereo visual odometry hands back, frame by frame.

The contract between the odometry engine (:mod:`skyrecon.odometry.engine`), its consumers
(the ``skyrecon odometry`` command, the delivery loop, GPS fusion, the benchmark) and the
outputs (``poses.txt``, ``trajectory.txt``, ``odometry.json``).

Frames: ``world`` is the odometry's world, by default the left camera frame of the first frame
(or the ``init_world_from_left`` given to the engine); ``left`` is the left camera of the current
frame (OpenCV axes). Units: metres, seconds, pixels, milliseconds for timings.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from skyrecon.core.rigid import Rigid3


class TrackingState(StrEnum):
    """How far a frame's pose can be trusted.

    * ``ok``: tracked with enough well-spread inliers.
    * ``degraded``: a pose was estimated but from little support (few inliers, poor spread,
      a suspicious input such as a frozen or dark frame); consumers should slow down.
    * ``lost``: no pose could be estimated from this frame; the pose given is a prediction
      (constant velocity) and must not be trusted. The engine re-initialises on the next
      usable frame and says so (``FrameEstimate.reinitialised``).
    """

    OK = "ok"
    DEGRADED = "degraded"
    LOST = "lost"


@dataclass
class FrameEstimate:
    """The odometry's answer for one stereo frame.

    Attributes:
        index: frame index from 0, in the order frames were given.
        timestamp_s: the frame's time, seconds (as given to the engine).
        world_from_left: (frames ``("world", "left")``) pose of the left camera, metres.
        state: :class:`TrackingState`.
        reason: empty when ``state`` is ok; otherwise one short sentence saying why
            (e.g. "black frame", "frozen frame (identical to the previous one)",
            "12 inliers (< 30)", "pure rotation: no stereo depth in view").
        keyframe: this frame became a keyframe.
        reinitialised: the engine started a new track at this frame (after a loss); the pose
            is chained to the last trusted one by the constant-velocity prediction.
        n_features: features detected or tracked in the left image.
        n_stereo: of those, with a stereo correspondence (a 3D point).
        n_tracked: features tracked from the previous frame or matched to the local map.
        n_inliers: PnP RANSAC inliers behind the pose.
        reprojection_rms_px: RMS reprojection error of the inliers after refinement, pixels
            (NaN when lost).
        timings_ms: wall-clock milliseconds per stage (e.g. ``track``, ``stereo``, ``pnp``,
            ``window_ba``, ``total``).
        position_sigma_m: rough 1-sigma of the position relative to the previous frame, metres
            (NaN when unknown); lets fusion weight the odometry.
        loop: what loop closure did at this keyframe (empty: nothing), e.g. "loop closed with
            frame 120: correction 0.84 m"; a closed loop moves this frame's pose (and the keyframes
            before it) onto the corrected trajectory.
    """

    index: int
    timestamp_s: float
    world_from_left: Rigid3
    state: TrackingState
    reason: str = ""
    keyframe: bool = False
    reinitialised: bool = False
    n_features: int = 0
    n_stereo: int = 0
    n_tracked: int = 0
    n_inliers: int = 0
    reprojection_rms_px: float = float("nan")
    timings_ms: dict[str, float] = field(default_factory=dict)
    position_sigma_m: float = float("nan")
    loop: str = ""

    @property
    def position(self) -> np.ndarray:
        """(3,) centre of the left camera in the world, metres."""
        return self.world_from_left.origin_of_src_in_dst

    def as_json(self) -> dict:
        """The per-frame record of ``odometry.json``."""
        return {
            "index": self.index,
            "timestamp_s": float(self.timestamp_s),
            "state": self.state.value,
            "reason": self.reason,
            "keyframe": bool(self.keyframe),
            "reinitialised": bool(self.reinitialised),
            "n_features": int(self.n_features),
            "n_stereo": int(self.n_stereo),
            "n_tracked": int(self.n_tracked),
            "n_inliers": int(self.n_inliers),
            "reprojection_rms_px": None
            if not np.isfinite(self.reprojection_rms_px)
            else float(self.reprojection_rms_px),
            "position": [float(v) for v in self.position],
            "timings_ms": {k: round(float(v), 3) for k, v in self.timings_ms.items()},
            **({"loop": self.loop} if self.loop else {}),
        }
