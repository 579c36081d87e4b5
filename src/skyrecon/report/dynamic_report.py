"""The "city that moves" section of a mission report: movers, closest approaches, replans,
changes since the prior map.

* a plan view (the mission's overview) with every mover's TRUE path (cyan, a dot where it was
  when the drone came closest to it) and the drone's TRACKED paths (magenta), and the flown
  track marked at the closest approaches;
* the true clearance to the static city and to the movers along the flight;
* tables: the moments of closest approach to each mover, why each replan happened, the changes
  since the prior map and how fast the map caught up, the movers' detection figures.

World frame z up, metres; north (+y) is up.
"""

from __future__ import annotations

import html

import cv2
import numpy as np

from skyrecon.report.mission_report import (
    ORANGE,
    RED,
    _fmt,
    _img,
    _PlanView,
    _table,
    legend_html,
    overview_image,
    series_plot,
)

CYAN = (0, 170, 200)
MAGENTA = (210, 40, 160)


def _closest_approaches(result) -> list[dict]:
    """Per mover: the cycle, time, true distance and positions of the closest approach."""
    sc = result.scenario
    if sc.movers is None or not result.records:
        return []
    pos = np.array([r.position for r in result.records])
    t = np.array([r.time_s for r in result.records])
    out = []
    for m in sc.movers.movers:
        d = m.distance(pos, t)
        k = int(np.argmin(d))
        out.append(
            {
                "name": m.name,
                "kind": m.kind,
                "cycle": int(result.records[k].cycle),
                "time_s": float(t[k]),
                "distance_m": float(d[k]),
                "drone": pos[k],
                "mover": m.state_at(float(t[k]))[0],
            }
        )
    return sorted(out, key=lambda r: r["distance_m"])


def movers_image(result, extent, closest: list[dict] | None = None) -> np.ndarray:
    """The plan view with the movers' true and tracked paths and the closest approaches
    (``closest``: :func:`_closest_approaches` of ``result``, computed if None)."""
    sc = result.scenario
    img = overview_image(
        sc.city,
        extent,
        result.occ_map.occupied_centers(),
        [],
        None,
        result.flown_path(),
        sc.start,
        sc.goal,
    )
    x0, y0, x1, y1 = extent
    view = _PlanView(extent, max(1.0, min(4.0, 900 / max(x1 - x0, y1 - y0))))
    mon = result.monitor

    def poly(p, color, thick):
        p = np.asarray(p, dtype=np.float64)
        if len(p) >= 2:
            cv2.polylines(
                img, [np.round(view.px(p[:, :2])).astype(np.int32)], False, color, thick, cv2.LINE_AA
            )

    if mon is not None:
        for path in mon.true_paths.values():
            if path:
                poly(np.array(path)[:, 1:], CYAN, 1)
        for path in mon.track_paths.values():
            if len(path) >= 2:
                poly(np.array(path)[:, 1:], MAGENTA, 2)
    for ca in (_closest_approaches(result) if closest is None else closest)[:5]:
        for p, color in ((ca["drone"], RED), (ca["mover"], CYAN)):
            u, v = np.round(view.px(np.asarray(p)[None, :2])[0]).astype(int)
            cv2.circle(img, (int(u), int(v)), 5, color, 2, cv2.LINE_AA)
    return img


def _legend() -> str:
    return legend_html(
        [
            (RED, "flown track (circles: closest approaches)"),
            (CYAN, "movers' true paths (circles: where they were then)"),
            (MAGENTA, "movers as the drone tracked them"),
            (ORANGE, "drone's map: occupied voxels"),
        ]
    )


