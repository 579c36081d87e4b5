"""Self-contained HTML reports of simulated delivery missions (``skyrecon demo``).

Every picture is a PNG embedded as base64, so ``report.html`` opens offline on its own. The
pictures are drawn with OpenCV (no plotting library needed):

* :func:`overview_image`: a plan view of the TRUE city (buildings shaded by height, poles),
  the drone's final map (occupied voxels above the ground, orange), every path it planned
  (thin blue), the shortest feasible path in the true city (green), the flown track (red),
  the start (circle) and the goal (cross);
* a contact sheet of camera frames with their disparity;
* :func:`series_plot`: loop time, clearance and speed along the mission.

The 3D view of the map and paths is an iframe of ``view/index.html`` beside the report (written by
:func:`skyrecon.mission.outputs.write_mission_outputs` with :mod:`skyrecon.viewer`; it opens from
disk too).

World frame z up, metres; north (+y) is up in the plan view.
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Sequence

import cv2
import numpy as np

from skyrecon.io.disparity import colorize_disparity
from skyrecon.io.images import encode_png
from skyrecon.report.figures import contact_sheet, top_down_map

RED = (220, 40, 40)
GREEN = (20, 150, 60)
BLUE = (70, 120, 230)
ORANGE = (245, 140, 20)
PURPLE = (150, 60, 200)

_CSS = """
body { font-family: -apple-system, 'Segoe UI', Helvetica, Arial, sans-serif; margin: 24px auto; max-width: 1100px;
       color: #222; line-height: 1.4; padding: 0 16px; }
h1 { font-size: 1.6em; margin-bottom: 0.2em; } h2 { font-size: 1.2em; margin-top: 1.6em; border-bottom: 1px solid #ddd; }
.verdict { font-size: 1.15em; padding: 10px 14px; border-radius: 6px; margin: 12px 0; }
.ok { background: #e5f6e8; border: 1px solid #8fd19e; } .bad { background: #fde8e8; border: 1px solid #f1a5a5; }
table { border-collapse: collapse; margin: 8px 0; } td, th { padding: 4px 10px; border-bottom: 1px solid #eee; text-align: left; }
th { background: #f6f6f6; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
img { max-width: 100%; border: 1px solid #ddd; } .legend span { display: inline-block; margin-right: 14px; }
.sw { display: inline-block; width: 22px; height: 4px; vertical-align: middle; margin-right: 5px; }
.bar { display: inline-block; height: 12px; background: #5b8def; vertical-align: middle; }
.bar.render { background: #bbb; } small { color: #666; } code { background: #f3f3f3; padding: 1px 4px; }
"""


def png_data_uri(image: np.ndarray) -> str:
    """``data:image/png;base64,...`` of an (H, W) or (H, W, 3) uint8 RGB image."""
    return "data:image/png;base64," + base64.b64encode(encode_png(np.ascontiguousarray(image))).decode(
        "ascii"
    )


def _img(image: np.ndarray, alt: str) -> str:
    return f'<img src="{png_data_uri(image)}" alt="{html.escape(alt)}">'


class _PlanView:
    """World (x, y) metres -> pixel (u, v) of a plan view with north up (as ``top_down_map``)."""

    def __init__(self, extent: Sequence[float], px_per_m: float):
        self.x0, self.y0, self.x1, self.y1 = (float(v) for v in extent)
        self.s = float(px_per_m)

    def px(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) world x, y metres -> (N, 2) float pixel u, v."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return np.stack([(xy[:, 0] - self.x0) * self.s, (self.y1 - xy[:, 1]) * self.s], axis=1)


def overview_image(
    city,
    extent: Sequence[float],
    occupied_centers: np.ndarray | None = None,
    planned: Sequence[np.ndarray] = (),
    shortest: np.ndarray | None = None,
    flown: np.ndarray | None = None,
    start: np.ndarray | None = None,
    goal: np.ndarray | None = None,
    min_z: float = 1.0,
    max_px: int = 900,
    estimated: np.ndarray | None = None,
) -> np.ndarray:
    """The plan view of a mission (see the module docstring).

    Args:
        city: the true city (its boxes and cylinders are drawn).
        extent: ``(xmin, ymin, xmax, ymax)`` of the picture, world metres.
        occupied_centers: (M, 3) occupied voxel centres of the drone's map, world metres;
            those below ``min_z`` (the ground) are left out.
        planned: paths the drone planned, each (K, 3) world metres.
        shortest: (K, 3) shortest feasible path in the true city.
        flown: (N, 3) the flown (true) track.
        estimated: (N, 3) where the drone believed it was (its map and plans live in that
            estimated world), or None when it flew on the true pose.
        start, goal: (3,) world metres.
    Returns:
        (H, W, 3) uint8 RGB.
    """
    x0, y0, x1, y1 = extent
    ppm = max(1.0, min(4.0, max_px / max(x1 - x0, y1 - y0)))
    img = top_down_map(city.boxes, (x0, y0, x1, y1), (), city.cylinders, px_per_m=ppm)
    view = _PlanView(extent, ppm)
    H, W = img.shape[:2]
    if occupied_centers is not None and len(occupied_centers):
        c = np.asarray(occupied_centers, dtype=np.float64)
        c = c[c[:, 2] >= min_z]
        if len(c):
            uv = np.floor(view.px(c[:, :2])).astype(np.int64)
            ok = (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
            mask: np.ndarray = np.zeros((H, W), np.uint8)
            mask[uv[ok, 1], uv[ok, 0]] = 255
            r = max(1, int(round(0.25 * ppm)))
            mask = cv2.dilate(mask, np.ones((2 * r + 1, 2 * r + 1), np.uint8)) if r > 1 else mask
            m = mask > 0
            img[m] = (0.35 * img[m] + 0.65 * np.array(ORANGE)).astype(np.uint8)

    def poly(path, color, thick):
        p = np.asarray(path, dtype=np.float64)
        if len(p) >= 2:
            pts = np.round(view.px(p[:, :2])).astype(np.int32)
            cv2.polylines(img, [pts], False, color, thick, cv2.LINE_AA)

    for path in planned:
        poly(path, BLUE, 1)
    if shortest is not None:
        poly(shortest, GREEN, 2)
    if estimated is not None:
        poly(estimated, PURPLE, 1)
    if flown is not None:
        poly(flown, RED, 2)
    if start is not None:
        u, v = np.round(view.px(np.asarray(start)[None, :2])[0]).astype(int)
        cv2.circle(img, (int(u), int(v)), 7, (0, 0, 0), 2, cv2.LINE_AA)
    if goal is not None:
        u, v = np.round(view.px(np.asarray(goal)[None, :2])[0]).astype(int)
        cv2.drawMarker(img, (int(u), int(v)), (0, 0, 0), cv2.MARKER_CROSS, 18, 3)
        cv2.drawMarker(img, (int(u), int(v)), (255, 255, 255), cv2.MARKER_CROSS, 14, 1)
    # scale bar: 20 m
    L = int(round(20 * ppm))
    cv2.line(img, (12, H - 14), (12 + L, H - 14), (0, 0, 0), 3)
    cv2.putText(img, "20 m", (20 + L, H - 9), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def series_plot(
    x: np.ndarray,
    series: Sequence[tuple[str, np.ndarray, tuple[int, int, int]]],
    y_label: str,
    hlines: Sequence[tuple[str, float, tuple[int, int, int]]] = (),
    size: tuple[int, int] = (900, 220),
    y_max: float | None = None,
) -> np.ndarray:
    """A small line chart: ``series`` of (label, (N,) values, RGB colour) against ``x`` (N,),
    with labelled horizontal reference lines. Returns (H, W, 3) uint8 RGB."""
    W, H = size
    img = np.full((H, W, 3), 255, np.uint8)
    left, right, top, bottom = 56, 12, 40, 28
    x = np.asarray(x, dtype=np.float64)
    vals = [np.asarray(s[1], dtype=np.float64) for s in series]
    finite = (
        np.concatenate([v[np.isfinite(v)] for v in vals] + [np.array([h[1] for h in hlines])])
        if vals
        else np.zeros(1)
    )
    hi = float(y_max if y_max is not None else (np.percentile(finite, 99.5) * 1.1 if finite.size else 1.0))
    hi = max(hi, 1e-6)
    x_lo, x_hi = (float(x.min()), float(x.max())) if len(x) else (0.0, 1.0)
    x_hi = max(x_hi, x_lo + 1e-6)

    def u(xv):
        return left + (np.asarray(xv) - x_lo) / (x_hi - x_lo) * (W - left - right)

    def v(yv):
        return top + (1.0 - np.clip(np.asarray(yv) / hi, 0, 1)) * (H - top - bottom)

    cv2.rectangle(img, (left, top), (W - right, H - bottom), (200, 200, 200), 1)
    for frac in (0.0, 0.5, 1.0):
        yv = hi * frac
        cv2.putText(
            img, f"{yv:.3g}", (4, int(v(yv)) + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (90, 90, 90), 1, cv2.LINE_AA
        )
    cv2.putText(img, y_label, (left, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (40, 40, 40), 1, cv2.LINE_AA)
    for frac in (0.0, 0.25, 0.5, 0.75, 1.0):
        xv = x_lo + frac * (x_hi - x_lo)
        cv2.putText(
            img,
            f"{xv:.0f}",
            (int(u(xv)) - 8, H - 10),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.4,
            (90, 90, 90),
            1,
            cv2.LINE_AA,
        )
    for label, yv, color in hlines:
        cv2.line(img, (left, int(v(yv))), (W - right, int(v(yv))), color, 1, cv2.LINE_AA)
        cv2.putText(
            img,
            label,
            (W - right - 8 * len(label) - 4, int(v(yv)) - 4),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.4,
            color,
            1,
            cv2.LINE_AA,
        )
    lx = left
    for (label, _, color), val in zip(series, vals):
        ok = np.isfinite(val)
        if ok.sum() >= 2:
            pts = np.stack([u(x[ok]), v(val[ok])], axis=1).round().astype(np.int32)
            cv2.polylines(img, [pts], False, color, 1, cv2.LINE_AA)
        cv2.line(img, (lx, 29), (lx + 18, 29), color, 2)
        cv2.putText(img, label, (lx + 22, 33), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (40, 40, 40), 1, cv2.LINE_AA)
        (tw, _), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.42, 1)
        lx += 40 + tw
    return img


def _fmt(v) -> str:
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        return f"{v:.3f}" if abs(v) < 10 else f"{v:.1f}"
    return html.escape(str(v))


def _table(rows: Sequence[tuple[str, object, str]]) -> str:
    body = "".join(
        f"<tr><th>{html.escape(k)}</th><td class='num'>{_fmt(v)}</td><td><small>{html.escape(note)}</small></td></tr>"
        for k, v, note in rows
    )
    return f"<table>{body}</table>"


def _page(title: str, body: str) -> str:
    return (
        f"<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
        f"<meta name='viewport' content='width=device-width, initial-scale=1'><style>{_CSS}</style></head>"
        f"<body>{body}</body></html>\n"
    )


def legend_html(items: Sequence[tuple[tuple[int, int, int], str]], extra: str = "") -> str:
    """A legend line: (RGB colour, label) swatches, then ``extra`` HTML."""
    spans = "".join(f"<span><i class='sw' style='background: rgb{c}'></i>{t}</span>" for c, t in items)
    return f"<p class='legend'>{spans}{extra}</p>"


def _legend(estimated: bool = False) -> str:
    items = [
        (RED, "flown track"),
        *([(PURPLE, "estimated track (the drone's belief)")] if estimated else []),
        (BLUE, "planned paths (each replan)"),
        (GREEN, "shortest feasible path (true city)"),
        (ORANGE, "drone's map: occupied voxels"),
    ]
    return legend_html(items, "<span>○ start</span><span>✕ goal</span>")


def _timing_table(stage_ms: dict, loop_stages: Sequence[str]) -> str:
    rows = []
    worst = max([v["median"] or 0.0 for v in stage_ms.values()] + [1e-6])
    for name in ["render", *loop_stages, "loop"]:
        st = stage_ms.get(name)
        if not st:
            continue
        med = st["median"] or 0.0
        width = int(240 * med / worst)
        cls = "bar render" if name == "render" else "bar"
        note = (
            "simulator (not part of the loop)"
            if name == "render"
            else ("stereo + map + planning + control" if name == "loop" else "")
        )
        rows.append(
            f"<tr><th>{name}</th><td class='num'>{_fmt(st['median'])}</td><td class='num'>{_fmt(st['p95'])}</td>"
            f"<td class='num'>{_fmt(st['mean'])}</td><td><span class='{cls}' style='width:{width}px'></span> "
            f"<small>{note}</small></td></tr>"
        )
    return (
        "<table><tr><th>stage</th><th>median ms</th><th>p95 ms</th><th>mean ms</th><th></th></tr>"
        + "".join(rows)
        + "</table>"
    )


def render_mission_report(
    result, metrics: dict, extra_notes: Sequence[str] = (), view_src: str | None = None
) -> str:
    """The HTML report of a flown mission.

    Args:
        result: a :class:`~skyrecon.mission.loop.MissionResult`.
        metrics: its :func:`~skyrecon.mission.metrics.mission_metrics`.
        extra_notes: lines added under the verdict (e.g. where the outputs are).
        view_src: relative address of the mission's 3D view page (``view/index.html``, written by
            :mod:`skyrecon.viewer`), embedded in an iframe under the plan view; None: no 3D view.
    """
    sc, cfg = result.scenario, result.config
    m = metrics
    ok = m["success"]
    if ok:
        verdict = (
            f"Delivered: {m['path_length_m']:.1f} m flown in {m['flight_time_s']:.1f} s, no collision, closest "
            f"approach {m['min_clearance_m']:.2f} m, loop {m['loop_hz']:.1f} Hz."
        )
    else:
        verdict = f"Mission failed ({html.escape(m['reason'])}): {html.escape(m['message'])}"
    box = sc.box
    extent = (box.origin[0], box.origin[1], box.upper[0], box.upper[1])
    flown = result.flown_path()
    recs = result.records
    estimated = None
    if recs and recs[0].est_position is not None:
        est_end = (
            result.final_est_position if result.final_est_position is not None else result.final_position
        )
        estimated = np.vstack([np.array([r.est_position for r in recs]), est_end[None]])
    over = overview_image(
        sc.city,
        extent,
        result.occ_map.occupied_centers(),
        [p.waypoints for p in result.plans],
        sc.shortest.waypoints if sc.shortest.success else None,
        flown,
        sc.start,
        sc.goal,
        estimated=estimated,
    )
    t = np.array([r.time_s for r in recs])
    loop_img = series_plot(
        t,
        [
            ("loop (no render)", np.array([r.loop_ms for r in recs]), (70, 120, 230)),
            ("distance field", np.array([r.timings_ms["distance"] for r in recs]), (245, 140, 20)),
            ("stereo", np.array([r.timings_ms["stereo"] for r in recs]), (20, 150, 60)),
        ],
        "milliseconds per cycle vs. simulated time (s)",
        [("100 ms = 10 Hz", 100.0, (200, 40, 40))],
    )
    clr = np.array([r.clearance_m for r in recs])
    clr_img = series_plot(
        t,
        [
            ("true clearance (m)", np.minimum(clr, 15.0), (70, 120, 230)),
            ("speed (m/s)", np.array([r.speed_mps for r in recs]), (20, 150, 60)),
            ("stopping-rule limit (m/s)", np.array([r.stop_limit_mps for r in recs]), (200, 120, 20)),
        ],
        "clearance to the true geometry, speed and the speed it can stop from vs. simulated time (s)",
        [(f"safety margin {cfg.safety_margin_m:g} m", cfg.safety_margin_m, (200, 40, 40))],
        y_max=max(10.0, cfg.cruise_speed_mps * 1.2),
    )
    pose_img = None
    if estimated is not None:
        pose_img = series_plot(
            t,
            [
                ("pose error (m)", np.array([r.pose_error_m for r in recs]), PURPLE),
                (
                    "lost (1) / degraded (0.5)",
                    np.array([{"lost": 1.0, "degraded": 0.5}.get(r.pose_state, 0.0) for r in recs]),
                    RED,
                ),
            ],
            "distance between the believed and the true position vs. simulated time (s)",
            [],
            y_max=max(1.0, 1.2 * float(max(r.pose_error_m for r in recs))),
        )
    frames, labels = [], []
    for f in result.frames:
        finite = f.disparity[np.isfinite(f.disparity)]
        top = float(np.percentile(finite, 99)) if finite.size else float(cfg.max_disparity)
        frames += [f.left, colorize_disparity(f.disparity, 0.0, max(top, 1.0))]
        tag = f" ({f.label})" if f.label else ""
        labels += [f"cycle {f.cycle}, t = {f.cycle * cfg.dt:.1f} s{tag}", f"disparity, cycle {f.cycle}"]
    sheet = contact_sheet(frames, labels, columns=2, tile_width=420) if frames else None
    ratio_note = "target <= 1.3" if m["length_ratio"] is not None else ""
    rows = [
        ("success", m["success"], "arrived without touching anything"),
        ("collisions", m["collisions"], "against the TRUE geometry"),
        ("min clearance (m)", m["min_clearance_m"], f"true distance, target > {cfg.safety_margin_m:g} m"),
        ("flown length (m)", m["path_length_m"], ""),
        ("straight line (m)", m["straight_line_m"], "start to goal"),
        ("shortest feasible (m)", m["shortest_feasible_m"], f"true city, clearance {cfg.clearance_m:g} m"),
        ("length ratio", m["length_ratio"], ratio_note),
        ("replans", m["replans"], "new paths after the first"),
        ("loop rate (Hz)", m["loop_hz"], "median, rendering excluded; target >= 10"),
        (
            "loop p99 (ms)",
            m["loop_ms_p99"],
            f"max {m['loop_ms_max']} ms; latency budget {1e3 * cfg.latency_budget_s:g} ms",
        ),
        (
            "mean speed (m/s)",
            m["mean_speed_mps"],
            f"cruise {cfg.cruise_speed_mps:g} m/s; the rig supports {m['speed_supported_mps']} m/s",
        ),
        (
            "stop-limited cycles",
            m["stop_limited_fraction"],
            "share of cycles the stopping rule set the speed",
        ),
        (
            "stopping rule held",
            m["stop_rule_ok"],
            f"braking at full deceleration in {m['braking_cycles']} cycles",
        ),
        ("flight time (s)", m["flight_time_s"], "simulated"),
        ("cycles", m["cycles"], f"{cfg.cycle_hz:g} per simulated second"),
        ("measured pixels", m["mean_measured_fraction"], "mean share with a stereo match"),
        (
            "image noise (grey levels)",
            m.get("image_noise_median"),
            f"median measured on the frames; the texture tests stand above it (simulated camera noise "
            f"{cfg.camera_noise:g})",
        ),
        ("pose source", m.get("pose_source", "truth"), "where the drone's pose came from"),
        ("drift at the end (m)", m.get("drift_m"), "believed vs true position"),
        ("pose ATE (m)", m.get("ate_m"), "RMS over the flight of believed vs true position"),
        (
            "pose degraded / lost cycles",
            f"{m.get('pose_degraded_cycles', 0)} / {m.get('pose_lost_cycles', 0)}",
            "slows down when degraded, hovers without mapping when lost",
        ),
        ("seed", m["seed"], ""),
        ("wall time (s)", m["wall_s"], "rendering and set-up included"),
    ]
    if not ok:
        rows.insert(1, ("reason", m["reason"], m["message"]))
    from skyrecon.mission.perception import hit_range_m  # the mission package imports this module

    settings = (
        f"{cfg.width}x{cfg.height} stereo, {cfg.hfov_deg:g}° hfov, baseline {cfg.baseline_m:g} m, "
        f"{cfg.matcher} (max disparity {cfg.max_disparity}); voxels {cfg.voxel_size_m:g} m, map range "
        f"{hit_range_m(cfg):.1f} m (trusted depth); clearance {cfg.clearance_m:g} m; altitude {cfg.min_altitude_m:g}–"
        f"{cfg.max_altitude_m:g} m; cruise {cfg.cruise_speed_mps:g} m/s, {cfg.max_accel_mps2:g} m/s², "
        f"{cfg.max_yaw_rate_deg_s:g}°/s; drone radius {cfg.drone_radius_m:g} m"
    )
    notes = "".join(f"<p><small>{html.escape(n)}</small></p>" for n in extra_notes)
    notes += "".join(f"<p><b>Warning:</b> {html.escape(w)}</p>" for w in m.get("warnings", []))
    body = [
        f"<h1>Delivery mission, seed {sc.seed}</h1>",
        f"<p>From {_xyz(sc.start)} to {_xyz(sc.goal)} ({sc.straight_line_m:.0f} m apart, buildings in between) through "
        f"a city the drone has never seen: it maps with its stereo camera as it flies.</p>",
        f"<div class='verdict {'ok' if ok else 'bad'}'>{verdict}</div>",
        notes,
        "<h2>Where it flew</h2>",
        _legend(estimated is not None),
        _img(over, "plan view of the mission"),
        *_view_3d(view_src),
        "<h2>Metrics</h2>",
        _table(rows),
        *_dynamic(result, m, extent),
        "<h2>Time per stage</h2>",
        _timing_table(m["stage_ms"], m["loop_stages"]),
        _img(loop_img, "loop time per cycle"),
        _img(clr_img, "clearance and speed"),
        *(["<h2>Pose estimate</h2>", _img(pose_img, "pose error")] if pose_img is not None else []),
        "<h2>What the camera saw</h2>",
        _img(sheet, "camera frames and disparity") if sheet is not None else "<p>No frames.</p>",
        "<h2>Settings</h2>",
        f"<p><small>{html.escape(settings)}</small></p>",
    ]
    return _page(f"skyrecon mission {sc.seed}", "".join(body))


def _view_3d(src: str | None) -> list[str]:
    """The 3D view section: an iframe of the viewer page (works when the report is opened from disk)."""
    if not src:
        return []
    s = html.escape(src, quote=True)
    return [
        "<h2>In 3D</h2>",
        "<p><small>The drone's final map (occupied voxels, coloured by height), the flown track (red) and "
        "the last planned path (blue). Drag to orbit, right-drag to pan, wheel to zoom; "
        f"<a href='{s}'>open full page</a>.</small></p>",
        f"<iframe src='{s}' title='3D view of the map and the flown path' loading='lazy' "
        "style='width: 100%; height: 560px; border: 1px solid #ddd;'></iframe>",
    ]


def _dynamic(result, metrics: dict, extent) -> list[str]:
    from skyrecon.report.dynamic_report import dynamic_section, faults_section  # they draw on this module

    return dynamic_section(result, metrics, extent) + faults_section(result, metrics)


def _xyz(p) -> str:
    return "(" + ", ".join(f"{float(v):.1f}" for v in np.asarray(p).reshape(-1)) + ") m"


def render_refused_report(message: str, code: str, seed: int, cfg, city=None, start=None, goal=None) -> str:
    """The HTML report of a mission refused before take-off (impossible input), saying why.

    Args:
        message: the reason in words; code: its short form.
        seed: the city's seed; cfg: the mission settings.
        city: the city (to show where the endpoints lie), if it could be generated.
        start, goal: the endpoints asked for ((3,) world metres) or None.
    """
    body = [
        f"<h1>Delivery mission, seed {seed}: not flown</h1>",
        f"<div class='verdict bad'>This mission is impossible: {html.escape(message)}</div>",
        f"<p><small>reason code: <code>{html.escape(code)}</code></small></p>",
    ]
    if city is not None:
        x0, y0, x1, y1 = city.extent
        pad = 10.0
        img = overview_image(
            city,
            (x0 - pad, y0 - pad, x1 + pad, y1 + pad),
            start=None if start is None else np.asarray(start, dtype=float),
            goal=None if goal is None else np.asarray(goal, dtype=float),
        )
        body += [
            "<h2>The city</h2>",
            "<p class='legend'><span>○ start</span><span>✕ goal</span></p>",
            _img(img, "plan view of the city"),
        ]
    body += [
        "<h2>What to do</h2>",
        "<p>Pick a start and a goal in open air over the streets, inside the flight band "
        f"({cfg.min_altitude_m:g}–{cfg.max_altitude_m:g} m) and at least "
        f"{cfg.clearance_m + cfg.planning_margin_m:.1f} m from every building, e.g. "
        "<code>skyrecon demo --start X Y Z --goal X Y Z --out DIR</code>, or leave them out and let the seed pick.</p>",
    ]
    return _page(f"skyrecon mission {seed} (not flown)", "".join(body))


def render_summary_report(rows: Sequence[dict], title: str = "Delivery missions") -> str:
    """An HTML table of many missions: one row per mission (its metrics dict plus ``folder``)."""
    cols = [
        ("seed", "seed"),
        ("success", "success"),
        ("reason", "reason"),
        ("collisions", "collisions"),
        ("min_clearance_m", "min clearance m"),
        ("path_length_m", "flown m"),
        ("shortest_feasible_m", "shortest m"),
        ("length_ratio", "ratio"),
        ("replans", "replans"),
        ("loop_hz", "loop Hz"),
    ]
    head = "".join(f"<th>{h}</th>" for _, h in cols) + "<th>report</th>"
    body = []
    for r in rows:
        cells = "".join(f"<td class='num'>{_fmt(r.get(k))}</td>" for k, _ in cols)
        link = f"<a href='{html.escape(r.get('folder', ''))}/report.html'>open</a>" if r.get("folder") else ""
        body.append(f"<tr>{cells}<td>{link}</td></tr>")
    n = len(rows)
    ok = sum(1 for r in rows if r.get("success"))
    coll = sum(int(r.get("collisions") or 0) for r in rows)
    hz = [r["loop_hz"] for r in rows if r.get("loop_hz")]
    ratios = [r["length_ratio"] for r in rows if r.get("length_ratio")]
    clr = [r["min_clearance_m"] for r in rows if r.get("min_clearance_m") is not None]
    summary = (
        f"{ok} of {n} delivered, {coll} collisions; min clearance {min(clr):.2f} m; "
        if clr
        else f"{ok} of {n} delivered; "
    )
    if ratios:
        summary += f"length ratio median {np.median(ratios):.3f}, worst {max(ratios):.3f}; "
    if hz:
        summary += f"loop rate median {np.median(hz):.1f} Hz, slowest {min(hz):.1f} Hz"
    return _page(
        title,
        f"<h1>{html.escape(title)}</h1><div class='verdict {'ok' if ok == n else 'bad'}'>"
        f"{html.escape(summary)}</div><table><tr>{head}</tr>{''.join(body)}</table>",
    )
