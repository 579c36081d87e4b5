"""Accuracy of a ``skyrecon survey`` output against a synthetic survey's truth (``skyrecon render survey``).

* camera position error: each registered photo's estimated position (``survey.json`` lat/lon/alt)
  against its true centre, both in the truth's ENU frame, metres; beside it the GPS limit, the
  error of the true shape placed on the tags by a similarity (what a perfect model would reach);
* DSM height error: per covered DSM cell, the DSM height against the true highest surface at the
  cell centre (a ray cast straight down through the synthetic city), metres; absolute, and
  relative (``_relative``: the cells moved by the similarity that best maps the estimated camera
  centres onto the true ones, which takes the georeferencing's error out: the model's own shape);
* cloud accuracy / completeness: the dense cloud against points sampled on the true surface seen
  from above (the same downward rays on a 0.25 m grid), at 0.3 m.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from skyrecon.eval.mvs_metrics import evaluate_cloud
from skyrecon.io.las import read_las
from skyrecon.sfm.align import umeyama
from skyrecon.sim import generate_city
from skyrecon.survey.geo import GeoOrigin, enu_from_lla, lla_from_projected


def true_centres(photos_root: Path) -> dict[str, np.ndarray]:
    out = {}
    for line in (photos_root / "cameras_true.txt").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        t = line.split()
        out[t[0]] = np.array([float(t[1]), float(t[2]), float(t[3])])
    return out


def _camera_pairs(
    doc: dict[str, Any], true: dict[str, np.ndarray], origin: GeoOrigin
) -> tuple[np.ndarray, np.ndarray]:
    """(estimated, true) centres (N, 3) of the registered photos, metres in the truth's ENU frame,
    from a ``survey.json`` document and the true centres by name."""
    cams = [c for c in doc["cameras"] if c["name"] in true]
    est = enu_from_lla(origin, [c["lat"] for c in cams], [c["lon"] for c in cams], [c["alt"] for c in cams])
    return est, np.stack([true[c["name"]] for c in cams])


def gps_limit(photos_root: Path) -> float | None:
    """The median camera error of the best GPS-only georeferencing there can be: the *true* camera
    centres placed by the least-squares similarity onto the photos' GPS tags (the wrong tags left
    out), metres. A survey whose shape were perfect would still be this far off: the tags' own
    noise, averaged over the photos, sets it. None for real sets (their tags are the truth)."""
    from skyrecon.survey.exif import read_photo_meta

    truth = json.loads((photos_root / "survey_truth.json").read_text())
    if truth.get("real"):
        return None
    origin = GeoOrigin.from_json(truth["origin"])
    true = true_centres(photos_root)
    wrong = set(truth["wrong_tags"])
    tagged = [(n, read_photo_meta(photos_root / "images" / n)) for n in sorted(true) if n not in wrong]
    tagged = [(n, m) for n, m in tagged if m.has_gps]
    tags = enu_from_lla(
        origin, [m.lat_deg for _, m in tagged], [m.lon_deg for _, m in tagged], [m.alt_m for _, m in tagged]
    )
    centres = np.stack([true[n] for n, _ in tagged])
    placed = umeyama(centres, tags).transform.apply(centres)
    return float(np.median(np.linalg.norm(placed - centres, axis=1)))


def camera_errors(survey_dir: Path, photos_root: Path) -> dict[str, Any]:
    truth = json.loads((photos_root / "survey_truth.json").read_text())
    origin = GeoOrigin.from_json(truth["origin"])
    doc = json.loads((survey_dir / "survey.json").read_text())
    true = true_centres(photos_root)
    est, true_c = _camera_pairs(doc, true, origin)
    err = np.linalg.norm(est - true_c, axis=1)
    wrong = set(truth["wrong_tags"])
    aside = {s["name"] for s in doc["set_aside"]}
    return {
        "registered": f"{len(err)}/{len(true)}",
        "cam_err_median_m": float(np.median(err)),
        "cam_err_median_m_gps_limit": gps_limit(photos_root),
        "cam_err_p95_m": float(np.percentile(err, 95)),
        "cam_err_max_m": float(err.max()),
        "wrong_tags_found": f"{len(wrong & aside)}/{len(wrong)}",
        "good_tags_set_aside": len(aside - wrong),
    }


def _true_top(city, east: np.ndarray, north: np.ndarray) -> np.ndarray:
    """True highest surface height (z, metres) straight below (E, N) points of the truth's frame."""
    top = 1000.0
    o = np.stack([east, north, np.full_like(east, top)], axis=1)
    d = np.tile([0.0, 0.0, -1.0], (len(o), 1))
    t = city.raycast(o, d)
    return top - t


