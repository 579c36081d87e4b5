"""A self-contained HTML report of a structure-from-motion run (works offline: histograms are
inline SVG, the top view is an embedded PNG)."""

from __future__ import annotations

import base64
import html
import math

import cv2
import numpy as np

from skyrecon.io.images import encode_png
from skyrecon.sfm.result import SfMResult

__all__ = ["svg_histogram", "top_view_png", "report_html"]


def svg_histogram(
    values: np.ndarray,
    bins: int | np.ndarray,
    title: str,
    xlabel: str,
    width: int = 460,
    height: int = 240,
    integer: bool = False,
) -> str:
    """An inline SVG bar chart of the histogram of ``values`` (1-D)."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return f"<p><em>{html.escape(title)}: no data</em></p>"
    counts, edges = np.histogram(v, bins=bins)
    ml, mr, mt, mb = 48, 12, 26, 38
    pw, ph = width - ml - mr, height - mt - mb
    cmax = max(int(counts.max()), 1)
    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
        f'viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="11">',
        f'<text x="{width / 2}" y="16" text-anchor="middle" font-size="13">{html.escape(title)}</text>',
        f'<line x1="{ml}" y1="{mt + ph}" x2="{ml + pw}" y2="{mt + ph}" stroke="#333"/>',
        f'<line x1="{ml}" y1="{mt}" x2="{ml}" y2="{mt + ph}" stroke="#333"/>',
    ]
    n = len(counts)
    bw = pw / n
    for k, c in enumerate(counts):
        h = ph * c / cmax
        out.append(
            f'<rect x="{ml + k * bw + 0.5:.1f}" y="{mt + ph - h:.1f}" width="{max(bw - 1, 0.5):.1f}" '
            f'height="{h:.1f}" fill="#4a7ab5"><title>{edges[k]:.3g}-{edges[k + 1]:.3g}: {int(c)}</title></rect>'
        )
    for frac in (0.0, 0.5, 1.0):
        y = mt + ph * (1 - frac)
        out.append(f'<text x="{ml - 4}" y="{y + 4:.1f}" text-anchor="end">{int(round(cmax * frac))}</text>')
    ticks = np.linspace(0, n, min(n, 6) + 1).astype(int)
    for k in np.unique(ticks):
        x = ml + k * bw
        lab = f"{edges[k]:.0f}" if integer else f"{edges[k]:.2g}"
        out.append(f'<text x="{x:.1f}" y="{mt + ph + 14}" text-anchor="middle">{lab}</text>')
    out.append(f'<text x="{ml + pw / 2}" y="{height - 6}" text-anchor="middle">{html.escape(xlabel)}</text>')
    out.append("</svg>")
    return "".join(out)


def _view_basis(centers: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(3, 3) rows: two in-picture axes and the viewing axis (least variance of the cameras)."""
    data = centers if len(centers) >= 3 else points
    if len(data) < 3:
        return np.eye(3)
    d = data - data.mean(axis=0)
    _, S, Vt = np.linalg.svd(d, full_matrices=False)
    if len(S) < 3 or S[1] < 1e-9 * max(S[0], 1e-300):  # collinear cameras: use the points
        d = points - points.mean(axis=0) if len(points) >= 3 else d
        _, _, Vt = np.linalg.svd(d, full_matrices=False)
    B = Vt.copy()
    if np.linalg.det(B) < 0:
        B[1] = -B[1]
    return B


def top_view_png(result: SfMResult, size: int = 900, max_points: int = 60000, seed: int = 0) -> bytes:
    """PNG of the cameras (red, with viewing directions) and the points (their colours) seen
    along the direction in which the camera centres spread least (from above for flights)."""
    rec = result.reconstruction
    xyz, rgb = rec.points_array()
    ims = sorted(rec.images.values(), key=lambda im: im.image_id)
    C = np.array([im.center_world for im in ims]).reshape(-1, 3)
    Z = np.array([im.cam_from_world.R[2] for im in ims]).reshape(-1, 3)  # optical axes in the world
    img = np.full((size, size, 3), 255, np.uint8)
    if len(C) == 0 and len(xyz) == 0:
        return encode_png(img)
    B = _view_basis(C, xyz)
    if len(xyz) > max_points:
        sel = np.random.default_rng(seed).choice(len(xyz), max_points, replace=False)
        xyz, rgb = xyz[sel], rgb[sel]
    p2 = xyz @ B[:2].T
    c2 = C @ B[:2].T
    allp = np.concatenate([c2, p2[: max(1, len(p2))]]) if len(p2) else c2
    if len(p2) > 20:  # frame the robust bulk of the points plus all cameras
        lo = np.minimum(np.percentile(p2, 1, axis=0), c2.min(axis=0) if len(c2) else np.inf)
        hi = np.maximum(np.percentile(p2, 99, axis=0), c2.max(axis=0) if len(c2) else -np.inf)
    else:
        lo, hi = allp.min(axis=0), allp.max(axis=0)
    span = float(max(hi[0] - lo[0], hi[1] - lo[1], 1e-9))
    margin = 30
    s = (size - 2 * margin) / span
    centre = (lo + hi) / 2

    def px(q: np.ndarray) -> np.ndarray:
        return np.stack([size / 2 + (q[:, 0] - centre[0]) * s, size / 2 - (q[:, 1] - centre[1]) * s], axis=1)

    if len(p2):
        uv = np.round(px(p2)).astype(np.int64)
        ok = (uv[:, 0] >= 0) & (uv[:, 0] < size) & (uv[:, 1] >= 0) & (uv[:, 1] < size)
        img[uv[ok, 1], uv[ok, 0]] = rgb[ok]
        img = np.asarray(
            cv2.erode(img, np.ones((2, 2), np.uint8)), np.uint8
        )  # 2x2 dots (darker wins over white)
    if len(c2):
        cu = px(c2)
        d2 = Z @ B[:2].T
        arrow = 0.04 * span * s
        for (u, v), (du, dv) in zip(cu, d2):
            n = math.hypot(du, dv)
            end = (
                (int(round(u + arrow * du / n)), int(round(v - arrow * dv / n)))
                if n > 1e-9
                else (int(u), int(v))
            )
            cv2.line(img, (int(round(u)), int(round(v))), end, (200, 30, 30), 1, cv2.LINE_AA)
            cv2.circle(img, (int(round(u)), int(round(v))), 3, (220, 20, 20), -1, cv2.LINE_AA)
        if len(cu) > 1:
            cv2.polylines(img, [np.round(cu).astype(np.int32)], False, (240, 150, 150), 1, cv2.LINE_AA)
    bar = 10 ** math.floor(math.log10(span / 5)) if span > 0 else 1.0
    cv2.line(img, (margin, size - 15), (margin + int(bar * s), size - 15), (0, 0, 0), 2)
    cv2.putText(
        img, f"{bar:g} units", (margin, size - 20), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA
    )
    return encode_png(img)