def dynamic_section(result, metrics: dict, extent) -> list[str]:
    """HTML pieces of the section (empty when nothing moved or changed and no prior was used)."""
    sc, cfg = result.scenario, result.config
    m = metrics
    dyn = m.get("dynamic") or {}
    if sc.movers is None and not sc.changes and m.get("prior_map") is None:
        return []
    recs = result.records
    out = ["<h2>A city that moves</h2>"]
    if sc.movers is not None:
        kinds = ", ".join(f"{n} {k}{'s' if n > 1 else ''}" for k, n in (dyn.get("mover_kinds") or {}).items())
        out.append(
            f"<p>{m.get('moving_obstacles', 0)} moving obstacles ({html.escape(kinds)}). The drone keeps what "
            "moves out of its map, tracks it and keeps clear of where it is going over the next "
            f"{cfg.mover_horizon_s:g} s.</p>"
        )
        closest = _closest_approaches(result)
        out += [_legend(), _img(movers_image(result, extent, closest), "movers: true and tracked paths")]
        t = np.array([r.time_s for r in recs])
        cm = np.array([r.clearance_moving_m for r in recs])
        cs = np.array([r.clearance_static_m for r in recs])
        out.append(
            _img(
                series_plot(
                    t,
                    [
                        ("to the static city (m)", np.minimum(cs, 20.0), (70, 120, 230)),
                        ("to the movers (m)", np.where(np.isfinite(cm), np.minimum(cm, 20.0), np.nan), CYAN),
                    ],
                    "true clearance vs. simulated time (s)",
                    [(f"drone radius {cfg.drone_radius_m:g} m", cfg.drone_radius_m, RED)],
                    y_max=20.0,
                ),
                "clearance to static and moving obstacles",
            )
        )
        rows = [
            (
                f"{ca['name']} ({ca['kind']})",
                round(ca["distance_m"], 2),
                f"at t = {ca['time_s']:.1f} s (cycle {ca['cycle']})",
            )
            for ca in closest
        ]
        out += ["<h3>Closest approach to each mover (true geometry, true time, metres)</h3>", _table(rows)]
        err = dyn.get("mover_position_error_m") or {}
        trail = dyn.get("phantom_trail") or {}
        vac = dyn.get("vacated_free_s") or {}
        out += [
            "<h3>Seeing the movers</h3>",
            _table(
                [
                    (
                        "detection recall",
                        dyn.get("mover_detection_recall"),
                        "frames with a drone or vehicle "
                        "within 20 m and visible, in which a track sat within 1.5 m of it; target >= 0.95",
                    ),
                    (
                        "position error median / p95 (m)",
                        f"{_fmt(err.get('median'))} / {_fmt(err.get('p95'))}",
                        "tracked vs true centre; target <= 0.5",
                    ),
                    (
                        "phantom trail",
                        trail.get("fraction_of_observed"),
                        "occupied share of the observed voxels "
                        "the movers swept until 2 s before the end; target <= 0.01",
                    ),
                    (
                        "vacated voxels freed (median / max s)",
                        f"{_fmt(vac.get('median'))} / {_fmt(vac.get('max'))}",
                        f"{vac.get('voxels', 0)} freed, {vac.get('still_occupied', 0)} still occupied",
                    ),
                    (
                        "min clearance to movers (m)",
                        m.get("min_clearance_moving_m"),
                        "true geometry, true time",
                    ),
                    ("min clearance to the static city (m)", m.get("min_clearance_static_m"), ""),
                ]
            ),
        ]
    reasons = m.get("replan_reasons") or {}
    if reasons:
        rows = [
            (
                k,
                v,
                {
                    "mover": "a mover's predicted sweep crossed the path",
                    "blocked": "the map showed the path inside the clearance",
                    "no_path": "no path yet",
                    "unseen": "held by space its cameras could not observe, it went round it",
                }.get(k, ""),
            )
            for k, v in reasons.items()
        ]
        out += ["<h3>Why it replanned</h3>", _table(rows)]
        events = [
            f"t = {r.time_s:.1f} s: {html.escape(r.replan_reason)}"
            + ("" if r.replan_ok else " (no path: hover)")
            for r in recs
            if r.replanned and r.replan_reason
        ]
        out.append(
            "<p><small>" + "; ".join(events[:60]) + (" ..." if len(events) > 60 else "") + "</small></p>"
        )
    changes = dyn.get("changes_seen") or []
    if changes:
        rows = []
        for c in changes:
            if c["kind"] == "added":
                rows.append(
                    (
                        f"new: {c['name']}",
                        c.get("delay_s"),
                        f"seconds from in trusted range "
                        f"(t = {_fmt(c.get('in_range_s'))} s) to in the map; target <= 0.5",
                    )
                )
            else:
                rows.append(
                    (
                        f"gone: {c['name']}",
                        c.get("free_delay_s_max"),
                        f"seconds from first seen through "
                        f"to free (worst voxel; p95 {_fmt(c.get('free_delay_s_p95'))} s; "
                        f"{c.get('freed_voxels')} of {c.get('touched_voxels')} seen freed, "
                        f"{c.get('freed_after_2s_voxels', '-')} after 2 s); target <= 2",
                    )
                )
        out += ["<h3>Changes since the prior map</h3>", _table(rows)]
    prior = m.get("prior_map")
    if prior:
        out.append(
            f"<p>Prior map: {html.escape(str(prior['source']))} ({prior['known_fraction']:.0%} of the area known). "
            f"The cameras added {prior['added_voxels']} occupied voxels and freed {prior['removed_voxels']} of it; "
            f"{prior['disagreement']:.1%} of the observed voxels disagreed with it"
            + (
                " — <b>that much disagreement suggests a map of another place or frame</b>."
                if prior["disagreement"] > 0.3
                else "."
            )
            + "</p>"
        )
    return out


