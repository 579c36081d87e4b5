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

from dataclasses import dataclass, field

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import rotation_angle_deg
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
from skyrecon.geometry.fundamental import FundamentalEstimate, estimate_fundamental
from skyrecon.geometry.homography import HomographyEstimate, decompose_homography, estimate_homography
from skyrecon.geometry.refine import refine_relative_pose
from skyrecon.geometry.sampling import RansacOptions
from skyrecon.geometry.triangulation import parallax_angles_deg, triangulate_midpoint
from skyrecon.twoview.result import Status, TwoViewGeometry
from skyrecon.twoview.settings import TwoViewSettings

__all__ = ["estimate_two_view_geometry", "fit_rotation"]

# Decision thresholds (fractions of the pose's inlier count unless stated).
PURE_ROTATION_SUPPORT = 0.8  # a rotation alone explains this share of the pose inliers
WRONG_K_RATIO = 0.85  # E inliers below this share of F inliers -> K seems wrong
PLANAR_SUPPORT = 0.85  # a homography explains this share of the pose inliers
PLANAR_AMBIGUITY = 0.95  # a second, different pose keeps this share of the best pose's inliers
LOW_PARALLAX_DEG = 1.0  # median triangulation angle below this -> small-baseline warning
IDENTICAL_FLOW_PX = 0.5  # median displacement (working pixels) of identical images


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


@dataclass
class _Estimation:
    """What the steps of :func:`estimate_two_view_geometry` share: the inputs in the units each
    step needs, the competing models fitted so far and the verdict being built.

    Matches are (M, 2) arrays; ``x1``/``x2`` in full-resolution pixels, ``x1n``/``x2n`` normalised
    camera coordinates (distortion removed). Poses are cam2_from_cam1. Errors are full-resolution
    pixels unless named ``_n`` (normalised units).
    """

    x1: np.ndarray
    x2: np.ndarray
    intr1: Intrinsics
    intr2: Intrinsics
    settings: TwoViewSettings
    seeds: np.ndarray  # (3,) int: the pose, the fundamental matrix, the homography
    working_scale: float  # working / full resolution
    focal: float  # pixels per normalised unit
    threshold: float  # inlier threshold, full-resolution pixels
    options: RansacOptions
    x1n: np.ndarray = field(init=False)
    x2n: np.ndarray = field(init=False)
    sigmas: np.ndarray | None = None  # (M,) relative noise of each match for the refinement
    warnings: list[str] = field(default_factory=list)
    diag: dict[str, float] = field(default_factory=dict)
    flow: float = 0.0  # median displacement, working pixels
    # the rotation-only model
    R_rot: np.ndarray = field(default_factory=lambda: np.eye(3))
    res_rot: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (M,) radians
    rot_inl: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    n_rot: int = 0
    # the fundamental matrix (n_F: -1 while not tried)
    fe: FundamentalEstimate | None = None
    n_F: int = -1
    # the pose
    R: np.ndarray | None = None
    t: np.ndarray | None = None
    E: np.ndarray | None = None
    inl: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    err: np.ndarray = field(default_factory=lambda: np.zeros(0))
    n_E: int = 0
    # the homography
    he: HomographyEstimate | None = None
    n_H: int = 0
    # the verdict
    status: Status = "ok"
    planar: bool = False
    ambiguity: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.x1n, self.x2n = self.intr1.normalized(self.x1), self.intr2.normalized(self.x2)
        M = len(self.x1)
        self.inl = np.zeros(M, dtype=bool)
        self.err = np.full(M, np.nan)

    @property
    def num_matches(self) -> int:
        return len(self.x1)

    @property
    def threshold_n(self) -> float:
        """The inlier threshold in normalised units."""
        return self.threshold / self.focal

    @property
    def refine_loss_scale_n(self) -> float:
        """Scale of the final refinement's loss, normalised units."""
        return self.settings.refine_loss_scale_px / self.working_scale / self.focal

    def unrelated(self) -> bool:
        """Too few pose inliers, absolutely or as a share of the matches."""
        return _unrelated(self.n_E, self.num_matches, self.settings)


def _unrelated(n_inl: int, n: int, s: TwoViewSettings) -> bool:
    return n_inl < s.min_inliers or n_inl < s.min_inlier_ratio * n


