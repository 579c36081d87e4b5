"""Writing a survey: model, LAZ cloud, GeoTIFFs, map, footprint, ``survey.json`` and ``report.html``.

Frames: the model, the map and ``survey.json``'s ``enu`` entries are in the local ENU frame around
``survey.json``'s ``origin`` (metres); ``cloud.laz``, ``dsm.tif`` and ``ortho.tif`` are in the
projected system (UTM zone of the origin unless told otherwise), heights WGS84 ellipsoidal metres;
``footprint.geojson`` and the cameras' ``lat``/``lon`` are WGS84 degrees.
"""

from __future__ import annotations

import html
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from skyrecon.core.reconstruction import Reconstruction
from skyrecon.io.atomic import make_temp_dir, sweep_stale_temps, write_text_atomic
from skyrecon.io.colmap import write_colmap_text
from skyrecon.io.las import write_point_cloud
from skyrecon.mapping import OccupancyMap, export_occupied_ply, save_map, write_flown_path, write_map_preview
from skyrecon.memory import release_free_memory
from skyrecon.report.mission_report import png_data_uri
from skyrecon.survey.geo import lla_from_enu, projected_from_enu
from skyrecon.survey.pipeline import SurveyResult
from skyrecon.survey.rasters import SurfaceRasters, footprint_geojson, surface_rasters, write_geotiff

__all__ = ["write_survey_outputs", "survey_json", "GEO_ORIGIN_FILE"]

#: The map directory's geographic origin (lat, lon, alt of its world origin), for ``skyrecon plan``.
GEO_ORIGIN_FILE = "geo_origin.json"


def _json(path: Path, doc: dict[str, Any]) -> None:
    write_text_atomic(path, json.dumps(doc, indent=2, allow_nan=False) + "\n")


def _finite(v: float | None, nd: int = 4) -> float | None:
    return None if v is None or not np.isfinite(v) else round(float(v), nd)


def survey_json(result: SurveyResult, rasters: SurfaceRasters | None, files: list[str]) -> dict[str, Any]:
    """The ``survey.json`` document (see the module and the command's help)."""
    model = result.model
    geo = result.georef
    ims = sorted(model.images.values(), key=lambda im: im.name)
    centres = np.array([im.center_world for im in ims]).reshape(-1, 3)
    lat, lon, alt = lla_from_enu(result.origin, centres)
    cams = []
    for k, im in enumerate(ims):
        r = geo.gps_residuals_m.get(im.name)
        cams.append(
            {
                "name": im.name,
                "lat": round(float(lat[k]), 9),
                "lon": round(float(lon[k]), 9),
                "alt": round(float(alt[k]), 3),
                "enu_m": [round(float(v), 4) for v in centres[k]],
                "gps_residual_m": _finite(r, 3),
                "set_aside": im.name in geo.set_aside,
            }
        )
    res = np.array([v for n, v in geo.gps_residuals_m.items() if n not in geo.set_aside])
    doc: dict[str, Any] = {
        "command": "skyrecon survey",
        "origin": result.origin.to_json(),
        "frame": "local East-North-Up metres around origin (model/, map/, enu_m); heights WGS84 ellipsoidal",
        "camera": {
            "source": result.camera_source,
            "K": result.camera.K.tolist(),
            "size": list(result.camera.size),
        },
        "georeference": {
            **geo.to_json_dict(),
            "gps_residual_median_m": _finite(float(np.median(res))) if len(res) else None,
            "gps_residual_rms_m": _finite(float(np.sqrt(np.mean(res**2)))) if len(res) else None,
        },
        "set_aside": [{"name": n, "residual_m": round(r, 3)} for n, r in geo.set_aside.items()],
        "photos": len(result.metas),
        "registered": len(model.images),
        "not_registered": result.unregistered,
        "cameras": cams,
        "points_sparse": len(model.points3d),
        "points_dense": len(result.mvs.cloud),
        "timings_s": {k: round(v, 2) for k, v in result.timings_s.items()},
        "diagnostics": result.diagnostics,
        "warnings": result.warnings,
        "files": sorted(files),
    }
    if rasters is not None:
        doc["rasters"] = {
            "epsg": rasters.epsg,
            "cell_m": rasters.cell_m,
            "shape": list(rasters.shape),
            "covered_cells": int(rasters.valid.sum()),
        }
    return doc