def _table(rows: list[tuple[str, str]]) -> str:
    return (
        "<table>"
        + "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in rows)
        + "</table>"
    )


def report_html(result: SfMResult, title: str = "Structure from motion") -> str:
    """The report as one HTML string (no external resources)."""
    rec = result.reconstruction
    errs = rec.reprojection_errors()
    tl = np.array([len(p.track) for p in rec.points3d.values()], np.int64)
    n, k = len(result.images), result.num_registered
    d = result.diagnostics
    m = d.get("mapper", {})
    summary = [
        ("registered images", f"{k} of {n}"),
        ("3D points", f"{len(rec.points3d)}"),
        ("observations", f"{int(tl.sum()) if len(tl) else 0}"),
        ("mean track length", f"{tl.mean():.2f}" if len(tl) else "-"),
        (
            "reprojection error (mean / median)",
            f"{errs.mean():.3f} / {np.median(errs):.3f} px" if len(errs) else "-",
        ),
        (
            "pairs (mode, matched, verified)",
            f"{d.get('pairing', {}).get('mode', '?')}, {d.get('pairing', {}).get('num_pairs', '?')}, "
            f"{d.get('pairs_verified', '?')}",
        ),
        ("initial pair", f"{m.get('init_pair', '-')}"),
        ("bundle adjustments (local / global)", f"{m.get('local_ba', 0)} / {m.get('global_ba', 0)}"),
    ]
    timing = [(k_, f"{v:.2f} s") for k_, v in result.timings.items()]
    hist_err = svg_histogram(
        errs,
        np.linspace(0, max(2.0, float(np.percentile(errs, 99.5)) if len(errs) else 2.0), 41),
        "Reprojection error",
        "pixels",
    )
    hist_tl = svg_histogram(
        tl,
        np.arange(1.5, max(int(tl.max()) if len(tl) else 2, 3) + 1.5),
        "Track length",
        "images per point",
        integer=True,
    )
    png = base64.b64encode(top_view_png(result)).decode("ascii")
    rows = []
    for im in result.images:
        status = "registered" if im.registered else "left out"
        err = f"{im.mean_error_px:.3f}" if im.registered and np.isfinite(im.mean_error_px) else ""
        rows.append(
            f"<tr class='{'ok' if im.registered else 'bad'}'><td>{html.escape(im.name)}</td><td>{status}</td>"
            f"<td>{im.num_features}</td><td>{im.num_points if im.registered else ''}</td><td>{err}</td>"
            f"<td>{html.escape(im.reason)}</td></tr>"
        )
    warn = "".join(f"<li>{html.escape(w)}</li>" for w in result.warnings)
    note = html.escape(result.note)
    css = (
        "body{font-family:sans-serif;margin:24px;color:#222}table{border-collapse:collapse;margin:8px 0}"
        "th,td{border:1px solid #ccc;padding:3px 8px;text-align:left;font-size:13px}th{background:#f3f3f3}"
        "tr.bad td{background:#fde8e8}.figs{display:flex;flex-wrap:wrap;gap:16px}pre{background:#f6f6f6;padding:8px}"
        "img{border:1px solid #ccc;max-width:100%}"
    )
    return (
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
        f"<style>{css}</style></head><body><h1>{html.escape(title)}</h1>"
        f"<pre>{note}</pre>"
        + (f"<h2>Warnings</h2><ul>{warn}</ul>" if warn else "")
        + f"<h2>Summary</h2>{_table(summary)}<h2>Timings</h2>{_table(timing)}"
        f"<h2>Figures</h2><div class='figs'>{hist_err}{hist_tl}</div>"
        f"<h3>Top view (cameras red, points in their colours)</h3>"
        f"<img alt='top view' src='data:image/png;base64,{png}'/>"
        f"<h2>Images</h2><table><tr><th>image</th><th>status</th><th>features</th><th>3D points</th>"
        f"<th>mean error (px)</th><th>reason</th></tr>{''.join(rows)}</table>"
        f"<p style='color:#888;font-size:12px'>seed {result.seed}</p></body></html>\n"
    )
