"""From pixel matches to the relative geometry of two views, with honest diagnostics.

Besides the pose (5-point LO-RANSAC, or F then E), three competing models are fitted to the same
matches: a fundamental matrix (no intrinsics), a homography (plane or pure rotation) and a pure
rotation. Comparing their support tells apart the cases the pipeline must not paper over:

* a rotation alone explains the matches (identical images, camera only turned): R, no t;
* too few inliers for any model (unrelated images): no pose;
* F explains far more matches than E: the intrinsics seem wrong;
* a homography explains (almost) everything: planar scene (pose kept, warned);
* tiny triangulation angles: small baseline (pose kept, warned).
"""

from __future__ import annotations

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.errors import EstimationError, InputError
from skyrecon.geometry.epipolar import (
    essential_from_fundamental,
    essential_from_pose,
    fundamental_from_essential,
    project_to_essential,
    sampson_sq,
    select_pose,
)
from skyrecon.geometry.essential import estimate_essential, finalize_pose, focal_scale, polish_pose
from skyrecon.geometry.fundamental import estimate_fundamental
from skyrecon.geometry.homography import decompose_homography, estimate_homography
from skyrecon.geometry.refine import refine_relative_pose
from skyrecon.geometry.sampling import RansacOptions
from skyrecon.geometry.triangulation import parallax_angles_deg, triangulate_midpoint
from skyrecon.twoview.result import TwoViewGeometry
from skyrecon.twoview.settings import TwoViewSettings

__all__ = ["estimate_two_view_geometry", "fit_rotation"]

# Decision thresholds (fractions of the pose's inlier count unless stated).
PURE_ROTATION_SUPPORT = 0.8  # a rotation alone explains this share of the pose inliers
WRONG_K_RATIO = 0.85  # E inliers below this share of F inliers -> K seems wrong
PLANAR_SUPPORT = 0.85  # a homography explains this share of the pose inliers
PLANAR_AMBIGUITY = 0.95  # a second, different pose keeps this share of the best pose's inliers
LOW_PARALLAX_DEG = 1.0  # median triangulation angle below this -> small-baseline warning
IDENTICAL_FLOW_PX = 0.5  # median displacement (working pixels) of identical images


def _rot_deg(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(A.T @ B) - 1.0) / 2.0, -1.0, 1.0))))


def _kabsch(M: np.ndarray) -> np.ndarray:
    """Rotation(s) maximising ``trace(R^T M)`` for (..., 3, 3) correlation matrices M."""
    U, _, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.zeros(M.shape[:-2] + (3, 3))
    D[..., 0, 0] = 1.0
    D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    return U @ D @ Vt