def write_unreferenced_outputs(
    model: Reconstruction,
    unregistered: dict[str, str],
    warnings: list[str],
    reason: str,
    photos: int,
    out: str | Path,
) -> list[str]:
    """What a survey that cannot be georeferenced can still give: ``model/`` (COLMAP text, the
    structure-from-motion model in its own gauge: arbitrary origin, orientation and scale) and
    ``survey.json`` (``georeferenced: false``, why, and per photo its centre in that gauge).
    Returns the names written (``survey.json`` last)."""
    out = Path(out)
    write_colmap_text(out / "model", model)
    ims = sorted(model.images.values(), key=lambda im: im.name)
    doc = {
        "command": "skyrecon survey",
        "georeferenced": False,
        "why": reason,
        "frame": "the structure-from-motion model's own gauge (arbitrary origin, orientation and scale)",
        "photos": photos,
        "registered": len(model.images),
        "not_registered": unregistered,
        "cameras": [
            {"name": im.name, "center_model": [round(float(v), 6) for v in im.center_world]} for im in ims
        ],
        "points_sparse": len(model.points3d),
        "warnings": warnings,
        "files": ["model/", "survey.json"],
    }
    _json(out / "survey.json", doc)
    return ["model/", "survey.json"]


def _write_map(result: SurveyResult, out: Path) -> None:
    """``map/``: the map (``skyrecon plan`` reads it), flown track, occupied voxels, preview and the
    geographic origin of its frame; built beside ``out`` and swapped in. (The survey's footprint is
    ``OUT/footprint.geojson``, from the DSM.)"""
    out.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale_temps(out.parent, recursive=False)
    tmp = make_temp_dir(out.parent, out.name)
    try:
        occ = result.map
        save_map(occ, tmp)
        if len(result.track):
            write_flown_path(tmp, result.track, 1.0)
        export_occupied_ply(occ, tmp / "occupied.ply")
        o = result.origin
        write_map_preview(occ, tmp / "preview.png", [result.track] if len(result.track) else [])
        _json(tmp / GEO_ORIGIN_FILE, {**o.to_json(), "frame": "map world = local East-North-Up metres"})
        counts = occ.counts()
        _json(
            tmp / "map_summary.json",
            {"source": "skyrecon survey", "voxels": {k: int(v) for k, v in counts.items()}},
        )
        if out.exists():
            old = make_temp_dir(out.parent, f"{out.name}.old")
            os.rmdir(old)
            os.replace(out, old)
            shutil.rmtree(old, ignore_errors=True)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_survey_outputs(
    result: SurveyResult,
    out: str | Path,
    cloud_format: str = "laz",
    cell_m: float | None = None,
    epsg: int | None = None,
    release_map: bool = False,
) -> list[str]:
    """Write every output of a survey into ``out``; returns the names written (``survey.json`` last).

    With ``release_map`` (the command line), ``result.map`` is replaced by an empty map of the same
    voxel size once ``map/`` is written: a survey's map is gigabytes, and the cloud and rasters
    written next need room."""
    t0 = time.perf_counter()
    out = Path(out)
    files: list[str] = []
    write_colmap_text(out / "model", result.model)
    files.append("model/")
    # the map first: its export's temporaries are gone before the cloud's arrays are made
    _write_map(result, out / "map")
    if release_map:
        result.map = OccupancyMap(voxel_size_m=result.map.voxel_size)
    release_free_memory()
    cloud = result.mvs.cloud
    rasters = None
    if len(cloud):
        proj, code = projected_from_enu(result.origin, cloud.points.astype(np.float64), epsg)
        written = write_point_cloud(
            out / "cloud.laz",
            cloud,
            cloud_format,
            crs=f"EPSG:{code}" if cloud_format != "ply" else None,
            points=proj,
        )
        files.append(written.name)
        del proj
        release_free_memory()  # the writer's point records
        rasters = surface_rasters(cloud.points, cloud.colors, result.origin, cell_m, code)
        release_free_memory()
        write_geotiff(out / "dsm.tif", rasters, "dsm")
        write_geotiff(out / "ortho.tif", rasters, "ortho")
        write_text_atomic(out / "footprint.geojson", json.dumps(footprint_geojson(rasters), indent=1) + "\n")
        files += ["dsm.tif", "ortho.tif", "footprint.geojson"]
    files.append("map/")
    result.timings_s["outputs"] = time.perf_counter() - t0
    write_text_atomic(out / "report.html", survey_report_html(result, rasters))
    files.append("report.html")
    files.append("survey.json")
    _json(out / "survey.json", survey_json(result, rasters, files))
    return files


