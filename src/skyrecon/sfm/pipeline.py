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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.reconstruction import Image, Point3D, Reconstruction
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import EstimationError, InputError
from skyrecon.executor import Executor, get_executor
from skyrecon.features.match import match_descriptors
from skyrecon.sfm._pool import run_scoped_executor
from skyrecon.sfm.extract import ExtractedImage, ExtractTask, extract_one, load_features
from skyrecon.sfm.mapper import IncrementalMapper, MapperInput, MapperOutput
from skyrecon.sfm.matching import PairGeometry, run_matching
from skyrecon.sfm.pairs import PairSelection, resolve_pair_mode, select_pairs
from skyrecon.sfm.result import ImageStatus, SfMResult
from skyrecon.sfm.retrieval import vlad_descriptors
from skyrecon.sfm.settings import PairMode, SfMSettings
from skyrecon.sfm.tracks import Tracks, build_tracks
from skyrecon.sfm.viewgraph import rotation_inconsistent_pairs
from skyrecon.threads import limited_threads
from skyrecon.twoview.estimate import estimate_two_view_geometry
from skyrecon.twoview.settings import TwoViewSettings

__all__ = ["run_sfm", "image_names"]


def image_names(paths: Sequence[Path]) -> list[str]:
    """Names of images: paths relative to their deepest common directory (the file name when
    they share one directory). Symbolic links keep their own names (a folder of links named
    ``photo_*.png`` gives those names, not their targets'), so names join back onto the folder."""
    absolute = [Path(os.path.abspath(p)) for p in paths]
    parents = [p.parent for p in absolute]
    common = Path(os.path.commonpath([str(p) for p in parents])) if parents else Path(".")
    return [p.relative_to(common).as_posix() for p in absolute]


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
    pairs: list[PairGeometry], x: dict[int, str], cams: list[Intrinsics], settings: SfMSettings
) -> list[str]:
    """Run the full two-view diagnostics (E vs F vs H vs rotation) on the pairs with the most
    matches, to explain a failed or partial reconstruction (e.g. a wrong K)."""
    out: list[str] = []
    best = sorted(pairs, key=lambda p: -p.num_matches)[:3]
    for p in best:
        fi = load_features(x[p.i], ("keypoints", "descriptors"))
        fj = load_features(x[p.j], ("keypoints", "descriptors"))
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
    pairs: np.ndarray | None = None,
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
        workspace: directory for cached features and pair matches (reused by later runs, so a
            killed run resumes); default a temporary
            directory removed at the end.
        pairs: (P, 2) input-image indices of the pairs to match, instead of
            ``settings.pairing`` (e.g. photos near each other by GPS); pairs with an unusable
            image are dropped.
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
    tmp = None
    if workspace is None:
        tmp = tempfile.TemporaryDirectory(prefix="skyrecon-sfm-")
        workspace = tmp.name
    cache_dir = Path(workspace) / "features"
    cache_dir.mkdir(parents=True, exist_ok=True)
    state = _SfMRun(
        paths,
        names,
        cams_in,
        settings,
        executor,
        workers,
        seed,
        cache_dir,
        resolve_pair_mode(settings.pair_mode, names, settings.pairing),
        t_total,
        given_pairs=None if pairs is None else np.asarray(pairs, np.int64).reshape(-1, 2),
    )
    try:
        with limited_threads(1):
            return _run(state)
    finally:
        release()
        if tmp is not None:
            tmp.cleanup()


