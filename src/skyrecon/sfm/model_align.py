"""Aligning models to each other: similarity from matched camera centres, ICP with or without scale.

The library behind ``skyrecon align``:

    result = align_model(rec, positions, AlignOptions(max_distance=2.0))   # name -> (3,) metres
    result = align_model(rec, other_reconstruction)                        # common images, then ICP
    result = align_model(rec, point_cloud, AlignOptions(init=T0))          # ICP
    result.world_from_model, result.residual_rms_m, result.outliers, result.to_json_dict()

Frames: every transform returned is a
:class:`~skyrecon.sfm.align.Sim3` ``target_from_source`` (``p_target = s R p_source + t``); points
are (N, 3) float64 in their frame's units (metres once georeferenced).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy.spatial import cKDTree

from skyrecon.core.depth import PointCloud
from skyrecon.core.reconstruction import Reconstruction
from skyrecon.core.rigid import orthonormalize, rotation_angle_deg, rotvec_to_matrix
from skyrecon.errors import EstimationError, InputError
from skyrecon.sfm.align import AlignmentResult, Sim3, estimate_normals, icp, robust_umeyama, umeyama

__all__ = [
    "AlignMethod",
    "AlignOptions",
    "AlignResult",
    "ModelCentres",
    "align_model",
    "align_to_positions",
    "align_to_model",
    "align_to_cloud",
    "match_names",
    "merged_cloud",
    "scene_extent",
    "check_spread",
    "fit_camera_centres",
    "point_spacing",
    "icp_plane_with_scale",
    "icp_refine",
    "subsample_cloud",
    "centroid_init",
]


def scene_extent(points: np.ndarray) -> float:
    """Largest distance of the points from their centroid x 2 (a robust, cheap scene size)."""
    if len(points) == 0:
        return 0.0
    c = points.mean(axis=0)
    return 2.0 * float(np.max(np.linalg.norm(points - c, axis=1)))


def check_spread(points: np.ndarray, what: str, names: list[str]) -> None:
    c = points - points.mean(axis=0)
    S = np.linalg.svd(c, compute_uv=False)
    listed = ", ".join(names[:4]) + (" ..." if len(names) > 4 else "")
    if S[0] <= 1e-9 * max(1.0, float(np.abs(points).max())):
        raise InputError(f"the {what} of {listed} all coincide: no alignment can be fitted")
    if S[1] < 1e-2 * S[0]:
        raise InputError(
            f"the {what} of the {len(points)} matched images ({listed}) lie on a line: the rotation about it is "
            "undetermined; use images off that line (e.g. of another flight leg)"
        )


def fit_camera_centres(
    src: np.ndarray,
    dst: np.ndarray,
    names: list[str],
    with_scale: bool,
    threshold: float | None,
    seed: int,
    what: str,
) -> tuple[AlignmentResult, float | None]:
    """Robust similarity from matched camera centres; returns (fit, threshold used).

    ``src`` (N, 3) model centres and ``dst`` (N, 3) reference centres; with exactly 3 pairs the
    plain Umeyama fit is returned and the threshold is None."""
    check_spread(dst, what, names)
    check_spread(src, "model's camera centres", names)
    if len(src) == 3:
        return umeyama(src, dst, with_scale), None
    thr = threshold if threshold is not None else 0.05 * scene_extent(dst)
    try:
        fit = robust_umeyama(src, dst, thr, with_scale, seed)
    except EstimationError as exc:
        raise EstimationError(
            f"{exc}: the {what} do not fit one similarity; check the names and units, or give a "
            "larger --max-distance"
        ) from None
    return fit, thr


def point_spacing(points: np.ndarray, tree: cKDTree, seed: int) -> float:
    """Median distance of a point to its nearest neighbour (a sample of up to 5000 points)."""
    rng = np.random.default_rng(seed)
    sub = points if len(points) <= 5000 else points[rng.choice(len(points), 5000, replace=False)]
    d, _ = tree.query(sub, k=2)
    v = d[:, 1]
    v = v[np.isfinite(v) & (v > 0)]
    return float(np.median(v)) if len(v) else 0.0


def icp_plane_with_scale(
    src: np.ndarray,
    T: Sim3,
    points: np.ndarray,
    normals: np.ndarray,
    tree: cKDTree,
    max_distance: float,
    max_iterations: int,
    size: float,
    tolerance: float = 1e-7,
) -> tuple[Sim3, int, bool, float, float, int]:
    """Point-to-plane ICP for a similarity (7 unknowns), robust (Huber weights, MAD scale).

    The library's point-to-plane ICP is rigid, and point-to-point ICP with scale is biased by how
    the target is sampled; this solves the linearised ``n . (s dR (p - c) + c + t - q) = 0`` for
    rotation, translation and scale about the matched points' centroid ``c`` at every iteration.
    Returns ``(target_from_source, iterations, converged, rmse, fitness, correspondences)``.
    """
    converged, it, rmse, fitness, n_corr = False, 0, float("nan"), 0.0, 0
    for it in range(1, max_iterations + 1):  # noqa: B007  (the count is returned)
        p = T.apply(src)
        d, j = tree.query(p, k=1, distance_upper_bound=max_distance)
        ok = np.isfinite(d)
        n_corr = int(ok.sum())
        fitness = n_corr / max(len(src), 1)
        if n_corr < 7:
            raise EstimationError(
                f"ICP: only {n_corr} model points lie within {max_distance:.3g} m of the "
                "reference; give a better --init or a larger --max-distance"
            )
        p, q, n = p[ok], points[j[ok]], normals[j[ok]]
        c = p.mean(axis=0)
        pc = p - c
        r = np.sum((p - q) * n, axis=1)
        sigma = 1.4826 * float(np.median(np.abs(r))) + 1e-12
        u = np.abs(r) / sigma
        w = np.where(u <= 1.345, 1.0, 1.345 / np.maximum(u, 1e-12))
        A = np.concatenate([np.cross(pc, n), n, np.sum(n * pc, axis=1, keepdims=True)], axis=1)
        H = (A * w[:, None]).T @ A
        g = (A * w[:, None]).T @ r
        try:
            x = -np.linalg.solve(H + 1e-12 * np.trace(H) * np.eye(7), g)
        except np.linalg.LinAlgError:
            raise EstimationError(
                "ICP: the point-to-plane system is singular (the points lie on one plane "
                "or line); use --no-scale or another reference"
            ) from None
        s = 1.0 + float(x[6])
        if not s > 0:
            raise EstimationError("ICP: the scale update became non-positive; give a better --init")
        dR = rotvec_to_matrix(x[:3])
        step = Sim3(dR, c + x[3:6] - s * dR @ c, s)
        T = step @ T
        T = Sim3(orthonormalize(T.R), T.t, T.scale)
        rmse = float(np.sqrt(np.sum(w * r * r) / max(float(w.sum()), 1e-300)))
        if float(np.max(np.linalg.norm(step.apply(p) - p, axis=1))) < tolerance * size:
            converged = True
            break
    return T, it, converged, rmse, fitness, n_corr


def icp_refine(
    src: np.ndarray,
    target: PointCloud,
    T0: Sim3,
    with_scale: bool,
    max_distance: float | None,
    max_iterations: int,
    seed: int,
) -> tuple[Sim3, dict[str, Any]]:
    """ICP from ``T0`` (target_from_source), in a frame centred on the target.

    A coarse stage (point-to-point with scale, or point-to-plane without) at a generous distance,
    then a fine point-to-plane stage (with scale: :func:`icp_plane_with_scale`) at a tight one.
    Returns ``(target_from_source Sim3, stats)``."""
    tgt = np.asarray(target.points, np.float64)
    shift = tgt.mean(axis=0)
    local_pts = tgt - shift
    tree = cKDTree(local_pts)
    normals = (
        np.asarray(target.normals, np.float64)
        if target.normals is not None
        else estimate_normals(local_pts, 12, tree)
    )
    local = PointCloud(local_pts, None, normals)
    T = Sim3(T0.R, T0.t - shift, T0.scale)
    spacing = point_spacing(local_pts, tree, seed)
    size = scene_extent(tgt)
    d1 = max_distance if max_distance is not None else max(0.1 * size, 10 * spacing)
    if len(src) > 50_000:  # enough for 7 unknowns; keeps every iteration fast
        src = src[np.sort(np.random.default_rng(seed).choice(len(src), 50_000, replace=False))]

    def stage(kind: str, d: float, r: Any, iterations: int, converged: bool) -> dict:
        return {
            "kind": kind,
            "max_distance_m": d,
            "iterations": iterations,
            "converged": converged,
            "rmse_m": r.rmse,
            "fitness": r.fitness,
            "num_correspondences": r.num_correspondences,
        }

    first = icp(
        src,
        local,
        init=T,
        point_to_plane=not with_scale,
        with_scale=with_scale,
        robust=True,
        max_distance=d1,
        max_iterations=max_iterations,
        seed=seed,
    )
    stages = [
        stage(
            "point-to-point with scale" if with_scale else "point-to-plane",
            d1,
            first,
            first.iterations,
            bool(first.converged),
        )
    ]
    d2 = max_distance if max_distance is not None else max(3.0 * first.rmse, 3.0 * spacing, 1e-9 * size)
    T = first.transform
    if not with_scale:
        last = icp(
            src,
            local,
            init=T,
            point_to_plane=True,
            robust=True,
            max_distance=d2,
            max_iterations=max_iterations,
            seed=seed,
        )
        stages.append(stage("point-to-plane", d2, last, last.iterations, bool(last.converged)))
        T, converged = last.transform, bool(last.converged)
    else:
        T, iterations, converged, rmse, fitness, n_corr = icp_plane_with_scale(
            src, T, local_pts, normals, tree, d2, max_iterations, size
        )
        stages.append(
            {
                "kind": "point-to-plane with scale",
                "max_distance_m": d2,
                "iterations": iterations,
                "converged": converged,
                "rmse_m": rmse,
                "fitness": fitness,
                "num_correspondences": n_corr,
            }
        )
    world = Sim3(T.R, T.t + shift, T.scale)
    p = T.apply(src)
    dist, j = tree.query(p, k=1)
    inl = dist <= d2
    plane = np.abs(np.sum((p - local_pts[j]) * normals[j], axis=1))
    stats = {
        "converged": converged,
        "stages": stages,
        "max_distance_m": d2,
        "fitness": float(inl.mean()) if len(inl) else 0.0,
        "num_correspondences": int(inl.sum()),
        "point_to_plane_rms_m": float(np.sqrt(np.mean(plane[inl] ** 2))) if inl.any() else float("nan"),
        "point_to_plane_median_m": float(np.median(plane[inl])) if inl.any() else float("nan"),
        "nearest_point_median_m": float(np.median(dist[inl])) if inl.any() else float("nan"),
        "target_spacing_m": spacing,
    }
    return world, stats


def subsample_cloud(cloud: PointCloud, n_max: int, seed: int) -> PointCloud:
    """``cloud`` itself, or a seeded random subset of ``n_max`` of its points (in their order)."""
    if len(cloud) <= n_max:
        return cloud
    idx = np.sort(np.random.default_rng(seed).choice(len(cloud), n_max, replace=False))
    return cloud.select(idx)


def centroid_init(src: np.ndarray, tgt: np.ndarray, with_scale: bool) -> Sim3:
    """``tgt_from_src`` without rotation: medians matched, scale from the median spreads."""
    ms, mt = np.median(src, axis=0), np.median(tgt, axis=0)
    ss = float(np.median(np.linalg.norm(src - ms, axis=1)))
    st = float(np.median(np.linalg.norm(tgt - mt, axis=1)))
    s = st / ss if with_scale and ss > 0 and st > 0 else 1.0
    return Sim3(np.eye(3), mt - s * ms, s)


# ----------------------------------------------------------------------------------------------
# aligning a whole model: one function per reference, one result type
# ----------------------------------------------------------------------------------------------
AlignMethod = Literal["positions", "model", "cloud"]


@dataclass(frozen=True)
class AlignOptions:
    """How a model is aligned.

    Attributes:
        with_scale: fit a similarity (else rigid: rotation and translation only).
        max_distance: positions: inlier distance of the robust fit (default 5 % of the positions'
            extent); model / cloud: largest ICP correspondence distance (default automatic). Metres
            of the reference.
        init: initial ``world_from_model`` for model / cloud alignment (None: automatic).
        refine_with_icp: model: refine the camera-centre fit by ICP on the 3D points.
        max_iterations: ICP iterations per stage.
        seed: seed of RANSAC and ICP subsampling.
        max_target_points: ICP works on at most this many reference points (a seeded subset beyond).
    """

    with_scale: bool = True
    max_distance: float | None = None
    init: Sim3 | None = None
    refine_with_icp: bool = True
    max_iterations: int = 50
    seed: int = 0
    max_target_points: int = 400_000


@dataclass
class AlignResult:
    """A model aligned to a reference, with the residuals that say how well.

    ``world_from_model`` maps model points to the reference frame: ``p_world = scale R p_model + t``.
    Optional fields are None where the method has no such entry (they are then left out of
    :meth:`to_json_dict`).

    Attributes:
        method: ``"positions"``, ``"model"`` or ``"cloud"``.
        world_from_model: the fitted similarity (scale 1 for a rigid fit).
        model: label of the model (its directory).
        reference: label of the reference (positions file, model directory or PLY).
        residuals_of: what the residuals measure (camera centres or point-to-plane distances).
        num_correspondences: matched camera centres, or ICP point correspondences.
        residual_rms_m, residual_median_m: over the inliers, metres of the reference.
        num_images, num_points: registered images and 3D points of the model.
        with_scale: whether the scale was estimated.
        warnings: what the user should check, most important first.
        num_inliers: camera centres that fit (positions, or models with common images).
        inlier_threshold_m: positions: inlier distance used (None for an exact 3-point fit).
        residual_max_m: positions: largest inlier residual.
        residuals_m: image name -> camera-centre residual (metres), inliers and outliers.
        outliers: image names set aside by the robust fit.
        positions_without_image, images_without_position: positions: unmatched names.
        init: model / cloud: where the initial alignment came from.
        initial_world_from_model: model / cloud: the initial alignment.
        icp: model / cloud: ICP statistics (stages, convergence, fitness, residuals); None
            without ICP.
        cloud_points_used: cloud: reference points ICP used, when subsampled.
        reference_points: model / cloud: the reference's points (for a merged cloud).
    """

    method: AlignMethod
    world_from_model: Sim3
    model: str
    reference: str
    residuals_of: str
    num_correspondences: int
    residual_rms_m: float
    residual_median_m: float
    num_images: int = 0
    num_points: int = 0
    with_scale: bool = True
    warnings: list[str] = field(default_factory=list)
    num_inliers: int | None = None
    inlier_threshold_m: float | None = None
    residual_max_m: float | None = None
    residuals_m: dict[str, float] | None = None
    outliers: list[str] | None = None
    positions_without_image: list[str] | None = None
    images_without_position: list[str] | None = None
    init: str | None = None
    initial_world_from_model: Sim3 | None = None
    icp: dict[str, Any] | None = None
    cloud_points_used: int | None = None
    reference_points: PointCloud | None = None

    @property
    def rotation_deg(self) -> float:
        """Rotation angle of ``world_from_model``, degrees."""
        return rotation_angle_deg(self.world_from_model.R)

    def to_json_dict(self) -> dict[str, Any]:
        """The entries of ``align.json`` (without ``files`` and ``seconds``), in their order.

        Values may hold NaN (e.g. ICP residuals without correspondences): the writer maps them to
        null."""
        T = self.world_from_model
        out: dict[str, Any] = {
            "method": self.method,
            "world_from_model": T.to_json_dict(),
            "scale": T.scale,
            "R": T.R.tolist(),
            "t": T.t.tolist(),
            "rotation_deg": self.rotation_deg,
            "model": self.model,
            "reference": self.reference,
        }
        if self.method != "positions":
            initial = self.initial_world_from_model
            out["init"] = self.init
            out["initial_world_from_model"] = None if initial is None else initial.to_json_dict()
            out["icp"] = self.icp
        out["residuals_of"] = self.residuals_of
        out["num_correspondences"] = self.num_correspondences
        if self.num_inliers is not None:
            out["num_inliers"] = self.num_inliers
        if self.method == "positions":
            out["inlier_threshold_m"] = self.inlier_threshold_m
        out["residual_rms_m"] = self.residual_rms_m
        out["residual_median_m"] = self.residual_median_m
        optional = {
            "residual_max_m": self.residual_max_m,
            "residuals_m": self.residuals_m,
            "outliers": self.outliers,
            "positions_without_image": self.positions_without_image,
            "images_without_position": self.images_without_position,
            "cloud_points_used": self.cloud_points_used,
        }
        out.update({k: v for k, v in optional.items() if v is not None})
        out.update(
            {
                "num_images": self.num_images,
                "num_points": self.num_points,
                "with_scale": self.with_scale,
                "warnings": self.warnings,
            }
        )
        return out

    def summary_line(self) -> str:
        """One line for the user: what was aligned to what, scale, rotation, residuals, ICP."""
        if self.method == "positions":
            what = f"{self.num_correspondences} camera positions ({self.num_inliers} inliers)"
        elif self.method == "model":
            what = f"the model {self.reference}"
            if self.num_inliers is not None:
                what += f" ({self.num_correspondences} common images)"
        else:
            what = f"the cloud {self.reference}"
        icp_note = ""
        if self.icp:
            icp_note = (
                f"; ICP {'converged' if self.icp['converged'] else 'did NOT converge'}, "
                f"{100 * self.icp['fitness']:.0f} % of points matched"
            )
        T = self.world_from_model
        return (
            f"aligned {self.num_images} images and {self.num_points} points to {what}: scale {T.scale:.6g}, "
            f"rotation {self.rotation_deg:.2f} deg, residual RMS {self.residual_rms_m:.4g} m, "
            f"median {self.residual_median_m:.4g} m{icp_note}"
        )


@dataclass(frozen=True)
class ModelCentres:
    """The registered images of a model in image-id order and their camera centres.

    Attributes:
        names: image names.
        centres: name -> (3,) camera centre in the model's world frame.
    """

    names: list[str]
    centres: dict[str, np.ndarray]

    @classmethod
    def of(cls, rec: Reconstruction) -> ModelCentres:
        images = sorted(rec.images.values(), key=lambda im: im.image_id)
        return cls([im.name for im in images], {im.name: im.center_world for im in images})

    def stack(self, names: list[str]) -> np.ndarray:
        """(len(names), 3) centres of ``names``."""
        return np.stack([self.centres[n] for n in names])


def match_names(model_names: list[str], other_names: list[str]) -> dict[str, str]:
    """model name -> other name: exact names first, then by file name, then by name without
    extension (only where that key is unique on both sides)."""
    pairs: dict[str, str] = {}
    keys = (lambda n: n, lambda n: Path(n).name, lambda n: Path(n).stem)
    for key in keys:
        left = [n for n in model_names if n not in pairs]
        taken = set(pairs.values())
        right = [n for n in other_names if n not in taken]
        km: dict[str, list[str]] = {}
        ko: dict[str, list[str]] = {}
        for n in left:
            km.setdefault(key(n), []).append(n)
        for n in right:
            ko.setdefault(key(n), []).append(n)
        for k, ms in km.items():
            if len(ms) == 1 and len(ko.get(k, [])) == 1:
                pairs[ms[0]] = ko[k][0]
    return pairs


def _listed(names: list[str]) -> str:
    return f"{', '.join(names[:3])}{' ...' if len(names) > 3 else ''}"


def _inlier_stats(res: np.ndarray, inl: np.ndarray) -> tuple[float, float]:
    return float(np.sqrt(np.mean(res[inl] ** 2))), float(np.median(res[inl]))


def align_to_positions(
    rec: Reconstruction,
    positions: dict[str, np.ndarray],
    options: AlignOptions | None = None,
    *,
    model: str = "model",
    reference: str = "positions",
) -> AlignResult:
    """Fit ``world_from_model`` to known camera centres (robust Umeyama).

    Args:
        rec: the model (registered images with finite poses).
        positions: image name -> (3,) camera centre in the world frame, metres.
        options: ``with_scale``, ``max_distance`` (inlier distance), ``seed``.
        model, reference: labels of the model and the positions file (results and messages).
    Raises:
        InputError: fewer than 3 model images have a position, or they lie on a line.
        EstimationError: the positions do not fit one similarity.
    """
    options = options or AlignOptions()
    model_centres = ModelCentres.of(rec)
    names = model_centres.names
    pairs = match_names(names, list(positions))
    if not pairs:
        raise InputError(
            f"none of the {len(positions)} names in the positions file matches one of the {len(names)} model "
            f"images (model: {_listed(names)}; file: {_listed(list(positions))})",
            reference,
        )
    matched = [n for n in names if n in pairs]
    if len(matched) < 3:
        raise InputError(
            f"only {len(matched)} model images have a position ({', '.join(matched)}); at least 3 are needed",
            reference,
        )
    src = model_centres.stack(matched)
    dst = np.stack([positions[pairs[n]] for n in matched])
    fit, thr = fit_camera_centres(
        src, dst, matched, options.with_scale, options.max_distance, options.seed, "positions"
    )
    T = fit.transform
    res = np.linalg.norm(T.apply(src) - dst, axis=1)
    inl = fit.inliers
    warnings: list[str] = []
    outliers = [n for n, ok in zip(matched, inl) if not ok]
    if outliers:
        warnings.append(
            f"{len(outliers)} positions do not fit the others (more than {thr:.3g} m off) and were "
            f"ignored: "
            + ", ".join(f"{n} ({r:.2f} m)" for n, r, ok in zip(matched, res, inl) if not ok)[:400]
        )
    scale_hint = float(np.ptp(dst[:, :2], axis=0).max())
    if np.all(np.abs(dst[:, 0]) <= 180) and np.all(np.abs(dst[:, 1]) <= 90) and scale_hint < 0.05:
        warnings.append(
            "the positions look like latitude/longitude in degrees; convert them to metres "
            "(e.g. local east-north-up or UTM) first"
        )
    rms, median = _inlier_stats(res, inl)
    return AlignResult(
        "positions",
        T,
        model,
        reference,
        "camera centres",
        len(matched),
        rms,
        median,
        warnings=warnings,
        num_inliers=int(inl.sum()),
        inlier_threshold_m=thr,
        residual_max_m=float(res[inl].max()),
        residuals_m={n: float(r) for n, r in zip(matched, res)},
        outliers=outliers,
        positions_without_image=sorted(set(positions) - set(pairs.values())),
        images_without_position=[n for n in names if n not in pairs],
    )


def align_to_model(
    rec: Reconstruction,
    ref: Reconstruction,
    options: AlignOptions | None = None,
    *,
    model: str = "model",
    reference: str = "reference",
) -> AlignResult:
    """Fit ``world_from_model`` to another model (``world`` = the reference model's frame).

    The camera centres of images with the same names give the similarity (robust Umeyama; with
    fewer than 3 common names ``options.init`` does), then ICP on the 3D points refines it
    (unless ``options.refine_with_icp`` is off or either model has fewer than 10 points).

    Raises:
        InputError: fewer than 3 common names and no ``options.init``; centres on a line.
    """
    options = options or AlignOptions()
    model_centres, ref_centres = ModelCentres.of(rec), ModelCentres.of(ref)
    pairs = match_names(model_centres.names, ref_centres.names)
    matched = [n for n in model_centres.names if n in pairs]
    xyz, _ = rec.points_array()
    ref_xyz, ref_rgb = ref.points_array()
    reference_points = PointCloud(ref_xyz, ref_rgb)
    warnings: list[str] = []
    fit = None
    src = model_centres.stack(matched) if matched else np.zeros((0, 3))
    dst = np.stack([ref_centres.centres[pairs[n]] for n in matched]) if matched else np.zeros((0, 3))
    if len(matched) >= 3:
        fit, _ = fit_camera_centres(
            src, dst, matched, options.with_scale, None, options.seed, "reference model's camera centres"
        )
        T0, init_kind = fit.transform, "camera centres"
        if options.init is not None:
            warnings.append("--init ignored: the common images give the initial alignment")
    elif options.init is not None:
        T0, init_kind = options.init, "file"
    else:
        common = f" ({', '.join(matched)})" if matched else ""
        raise InputError(
            f"the models have {len(matched) or 'no'} image names in common{common}; at least 3 are needed to align "
            "by camera centres: give --init FILE (e.g. the align.json of both models aligned to GPS), or align "
            "each with --positions",
            reference,
        )
    T, icp_stats = T0, None
    if options.refine_with_icp:
        if len(xyz) < 10 or len(ref_xyz) < 10:
            warnings.append("too few 3D points for ICP; the camera centres alone give the alignment")
        else:
            T, icp_stats = icp_refine(
                xyz,
                subsample_cloud(reference_points, options.max_target_points, options.seed),
                T0,
                options.with_scale and init_kind == "file",
                options.max_distance,
                options.max_iterations,
                options.seed,
            )
    result = _icp_aligned(
        "model",
        T,
        T0,
        init_kind,
        icp_stats,
        "point-to-plane distances of the 3D points (ICP)",
        model=model,
        reference=reference,
        warnings=warnings,
        reference_points=reference_points,
    )
    if matched:
        res = np.linalg.norm(T.apply(src) - dst, axis=1)
        inl = fit.inliers if fit is not None else np.ones(len(matched), bool)
        result.residuals_of = "camera centres of common images"
        result.num_correspondences = len(matched)
        result.num_inliers = int(inl.sum())
        result.residual_rms_m, result.residual_median_m = _inlier_stats(res, inl)
        result.residuals_m = {n: float(r) for n, r in zip(matched, res)}
        result.outliers = [n for n, ok in zip(matched, inl) if not ok]
    return result


def _icp_aligned(
    method: AlignMethod,
    T: Sim3,
    T0: Sim3,
    init_kind: str,
    icp_stats: dict[str, Any] | None,
    residuals_of: str,
    *,
    model: str,
    reference: str,
    warnings: list[str],
    reference_points: PointCloud,
) -> AlignResult:
    """An :class:`AlignResult` whose residuals are ICP's point-to-plane distances (NaN without ICP)."""
    if icp_stats is None:  # no ICP: the initial alignment, unchecked
        what, n, rms, median = "none (no common images and no ICP)", 0, float("nan"), float("nan")
    else:
        what, n = residuals_of, icp_stats["num_correspondences"]
        rms, median = icp_stats["point_to_plane_rms_m"], icp_stats["point_to_plane_median_m"]
    return AlignResult(
        method,
        T,
        model,
        reference,
        what,
        n,
        rms,
        median,
        warnings=warnings,
        init=init_kind,
        initial_world_from_model=T0,
        icp=icp_stats,
        reference_points=reference_points,
    )


def align_to_cloud(
    rec: Reconstruction,
    cloud: PointCloud,
    options: AlignOptions | None = None,
    *,
    model: str = "model",
    reference: str = "cloud",
) -> AlignResult:
    """Fit ``world_from_model`` to a point cloud by ICP of the model's 3D points.

    Starts from ``options.init``, else from the model as it is when at least half its points lie
    within 5 % of the cloud's extent of the cloud, else from the centroids and spreads of both (no
    rotation). Residuals are point-to-plane distances within the ICP distance.

    Raises:
        InputError: the cloud or the model has fewer than 10 points.
        EstimationError: ICP finds too few correspondences or a singular system.
    """
    options = options or AlignOptions()
    xyz, _ = rec.points_array()
    if len(cloud) < 10:
        raise InputError(f"the cloud has only {len(cloud)} points; ICP needs more", reference)
    if len(xyz) < 10:
        raise InputError(f"the model has only {len(xyz)} 3D points; ICP needs more", model)
    target = subsample_cloud(cloud, options.max_target_points, options.seed)
    tgt = np.asarray(target.points, np.float64)
    warnings: list[str] = []
    if options.init is not None:
        T0, init_kind = options.init, "file"
    else:
        probe = 0.05 * scene_extent(tgt)
        d, _ = cKDTree(tgt).query(xyz, k=1, distance_upper_bound=probe)
        if np.mean(np.isfinite(d)) >= 0.5:
            T0, init_kind = Sim3(), "identity (the model already overlaps the cloud)"
        else:
            T0, init_kind = centroid_init(xyz, tgt, options.with_scale), "centroids and spread (no rotation)"
            warnings.append(
                "initial alignment from the centroids and spreads of both clouds, without rotation; "
                "if the model is turned relative to the cloud give --init (or align with "
                "--positions first)"
            )
    T, icp_stats = icp_refine(
        xyz, target, T0, options.with_scale, options.max_distance, options.max_iterations, options.seed
    )
    result = _icp_aligned(
        "cloud",
        T,
        T0,
        init_kind,
        icp_stats,
        "point-to-plane distances of the model's points to the cloud (within the ICP distance)",
        model=model,
        reference=reference,
        warnings=warnings,
        reference_points=cloud,
    )
    if len(target) < len(cloud):
        result.cloud_points_used = len(target)
    return result


def _icp_warnings(icp_stats: dict[str, Any]) -> tuple[list[str], list[str]]:
    """(warnings to put first, warnings to append) about an ICP run."""
    first, last = [], []
    if not icp_stats["converged"]:
        stage = icp_stats["stages"][-1]
        first.append(
            f"ICP did not converge in {stage['iterations']} iterations (RMS {stage['rmse_m']:.3g} m); "
            "the alignment may be off: check it, give --init, or raise --max-iterations"
        )
    if icp_stats["fitness"] < 0.2:
        last.append(
            f"only {100 * icp_stats['fitness']:.0f} % of the model's points lie within "
            f"{icp_stats['max_distance_m']:.3g} m of the reference after ICP: the two may overlap "
            "little, or the initial alignment was too far off"
        )
    return first, last


def align_model(
    rec: Reconstruction,
    reference: dict[str, np.ndarray] | Reconstruction | PointCloud,
    options: AlignOptions | None = None,
    *,
    model_label: str = "model",
    reference_label: str = "reference",
) -> AlignResult:
    """Align a model to a reference: camera positions, another model, or a point cloud.

    Args:
        rec: the model (registered images with finite poses and finite points).
        reference: image name -> (3,) known camera centre (:func:`align_to_positions`), a
            :class:`Reconstruction` (:func:`align_to_model`) or a :class:`PointCloud`
            (:func:`align_to_cloud`); metres of the reference frame.
        options: see :class:`AlignOptions`.
        model_label, reference_label: names of the inputs in the result and in error messages.
    Returns:
        AlignResult with ``world_from_model``, residuals, outliers, ICP statistics and warnings
        (ICP convergence first).
    Raises:
        InputError: too few correspondences or points (the message says what to give).
        EstimationError: no finite alignment, or a failed robust fit or ICP.
    """
    options = options or AlignOptions()
    if isinstance(reference, Reconstruction):
        result = align_to_model(rec, reference, options, model=model_label, reference=reference_label)
    elif isinstance(reference, PointCloud):
        result = align_to_cloud(rec, reference, options, model=model_label, reference=reference_label)
    else:
        result = align_to_positions(rec, reference, options, model=model_label, reference=reference_label)
    if result.icp:
        first, last = _icp_warnings(result.icp)
        result.warnings = first + result.warnings + last
    T = result.world_from_model
    if not (np.all(np.isfinite(T.matrix)) and T.scale > 0):
        raise EstimationError("the alignment is not finite")
    result.num_images = len(rec.images)
    result.num_points = len(rec.points3d)
    result.with_scale = options.with_scale
    return result


def merged_cloud(aligned: Reconstruction, reference_points: PointCloud) -> PointCloud:
    """The aligned model's points (float32, their colours) followed by the reference's points
    (grey 160 where the reference has no colours)."""
    a_xyz, a_rgb = aligned.points_array()
    ref_rgb = (
        reference_points.colors
        if reference_points.colors is not None
        else np.full((len(reference_points), 3), 160, np.uint8)
    )
    return PointCloud(
        np.concatenate([a_xyz.astype(np.float32), reference_points.points]),
        np.concatenate([a_rgb, ref_rgb]),
    )