# ----------------------------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------------------------
def _overlay(result: SurveyResult, rasters: SurfaceRasters) -> np.ndarray:
    """The orthophoto (scaled to about 900 px, at most 4x up) with the estimated camera positions (blue), their GPS
    tags (grey lines to them) and the set-aside tags (red)."""
    img = rasters.ortho_rgb.copy()
    img[~rasters.valid] = 255
    h, w = img.shape[:2]
    s = min(4.0, 900.0 / max(h, w, 1))
    if s != 1.0:
        interp = cv2.INTER_AREA if s < 1.0 else cv2.INTER_NEAREST
        img = cv2.resize(img, (max(1, int(w * s)), max(1, int(h * s))), interpolation=interp)
    a, _, c, _, e, f = rasters.transform

    def px(enu: np.ndarray) -> np.ndarray:
        p, _ = projected_from_enu(result.origin, enu.reshape(-1, 3), rasters.epsg)
        return np.stack([(p[:, 0] - c) / a * s, (p[:, 1] - f) / e * s], axis=1)

    names = sorted(result.model.images)
    ims = [result.model.images[k] for k in names]
    if not ims:
        return img
    est = px(np.array([im.center_world for im in ims]))
    for k, im in enumerate(ims):
        g = result.gps_enu.get(im.name)
        if g is None:
            continue
        q = px(g)[0]
        bad = im.name in result.georef.set_aside
        color = (220, 30, 30) if bad else (120, 120, 120)
        cv2.line(img, tuple(int(v) for v in est[k]), tuple(int(v) for v in q), color, 1, cv2.LINE_AA)
        cv2.circle(img, tuple(int(v) for v in q), 3 if bad else 2, color, -1, cv2.LINE_AA)
    for p in est:
        cv2.circle(img, tuple(int(v) for v in p), 3, (30, 80, 230), -1, cv2.LINE_AA)
    return img


def _hist(values: np.ndarray, bins: int = 20, width: int = 480, height: int = 160) -> np.ndarray:
    img = np.full((height, width, 3), 255, np.uint8)
    if len(values) == 0:
        return img
    hi = float(np.percentile(values, 99)) or 1.0
    counts, _ = np.histogram(np.clip(values, 0, hi), bins=bins, range=(0, hi))
    bw = width // bins
    top = max(int(counts.max()), 1)
    for i, n in enumerate(counts):
        bh = int((height - 20) * n / top)
        cv2.rectangle(
            img, (i * bw + 1, height - 15 - bh), ((i + 1) * bw - 2, height - 15), (70, 110, 200), -1
        )
    cv2.putText(img, f"0 .. {hi:.2f} m", (4, height - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    return img


def survey_report_html(result: SurveyResult, rasters: SurfaceRasters | None) -> str:
    """A one-page HTML report: camera positions over the orthophoto, GPS residuals, stage times."""
    geo = result.georef
    esc = html.escape
    res = np.array([v for n, v in geo.gps_residuals_m.items() if n not in geo.set_aside])
    rows = [
        ("photos", f"{len(result.metas)} ({len(result.model.images)} registered)"),
        ("georeferenced to", "ground control points" if geo.method == "gcp" else "GPS tags"),
        (
            "origin (lat, lon, alt)",
            f"{result.origin.lat_deg:.7f}, {result.origin.lon_deg:.7f}, {result.origin.alt_m:.2f} m",
        ),
        ("fit RMS", f"{geo.rms_m:.3f} m"),
        (
            "GPS residual median / RMS",
            f"{np.median(res):.2f} / {np.sqrt(np.mean(res**2)):.2f} m" if len(res) else "n/a",
        ),
        ("tags set aside", ", ".join(f"{n} ({r:.1f} m)" for n, r in geo.set_aside.items()) or "none"),
        ("dense points", f"{len(result.mvs.cloud)}"),
    ]
    if rasters is not None:
        rows.append(
            (
                "rasters",
                f"EPSG:{rasters.epsg}, {rasters.cell_m:g} m cells, {rasters.shape[1]} x {rasters.shape[0]}",
            )
        )
    table = "".join(f"<tr><th>{esc(k)}</th><td>{esc(str(v))}</td></tr>" for k, v in rows)
    times = "".join(f"<tr><th>{esc(k)}</th><td>{v:.1f} s</td></tr>" for k, v in result.timings_s.items())
    times += f"<tr><th>total</th><td>{sum(result.timings_s.values()):.1f} s</td></tr>"
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>skyrecon survey</title>",
        "<style>body{font-family:sans-serif;margin:2em;max-width:1000px}th{text-align:left;padding-right:1em}"
        "img{max-width:100%;border:1px solid #ccc}</style></head><body>",
        "<h1>Survey</h1>",
        f"<table>{table}</table>",
    ]
    if rasters is not None:
        parts += [
            "<h2>Camera positions over the orthophoto</h2>",
            "<p>blue: estimated camera centres; grey: GPS tags (line to the estimate); red: tags set aside</p>",
            f"<img alt='orthophoto with cameras' src='{png_data_uri(_overlay(result, rasters))}'>",
        ]
    parts += [
        "<h2>GPS residuals (tags kept)</h2>",
        f"<img alt='GPS residual histogram' src='{png_data_uri(_hist(res))}'>",
        "<h2>Time per stage</h2>",
        f"<table>{times}</table>",
    ]
    if result.warnings:
        parts.append(
            "<h2>Warnings</h2><ul>" + "".join(f"<li>{esc(w)}</li>" for w in result.warnings) + "</ul>"
        )
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"