@dataclass
class _SfMRun:
    """What the steps of one run share: its inputs, and what each step leaves for the next.

    Image indices are input indices (0..n-1) unless a name says otherwise.

    Attributes:
        paths, names, cams_in: the input images and their cameras (input size).
        settings, executor, workers, seed, cache_dir: how the run works.
        pair_mode: the pairing mode, ``auto`` resolved over all input images.
        t_total: ``perf_counter`` at the start of :func:`run_sfm`.
        timings, diagnostics, warnings: the result's, filled step by step.
        reasons: image -> why it was left out (first reason wins).
        extracted: per image, what feature extraction found (``features`` step).
        usable: images still in play, ascending.
        scale: median working (feature) resolution / input resolution.
        selection: the pairs to match (``select_pairs`` step).
        pairs: verified pair geometries, input indices (``match_pairs`` step).
        keypoints, keypoint_sizes, colors: per image, (M_i, 2) input pixels, (M_i,), (M_i, 3) uint8.
        tracks: feature tracks over the usable images (``tracks`` step).
        cameras, camera_of_image: distinct cameras and (n,) index of each image's camera.
        mapped: the mapper's output (``map`` step).
        given_pairs: (P, 2) input-index pairs to match instead of selecting them, or None.
    """

    paths: list[Path]
    names: list[str]
    cams_in: list[Intrinsics]
    settings: SfMSettings
    executor: Executor
    workers: int
    seed: int
    cache_dir: Path
    pair_mode: PairMode
    t_total: float
    timings: dict[str, float] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    reasons: dict[int, str] = field(default_factory=dict)
    extracted: list[ExtractedImage] = field(default_factory=list)
    usable: list[int] = field(default_factory=list)
    scale: float = 1.0
    selection: PairSelection | None = None
    pairs: list[PairGeometry] = field(default_factory=list)
    keypoints: list[np.ndarray] = field(default_factory=list)
    keypoint_sizes: list[np.ndarray] = field(default_factory=list)
    colors: list[np.ndarray] = field(default_factory=list)
    tracks: Tracks | None = None
    cameras: list[Intrinsics] = field(default_factory=list)
    camera_of_image: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    mapped: MapperOutput | None = None
    given_pairs: np.ndarray | None = None

    @property
    def n(self) -> int:
        return len(self.paths)


def _run(state: _SfMRun) -> SfMResult:
    """The steps of :func:`run_sfm`, in order, on one shared state."""
    _extract_features(state)
    _leave_out_unusable(state)
    _select_pairs(state)
    _match_pairs(state)
    _leave_out_identical(state)
    _build_tracks(state)
    _map(state)
    _collect_warnings(state)
    return _result(state)


def _extract_features(state: _SfMRun) -> None:
    """Features of every image (per image on the executor, cached in the workspace)."""
    t0 = time.perf_counter()
    fs = state.settings.feature_settings
    tasks = [
        ExtractTask(k, str(p), state.names[k], fs, str(state.cache_dir), state.settings.target_features)
        for k, p in enumerate(state.paths)
    ]
    state.extracted = state.executor.map(extract_one, tasks, desc="features")
    state.timings["features"] = time.perf_counter() - t0
    state.diagnostics["features_cached"] = sum(1 for e in state.extracted if e.cached)
    for e in state.extracted:
        if not e.ok:
            state.reasons[e.index] = e.reason


def _leave_out_unusable(state: _SfMRun) -> None:
    """Leave out images of another size than their K, duplicate files and texture-poor images.

    Raises:
        InputError: no image has the size of its K, or fewer than two images are usable.
    """
    n, ext, reasons, cams_in, names = state.n, state.extracted, state.reasons, state.cams_in, state.names
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
    min_features = state.settings.min_features
    for e in ext:
        if e.index not in reasons and e.num_features < min_features:
            reasons[e.index] = (
                f"only {e.num_features} features (at least {min_features} needed): too little texture"
            )
    usable = [k for k in range(n) if k not in reasons]
    if len(usable) < 2:
        detail = "; ".join(f"{names[k]}: {r}" for k, r in sorted(reasons.items())[:10])
        raise InputError(f"fewer than two usable images ({len(usable)} of {n}): {detail}")
    state.usable = usable
    state.scale = float(np.median([ext[k].scale for k in usable]))
    state.diagnostics["working_scale"] = state.scale
    state.diagnostics["num_features"] = {names[k]: ext[k].num_features for k in range(n)}


def _select_pairs(state: _SfMRun) -> None:
    """The pairs of usable images to match (exhaustive, sequential or retrieval)."""
    t0 = time.perf_counter()
    if state.given_pairs is not None:
        state.selection = _given_selection(state.given_pairs, state.usable)
        state.timings["pairs"] = time.perf_counter() - t0
        state.diagnostics["pairing"] = {"mode": "given", "num_pairs": int(len(state.selection.pairs))}
        return
    paths_c = [state.extracted[k].cache_path for k in state.usable]
    pairing = state.settings.pairing
    sel = select_pairs(
        len(state.usable),
        state.pair_mode,
        pairing,
        lambda: vlad_descriptors(paths_c, pairing.retrieval_clusters, state.seed),
    )
    state.selection = sel
    state.timings["pairs"] = time.perf_counter() - t0
    state.diagnostics["pairing"] = {
        "mode": sel.mode,
        "num_pairs": int(len(sel.pairs)),
        "num_loop_pairs": sel.num_loop_pairs,
    }


