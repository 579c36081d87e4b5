"""Georeferencing a structure-from-motion model: to the photos' GPS tags, or to ground control points.

Both fit one similarity ``enu_from_model`` (``p_enu = s R p_model + t``) into the survey's local
East-North-Up frame (metres, see :mod:`skyrecon.survey.geo`):

* :func:`georeference_to_gps`: the camera centres against the GPS positions, robustly
  (:func:`skyrecon.sfm.model_align.align_to_positions`, RANSAC + refit). The inlier distance adapts
  to the GPS noise: a generous first fit, then ``3 x`` the median residual (between 1 m and the
  first threshold); the tags farther off are set aside and named. Camera centres of a survey lie
  nearly on one plane, so the GPS heights alone fix the model's tilt poorly (a few metres of height
  noise over the area); for a nadir survey (the cameras' mean viewing direction within 10 degrees of
  straight down) the tilt is combined with that direction (the photos look straight down on
  average, as a gimbal keeps them), each weighted by its uncertainty (OpenSfM's "vertical"
  orientation prior, made a weighted one).
* :func:`georeference_to_gcps`: each control point triangulated from its pixel observations in the
  registered photos (linear multi-view triangulation in the model frame), then a similarity to the
  points' known positions (robust from 4 points on).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skyrecon.core.reconstruction import Reconstruction
from skyrecon.core.rigid import rotvec_to_matrix
from skyrecon.errors import EstimationError, InputError
from skyrecon.sfm.align import Sim3, robust_umeyama, umeyama
from skyrecon.sfm.model_align import AlignOptions, ModelCentres, align_to_positions

__all__ = ["Georeference", "georeference_to_gps", "georeference_to_gcps", "triangulate_observations"]


@dataclass
class Georeference:
    """How a model was put in the ENU frame, and how well it fits.

    Attributes:
        method: ``"gps"`` or ``"gcp"``.
        enu_from_model: the similarity, ENU metres from model units.
        gps_residuals_m: photo name -> distance of its estimated centre from its GPS position, metres
            (every registered photo with a tag, set aside or not).
        set_aside: photo name -> residual of the tags the fit set aside (wrong tags).
        threshold_m: inlier distance of the GPS fit (None without GPS).
        rms_m: RMS of the fit's inlier residuals (GPS centres or control points), metres.
        gcps: per control point: name, observations used, residual (metres) or why it was not used.
        warnings: what the user should check.
        level: GPS: the nadir prior's numbers (tilt uncertainties, weight, correction), None if unused.
    """

    method: str
    enu_from_model: Sim3
    gps_residuals_m: dict[str, float] = field(default_factory=dict)
    set_aside: dict[str, float] = field(default_factory=dict)
    threshold_m: float | None = None
    rms_m: float = float("nan")
    gcps: list[dict[str, Any]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    level: dict[str, Any] | None = None

    def to_json_dict(self) -> dict[str, Any]:
        T = self.enu_from_model
        return {
            "method": self.method,
            "enu_from_model": T.to_json_dict(),
            "threshold_m": self.threshold_m,
            "rms_m": self.rms_m,
            "set_aside": self.set_aside,
            "gcps": self.gcps,
            "nadir_prior": self.level,
            "warnings": self.warnings,
        }


def _gps_residuals(rec: Reconstruction, T: Sim3, gps_enu: dict[str, np.ndarray]) -> dict[str, float]:
    centres = ModelCentres.of(rec)
    return {
        n: float(np.linalg.norm(T.apply(centres.centres[n]) - gps_enu[n]))
        for n in centres.names
        if n in gps_enu
    }


def georeference_to_gps(
    rec: Reconstruction,
    gps_enu: dict[str, np.ndarray],
    seed: int = 0,
    threshold_m: float | None = None,
    nadir_prior: bool = True,
) -> Georeference:
    """Fit ``enu_from_model`` to the GPS positions of the registered photos (see the module).

    Args:
        rec: the SfM model (its own gauge).
        gps_enu: photo name -> (3,) GPS position in the ENU frame, metres.
        seed: RANSAC seed.
        threshold_m: fixed inlier distance instead of the adaptive one, metres.
        nadir_prior: combine the tilt with the photos' mean viewing direction when they look
            straight down on average (see the module); False: the GPS fit's tilt alone.
    Raises:
        InputError: fewer than 3 registered photos have GPS, or they lie on a line.
        EstimationError: the positions do not fit one similarity.
    """
    if threshold_m is not None:
        res = align_to_positions(rec, gps_enu, AlignOptions(max_distance=threshold_m, seed=seed))
    else:
        dst = np.stack(list(gps_enu.values()))
        first = max(15.0, 0.05 * float(np.ptp(dst[:, :2], axis=0).max()))
        res = align_to_positions(rec, gps_enu, AlignOptions(max_distance=first, seed=seed))
        inl = [r for n, r in (res.residuals_m or {}).items() if n not in set(res.outliers or [])]
        thr = float(np.clip(3.0 * np.median(inl), 1.0, first)) if inl else first
        res = align_to_positions(rec, gps_enu, AlignOptions(max_distance=thr, seed=seed))
    T = res.world_from_model
    outliers = sorted(res.outliers or [], key=lambda n: -(res.residuals_m or {}).get(n, 0.0))
    inliers = [n for n in (res.residuals_m or {}) if n not in set(outliers)]
    level = None
    if nadir_prior:
        T, level = _nadir_level(rec, T, {n: gps_enu[n] for n in inliers if n in gps_enu})
    resid = _gps_residuals(rec, T, gps_enu)
    warnings = list(res.warnings)
    kept = np.array([resid[n] for n in inliers if n in resid])
    geo = Georeference(
        "gps",
        T,
        resid,
        {n: resid[n] for n in outliers if n in resid},
        res.inlier_threshold_m,
        float(np.sqrt(np.mean(kept**2))) if len(kept) else res.residual_rms_m,
        warnings=warnings,
    )
    geo.level = level
    return geo


def _nadir_level(
    rec: Reconstruction, T: Sim3, gps_inliers: dict[str, np.ndarray]
) -> tuple[Sim3, dict[str, Any] | None]:
    """``T`` with its tilt combined with the nadir prior (see the module); the prior's numbers, or
    None when it does not apply (oblique photos, too few cameras)."""
    ims = [im for im in rec.images.values() if im.name in gps_inliers]
    if len(ims) < 5:
        return T, None
    axes = np.stack([T.R @ im.cam_from_world.R[2] for im in ims])  # optical axes, ENU
    mean = axes.mean(axis=0)
    mean /= np.linalg.norm(mean)
    down = np.array([0.0, 0.0, -1.0])
    angle = float(np.arccos(np.clip(-mean[2], -1.0, 1.0)))
    if angle > np.radians(10.0):
        return T, None
    centres = np.stack([T.apply(im.center_world) for im in ims])
    gps = np.stack([gps_inliers[im.name] for im in ims])
    c0 = centres.mean(axis=0)
    r2 = float(np.mean(np.sum((centres[:, :2] - c0[:2]) ** 2, axis=1)))
    sigma_z = float(np.std(centres[:, 2] - gps[:, 2]))
    sigma_gps = sigma_z / max(np.sqrt(len(ims) * r2 / 2.0), 1e-9)  # tilt uncertainty of the GPS fit, rad
    spread = float(np.sqrt(np.mean(np.sum((axes[:, :2] - mean[:2]) ** 2, axis=1)) / 2.0))
    sigma_prior = max(spread, np.radians(0.05)) / np.sqrt(len(ims))  # of the mean direction, rad
    w = sigma_gps**2 / (sigma_gps**2 + sigma_prior**2)
    axis = np.cross(mean, down)
    n = np.linalg.norm(axis)
    if n < 1e-12:
        return T, None
    dR = rotvec_to_matrix(axis / n * angle * w)
    step = Sim3(dR, c0 - dR @ c0, 1.0)
    info = {
        "mean_view_from_nadir_deg": round(float(np.degrees(angle)), 4),
        "tilt_sigma_gps_deg": round(float(np.degrees(sigma_gps)), 4),
        "tilt_sigma_prior_deg": round(float(np.degrees(sigma_prior)), 4),
        "weight": round(float(w), 4),
        "applied_deg": round(float(np.degrees(angle * w)), 4),
    }
    return step @ T, info


def triangulate_observations(
    rec: Reconstruction, observations: dict[str, np.ndarray]
) -> tuple[np.ndarray, int]:
    """A point seen at pixels ``observations`` (image name -> (2,) (u, v), skyrecon pixels) in the
    registered images of ``rec``: ((3,) model-frame position, views used). Linear least squares
    (DLT) on normalised image coordinates (lens distortion removed).

    Raises:
        EstimationError: fewer than two registered images see it, or it does not triangulate
            in front of them.
    """
    rows = []
    used = 0
    for name, uv in observations.items():
        im = next((i for i in rec.images.values() if i.name == name), None)
        if im is None:
            continue
        cam = rec.cameras[im.camera_id]
        xn = cam.normalized(np.asarray(uv, np.float64).reshape(1, 2))[0]
        P = np.hstack([im.cam_from_world.R, im.cam_from_world.t[:, None]])
        rows.append(xn[0] * P[2] - P[0])
        rows.append(xn[1] * P[2] - P[1])
        used += 1
    if used < 2:
        raise EstimationError(f"seen in {used} registered photo(s); at least 2 are needed")
    A = np.asarray(rows)
    A /= np.linalg.norm(A, axis=1, keepdims=True)
    _, _, Vt = np.linalg.svd(A)
    X = Vt[-1]
    if abs(X[3]) < 1e-12:
        raise EstimationError("the observations do not meet at a point (rays parallel)")
    return X[:3] / X[3], used


def georeference_to_gcps(
    rec: Reconstruction,
    gcps: list[tuple[str, np.ndarray, dict[str, np.ndarray]]],
    seed: int = 0,
    threshold_m: float = 1.0,
) -> Georeference:
    """Fit ``enu_from_model`` to ground control points.

    Args:
        rec: the SfM model.
        gcps: (name, (3,) known ENU position metres, image name -> (2,) pixel) per control point.
        seed: RANSAC seed (4 points or more).
        threshold_m: inlier distance of the robust fit, metres.
    Raises:
        InputError: fewer than 3 control points could be triangulated.
    """
    info: list[dict[str, Any]] = []
    src, dst, names = [], [], []
    for name, enu, obs in gcps:
        try:
            X, used = triangulate_observations(rec, obs)
        except EstimationError as exc:
            info.append({"name": name, "observations": len(obs), "used": False, "why": str(exc)})
            continue
        src.append(X)
        dst.append(np.asarray(enu, np.float64))
        names.append(name)
        info.append({"name": name, "observations": len(obs), "views_used": used, "used": True})
    if len(src) < 3:
        raise InputError(
            f"only {len(src)} control points are seen in two or more registered photos; at least 3 are needed "
            "(check the image names in the GCP file)"
        )
    S, D = np.stack(src), np.stack(dst)
    fit = umeyama(S, D, True) if len(S) < 5 else robust_umeyama(S, D, threshold_m, True, seed)
    T = fit.transform
    r = np.linalg.norm(T.apply(S) - D, axis=1)
    warnings = []
    by_name = {d["name"]: d for d in info}
    for n, ri, ok in zip(names, r, fit.inliers):
        by_name[n]["residual_m"] = float(ri)
        if not ok:
            by_name[n]["used"] = False
            by_name[n]["why"] = f"does not fit the others ({ri:.2f} m off)"
            warnings.append(
                f"control point {n} is {ri:.2f} m off the others and was set aside; check its coordinates"
            )
    return Georeference(
        "gcp", T, rms_m=float(np.sqrt(np.mean(r[fit.inliers] ** 2))), gcps=info, warnings=warnings
    )
