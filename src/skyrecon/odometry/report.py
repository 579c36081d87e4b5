"""``report.html`` of ``skyrecon odometry``: a self-contained page (PNG figures embedded as base64,
drawn with OpenCV like :mod:`skyrecon.report.mission_report`).

* a top view of the trajectory (the plane of the two main directions of motion): the estimate,
  aligned onto the ground truth when there is one (SE(3), as the ATE), the ground truth, and the
  GPS-fused track and the accepted/rejected fixes when there was GPS;
* speed along the flight (estimate and ground truth);
* features: stereo, tracked, PnP inliers per frame;
* the tracking-state timeline (ok green, degraded orange, lost red) and the reasons;
* the metrics and timings tables, and what loop closure did.
"""

from __future__ import annotations

import html
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from skyrecon.core.rigid import Rigid3
from skyrecon.eval.odometry_metrics import OdometryMetrics
from skyrecon.odometry.run import OdometryRun
from skyrecon.report.mission_report import BLUE, GREEN, ORANGE, RED, png_data_uri, series_plot

__all__ = ["trajectory_top_view", "state_timeline", "render_odometry_report"]

GREY = (120, 120, 120)
_STATE_COLOURS = {"ok": (60, 170, 80), "degraded": ORANGE, "lost": RED}

_CSS = """
body { font-family: -apple-system, 'Segoe UI', Helvetica, Arial, sans-serif; margin: 24px auto; max-width: 1100px;
       color: #222; line-height: 1.4; padding: 0 16px; }
h1 { font-size: 1.6em; margin-bottom: 0.2em; } h2 { font-size: 1.2em; margin-top: 1.6em; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; margin: 8px 0; } td, th { padding: 4px 10px; border-bottom: 1px solid #eee; text-align: left; }
th { background: #f6f6f6; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
img { max-width: 100%; border: 1px solid #ddd; } .legend span { display: inline-block; margin-right: 14px; }
.sw { display: inline-block; width: 22px; height: 4px; vertical-align: middle; margin-right: 5px; }
small { color: #666; }
"""


def _plane_axes(points: np.ndarray) -> np.ndarray:
    """(2, 3) the two main directions of ``points`` (N, 3) (top view of a flight, whatever its world)."""
    if len(points) < 3:
        return np.eye(3)[:2]
    _, _, vt = np.linalg.svd(points - points.mean(axis=0), full_matrices=False)
    a, b = vt[0], vt[1]
    if abs(np.cross(a, b) @ np.array([0.0, 0.0, 1.0])) > 0.5 and np.cross(a, b)[2] < 0:
        b = -b  # seen from above when the world is z up
    return np.stack([a, b])