def faults_section(result, metrics: dict) -> list[str]:
    """HTML pieces of the faults section: the injected faults and when each was detected, every
    failsafe decision with its reason, and the timeline of the failsafe mode (empty without faults
    or decisions)."""
    m = metrics
    faults, events = m.get("faults") or [], m.get("failsafe_events") or []
    if not faults and not events:
        return []
    out = [
        "<h2>Faults and failsafes</h2>",
        f"<p>Outcome: <b>{html.escape(str(m.get('outcome')))}</b>. The drone judges its data each cycle "
        "(black, frozen, missing, late, noisy frames; overruns); without trustworthy depth it brakes to a "
        f"hover, and after {result.config.failsafe_after_s:g} s it acts ({html.escape(result.config.failsafe)}).</p>",
    ]
    if faults:
        rows = [
            (
                f"{f['name']}" + (f" ({f['value']})" if f.get("value") is not None else ""),
                f.get("detect_delay_s"),
                f"from t = {f['onset_s']} s"
                + ("" if f.get("duration_s") is None else f" for {f['duration_s']} s")
                + (
                    f"; detected at {f['detected_s']} s"
                    if f.get("detected_s") is not None
                    else ("; no frame arrived while it lasted" if f.get("masked") else "; not detected")
                ),
            )
            for f in faults
        ]
        out += ["<h3>Injected faults (seconds to detection; target <= 0.3)</h3>", _table(rows)]
    recs = result.records
    if recs:
        t = np.array([r.time_s for r in recs])
        level = {"fly": 0.0, "hold": 1.0, "return": 2.0, "land": 3.0}
        out.append(
            _img(
                series_plot(
                    t,
                    [
                        (
                            "mode: 0 fly, 1 hold, 2 return, 3 land",
                            np.array([level.get(r.mode, 0.0) for r in recs]),
                            RED,
                        ),
                        ("speed (m/s)", np.array([r.speed_mps for r in recs]), (20, 150, 60)),
                        (
                            "untrusted data",
                            np.array([0.5 if r.health and r.mode != "fly" else 0.0 for r in recs]),
                            ORANGE,
                        ),
                    ],
                    "failsafe mode and speed vs. simulated time (s)",
                    [],
                    y_max=max(4.0, 1.2 * max(r.speed_mps for r in recs)),
                ),
                "failsafe timeline",
            )
        )
    if events:
        rows = [(f"t = {e['time_s']} s", e["decision"], e["reason"]) for e in events[:80]]
        out += ["<h3>Every failsafe decision</h3>", _table(rows)]
    return out


__all__ = ["dynamic_section", "faults_section", "movers_image"]