def _match_sigmas(
    sizes1: np.ndarray | None, sizes2: np.ndarray | None, M: int, settings: TwoViewSettings
) -> np.ndarray | None:
    """(M,) relative localisation noise of each match from its keypoint diameters (median ~1),
    or None without (valid) sizes or with ``settings.scale_weighting`` off."""
    if not (settings.scale_weighting and sizes1 is not None and sizes2 is not None):
        return None
    sg = np.sqrt(np.asarray(sizes1, np.float64) ** 2 + np.asarray(sizes2, np.float64) ** 2)
    if not (len(sg) == M and np.all(np.isfinite(sg)) and np.all(sg > 0)):
        return None
    rel = sg / np.median(sg)
    floor = settings.scale_noise_floor
    return np.clip(np.sqrt(floor * floor + rel * rel) / np.sqrt(floor * floor + 1.0), 0.25, 16.0)


def _prepare(
    x1: np.ndarray,
    x2: np.ndarray,
    intr1: Intrinsics,
    intr2: Intrinsics,
    settings: TwoViewSettings,
    seed: int | np.random.Generator | None,
    working_scale: float,
    sizes1: np.ndarray | None,
    sizes2: np.ndarray | None,
) -> _Estimation:
    """Check the matches and set up the shared state (thresholds, seeds, weights, flow)."""
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
    ws = float(working_scale) if working_scale > 0 else 1.0
    thr = settings.threshold_px / ws  # full-resolution pixels
    opts = RansacOptions(
        threshold=thr,
        confidence=settings.confidence,
        max_iterations=settings.max_iterations,
        min_iterations=settings.min_iterations,
    )
    st = _Estimation(
        x1=x1,
        x2=x2,
        intr1=intr1,
        intr2=intr2,
        settings=settings,
        seeds=rng.integers(0, 2**31 - 1, size=3),
        working_scale=ws,
        focal=focal_scale(intr1, intr2),
        threshold=thr,
        options=opts,
    )
    st.diag.update(num_matches=float(M), threshold_px_full=thr)
    st.flow = float(np.median(np.hypot(*(x2 - x1).T)) * ws)
    st.diag["median_flow_px"] = st.flow
    st.sigmas = _match_sigmas(sizes1, sizes2, M, settings)
    return st


def _fit_rotation_model(st: _Estimation) -> None:
    """The rotation-only model and its support (residual angles below twice the threshold)."""
    thr_n = st.threshold_n
    st.R_rot, st.res_rot = fit_rotation(st.x1n, st.x2n, 2.0 * thr_n)
    st.rot_inl = st.res_rot < 2.0 * thr_n
    st.n_rot = int(np.count_nonzero(st.rot_inl))
    M = st.num_matches
    st.diag["num_inliers_rotation"] = float(st.n_rot)
    st.diag["inlier_ratio_rotation"] = st.n_rot / M
    residual_px = (
        float(np.median(st.res_rot[st.rot_inl]) * st.focal * st.working_scale) if st.n_rot else np.nan
    )
    st.diag["rotation_residual_px"] = float(residual_px)


def _rotation_explains(st: _Estimation, share_of: float) -> bool:
    """A rotation alone explains at least ``share_of`` matches (and enough of them)."""
    return st.n_rot >= st.settings.min_inliers and st.n_rot >= share_of


def _rotation_only(st: _Estimation) -> TwoViewGeometry:
    """The verdict when a rotation alone explains the matches: R (refined), no t."""
    R_rot, _ = fit_rotation(st.x1n[st.rot_inl], st.x2n[st.rot_inl], st.threshold_n)
    ang = rotation_angle_deg(R_rot)
    st.diag["rotation_only_angle_deg"] = ang
    M = st.num_matches
    if st.flow < IDENTICAL_FLOW_PX and ang < 0.05:
        msg = (
            f"the two images look identical (median displacement {st.flow:.2f} px): there is no "
            "parallax, so no translation can be recovered"
        )
    else:
        msg = (
            f"pure rotation (or a baseline too small for the scene depth): a rotation alone explains "
            f"{st.n_rot} of {M} matches, so there is no usable parallax and the translation cannot be "
            "recovered - move the camera sideways between the photos"
        )
    return TwoViewGeometry(
        "no_translation",
        R_rot,
        None,
        None,
        None,
        st.rot_inl,
        st.res_rot * st.focal,
        [msg] + st.warnings,
        st.diag,
    )


def _fit_fundamental(st: _Estimation) -> None:
    """A fundamental matrix and its support (``n_F``; 0 when none was found)."""
    s = st.settings
    try:
        st.fe = estimate_fundamental(st.x1, st.x2, s.fundamental_method, st.options, int(st.seeds[1]))
    except EstimationError:
        st.fe, st.n_F = None, 0
        return
    if s.fundamental_method in ("ransac", "lmeds", "magsac"):
        st.n_F = st.fe.num_inliers
    else:
        st.n_F = int(np.count_nonzero(st.fe.errors_px < st.threshold))