def dsm_errors(survey_dir: Path, photos_root: Path) -> dict[str, Any]:
    import rasterio

    truth = json.loads((photos_root / "survey_truth.json").read_text())
    origin = GeoOrigin.from_json(truth["origin"])
    city = generate_city(
        truth["city_seed"], size_m=float(truth["city_extent_m"][2] - truth["city_extent_m"][0])
    )
    with rasterio.open(survey_dir / "dsm.tif") as ds:
        dsm = ds.read(1).astype(np.float64)
        tr = ds.transform
        epsg = ds.crs.to_epsg()
        nodata = ds.nodata
    valid = np.isfinite(dsm) if nodata is None or np.isnan(nodata) else (dsm != nodata) & np.isfinite(dsm)
    rows, cols = np.nonzero(valid)
    e = tr.c + tr.a * (cols + 0.5)
    n = tr.f + tr.e * (rows + 0.5)
    lat, lon = lla_from_projected(e, n, epsg)
    # the DSM height (ellipsoidal) at the cell -> the truth frame's z; the cell centre's horizontal position
    enu = enu_from_lla(origin, lat, lon, dsm[rows, cols])
    # keep to the city (outside it the ground is all there is)
    ext = truth["city_extent_m"]
    inside = (enu[:, 0] > ext[0]) & (enu[:, 0] < ext[2]) & (enu[:, 1] > ext[1]) & (enu[:, 1] < ext[3])
    enu = enu[inside]
    z_true = _true_top(city, enu[:, 0], enu[:, 1])
    err = np.abs(enu[:, 2] - z_true)
    # the DSM's own shape: its cells (as 3D points) moved by the similarity that best maps the
    # estimated camera centres onto the true ones, so the georeferencing's error (GPS noise) is
    # taken out and what is left is the reconstruction's
    doc = json.loads((survey_dir / "survey.json").read_text())
    est, true = _camera_pairs(doc, true_centres(photos_root), origin)
    rel = umeyama(est, true).transform.apply(enu)
    err_rel = np.abs(rel[:, 2] - _true_top(city, rel[:, 0], rel[:, 1]))
    return {
        "dsm_cells": int(len(err)),
        "dsm_within_0.3m": float(np.mean(err <= 0.3)),
        "dsm_err_median_m": float(np.median(err)),
        "dsm_err_p95_m": float(np.percentile(err, 95)),
        "dsm_within_0.3m_relative": float(np.mean(err_rel <= 0.3)),
        "dsm_err_median_m_relative": float(np.median(err_rel)),
    }


def cloud_scores(survey_dir: Path, photos_root: Path, tau: float = 0.3) -> dict[str, Any]:
    truth = json.loads((photos_root / "survey_truth.json").read_text())
    origin = GeoOrigin.from_json(truth["origin"])
    city = generate_city(
        truth["city_seed"], size_m=float(truth["city_extent_m"][2] - truth["city_extent_m"][0])
    )
    cloud_path = next(p for p in (survey_dir / "cloud.laz", survey_dir / "cloud.las") if p.exists())
    pts, _ = read_las(cloud_path)
    import laspy

    epsg = laspy.read(cloud_path).header.parse_crs().to_epsg()
    lat, lon = lla_from_projected(pts[:, 0], pts[:, 1], epsg)
    enu = enu_from_lla(origin, lat, lon, pts[:, 2])
    lo, hi = enu[:, :2].min(axis=0), enu[:, :2].max(axis=0)
    ext = truth["city_extent_m"]
    lo, hi = np.maximum(lo, ext[:2]), np.minimum(hi, ext[2:])
    g = np.mgrid[lo[0] : hi[0] : 0.25, lo[1] : hi[1] : 0.25].reshape(2, -1).T
    ref = np.column_stack([g, _true_top(city, g[:, 0], g[:, 1])])
    # only the area the photos covered, shrunk by 10 m (edges are seen by few photos)
    cov = json.loads((photos_root / "survey_truth.json").read_text())["area_m"] / 2 - 10
    keep = (np.abs(ref[:, 0]) < cov) & (np.abs(ref[:, 1]) < cov)
    ref = ref[keep]
    inside = (np.abs(enu[:, 0]) < cov) & (np.abs(enu[:, 1]) < cov)
    s = evaluate_cloud(
        enu[inside], ref, [tau], reference_distance=lambda p: city.distance(p, include_ground=True)
    )
    acc, comp, _ = s.at(tau)
    return {
        "cloud_accuracy@0.3m": float(acc),
        "cloud_completeness@0.3m": float(comp),
        "cloud_points": int(len(pts)),
    }