def trajectory_top_view(
    tracks: Sequence[tuple[str, np.ndarray, tuple[int, int, int]]],
    points: Sequence[tuple[str, np.ndarray, tuple[int, int, int]]] = (),
    size: int = 720,
) -> np.ndarray:
    """A plan view of 3D tracks (each (N, 3) metres, same frame) in the plane of their main directions.

    Args:
        tracks: (label, positions, RGB colour) drawn as lines, the first one defines the plane.
        points: (label, positions, RGB colour) drawn as dots (e.g. GPS fixes).
    Returns:
        (H, W, 3) uint8 RGB with a legend and a scale bar.
    """
    ref = np.asarray(tracks[0][1], np.float64) if tracks else np.zeros((0, 3))
    axes = _plane_axes(ref)
    allp = np.vstack(
        [np.asarray(t[1], np.float64).reshape(-1, 3) for t in tracks if len(t[1])] or [np.zeros((1, 3))]
    )
    uv_all = allp @ axes.T
    lo, hi = uv_all.min(axis=0), uv_all.max(axis=0)
    span = max(float((hi - lo).max()), 1.0)
    margin = 40
    scale = (size - 2 * margin) / span
    W = int((hi[0] - lo[0]) * scale) + 2 * margin
    H = int((hi[1] - lo[1]) * scale) + 2 * margin + 30
    img = np.full((H, W, 3), 255, np.uint8)

    def px(p: np.ndarray) -> np.ndarray:
        uv = np.asarray(p, np.float64).reshape(-1, 3) @ axes.T
        return np.stack(
            [margin + (uv[:, 0] - lo[0]) * scale, H - 30 - margin - (uv[:, 1] - lo[1]) * scale], 1
        )

    for _, p, colour in points:
        for q in px(p).round().astype(int):
            cv2.circle(img, (int(q[0]), int(q[1])), 2, colour, -1, cv2.LINE_AA)
    for _, p, colour in tracks:
        if len(p) < 2:
            continue
        q = px(p).round().astype(np.int32)
        cv2.polylines(img, [q], False, colour, 2, cv2.LINE_AA)
        cv2.circle(img, (int(q[0, 0]), int(q[0, 1])), 5, colour, -1)
        cv2.drawMarker(img, (int(q[-1, 0]), int(q[-1, 1])), colour, cv2.MARKER_CROSS, 12, 2)
    # scale bar
    bar_m = float(10 ** np.floor(np.log10(max(span / 4, 1e-3))))
    L = int(bar_m * scale)
    cv2.line(img, (20, H - 15), (20 + L, H - 15), (0, 0, 0), 2)
    cv2.putText(
        img, f"{bar_m:g} m", (26 + L, H - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA
    )
    x = 20
    for label, _, colour in [*tracks, *points]:
        cv2.line(img, (x, 18), (x + 20, 18), colour, 3)
        cv2.putText(img, label, (x + 25, 23), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (40, 40, 40), 1, cv2.LINE_AA)
        (tw, _), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
        x += 45 + tw
    return img


def state_timeline(states: Sequence[str], width: int = 900, height: int = 36) -> np.ndarray:
    """A strip, one column band per frame: green ok, orange degraded, red lost. (H, W, 3) uint8 RGB."""
    img = np.full((height, width, 3), 255, np.uint8)
    n = max(len(states), 1)
    for k, s in enumerate(states):
        x0, x1 = int(k * width / n), max(int((k + 1) * width / n), int(k * width / n) + 1)
        img[4:-4, x0:x1] = _STATE_COLOURS.get(s, GREY)
    return img


def _fmt(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.3f}" if abs(v) < 100 else f"{v:.1f}"
    return html.escape(str(v))


def _table(rows: Sequence[tuple[str, Any, str]]) -> str:
    body = "".join(
        f"<tr><th>{html.escape(k)}</th><td class='num'>{_fmt(v)}</td><td><small>{html.escape(n)}</small></td></tr>"
        for k, v, n in rows
    )
    return f"<table>{body}</table>"


def _img(image: np.ndarray, alt: str) -> str:
    return f'<img src="{png_data_uri(image)}" alt="{html.escape(alt)}">'


def _speed(times: np.ndarray, poses: Sequence[Rigid3 | None]) -> np.ndarray:
    v = np.full(len(times), np.nan)
    for k in range(1, len(times)):
        a, b = poses[k - 1], poses[k]
        if a is not None and b is not None and times[k] > times[k - 1]:
            v[k] = np.linalg.norm(b.t - a.t) / (times[k] - times[k - 1])
    return v


def render_odometry_report(
    run: OdometryRun,
    summary: dict[str, Any],
    source: str,
    gt: Sequence[Rigid3 | None] | None = None,
    metrics: OdometryMetrics | None = None,
    gps_positions: np.ndarray | None = None,
) -> str:
    """The HTML page (a string). ``gt``: ground truth per frame (None entries allowed); ``metrics``:
    computed on the frames with ground truth (its alignment places the estimate on the ground truth);
    ``gps_positions`` (M, 3): the fixes, drawn in the GPS world (like the fused track)."""
    t = run.timestamps_s
    est = np.array([p.t for p in run.odometry])
    tracks: list[tuple[str, np.ndarray, tuple[int, int, int]]] = []
    points: list[tuple[str, np.ndarray, tuple[int, int, int]]] = []
    has_gt = gt is not None and any(p is not None for p in gt)
    if metrics is not None and gt is not None:  # everything in the ground truth's world
        tracks = [
            ("ground truth", np.array([p.t for p in gt if p is not None]), GREEN),
            ("odometry (aligned)", metrics.alignment.apply(est), RED),
        ]
    elif run.fused is None:
        tracks = [("odometry", est, RED)]
    if run.fused is not None:  # the GPS world (the ground truth's too, when both are given)
        tracks.append(("GPS-fused", np.array([p.t for p in run.fused]), BLUE))
        if gps_positions is not None and len(gps_positions):
            points.append(("GPS fixes", np.asarray(gps_positions, np.float64).reshape(-1, 3), GREY))
    top = trajectory_top_view(tracks, points)
    speed_series = [("estimate", _speed(t, run.odometry), RED)]
    if has_gt and gt is not None:
        speed_series.insert(0, ("ground truth", _speed(t, gt), GREEN))
    x = t - t[0] if len(t) else t
    speed = series_plot(x, speed_series, "speed, m/s (x: seconds)")
    feats = series_plot(
        np.arange(len(run.estimates)),
        [
            ("stereo", np.array([e.n_stereo for e in run.estimates], float), BLUE),
            ("tracked", np.array([e.n_tracked for e in run.estimates], float), ORANGE),
            ("inliers", np.array([e.n_inliers for e in run.estimates], float), GREEN),
        ],
        "features per frame (x: frame)",
    )
    timeline = state_timeline([e.state.value for e in run.estimates])
    rows = [
        ("frames", summary["frames"], ""),
        ("distance flown (estimate)", summary["distance_m"], "metres"),
        ("rate", summary["fps"], "frames per second of tracking"),
        ("ok / degraded / lost", f"{summary['ok']} / {summary['degraded']} / {summary['lost']}", ""),
        ("re-initialised", summary["reinitialised"], "times"),
        ("track time p50 / p95 / p99", "{p50} / {p95} / {p99}".format(**summary["track_ms"]), "milliseconds"),
    ]
    metric_html = "<p>No ground truth given: add <code>--gt POSES</code> for ATE, RPE and drift.</p>"
    if metrics is not None:
        m = metrics.as_json()
        mrows = [
            ("frames compared", m["frames"], ""),
            ("true path length", m["path_length_m"], "metres"),
            ("ATE RMSE", m["ate_rmse_m"], f"metres after {m['alignment'].upper()} alignment"),
            ("ATE max", m["ate_max_m"], "metres"),
            ("RPE over 100 m", m["rpe_100m"]["trans_rmse_m"], f"metres RMSE, {m['rpe_100m']['pairs']} pairs"),
            ("RPE over 1 s", m["rpe_1s"]["trans_rmse_m"], f"metres RMSE, {m['rpe_1s']['pairs']} pairs"),
            ("drift", m["drift"]["translation_pct"], "% of distance (KITTI way, 25/50/100 m sub-paths)"),
            ("rotation drift", m["drift"]["rotation_deg_per_100m"], "degrees per 100 m"),
        ]
        if "fused" in m:
            mrows.append(
                ("GPS-fused error RMSE", m["fused"]["rmse_m"], "metres, in the GPS world, not aligned")
            )
        metric_html = _table(mrows)
    reasons = ""
    for state in ("lost", "degraded"):
        r = summary["reasons"].get(state, {})
        if r:
            items = "".join(f"<li>{html.escape(k)}: {v}</li>" for k, v in r.items())
            reasons += f"<p>{state}:</p><ul>{items}</ul>"
    stage_rows = "".join(
        f"<tr><th>{html.escape(s)}</th>"
        + "".join(f"<td class='num'>{_fmt(p[q])}</td>" for q in ("p50", "p95", "p99", "max"))
        + "</tr>"
        for s, p in summary.get("stage_ms", {}).items()
    )
    gps_html = ""
    if "gps" in summary:
        g = summary["gps"]
        gps_html = "<h2>GPS</h2>" + _table(
            [
                ("fixes", g["fixes"], ""),
                (
                    "accepted / rejected",
                    f"{g['accepted']} / {g['rejected']}",
                    "rejected: innovation beyond the gate",
                ),
                (
                    "aligned",
                    "yes" if g["aligned"] else "no",
                    "the correction's rotation is known (the flight turned)",
                ),
            ]
        )
    loop_html = ""
    lc = summary.get("loop_closure")
    if lc and lc.get("enabled"):
        why = "; ".join(f"{k}: {v}" for k, v in lc.get("rejected_reasons", {}).items()) or "none"
        loop_html = "<h2>Loop closure</h2>" + _table(
            [
                ("searches", lc["searches"], "keyframes searched for a revisited place"),
                ("accepted / rejected", f"{lc['accepted']} / {lc['rejected']}", f"rejected: {why}"),
                ("pose-graph solves", lc["pose_graph_solves"], f"longest {lc['pose_graph_ms_max']} ms"),
                (
                    "largest correction",
                    lc["max_correction_m"],
                    f"metres ({lc['max_correction_deg']:.3f} degrees)",
                ),
            ]
        )
    legend = "".join(
        f"<span><i class='sw' style='background: rgb{c}'></i>{html.escape(s)}</span>"
        for s, c in _STATE_COLOURS.items()
    )
    body = (
        f"<h1>Stereo visual odometry</h1><p><small>{html.escape(source)}</small></p>"
        f"<h2>Summary</h2>{_table(rows)}<h2>Against ground truth</h2>{metric_html}{gps_html}{loop_html}"
        f"<h2>Trajectory (top view)</h2>{_img(top, 'trajectory')}"
        f"<h2>Speed</h2>{_img(speed, 'speed')}<h2>Features</h2>{_img(feats, 'features')}"
        f"<h2>Tracking state</h2><p class='legend'>{legend}</p>{_img(timeline, 'states')}{reasons}"
        f"<h2>Timings (ms)</h2><table><tr><th>stage</th><th>p50</th><th>p95</th><th>p99</th><th>max</th></tr>{stage_rows}</table>"
    )
    return (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'><title>skyrecon odometry</title>"
        f"<meta name='viewport' content='width=device-width, initial-scale=1'><style>{_CSS}</style></head>"
        f"<body>{body}</body></html>\n"
    )