def _pose_from_essential(st: _Estimation) -> None:
    """The pose by 5-point LO-RANSAC with the known intrinsics."""
    rp = estimate_essential(
        st.x1n,
        st.x2n,
        st.threshold_n,
        st.options,
        int(st.seeds[0]),
        st.settings.refine,
        "cauchy",
        st.refine_loss_scale_n,
        st.focal,
        st.sigmas,
    )
    st.R, st.t, st.E, st.inl, st.err = rp.R, rp.t, rp.E, rp.inliers, rp.errors_px


def _pose_from_fundamental(st: _Estimation) -> None:
    """The pose from the fundamental matrix (projected to an essential matrix), refined."""
    fe = st.fe
    if fe is None:
        raise EstimationError("no fundamental matrix")
    x1n, x2n = st.x1n, st.x2n
    E0 = project_to_essential(essential_from_fundamental(fe.F, st.intr1.K, st.intr2.K))
    R, t, _ = select_pose(E0, x1n, x2n, fe.inliers)
    if st.settings.refine and fe.num_inliers >= 6:
        r = refine_relative_pose(
            R,
            t,
            x1n[fe.inliers],
            x2n[fe.inliers],
            "cauchy",
            st.refine_loss_scale_n,
            sigmas=None if st.sigmas is None else st.sigmas[fe.inliers],
        )
        R, t = r.R, r.t
    st.R, st.t, st.E = R, t, essential_from_pose(R, t)
    st.err = np.sqrt(sampson_sq(st.E, x1n, x2n)) * st.focal
    st.inl = st.err < st.threshold


def _estimate_pose(st: _Estimation) -> None:
    """The pose by the configured route; a failure becomes a warning (no pose)."""
    try:
        if st.settings.pose_method == "essential":
            _pose_from_essential(st)
        else:
            _pose_from_fundamental(st)
    except EstimationError as exc:
        st.diag["pose_error"] = 1.0
        st.warnings.append(f"relative pose estimation failed: {exc}")
    st.n_E = int(np.count_nonzero(st.inl))


def _fit_fundamental_if_needed(st: _Estimation) -> None:
    """Fit F for the wrong-K test, which needs it only when E leaves many matches unexplained
    but is not hopeless (the pose route "fundamental" fitted it already)."""
    if st.n_F >= 0:
        return
    M = st.num_matches
    if st.n_E < WRONG_K_RATIO * M and not st.unrelated():
        _fit_fundamental(st)
    else:
        st.fe, st.n_F = None, 0


def _fit_homography(st: _Estimation) -> None:
    """A homography for the planar test (needed only when it explains most matches: few
    samples find it then)."""
    options = RansacOptions(
        threshold=2.0 * st.threshold, confidence=0.999, max_iterations=min(320, st.settings.max_iterations)
    )
    try:
        st.he = estimate_homography(st.x1, st.x2, options, int(st.seeds[2]))
        st.n_H = st.he.num_inliers
    except EstimationError:
        st.he, st.n_H = None, 0


def _record_support(st: _Estimation) -> None:
    """Inlier counts and ratios of E, F (NaN: not fitted) and H."""
    M = st.num_matches
    fitted = st.fe is not None or st.settings.pose_method == "fundamental"
    nf = float(st.n_F) if fitted else float("nan")
    st.diag.update(
        num_inliers_E=float(st.n_E),
        num_inliers_F=nf,
        num_inliers_H=float(st.n_H),
        inlier_ratio_E=st.n_E / M,
        inlier_ratio_F=nf / M,
        inlier_ratio_H=st.n_H / M,
    )