def _given_selection(pairs: np.ndarray, usable: list[int]) -> PairSelection:
    """The given input-index pairs as a selection over the usable images (others dropped)."""
    pos = np.full(int(max(usable, default=0)) + 1, -1, np.int64)
    pos[usable] = np.arange(len(usable))
    p = pairs[(pairs.min(axis=1) >= 0) & (pairs.max(axis=1) < len(pos))] if len(pairs) else pairs
    a, b = pos[p[:, 0]], pos[p[:, 1]]
    keep = (a >= 0) & (b >= 0) & (a != b)
    sel = np.unique(np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)[keep], axis=0)
    return PairSelection(sel.reshape(-1, 2).astype(np.int64), "given")


def _match_pairs(state: _SfMRun) -> None:
    """Match and verify the selected pairs (per chunk on the executor), then reject pairs whose
    rotation disagrees with the rotations chained along the strongest pairs."""
    sel = _required(state.selection, "pair selection")
    settings, usable = state.settings, state.usable
    t0 = time.perf_counter()
    geo_c = run_matching(
        sel.pairs,
        [state.extracted[k].cache_path for k in usable],
        [state.cams_in[k] for k in usable],
        state.scale,
        settings.matching,
        settings.verification,
        state.seed,
        state.executor,
        state.workers,
        str(state.cache_dir.parent / "matches"),
    )
    state.timings["matching"] = time.perf_counter() - t0
    pairs: list[PairGeometry] = []
    for g in geo_c:  # back to input indices
        g.i, g.j = usable[g.i], usable[g.j]
        pairs.append(g)
    state.pairs = pairs
    if settings.verification.max_rotation_inconsistency_deg > 0:
        trusted = None
        if sel.mode == "sequential":  # neighbouring frames: their rotations chain reliably
            trusted = np.array([g.j - g.i <= settings.pairing.window for g in pairs])
        bad, err = rotation_inconsistent_pairs(
            pairs, state.n, settings.verification.max_rotation_inconsistency_deg, trusted
        )
        for k in bad:
            g = pairs[k]
            g.reason = (
                f"relative rotation disagrees by {err[k]:.1f} deg with the rotations chained along the "
                "strongest pairs (repeated structure?)"
            )
            g.status, g.matches, g.R, g.t = "failed", g.matches[:0], None, None
        state.diagnostics["pairs_rotation_inconsistent"] = len(bad)
    for status, key in (
        ("ok", "pairs_verified"),
        ("no_translation", "pairs_no_translation"),
        ("failed", "pairs_failed"),
    ):
        state.diagnostics[key] = sum(1 for g in pairs if g.status == status)


def _leave_out_identical(state: _SfMRun) -> None:
    """Near-duplicates: of two identical-looking images (no parallax), the second is left out."""
    usable_set = set(state.usable)
    for g in state.pairs:
        if (
            g.status == "no_translation"
            and "identical" in g.reason
            and g.i in usable_set
            and g.j in usable_set
        ):
            state.reasons[g.j] = (
                f"duplicate: looks identical to {state.names[g.i]} (no parallax between them)"
            )
            usable_set.discard(g.j)
    state.usable = [k for k in state.usable if k in usable_set]


def _build_tracks(state: _SfMRun) -> None:
    """Load keypoints, sizes and colours of every image and join the matches into tracks."""
    t0 = time.perf_counter()
    for e in state.extracted:
        if e.ok and e.cache_path:
            f = load_features(e.cache_path, ("keypoints", "scales", "colors"))
            state.keypoints.append(f["keypoints"])
            state.keypoint_sizes.append(f["scales"])
            state.colors.append(f["colors"])
        else:
            state.keypoints.append(np.zeros((0, 2)))
            state.keypoint_sizes.append(np.zeros(0, np.float32))
            state.colors.append(np.zeros((0, 3), np.uint8))
    usable_set = set(state.usable)
    track_pairs = [
        (g.i, g.j, g.matches)
        for g in state.pairs
        if g.status != "failed" and g.i in usable_set and g.j in usable_set
    ]
    tracks = build_tracks([len(k) for k in state.keypoints], track_pairs, state.keypoints)
    state.tracks = tracks
    state.timings["tracks"] = time.perf_counter() - t0
    state.diagnostics["tracks"] = {
        "num_tracks": tracks.num_tracks,
        "num_observations": tracks.num_observations,
        "inconsistent_dropped": tracks.num_inconsistent,
        "mean_length": float(tracks.lengths.mean()) if tracks.num_tracks else 0.0,
    }