def fit_rotation(
    x1n: np.ndarray, x2n: np.ndarray, threshold: float, iterations: int = 5, samples: int = 64, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Robust rotation-only model ``b2 ~ R b1`` between bearing vectors.

    Two-point RANSAC (Kabsch on minimal samples, vectorised) followed by iteratively reweighted
    Kabsch (Wahba's problem) with Cauchy weights.

    Args:
        x1n, x2n: (N, 2) normalised coordinates.
        threshold: residual angle scale, radians (inlier test of the samples, Cauchy weights).
        iterations: reweighting rounds; samples: minimal samples drawn; seed: their seed.
    Returns:
        ``(R, residual)``: (3, 3) rotation (cam2_from_cam1) and (N,) residual angles, radians.
    """
    b1 = np.concatenate([x1n, np.ones((len(x1n), 1))], axis=1)
    b2 = np.concatenate([x2n, np.ones((len(x2n), 1))], axis=1)
    b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
    b2 /= np.linalg.norm(b2, axis=1, keepdims=True)

    def residuals(R: np.ndarray) -> np.ndarray:
        return np.arccos(np.clip(np.sum(b2 * (b1 @ R.T), axis=1), -1.0, 1.0))

    n = len(b1)
    R = _kabsch(b2.T @ b1)
    if n >= 2 and samples > 0:
        idx = np.random.default_rng(seed).integers(0, n, size=(samples, 2))
        Ms = np.einsum("ski,skj->sij", b2[idx], b1[idx])
        Rs = _kabsch(Ms)
        counts = np.array([np.count_nonzero(residuals(Rc) < threshold) for Rc in Rs])
        if counts.max() > np.count_nonzero(residuals(R) < threshold):
            R = Rs[int(np.argmax(counts))]
    res = residuals(R)
    for _ in range(iterations):
        w = 1.0 / (1.0 + (res / threshold) ** 2)
        R = _kabsch((b2 * w[:, None]).T @ b1)
        res = residuals(R)
    return R, res


def _rotation_only(
    R_rot: np.ndarray,
    x1n: np.ndarray,
    x2n: np.ndarray,
    rot_inl: np.ndarray,
    res_rot: np.ndarray,
    thr_n: float,
    f: float,
    flow: float,
    M: int,
    warnings: list[str],
    diag: dict[str, float],
) -> TwoViewGeometry:
    """The verdict when a rotation alone explains the matches: R (refined), no t."""
    R_rot, _ = fit_rotation(x1n[rot_inl], x2n[rot_inl], thr_n)
    ang = float(np.degrees(np.arccos(np.clip((np.trace(R_rot) - 1) / 2, -1, 1))))
    diag["rotation_only_angle_deg"] = ang
    n_rot = int(np.count_nonzero(rot_inl))
    if flow < IDENTICAL_FLOW_PX and ang < 0.05:
        msg = (
            f"the two images look identical (median displacement {flow:.2f} px): there is no "
            "parallax, so no translation can be recovered"
        )
    else:
        msg = (
            f"pure rotation (or a baseline too small for the scene depth): a rotation alone explains "
            f"{n_rot} of {M} matches, so there is no usable parallax and the translation cannot be "
            "recovered - move the camera sideways between the photos"
        )
    return TwoViewGeometry(
        "no_translation", R_rot, None, None, None, rot_inl, res_rot * f, [msg] + warnings, diag
    )


def _unrelated(n_inl: int, n: int, s: TwoViewSettings) -> bool:
    return n_inl < s.min_inliers or n_inl < s.min_inlier_ratio * n


def _planar_candidates(
    he,
    intr1: Intrinsics,
    intr2: Intrinsics,
    x1n: np.ndarray,
    x2n: np.ndarray,
    thr_n: float,
    R: np.ndarray | None,
    t: np.ndarray | None,
) -> list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]:
    """Pose hypotheses of a (nearly) planar scene: the 5-point result and the motions from the
    homography decomposition, each polished by local optimisation; sorted by MSAC cost."""
    hyps = [] if R is None or t is None else [(R, t)]
    h = he.inliers
    for Rh, th, _ in decompose_homography(he.H, intr1.K, intr2.K, x1n[h], x2n[h]):
        if np.linalg.norm(th) > 0:
            hyps.append((Rh, th))
    out = []
    for Rc, tc in hyps:
        Rp, tp, cost, inl = polish_pose(Rc, tc, x1n, x2n, thr_n)
        out.append((cost, Rp, tp, inl))
    out.sort(key=lambda c: c[0])
    return out


def estimate_two_view_geometry(
    x1: np.ndarray,
    x2: np.ndarray,
    intr1: Intrinsics,
    intr2: Intrinsics,
    settings: TwoViewSettings = TwoViewSettings(),
    seed: int | np.random.Generator | None = 0,
    working_scale: float = 1.0,
    sizes1: np.ndarray | None = None,
    sizes2: np.ndarray | None = None,
) -> TwoViewGeometry:
    """Relative pose and diagnostics from matched pixels.

    Args:
        x1, x2: (M, 2) matching pixels of images 1 and 2, full resolution.
        intr1, intr2: full-resolution intrinsics (lens distortion is removed).
        settings: thresholds and methods (``threshold_px`` is in working pixels).
        seed: seed or Generator for every random choice.
        working_scale: detection resolution / full resolution (<= 1): converts working pixels
            to full-resolution pixels.
        sizes1, sizes2: optional (M,) keypoint diameters of the matches (any unit): with
            ``settings.scale_weighting`` the final refinement weighs each match by the inverse
            of its expected localisation error, proportional to ``sqrt(size1^2 + size2^2)``.
    Returns:
        TwoViewGeometry.
    Raises:
        EstimationError: fewer than 8 matches.
        InputError: mismatched arrays.
    """
    x1 = np.asarray(x1, np.float64).reshape(-1, 2)
    x2 = np.asarray(x2, np.float64).reshape(-1, 2)
    if len(x1) != len(x2):
        raise InputError(f"{len(x1)} points in image 1 but {len(x2)} in image 2")
    M = len(x1)
    if M < 8:
        raise EstimationError(
            f"only {M} feature matches between the two images (at least 8 are needed): "
            "the images may not overlap, be too blurred or have too little texture"
        )
    rng = np.random.default_rng(seed) if not isinstance(seed, np.random.Generator) else seed
    seeds = rng.integers(0, 2**31 - 1, size=3)
    ws = float(working_scale) if working_scale > 0 else 1.0
    thr = settings.threshold_px / ws  # full-resolution pixels
    f = focal_scale(intr1, intr2)
    x1n, x2n = intr1.normalized(x1), intr2.normalized(x2)
    thr_n = thr / f
    opts = RansacOptions(
        threshold=thr,
        confidence=settings.confidence,
        max_iterations=settings.max_iterations,
        min_iterations=settings.min_iterations,
    )
    warnings: list[str] = []
    diag: dict[str, float] = {"num_matches": float(M), "threshold_px_full": thr}
    flow = np.median(np.hypot(*(x2 - x1).T)) * ws
    diag["median_flow_px"] = float(flow)

    sigmas = None
    if settings.scale_weighting and sizes1 is not None and sizes2 is not None:
        sg = np.sqrt(np.asarray(sizes1, np.float64) ** 2 + np.asarray(sizes2, np.float64) ** 2)
        if len(sg) == M and np.all(np.isfinite(sg)) and np.all(sg > 0):
            rel = sg / np.median(sg)
            floor = settings.scale_noise_floor
            sigmas = np.clip(np.sqrt(floor * floor + rel * rel) / np.sqrt(floor * floor + 1.0), 0.25, 16.0)

    # ----- a rotation alone? (identical images, pure rotation): decided first, it is cheap ----
    R_rot, res_rot = fit_rotation(x1n, x2n, 2.0 * thr_n)
    rot_inl = res_rot < 2.0 * thr_n
    n_rot = int(np.count_nonzero(rot_inl))
    diag["num_inliers_rotation"] = float(n_rot)
    diag["inlier_ratio_rotation"] = n_rot / M
    diag["rotation_residual_px"] = float(np.median(res_rot[rot_inl]) * f * ws) if n_rot else float("nan")
    if n_rot >= settings.min_inliers and n_rot >= 0.5 * M:
        return _rotation_only(R_rot, x1n, x2n, rot_inl, res_rot, thr_n, f, flow, M, warnings, diag)

    # ----- a fundamental matrix (the pose route "fundamental" needs it; otherwise it only
    # serves the wrong-K test, which cannot fire when E already explains most matches) ------
    def fit_fundamental():
        try:
            fe_ = estimate_fundamental(x1, x2, settings.fundamental_method, opts, int(seeds[1]))  # type: ignore[arg-type]
        except EstimationError:
            return None, 0
        n_ = (
            fe_.num_inliers
            if settings.fundamental_method in ("ransac", "lmeds", "magsac")
            else int(np.count_nonzero(fe_.errors_px < thr))
        )
        return fe_, n_

    fe, n_F = fit_fundamental() if settings.pose_method == "fundamental" else (None, -1)

    # ----- the pose -------------------------------------------------------------------------
    R = t = E = None
    inl = np.zeros(M, dtype=bool)
    err = np.full(M, np.nan)
    try:
        if settings.pose_method == "essential":
            rp = estimate_essential(
                x1n,
                x2n,
                thr_n,
                opts,
                int(seeds[0]),
                settings.refine,
                "cauchy",
                settings.refine_loss_scale_px / ws / f,
                f,
                sigmas,
            )
            R, t, E, inl, err = rp.R, rp.t, rp.E, rp.inliers, rp.errors_px
        else:
            if fe is None:
                raise EstimationError("no fundamental matrix")
            E0 = project_to_essential(essential_from_fundamental(fe.F, intr1.K, intr2.K))
            R, t, _ = select_pose(E0, x1n, x2n, fe.inliers)
            if settings.refine and fe.num_inliers >= 6:
                r = refine_relative_pose(
                    R,
                    t,
                    x1n[fe.inliers],
                    x2n[fe.inliers],
                    "cauchy",
                    settings.refine_loss_scale_px / ws / f,
                    sigmas=None if sigmas is None else sigmas[fe.inliers],
                )
                R, t = r.R, r.t
            E = essential_from_pose(R, t)
            err = np.sqrt(sampson_sq(E, x1n, x2n)) * f
            inl = err < thr
    except EstimationError as exc:
        diag["pose_error"] = 1.0
        warnings.append(f"relative pose estimation failed: {exc}")
    n_E = int(np.count_nonzero(inl))
    if n_F < 0:  # F is needed only when E leaves many matches unexplained but is not hopeless
        needed = n_E < WRONG_K_RATIO * M and not _unrelated(n_E, M, settings)
        fe, n_F = fit_fundamental() if needed else (None, 0)
    F_est = None if fe is None else fe.F
    # (the planar test needs H only when it explains most matches: few samples find it then)
    try:
        he = estimate_homography(
            x1,
            x2,
            RansacOptions(
                threshold=2.0 * thr, confidence=0.999, max_iterations=min(320, settings.max_iterations)
            ),
            int(seeds[2]),
        )
        n_H = he.num_inliers
    except EstimationError:
        he, n_H = None, 0
    nf = (
        float(n_F) if fe is not None or settings.pose_method == "fundamental" else float("nan")
    )  # nan: not fitted
    diag.update(
        num_inliers_E=float(n_E),
        num_inliers_F=nf,
        num_inliers_H=float(n_H),
        inlier_ratio_E=n_E / M,
        inlier_ratio_F=nf / M,
        inlier_ratio_H=n_H / M,
    )

    # ----- decisions ----------------------------------------------------------------------
    support = max(n_E, n_F)
    if n_rot >= settings.min_inliers and n_rot >= PURE_ROTATION_SUPPORT * support:
        return _rotation_only(R_rot, x1n, x2n, rot_inl, res_rot, thr_n, f, flow, M, warnings, diag)

    status = "ok"
    ambiguity: list[str] = []
    planar = he is not None and n_H >= PLANAR_SUPPORT * max(n_E, 1)
    if planar:
        cands = _planar_candidates(he, intr1, intr2, x1n, x2n, thr_n, R, t)
        if cands:
            cost, Rb, tb, inl_b = cands[0]
            if R is None or np.count_nonzero(inl_b) > n_E:
                rp = finalize_pose(
                    Rb,
                    tb,
                    x1n,
                    x2n,
                    thr_n,
                    inl_b if settings.refine else None,
                    "cauchy",
                    settings.refine_loss_scale_px / ws / f,
                    sigmas,
                    f,
                )
                R, t, E, inl, err = rp.R, rp.t, rp.E, rp.inliers, rp.errors_px
                n_E = int(np.count_nonzero(inl))
                diag["num_inliers_E"] = float(n_E)
                diag["inlier_ratio_E"] = n_E / M
            for _c2, R2, t2, inl2 in cands[1:]:
                differs = _rot_deg(R2, R) > 1.0 or np.degrees(np.arccos(np.clip(t2 @ t, -1, 1))) > 5.0
                if differs and np.count_nonzero(inl2) >= PLANAR_AMBIGUITY * n_E:
                    status = "uncertain"
                    ambiguity.append(
                        "planar scene with ambiguous motion: two different relative poses explain the "
                        f"matches about equally well ({n_E} and {int(np.count_nonzero(inl2))} inliers); the "
                        "returned one may be the wrong twin - add views of non-planar structure"
                    )
                    break
    if _unrelated(n_E, M, settings) or R is None:
        warnings.insert(
            0,
            f"too few inliers ({n_E} of {M} matches agree on one relative pose; at least "
            f"{max(settings.min_inliers, int(np.ceil(settings.min_inlier_ratio * M)))} needed): "
            "the images may show different scenes",
        )
        return TwoViewGeometry(
            "failed",
            None,
            None,
            None,
            F_est if n_F >= settings.min_inliers else None,
            inl,
            err,
            warnings,
            diag,
        )
    assert R is not None and t is not None and E is not None
    # (a fundamental matrix is degenerate on a plane: it over-fits, so the K test needs 3D structure)
    if not planar and n_F >= settings.min_inliers and n_E < WRONG_K_RATIO * n_F:
        status = "uncertain"
        warnings.append(
            f"the intrinsics K seem wrong: the essential matrix explains only {n_E} of {M} matches "
            f"({100 * n_E / M:.0f}%) but a fundamental matrix explains {n_F} ({100 * n_F / M:.0f}%); "
            "check the focal length, principal point and image size of K"
        )
    if planar:
        warnings.append(
            f"planar scene: a homography explains {n_H} of {M} matches ({n_E} pose inliers); the "
            "relative pose of a plane is less well constrained than that of a 3D scene"
        )
        warnings.extend(ambiguity)
    X = triangulate_midpoint(R, t, x1n[inl], x2n[inl])
    par = parallax_angles_deg(X, R, t)
    par = par[np.isfinite(par)]
    med_par = float(np.median(par)) if len(par) else 0.0
    diag["median_parallax_deg"] = med_par
    if med_par < LOW_PARALLAX_DEG:
        warnings.append(
            f"small baseline: the median triangulation angle is {med_par:.2f} deg; the translation "
            "direction and the depths are poorly constrained"
        )
    F = fundamental_from_essential(E, intr1.K, intr2.K)
    return TwoViewGeometry(status, R, t / np.linalg.norm(t), E, F, inl, err, warnings, diag)