def _planar_candidates(
    he: HomographyEstimate,
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


def _resolve_planar(st: _Estimation) -> None:
    """When a homography explains most pose inliers: keep the best of the polished pose
    hypotheses (5-point and homography decomposition) and flag the planar twin ambiguity."""
    he = st.he
    st.planar = he is not None and st.n_H >= PLANAR_SUPPORT * max(st.n_E, 1)
    if he is None or not st.planar:
        return
    cands = _planar_candidates(he, st.intr1, st.intr2, st.x1n, st.x2n, st.threshold_n, st.R, st.t)
    if not cands:
        return
    _, Rb, tb, inl_b = cands[0]
    if st.R is None or np.count_nonzero(inl_b) > st.n_E:
        rp = finalize_pose(
            Rb,
            tb,
            st.x1n,
            st.x2n,
            st.threshold_n,
            inl_b if st.settings.refine else None,
            "cauchy",
            st.refine_loss_scale_n,
            st.sigmas,
            st.focal,
        )
        st.R, st.t, st.E, st.inl, st.err = rp.R, rp.t, rp.E, rp.inliers, rp.errors_px
        st.n_E = int(np.count_nonzero(st.inl))
        st.diag["num_inliers_E"] = float(st.n_E)
        st.diag["inlier_ratio_E"] = st.n_E / st.num_matches
    assert st.R is not None and st.t is not None
    for _, R2, t2, inl2 in cands[1:]:
        differs = (
            rotation_angle_deg(R2.T @ st.R) > 1.0 or np.degrees(np.arccos(np.clip(t2 @ st.t, -1, 1))) > 5.0
        )
        n2 = int(np.count_nonzero(inl2))
        if differs and n2 >= PLANAR_AMBIGUITY * st.n_E:
            st.status = "uncertain"
            st.ambiguity.append(
                "planar scene with ambiguous motion: two different relative poses explain the "
                f"matches about equally well ({st.n_E} and {n2} inliers); the "
                "returned one may be the wrong twin - add views of non-planar structure"
            )
            break


def _failed(st: _Estimation) -> TwoViewGeometry:
    """The verdict when too few matches agree on one pose: no pose (F kept when well supported)."""
    s, M = st.settings, st.num_matches
    st.warnings.insert(
        0,
        f"too few inliers ({st.n_E} of {M} matches agree on one relative pose; at least "
        f"{max(s.min_inliers, int(np.ceil(s.min_inlier_ratio * M)))} needed): "
        "the images may show different scenes",
    )
    F = st.fe.F if st.fe is not None and st.n_F >= s.min_inliers else None
    return TwoViewGeometry("failed", None, None, None, F, st.inl, st.err, st.warnings, st.diag)


def _check_intrinsics(st: _Estimation) -> None:
    """Flag wrong intrinsics when F explains far more matches than E (not on a plane, where F
    over-fits: the K test needs 3D structure)."""
    n_E, n_F, M = st.n_E, st.n_F, st.num_matches
    if not st.planar and n_F >= st.settings.min_inliers and n_E < WRONG_K_RATIO * n_F:
        st.status = "uncertain"
        st.warnings.append(
            f"the intrinsics K seem wrong: the essential matrix explains only {n_E} of {M} matches "
            f"({100 * n_E / M:.0f}%) but a fundamental matrix explains {n_F} ({100 * n_F / M:.0f}%); "
            "check the focal length, principal point and image size of K"
        )


def _warn_planar(st: _Estimation) -> None:
    """The planar-scene warning and any twin ambiguity."""
    if st.planar:
        st.warnings.append(
            f"planar scene: a homography explains {st.n_H} of {st.num_matches} matches ({st.n_E} pose "
            "inliers); the relative pose of a plane is less well constrained than that of a 3D scene"
        )
        st.warnings.extend(st.ambiguity)


def _check_parallax(st: _Estimation, R: np.ndarray, t: np.ndarray) -> None:
    """Median triangulation angle of the inliers; warn below :data:`LOW_PARALLAX_DEG`."""
    X = triangulate_midpoint(R, t, st.x1n[st.inl], st.x2n[st.inl])
    par = parallax_angles_deg(X, R, t)
    par = par[np.isfinite(par)]
    med_par = float(np.median(par)) if len(par) else 0.0
    st.diag["median_parallax_deg"] = med_par
    if med_par < LOW_PARALLAX_DEG:
        st.warnings.append(
            f"small baseline: the median triangulation angle is {med_par:.2f} deg; the translation "
            "direction and the depths are poorly constrained"
        )


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
    st = _prepare(x1, x2, intr1, intr2, settings, seed, working_scale, sizes1, sizes2)
    # a rotation alone? (identical images, pure rotation): decided first, it is cheap
    _fit_rotation_model(st)
    if _rotation_explains(st, 0.5 * st.num_matches):
        return _rotation_only(st)
    # the competing models: F (first when the pose comes from it), the pose, F for the K test, H
    if settings.pose_method == "fundamental":
        _fit_fundamental(st)
    _estimate_pose(st)
    _fit_fundamental_if_needed(st)
    _fit_homography(st)
    _record_support(st)
    # the decisions
    if _rotation_explains(st, PURE_ROTATION_SUPPORT * max(st.n_E, st.n_F)):
        return _rotation_only(st)
    _resolve_planar(st)
    if st.unrelated() or st.R is None or st.t is None or st.E is None:
        return _failed(st)
    _check_intrinsics(st)
    _warn_planar(st)
    _check_parallax(st, st.R, st.t)
    F = fundamental_from_essential(st.E, intr1.K, intr2.K)
    return TwoViewGeometry(
        st.status, st.R, st.t / np.linalg.norm(st.t), st.E, F, st.inl, st.err, st.warnings, st.diag
    )
