"""Structure from motion end to end: images + intrinsics -> poses and a sparse coloured model.

    result = run_sfm(paths, intrinsics, SfMSettings(), seed=0, workspace="out/workspace")
    result.reconstruction      # COLMAP-ready (cameras at the input size, cam_from_world poses)
    result.unregistered        # name -> why it was left out
    write_sfm_outputs("out", result)

Stages: features (per image, executor, cached in the workspace) -> pair selection (exhaustive,
sequential or retrieval) -> matching and geometric verification (per chunk of pairs, executor)
-> tracks (union-find) -> incremental mapper with bundle adjustment.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.reconstruction import Image, Point3D, Reconstruction
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import EstimationError, InputError
from skyrecon.executor import Executor, get_executor
from skyrecon.sfm._pool import run_scoped_executor
from skyrecon.sfm._threads import limited_threads
from skyrecon.sfm.extract import ExtractedImage, ExtractTask, extract_one, load_features
from skyrecon.sfm.mapper import IncrementalMapper, MapperInput, MapperOutput
from skyrecon.sfm.matching import PairGeometry, run_matching
from skyrecon.sfm.pairs import select_pairs
from skyrecon.sfm.result import ImageStatus, SfMResult
from skyrecon.sfm.retrieval import vlad_descriptors
from skyrecon.sfm.settings import SfMSettings
from skyrecon.sfm.tracks import build_tracks
from skyrecon.sfm.viewgraph import rotation_inconsistent_pairs

__all__ = ["run_sfm", "image_names"]


def image_names(paths: Sequence[Path]) -> list[str]:
    """Names of images: paths relative to their deepest common directory (the file name when
    they share one directory)."""
    parents = [p.resolve().parent for p in paths]
    common = Path(os.path.commonpath([str(p) for p in parents])) if parents else Path(".")
    return [p.resolve().relative_to(common).as_posix() for p in paths]


def _check_intrinsics(intrinsics: Intrinsics | Sequence[Intrinsics], n: int) -> list[Intrinsics]:
    if isinstance(intrinsics, Intrinsics):
        cams = [intrinsics] * n
    else:
        cams = list(intrinsics)
        if len(cams) != n:
            raise InputError(f"got {len(cams)} intrinsics for {n} images; give one for all or one per image")
    for _k, c in enumerate(cams):
        if not isinstance(c, Intrinsics):
            raise InputError(f"intrinsics must be Intrinsics objects, got {type(c).__name__}")
        if not (-0.5 <= c.cx <= c.width - 0.5 and -0.5 <= c.cy <= c.height - 0.5):
            raise InputError(
                f"the camera K does not fit its {c.width}x{c.height} image: the principal point "
                f"({c.cx:.1f}, {c.cy:.1f}) lies outside it; K is probably for another image size "
                "(scale fx, fy, cx, cy by the resize factor)"
            )
    return cams


def _camera_ids(cams: list[Intrinsics]) -> tuple[list[Intrinsics], np.ndarray]:
    uniq: list[Intrinsics] = []
    ids = np.zeros(len(cams), np.int64)
    for k, c in enumerate(cams):
        for u, d in enumerate(uniq):
            if d is c or d == c:
                ids[k] = u
                break
        else:
            uniq.append(c)
            ids[k] = len(uniq) - 1
    return uniq, ids


def _diagnose_pairs(
    pairs: list[PairGeometry], x: dict, cams: list[Intrinsics], settings: SfMSettings
) -> list[str]:
    """Run the full two-view diagnostics (E vs F vs H vs rotation) on the pairs with the most
    matches, to explain a failed or partial reconstruction (e.g. a wrong K)."""
    from skyrecon.twoview.estimate import estimate_two_view_geometry
    from skyrecon.twoview.settings import TwoViewSettings

    out: list[str] = []
    best = sorted(pairs, key=lambda p: -p.num_matches)[:3]
    for p in best:
        fi = load_features(x[p.i], ("keypoints", "descriptors"))
        fj = load_features(x[p.j], ("keypoints", "descriptors"))
        from skyrecon.features.match import match_descriptors

        m = match_descriptors(fi["descriptors"], fj["descriptors"], settings.matching)
        if len(m) < 8:
            continue
        try:
            g = estimate_two_view_geometry(
                fi["keypoints"][m.idx1],
                fj["keypoints"][m.idx2],
                cams[p.i],
                cams[p.j],
                TwoViewSettings(dense=False),
                0,
            )
        except EstimationError:
            continue
        for w in g.warnings:
            if "intrinsics" in w and w not in out:
                out.append(w)
    return out


def run_sfm(
    image_paths: Sequence[str | Path],
    intrinsics: Intrinsics | Sequence[Intrinsics],
    settings: SfMSettings | None = None,
    executor: Executor | None = None,
    seed: int = 0,
    workspace: str | Path | None = None,
) -> SfMResult:
    """Recover every camera's pose and a sparse coloured 3D model from photos or flight frames.

    Args:
        image_paths: the images (JPEG/PNG). For ``settings.sequential`` they must be in flight
            order.
        intrinsics: the camera at the *input* image size (one for all images, or one per image).
            Lens distortion in it is taken into account.
        settings: pipeline settings (default :class:`SfMSettings`).
        executor: fans out per-image and per-pair work (default :func:`skyrecon.executor.get_executor`;
            when that is the local process executor, one pool of the same size serves all stages).
        seed: seeds every random choice; a given seed gives the same result.
        workspace: directory for cached features (reused by later runs); default a temporary
            directory removed at the end.
    Returns:
        SfMResult. Images that cannot be used (unreadable, wrong size for K, duplicates, too
        little texture, no overlap, failed registration) are left out and listed with the reason;
        the model of the others is returned.
    Raises:
        InputError: fewer than two images, missing files, a K that does not fit the images, or
            fewer than two usable images.
        EstimationError: no image pair can start a reconstruction (the message says why).
    """
    t_total = time.perf_counter()
    settings = settings or SfMSettings()
    paths = [Path(p) for p in image_paths]
    if len(paths) < 2:
        raise InputError(f"structure from motion needs at least two images, got {len(paths)}")
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise InputError(
            f"image files not found: {', '.join(missing[:5])}" + (" ..." if len(missing) > 5 else "")
        )
    if len({p.resolve() for p in paths}) != len(paths):
        raise InputError("the same image file is listed twice")
    n = len(paths)
    names = image_names(paths)
    cams_in = _check_intrinsics(intrinsics, n)
    release = lambda: None  # noqa: E731
    if executor is None:
        # the configured executor; the local process one is kept alive across the stages
        executor, release = run_scoped_executor(get_executor())
    workers = int(getattr(executor, "workers", 1) or 1)
    timings: dict[str, float] = {}
    diagnostics: dict = {}
    warnings: list[str] = []
    tmp = None
    if workspace is None:
        tmp = tempfile.TemporaryDirectory(prefix="skyrecon-sfm-")
        workspace = tmp.name
    cache_dir = Path(workspace) / "features"
    cache_dir.mkdir(parents=True, exist_ok=True)
    try:
        with limited_threads(1):
            return _run(
                paths,
                names,
                cams_in,
                settings,
                executor,
                workers,
                seed,
                cache_dir,
                timings,
                diagnostics,
                warnings,
                t_total,
            )
    finally:
        release()
        if tmp is not None:
            tmp.cleanup()


def _run(
    paths,
    names,
    cams_in,
    settings,
    executor,
    workers,
    seed,
    cache_dir,
    timings,
    diagnostics,
    warnings,
    t_total,
):
    n = len(paths)
    # ----- features ---------------------------------------------------------------------------
    t0 = time.perf_counter()
    fs = settings.feature_settings
    tasks = [
        ExtractTask(k, str(p), names[k], fs, str(cache_dir), settings.target_features)
        for k, p in enumerate(paths)
    ]
    ext: list[ExtractedImage] = executor.map(extract_one, tasks, desc="features")
    timings["features"] = time.perf_counter() - t0
    diagnostics["features_cached"] = sum(1 for e in ext if e.cached)
    reasons: dict[int, str] = {}
    for e in ext:
        if not e.ok:
            reasons[e.index] = e.reason
    # size checks against the calibration
    fits = [k for k in range(n) if k not in reasons and (ext[k].width, ext[k].height) == cams_in[k].size]
    if not fits and len(reasons) < n:
        sizes = sorted({f"{e.width}x{e.height}" for e in ext if e.ok})
        c = cams_in[0]
        raise InputError(
            f"none of the {n} images has the size the camera K is for ({c.width}x{c.height}); the images are "
            f"{', '.join(sizes)}: give K for the image size (scale fx, fy, cx, cy by the resize factor)"
        )
    for e in ext:
        if e.ok and (e.width, e.height) != cams_in[e.index].size:
            c = cams_in[e.index]
            reasons[e.index] = (
                f"image is {e.width}x{e.height} but the camera K is for {c.width}x{c.height} "
                "(mixed image sizes: resize it or give it its own K)"
            )
    seen: dict[str, int] = {}
    for e in ext:
        if e.index in reasons or not e.file_hash:
            continue
        if e.file_hash in seen:
            reasons[e.index] = f"duplicate: the same file content as {names[seen[e.file_hash]]}"
        else:
            seen[e.file_hash] = e.index
    for e in ext:
        if e.index not in reasons and e.num_features < settings.min_features:
            reasons[e.index] = (
                f"only {e.num_features} features (at least {settings.min_features} needed): too little texture"
            )
    usable = [k for k in range(n) if k not in reasons]
    if len(usable) < 2:
        detail = "; ".join(f"{names[k]}: {r}" for k, r in sorted(reasons.items())[:10])
        raise InputError(f"fewer than two usable images ({len(usable)} of {n}): {detail}")
    scale = float(np.median([ext[k].scale for k in usable]))
    diagnostics["working_scale"] = scale
    diagnostics["num_features"] = {names[k]: ext[k].num_features for k in range(n)}
    paths_c = [ext[k].cache_path for k in usable]
    cams_c = [cams_in[k] for k in usable]

    # ----- pairs ------------------------------------------------------------------------------
    t0 = time.perf_counter()
    sel = select_pairs(
        len(usable),
        settings.pair_mode,
        settings.pairing,
        lambda: vlad_descriptors(paths_c, settings.pairing.retrieval_clusters, seed),
    )
    timings["pairs"] = time.perf_counter() - t0
    diagnostics["pairing"] = {
        "mode": sel.mode,
        "num_pairs": int(len(sel.pairs)),
        "num_loop_pairs": sel.num_loop_pairs,
    }

    # ----- matching and verification ------------------------------------------------------------
    t0 = time.perf_counter()
    geo_c = run_matching(
        sel.pairs, paths_c, cams_c, scale, settings.matching, settings.verification, seed, executor, workers
    )
    timings["matching"] = time.perf_counter() - t0
    pairs: list[PairGeometry] = []
    for g in geo_c:  # back to input indices
        g.i, g.j = usable[g.i], usable[g.j]
        pairs.append(g)
    if settings.verification.max_rotation_inconsistency_deg > 0:
        trusted = None
        if sel.mode == "sequential":  # neighbouring frames: their rotations chain reliably
            trusted = np.array([g.j - g.i <= settings.pairing.window for g in pairs])
        bad, err = rotation_inconsistent_pairs(
            pairs, n, settings.verification.max_rotation_inconsistency_deg, trusted
        )
        for k in bad:
            g = pairs[k]
            g.reason = (
                f"relative rotation disagrees by {err[k]:.1f} deg with the rotations chained along the "
                "strongest pairs (repeated structure?)"
            )
            g.status, g.matches, g.R, g.t = "failed", g.matches[:0], None, None
        diagnostics["pairs_rotation_inconsistent"] = len(bad)
    diagnostics["pairs_verified"] = sum(1 for g in pairs if g.status == "ok")
    diagnostics["pairs_no_translation"] = sum(1 for g in pairs if g.status == "no_translation")
    diagnostics["pairs_failed"] = sum(1 for g in pairs if g.status == "failed")
    # near-duplicates: identical-looking images
    usable_set = set(usable)
    for g in pairs:
        if (
            g.status == "no_translation"
            and "identical" in g.reason
            and g.i in usable_set
            and g.j in usable_set
        ):
            reasons[g.j] = f"duplicate: looks identical to {names[g.i]} (no parallax between them)"
            usable_set.discard(g.j)
    usable = [k for k in usable if k in usable_set]

    # ----- tracks -----------------------------------------------------------------------------
    t0 = time.perf_counter()
    kp, sizes, colors = [], [], []
    for k in range(n):
        if ext[k].ok and ext[k].cache_path:
            f = load_features(ext[k].cache_path, ("keypoints", "scales", "colors"))
            kp.append(f["keypoints"])
            sizes.append(f["scales"])
            colors.append(f["colors"])
        else:
            kp.append(np.zeros((0, 2)))
            sizes.append(np.zeros(0, np.float32))
            colors.append(np.zeros((0, 3), np.uint8))
    track_pairs = [
        (g.i, g.j, g.matches)
        for g in pairs
        if g.status != "failed" and g.i in usable_set and g.j in usable_set
    ]
    tracks = build_tracks([len(k) for k in kp], track_pairs, kp)
    timings["tracks"] = time.perf_counter() - t0
    diagnostics["tracks"] = {
        "num_tracks": tracks.num_tracks,
        "num_observations": tracks.num_observations,
        "inconsistent_dropped": tracks.num_inconsistent,
        "mean_length": float(tracks.lengths.mean()) if tracks.num_tracks else 0.0,
    }

    # ----- mapping ----------------------------------------------------------------------------
    t0 = time.perf_counter()
    cameras, cam_ids = _camera_ids(cams_in)
    usable_mask = np.zeros(n, bool)
    usable_mask[usable] = True
    data = MapperInput(names, kp, sizes, colors, cameras, cam_ids, tracks, pairs, usable_mask, scale)
    mapper = IncrementalMapper(data, settings.mapper, settings.bundle, seed)
    try:
        out = mapper.run()
    except EstimationError as exc:
        extra = _diagnose_pairs(
            [g for g in pairs if g.status != "failed"] or pairs,
            {k: ext[k].cache_path for k in range(n)},
            cams_in,
            settings,
        )
        left = "; ".join(f"{names[k]}: {r}" for k, r in sorted(reasons.items())[:10])
        msg = str(exc)
        if extra:
            msg += ". " + " ".join(extra)
        if left:
            msg += f". Images left out before mapping: {left}"
        raise EstimationError(msg) from None
    timings["mapping"] = time.perf_counter() - t0
    diagnostics["mapper"] = out.diagnostics
    if out.init_pair is not None:
        diagnostics["mapper"]["init_pair"] = [names[out.init_pair[0]], names[out.init_pair[1]]]
    diagnostics["mapper"]["registration_order"] = [names[i] for i in out.registration_order]
    warnings.extend(out.warnings)
    for i, why in out.failures.items():
        reasons.setdefault(i, why)
    if out.registered.sum() < 0.8 * len(usable):
        extra = _diagnose_pairs(
            [g for g in pairs if g.status == "ok"] or pairs,
            {k: ext[k].cache_path for k in range(n)},
            cams_in,
            settings,
        )
        warnings.extend(extra)
    if reasons:
        warnings.insert(
            0,
            f"{len(reasons)} of {n} images were left out of the model: "
            + ", ".join(names[k] for k in sorted(reasons)[:10])
            + (" ..." if len(reasons) > 10 else ""),
        )
    rec, statuses = _assemble(names, paths, ext, kp, out, tracks, cameras, cam_ids, reasons)
    timings["total"] = time.perf_counter() - t_total
    return SfMResult(rec, statuses, diagnostics, timings, warnings, seed)


def _assemble(
    names, paths, ext, kp, out: MapperOutput, tracks, cameras, cam_ids, reasons
) -> tuple[Reconstruction, list[ImageStatus]]:
    n = len(names)
    pt_tracks = np.nonzero(out.has_point)[0]
    pid = np.full(tracks.num_tracks, -1, np.int64)
    pid[pt_tracks] = np.arange(1, len(pt_tracks) + 1)
    obs = np.nonzero(out.active)[0]
    o_img = tracks.obs_image[obs]
    o_kp = tracks.obs_kp[obs]
    o_trk = tracks.obs_track[obs]
    rec = Reconstruction()
    for c, cam in enumerate(cameras):
        rec.cameras[c + 1] = cam if out.cameras is None else out.cameras[c]
    statuses = []
    order = np.argsort(o_img, kind="stable")
    bounds = np.searchsorted(o_img[order], np.arange(n + 1))
    for i in range(n):
        sl = order[bounds[i] : bounds[i + 1]]
        st = ImageStatus(names[i], str(paths[i]), bool(out.registered[i]), "", -1, ext[i].num_features)
        if out.registered[i]:
            ids = np.full(len(kp[i]), -1, np.int64)
            ids[o_kp[sl]] = pid[o_trk[sl]]
            pose = Rigid3(out.R[i], out.t[i], "cam", "world")
            rec.images[i + 1] = Image(i + 1, names[i], int(cam_ids[i]) + 1, pose, kp[i], ids)
            st.image_id = i + 1
            st.num_points = int(len(sl))
            e = out.errors_px[obs[sl]]
            st.mean_error_px = float(np.mean(e)) if len(e) else float("nan")
        else:
            st.reason = reasons.get(i, "not registered")
        statuses.append(st)
    # points with tracks (image_id, keypoint index)
    by_trk = np.argsort(o_trk, kind="stable")
    tb = np.searchsorted(o_trk[by_trk], pt_tracks)
    te = np.searchsorted(o_trk[by_trk], pt_tracks, side="right")
    err_obs = out.errors_px[obs]
    for k, t in enumerate(pt_tracks):
        sl = by_trk[tb[k] : te[k]]
        track = np.stack([o_img[sl] + 1, o_kp[sl]], axis=1)
        e = err_obs[sl]
        rec.points3d[int(pid[t])] = Point3D(
            int(pid[t]), out.points[t], out.colors[t], float(np.mean(e)), track
        )
    return rec, statuses
