"""Running an odometry engine over a sequence, with optional GPS fusion, and summarising the run.

The engine is anything with ``track(left, right, timestamp_s) -> FrameEstimate`` and
``trajectory() -> list[Rigid3]`` (refined ``world_from_left`` of every frame so far), such as
:class:`skyrecon.odometry.engine.StereoOdometry`.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from skyrecon.core.rigid import Rigid3
from skyrecon.io.gps import GpsFix
from skyrecon.odometry.gps import GpsFusion
from skyrecon.odometry.types import FrameEstimate, TrackingState

__all__ = ["OdometryEngine", "OdometryRun", "run_odometry", "summarize_run", "percentiles"]


class OdometryEngine(Protocol):
    def track(self, left: np.ndarray, right: np.ndarray, timestamp_s: float) -> FrameEstimate: ...

    def trajectory(self) -> list[Rigid3]: ...


@dataclass
class OdometryRun:
    """What :func:`run_odometry` gives back.

    Attributes:
        estimates: the engine's per-frame answers.
        odometry: the engine's final (refined) ``world_from_left`` per frame, metres.
        timestamps_s: (N,) frame times.
        track_ms: (N,) wall-clock milliseconds of each ``track`` call.
        seconds: wall-clock seconds of the whole loop (reading frames included).
        fused: GPS-fused ``world_from_left`` per frame (None without GPS); online values, as a vehicle
            would have had them.
        fusion: the fusion state with its per-fix log (None without GPS).
        loops: the engine's loop-closure diagnostics (``loop_report()``), None when it has none.
    """

    estimates: list[FrameEstimate]
    odometry: list[Rigid3]
    timestamps_s: np.ndarray
    track_ms: np.ndarray
    seconds: float
    fused: list[Rigid3] | None = None
    fusion: GpsFusion | None = None
    loops: dict[str, Any] | None = None

    @property
    def poses(self) -> list[Rigid3]:
        """The best poses: fused when there was GPS, else the odometry."""
        return self.fused if self.fused is not None else self.odometry


def run_odometry(
    engine: OdometryEngine,
    frames: Iterable[tuple[np.ndarray, np.ndarray]],
    timestamps_s: Sequence[float] | np.ndarray,
    fixes: Sequence[GpsFix] | None = None,
    fusion: GpsFusion | None = None,
    on_frame: Callable[[FrameEstimate, np.ndarray], None] | None = None,
) -> OdometryRun:
    """Track every frame; with ``fixes``, feed each frame's odometry pose and the fixes received since
    the previous frame into ``fusion`` (a fresh :class:`GpsFusion` by default). ``on_frame`` (an
    observer, e.g. a recording) is called with each frame's estimate and its (H, W, 3) left image,
    outside the timed ``track`` call."""
    t = np.asarray(timestamps_s, np.float64)
    fix_t = np.array([f.time_s for f in fixes]) if fixes else np.zeros(0)
    if fixes is not None and fusion is None:
        fusion = GpsFusion()
    estimates: list[FrameEstimate] = []
    fused: list[Rigid3] = []
    track_ms = []
    lo = 0
    t0 = time.perf_counter()
    for k, (left, right) in enumerate(frames):
        a = time.perf_counter()
        est = engine.track(left, right, float(t[k]))
        track_ms.append(1000.0 * (time.perf_counter() - a))
        estimates.append(est)
        if on_frame is not None:
            on_frame(est, left)
        if fixes is not None and fusion is not None:
            hi = int(np.searchsorted(fix_t, t[k], side="right"))
            fused.append(fusion.update(float(t[k]), est.world_from_left, list(fixes[lo:hi])))
            lo = hi
    seconds = time.perf_counter() - t0
    n = len(estimates)
    odometry = list(engine.trajectory())[:n] if n else []
    if len(odometry) != n:  # an engine that refines nothing: its per-frame answers
        odometry = [e.world_from_left for e in estimates]
    loop_report = getattr(engine, "loop_report", None)
    return OdometryRun(
        estimates,
        [p.with_frames("world", "left") for p in odometry],
        t[:n],
        np.array(track_ms),
        seconds,
        fused if fixes is not None else None,
        fusion,
        loop_report() if callable(loop_report) else None,
    )


def percentiles(values: Sequence[float] | np.ndarray) -> dict[str, float | None]:
    """``{"p50", "p95", "p99", "max"}`` of finite values (None when there are none)."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return {"p50": None, "p95": None, "p99": None, "max": None}
    p = np.percentile(v, [50, 95, 99])
    return {
        "p50": round(float(p[0]), 3),
        "p95": round(float(p[1]), 3),
        "p99": round(float(p[2]), 3),
        "max": round(float(v.max()), 3),
    }


def summarize_run(run: OdometryRun) -> dict[str, Any]:
    """The ``summary`` of ``odometry.json``: frames, rate, state counts with reasons, timings, distance."""
    est = run.estimates
    states = Counter(e.state.value for e in est)
    reasons: dict[str, Counter] = {s.value: Counter() for s in (TrackingState.DEGRADED, TrackingState.LOST)}
    for e in est:
        if e.state != TrackingState.OK:
            reasons[e.state.value][e.reason or "(no reason given)"] += 1
    stages = sorted({k for e in est for k in e.timings_ms})
    pos = np.array([p.t for p in run.odometry]) if run.odometry else np.zeros((0, 3))
    dist = float(np.sum(np.linalg.norm(np.diff(pos, axis=0), axis=1))) if len(pos) > 1 else 0.0
    track_s = float(run.track_ms.sum()) / 1000.0
    out: dict[str, Any] = {
        "frames": len(est),
        "duration_s": float(run.timestamps_s[-1] - run.timestamps_s[0]) if len(est) > 1 else 0.0,
        "distance_m": round(dist, 3),
        "fps": round(len(est) / track_s, 2) if track_s > 0 else None,
        "fps_with_io": round(len(est) / run.seconds, 2) if run.seconds > 0 else None,
        "ok": states.get("ok", 0),
        "degraded": states.get("degraded", 0),
        "lost": states.get("lost", 0),
        "reinitialised": sum(e.reinitialised for e in est),
        "keyframes": sum(e.keyframe for e in est),
        "reasons": {k: dict(v.most_common()) for k, v in reasons.items()},
        "track_ms": percentiles(run.track_ms),
        "stage_ms": {s: percentiles([e.timings_ms.get(s, np.nan) for e in est]) for s in stages},
    }
    if run.loops is not None:
        out["loop_closure"] = run.loops
    if run.fusion is not None:
        f = run.fusion
        out["gps"] = {
            "fixes": len(f.updates),
            "accepted": f.accepted,
            "rejected": f.rejected,
            "aligned": f.aligned,
            "world_from_odom": {"R": f.world_from_odom.R.tolist(), "t": f.world_from_odom.t.tolist()},
        }
    return out