def _map(state: _SfMRun) -> None:
    """Incremental mapping with bundle adjustment.

    Raises:
        EstimationError: no initial pair; the message adds the two-view diagnostics of the
            strongest pairs and the images left out before mapping.
    """
    t0 = time.perf_counter()
    names, n = state.names, state.n
    state.cameras, state.camera_of_image = _camera_ids(state.cams_in)
    usable_mask = np.zeros(n, bool)
    usable_mask[state.usable] = True
    data = MapperInput(
        names,
        state.keypoints,
        state.keypoint_sizes,
        state.colors,
        state.cameras,
        state.camera_of_image,
        _required(state.tracks, "tracks"),
        state.pairs,
        usable_mask,
        state.scale,
        _sequence_reach(state),
    )
    mapper = IncrementalMapper(data, state.settings.mapper, state.settings.bundle, state.seed)
    try:
        out = mapper.run()
    except EstimationError as exc:
        extra = _diagnose_state(state, [g for g in state.pairs if g.status != "failed"])
        left = "; ".join(f"{names[k]}: {r}" for k, r in sorted(state.reasons.items())[:10])
        msg = str(exc)
        if extra:
            msg += ". " + " ".join(extra)
        if left:
            msg += f". Images left out before mapping: {left}"
        raise EstimationError(msg) from None
    state.mapped = out
    state.timings["mapping"] = time.perf_counter() - t0
    state.diagnostics["mapper"] = out.diagnostics
    if out.init_pair is not None:
        state.diagnostics["mapper"]["init_pair"] = [names[out.init_pair[0]], names[out.init_pair[1]]]
    state.diagnostics["mapper"]["registration_order"] = [names[i] for i in out.registration_order]
    state.warnings.extend(out.warnings)
    for i, why in out.failures.items():
        state.reasons.setdefault(i, why)


def _sequence_reach(state: _SfMRun) -> int:
    """How far apart two frames of a flight are still paired along the sequence (0 when the
    images are not matched as a sequence)."""
    sel = state.selection
    if sel is None or sel.mode != "sequential":
        return 0
    p = state.settings.pairing
    return int(max(p.window, p.max_offset if p.exponential else 0))


def _diagnose_state(state: _SfMRun, candidates: list[PairGeometry]) -> list[str]:
    """:func:`_diagnose_pairs` on ``candidates`` (all pairs when there are none)."""
    return _diagnose_pairs(
        candidates or state.pairs,
        {k: state.extracted[k].cache_path for k in range(state.n)},
        state.cams_in,
        state.settings,
    )


def _collect_warnings(state: _SfMRun) -> None:
    """Explain a partial model (two-view diagnostics) and list the left-out images first."""
    out = _required(state.mapped, "mapping")
    if out.registered.sum() < 0.8 * len(state.usable):
        state.warnings.extend(_diagnose_state(state, [g for g in state.pairs if g.status == "ok"]))
    reasons, names = state.reasons, state.names
    if reasons:
        state.warnings.insert(
            0,
            f"{len(reasons)} of {state.n} images were left out of the model: "
            + ", ".join(names[k] for k in sorted(reasons)[:10])
            + (" ..." if len(reasons) > 10 else ""),
        )


def _result(state: _SfMRun) -> SfMResult:
    rec, statuses = _assemble(
        state.names,
        state.paths,
        state.extracted,
        state.keypoints,
        _required(state.mapped, "mapping"),
        _required(state.tracks, "tracks"),
        state.cameras,
        state.camera_of_image,
        state.reasons,
    )
    state.timings["total"] = time.perf_counter() - state.t_total
    return SfMResult(rec, statuses, state.diagnostics, state.timings, state.warnings, state.seed)


_T = TypeVar("_T")


def _required(value: _T | None, step: str) -> _T:
    """``value``, which an earlier step has set (a programming error otherwise)."""
    if value is None:
        raise RuntimeError(f"SfM step order: {step} has not run")
    return value


def _assemble(
    names: list[str],
    paths: list[Path],
    ext: list[ExtractedImage],
    kp: list[np.ndarray],
    out: MapperOutput,
    tracks: Tracks,
    cameras: list[Intrinsics],
    cam_ids: np.ndarray,
    reasons: dict[int, str],
) -> tuple[Reconstruction, list[ImageStatus]]:
    """The COLMAP-ready model of the mapper's output and one status per input image."""
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
