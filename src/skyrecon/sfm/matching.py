"""Descriptor matching and geometric verification of image pairs, fanned out on the executor.

Work items are chunks of pairs sharing images; workers read the cached features (with a small
per-process cache), match descriptors (ratio test + mutual check, :mod:`skyrecon.features`) and
verify each pair with the two-view machinery: 5-point LO-RANSAC on the essential matrix
(:func:`skyrecon.geometry.estimate_essential`), a rotation-only model
(:func:`skyrecon.twoview.fit_rotation`) that exposes pure rotations and identical images, and a
homography test (:func:`skyrecon.geometry.estimate_homography`) measuring planarity for the
choice of the initial pair.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.errors import EstimationError
from skyrecon.features.match import MatchSettings, match_descriptors
from skyrecon.geometry.essential import estimate_essential, finalize_pose
from skyrecon.geometry.homography import estimate_homography
from skyrecon.geometry.sampling import RansacOptions
from skyrecon.geometry.triangulation import parallax_angles_deg, triangulate_midpoint
from skyrecon.io.task_cache import map_cached, task_key
from skyrecon.sfm.extract import load_features
from skyrecon.sfm.guided import guided_match
from skyrecon.sfm.settings import VerificationSettings
from skyrecon.threads import limited_threads
from skyrecon.twoview.estimate import fit_rotation

__all__ = [
    "PairGeometry",
    "MatchTask",
    "verify_matches",
    "match_pair",
    "match_and_verify_chunk",
    "chunk_pairs",
    "run_matching",
]


@dataclass
class PairGeometry:
    """A matched and verified image pair.

    Attributes:
        i, j: image indices (``i < j``).
        status: ``"ok"`` (relative pose with translation), ``"no_translation"`` (a rotation
            alone explains the matches: pure rotation or identical images) or ``"failed"``.
        num_matches: putative descriptor matches.
        matches: (K, 2) int32 verified keypoint pairs ``[kp in i, kp in j]`` (empty when failed).
        R, t: ``cam_j_from_cam_i`` rotation (``ok`` and ``no_translation``) and unit translation
            (``ok`` only); None otherwise.
        median_parallax_deg: median triangulation angle of the inliers (0 without a pose).
        homography_ratio: share of the E inliers a homography explains (NaN when not tested).
        median_flow_px: median displacement of the putative matches, input pixels.
        reason: why the pair failed or has no translation, else "".
    """

    i: int
    j: int
    status: str
    num_matches: int
    matches: np.ndarray = field(repr=False)
    R: np.ndarray | None = None
    t: np.ndarray | None = None
    median_parallax_deg: float = 0.0
    homography_ratio: float = float("nan")
    median_flow_px: float = float("nan")
    reason: str = ""

    @property
    def num_inliers(self) -> int:
        return int(len(self.matches))


@dataclass(frozen=True)
class MatchTask:
    """A chunk of pairs for one worker (picklable).

    Attributes:
        pairs: (P, 2) image indices.
        seeds: (P,) RANSAC seeds.
        paths: image index -> cached feature file, for the images of the chunk.
        intrinsics: image index -> camera, for the images of the chunk.
        scale: detection resolution / input resolution (thresholds are in working pixels).
    """

    pairs: np.ndarray
    seeds: np.ndarray
    paths: dict
    intrinsics: dict
    scale: float
    matching: MatchSettings
    verification: VerificationSettings


def _failed(i: int, j: int, n: int, reason: str, flow: float = float("nan")) -> PairGeometry:
    return PairGeometry(i, j, "failed", n, np.zeros((0, 2), np.int32), median_flow_px=flow, reason=reason)


def verify_matches(
    i: int,
    j: int,
    x1: np.ndarray,
    x2: np.ndarray,
    idx: np.ndarray,
    intr1: Intrinsics,
    intr2: Intrinsics,
    settings: VerificationSettings,
    scale: float = 1.0,
    seed: int = 0,
) -> PairGeometry:
    """Verify putative matches of images i and j.

    Args:
        x1, x2: (M, 2) matched keypoints, input pixels.
        idx: (M, 2) keypoint indices of the matches.
        intr1, intr2: cameras (lens distortion is removed).
        settings: thresholds (``threshold_px`` in working pixels).
        scale: working resolution / input resolution.
        seed: RANSAC seed.
    """
    M = len(x1)
    flow = float(np.median(np.hypot(*(x2 - x1).T))) if M else float("nan")
    if M < settings.min_matches:
        return _failed(i, j, M, f"only {M} feature matches (at least {settings.min_matches} needed)", flow)
    f = float(np.mean([intr1.fx, intr1.fy, intr2.fx, intr2.fy]))
    thr = settings.threshold_px / max(scale, 1e-9)
    thr_n = thr / f
    x1n, x2n = intr1.normalized(x1), intr2.normalized(x2)
    opts = RansacOptions(
        threshold=thr,
        confidence=settings.confidence,
        max_iterations=settings.max_iterations,
        min_iterations=32,
        local_optimization=settings.local_optimization,
    )
    R_rot, res_rot = fit_rotation(x1n, x2n, 2.0 * thr_n)
    rot_inl = res_rot < 2.0 * thr_n
    n_rot = int(np.count_nonzero(rot_inl))
    try:
        rp = estimate_essential(x1n, x2n, thr_n, opts, seed, refine=False, pixel_scale=f)
        inl, R, t = rp.inliers, rp.R, rp.t
    except EstimationError as exc:
        inl, R, t = np.zeros(M, bool), None, None
        reason = f"no relative pose ({exc})"
    n_E = int(np.count_nonzero(inl))
    if n_rot >= settings.min_inliers and n_rot >= settings.rotation_support * max(n_E, 1):
        what = (
            "the images look identical"
            if flow < 0.5 / max(scale, 1e-9)
            else "a rotation alone explains the matches"
        )
        return PairGeometry(
            i,
            j,
            "no_translation",
            M,
            idx[rot_inl].astype(np.int32),
            R_rot,
            None,
            median_flow_px=flow,
            reason=f"{what} ({n_rot} of {M} matches): no parallax",
        )
    if n_E < settings.min_inliers or R is None or t is None:
        return _failed(
            i,
            j,
            M,
            f"only {n_E} of {M} matches agree on a relative pose (at least {settings.min_inliers} needed)"
            if R is not None
            else reason,
            flow,
        )
    X = triangulate_midpoint(R, t, x1n[inl], x2n[inl])
    par = parallax_angles_deg(X, R, t)
    par = par[np.isfinite(par)]
    hr = float("nan")
    if settings.homography_iterations > 0 and n_E >= 8:
        try:
            he = estimate_homography(
                x1[inl],
                x2[inl],
                RansacOptions(
                    threshold=2.0 * thr,
                    confidence=0.99,
                    max_iterations=settings.homography_iterations,
                    min_iterations=16,
                    local_optimization=False,
                ),
                seed + 1,
            )
            hr = he.num_inliers / n_E
        except EstimationError:
            hr = 0.0
    return PairGeometry(
        i, j, "ok", M, idx[inl].astype(np.int32), R, t, float(np.median(par)) if len(par) else 0.0, hr, flow
    )


def strongest(responses: np.ndarray, n: int) -> np.ndarray:
    """Sorted indices of the ``n`` largest responses (all when ``n`` is 0 or covers them)."""
    if n <= 0 or len(responses) <= n:
        return np.arange(len(responses))
    return np.sort(np.argpartition(-responses, n - 1)[:n])


def _guided(
    g: PairGeometry,
    fi: dict,
    fj: dict,
    intr1: Intrinsics,
    intr2: Intrinsics,
    matching: MatchSettings,
    settings: VerificationSettings,
    scale: float,
) -> PairGeometry:
    """Re-match all features of a verified pair along its epipolar lines and refine the pose."""
    assert g.R is not None and g.t is not None
    f = float(np.mean([intr1.fx, intr1.fy, intr2.fx, intr2.fy]))
    thr_n = settings.threshold_px / max(scale, 1e-9) / f
    band = settings.guided_band_px / max(scale, 1e-9) / f
    x1n_all = intr1.normalized(fi["keypoints"])
    x2n_all = intr2.normalized(fj["keypoints"])
    # depth range of the coarse inliers (unit baseline), widened generously
    a, b = g.matches[:, 0], g.matches[:, 1]
    X = triangulate_midpoint(g.R, g.t, x1n_all[a], x2n_all[b])
    z1 = X[:, 2]
    z2 = X @ g.R[2] + g.t[2]
    ok = np.isfinite(z1) & np.isfinite(z2) & (z1 > 0) & (z2 > 0)
    if np.count_nonzero(ok) >= 8:
        r1 = (0.5 * np.percentile(z1[ok], 1), 2.0 * np.percentile(z1[ok], 99))
        r2 = (0.5 * np.percentile(z2[ok], 1), 2.0 * np.percentile(z2[ok], 99))
    else:
        r1 = r2 = (1e-6, np.inf)
    gm = guided_match(
        x1n_all,
        fi["descriptors"],
        x2n_all,
        fj["descriptors"],
        g.R,
        g.t,
        band,
        r1,
        r2,
        matching.ratio,
        matching.mutual,
    )
    if len(gm) <= g.num_inliers:
        return g
    x1n, x2n = x1n_all[gm[:, 0]], x2n_all[gm[:, 1]]
    rp = finalize_pose(g.R, g.t, x1n, x2n, thr_n, np.ones(len(gm), bool), "cauchy", 0.5 * thr_n, None, f)
    inl = rp.inliers
    if np.count_nonzero(inl) <= g.num_inliers:
        return g
    X = triangulate_midpoint(rp.R, rp.t, x1n[inl], x2n[inl])
    par = parallax_angles_deg(X, rp.R, rp.t)
    par = par[np.isfinite(par)]
    return PairGeometry(
        g.i,
        g.j,
        "ok",
        len(gm),
        gm[inl].astype(np.int32),
        rp.R,
        rp.t,
        float(np.median(par)) if len(par) else 0.0,
        g.homography_ratio,
        g.median_flow_px,
    )


def match_pair(
    i: int,
    j: int,
    fi: dict,
    fj: dict,
    intr1: Intrinsics,
    intr2: Intrinsics,
    matching: MatchSettings,
    settings: VerificationSettings,
    scale: float = 1.0,
    seed: int = 0,
) -> PairGeometry:
    """Match and verify one pair: coarse match of the strongest features, verification, then
    (``settings.guided``) guided matching of all features and pose refinement.

    Args:
        fi, fj: feature arrays of the two images (``keypoints`` (N, 2) input pixels,
            ``descriptors`` (N, D), ``responses`` (N,)).
        intr1, intr2: the cameras; scale: working / input resolution; seed: RANSAC seed.
    """
    si = strongest(fi["responses"], settings.coarse_features)
    sj = strongest(fj["responses"], settings.coarse_features)
    m = match_descriptors(fi["descriptors"][si], fj["descriptors"][sj], matching)
    a, b = si[m.idx1], sj[m.idx2]
    idx = np.stack([a, b], axis=1)
    g = verify_matches(i, j, fi["keypoints"][a], fj["keypoints"][b], idx, intr1, intr2, settings, scale, seed)
    if (
        g.status != "ok"
        or not settings.guided
        or (len(si) == len(fi["responses"]) and len(sj) == len(fj["responses"]))
    ):
        return g
    return _guided(g, fi, fj, intr1, intr2, matching, settings, scale)


_KEYS = ("keypoints", "descriptors", "responses")


def match_and_verify_chunk(task: MatchTask) -> list[PairGeometry]:
    """Match and verify every pair of a chunk (module-level: runs in worker processes,
    single-threaded: the executor parallelises)."""
    with limited_threads(1):
        return _match_chunk(task)


def _match_chunk(task: MatchTask) -> list[PairGeometry]:
    out = []
    for (i, j), seed in zip(task.pairs.tolist(), task.seeds.tolist()):
        fi = load_features(task.paths[i], _KEYS)
        fj = load_features(task.paths[j], _KEYS)
        out.append(
            match_pair(
                i,
                j,
                fi,
                fj,
                task.intrinsics[i],
                task.intrinsics[j],
                task.matching,
                task.verification,
                task.scale,
                int(seed),
            )
        )
    return out


def chunk_pairs(pairs: np.ndarray, n_chunks_hint: int, max_chunk: int = 16) -> list[np.ndarray]:
    """Split (P, 2) pairs (sorted by first image) into chunks of consecutive pairs, so a worker
    reuses the features of the images it has just read."""
    P = len(pairs)
    if P == 0:
        return []
    size = int(np.clip(np.ceil(P / max(1, n_chunks_hint)), 1, max_chunk))
    return [pairs[k : k + size] for k in range(0, P, size)]


def pair_seeds(pairs: np.ndarray, seed: int) -> np.ndarray:
    """(P,) deterministic per-pair seeds derived from the run's seed and the pair's images."""
    ss = np.random.SeedSequence([int(seed) & 0xFFFFFFFF, 0x5F3A])
    base = int(ss.generate_state(1)[0])
    return (
        (base + pairs[:, 0].astype(np.int64) * 1_000_003 + pairs[:, 1].astype(np.int64) * 7919) % (2**31 - 1)
    ).astype(np.int64)


def run_matching(
    pairs: np.ndarray,
    feature_paths: Sequence[str],
    intrinsics: Sequence[Intrinsics],
    scale: float,
    matching: MatchSettings,
    verification: VerificationSettings,
    seed: int,
    executor,
    workers: int = 1,
    cache_dir: str | None = None,
) -> list[PairGeometry]:
    """Match and verify all pairs on the executor; results in the order of ``pairs``.

    With ``cache_dir``, each chunk's result is kept there as soon as it is computed and reused by
    a rerun with the same features and settings (see :mod:`skyrecon.io.task_cache`)."""
    seeds = pair_seeds(pairs, seed)
    chunks = chunk_pairs(pairs, 4 * max(1, workers))
    tasks = []
    k = 0
    for c in chunks:
        imgs = np.unique(c)
        tasks.append(
            MatchTask(
                c,
                seeds[k : k + len(c)],
                {int(a): feature_paths[a] for a in imgs},
                {int(a): intrinsics[a] for a in imgs},
                scale,
                matching,
                verification,
            )
        )
        k += len(c)
    keys = [task_key(t, "match_and_verify_chunk") for t in tasks]
    results, _ = map_cached(executor, match_and_verify_chunk, tasks, keys, cache_dir, desc="matching")
    return [g for chunk in results for g in chunk]
