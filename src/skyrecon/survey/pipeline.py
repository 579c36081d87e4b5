"""The survey pipeline: geotagged photos -> georeferenced model, cloud, DSM, orthophoto and map.

    result = run_survey(SurveyInputs(photos_dir, camera_txt=None, gcp_file=None), out, SurveyOptions())

Stages (each timed in ``SurveyResult.timings_s``):

1. ``photos``: the images of the folder and their tags (:mod:`skyrecon.survey.exif`); the camera
   from ``K.txt`` or the EXIF focal length and sensor width; the local ENU frame's origin.
2. ``sfm``: structure from motion (:func:`skyrecon.sfm.run_sfm`) on pairs chosen by GPS proximity
   (each photo with its nearest tagged photos and its neighbours in flight order); features and
   matches cached in ``workspace/sfm``, the finished model in ``workspace/sfm_model.pkl``.
3. ``georef``: the model into the ENU frame (:mod:`skyrecon.survey.georef`), GPS or control points;
   the origin's height is then moved to the ground (the 5th percentile of the sparse points).
4. ``mvs``: dense depth per photo and the fused cloud (:func:`skyrecon.mvs.run_mvs`, its depth
   ranges and sources from the SfM model's points), each view's depth and planar prior kept in ``workspace/mvs`` as soon as they are computed.
5. ``map``: an occupancy map from the depth maps (:class:`skyrecon.mapping.OccupancyMap`), the
   flight track marked free.

A rerun with the same inputs and options resumes: cached features, matches, model, depth maps and
planar priors are reused. Freed memory is handed back to the system after each stage
(:func:`skyrecon.memory.release_free_memory`), so the resident size follows what the run holds.
Frames: ENU metres around ``SurveyResult.origin`` (float64); everything written in a projected
system (UTM) is converted from it at the end.
"""

from __future__ import annotations

import pickle
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from skyrecon.core import PosedView
from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.reconstruction import Reconstruction
from skyrecon.errors import EstimationError, InputError
from skyrecon.executor import Executor, get_executor
from skyrecon.io.atomic import write_bytes_atomic
from skyrecon.io.calib import read_K_txt
from skyrecon.io.task_cache import task_key
from skyrecon.mapping import MapConfig, OccupancyMap
from skyrecon.memory import release_free_memory
from skyrecon.mvs import MVSResult, MVSSettings, run_mvs
from skyrecon.mvs.planar_prior import PlanarPriorSettings
from skyrecon.progress import progress
from skyrecon.sfm import SfMSettings, run_sfm
from skyrecon.sfm._pool import run_scoped_executor
from skyrecon.sfm.align import Sim3
from skyrecon.survey.exif import PhotoMeta, intrinsics_from_meta, read_photo_meta
from skyrecon.survey.gcp import GcpList, read_gcp_list
from skyrecon.survey.geo import GeoOrigin, enu_from_lla
from skyrecon.survey.georef import Georeference, georeference_to_gcps, georeference_to_gps

__all__ = ["NotGeoreferenced", "SurveyInputs", "SurveyOptions", "SurveyResult", "run_survey", "gps_pairs"]


@dataclass(frozen=True)
class SurveyInputs:
    """What a survey starts from.

    Attributes:
        photos: the image files, in flight (name) order.
        camera_txt: ``K.txt`` for the photos' size, or None (EXIF focal length and sensor size).
        gcp_file: OpenDroneMap ``gcp_list.txt``, or None (georeference to the GPS tags).
        origin: the local frame's geographic origin, or None (chosen from the tags).
    """

    photos: list[Path]
    camera_txt: Path | None = None
    gcp_file: Path | None = None
    origin: GeoOrigin | None = None


@dataclass(frozen=True)
class SurveyOptions:
    """How the survey runs.

    Attributes:
        sfm_image_size: longer side of the images for SfM features, pixels (None: full size).
        mvs_image_size: longer side of the MVS working images (depth maps), pixels.
        pair_neighbors: each photo is matched with this many nearest photos by GPS.
        pair_window: and with this many following photos in flight order.
        exhaustive_up_to: every pair is matched for sets of at most this many photos.
        voxel_m: occupancy-map voxel edge, metres.
        gps_threshold_m: fixed inlier distance of the GPS fit (None: adaptive), metres.
        seed: seed of every random choice.
        workers: worker processes (None: all cores).
        planar_prior: give plain (textureless) surfaces such as flat roofs the plane their
            surroundings support in the depth maps (:mod:`skyrecon.mvs.planar_prior`); off: faster,
            such surfaces stay without depth (holes in the DSM, unknown in the map).
    """

    sfm_image_size: int | None = 1600
    mvs_image_size: int = 640
    pair_neighbors: int = 10
    pair_window: int = 3
    exhaustive_up_to: int = 50
    voxel_m: float = 0.5
    gps_threshold_m: float | None = None
    seed: int = 0
    workers: int | None = None
    planar_prior: bool = True


@dataclass
class SurveyResult:
    """Everything a survey computed (ENU frame around ``origin``, metres).

    Attributes:
        origin: the local frame's geographic origin.
        camera: the camera the run started from; camera_source: ``"K.txt"``, ``"exif"`` (focal
            length and sensor width) or ``"exif-35mm"`` (35 mm equivalent; refined by SfM).
        metas: the tags of every photo, in input order.
        gps_enu: photo name -> (3,) GPS position in ENU metres (tagged photos).
        model: the SfM model in the ENU frame.
        unregistered: photo name -> why SfM left it out.
        georef: the fit and its residuals.
        mvs: the dense result (cloud and depth maps, ENU).
        map: the occupancy map (ENU).
        track: (N, 3) estimated camera centres in flight order, ENU metres.
        timings_s: seconds per stage.
        diagnostics: numbers of each stage (pairs, cache hits, ...).
        warnings: what the user should know.
    """

    origin: GeoOrigin
    camera: Intrinsics
    camera_source: str
    metas: list[PhotoMeta]
    gps_enu: dict[str, np.ndarray]
    model: Reconstruction
    unregistered: dict[str, str]
    georef: Georeference
    mvs: MVSResult
    map: OccupancyMap
    track: np.ndarray
    gcps: GcpList | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


# ----------------------------------------------------------------------------------------------
# photos, camera, origin
# ----------------------------------------------------------------------------------------------
def _camera(inputs: SurveyInputs, metas: list[PhotoMeta]) -> tuple[Intrinsics, str]:
    sizes: dict[tuple[int, int], int] = {}
    for m in metas:
        sizes[(m.width, m.height)] = sizes.get((m.width, m.height), 0) + 1
    size = max(sizes, key=lambda s: sizes[s])
    if inputs.camera_txt is not None:
        return read_K_txt(inputs.camera_txt, size[0], size[1]), "K.txt"
    first = next(m for m in metas if (m.width, m.height) == size)
    exact = first.focal_mm is not None and first.sensor_width_mm is not None
    return intrinsics_from_meta(first), "exif" if exact else "exif-35mm"


def _origin(inputs: SurveyInputs, metas: list[PhotoMeta], gcps: GcpList | None) -> GeoOrigin | None:
    """The local frame's origin: ``--origin``, else the median GPS tag, else the control points'
    centre; None when there is neither (the model can then only be made unreferenced)."""
    if inputs.origin is not None:
        return inputs.origin
    tagged = [m for m in metas if m.has_gps]
    if tagged:
        lat = float(np.median([m.lat_deg for m in tagged]))
        lon = float(np.median([m.lon_deg for m in tagged]))
        alt = float(np.median([m.alt_m for m in tagged]))
        return GeoOrigin(lat, lon, alt)
    if gcps is not None:
        return GeoOrigin(
            float(np.median([g.lat_deg for g in gcps.points])),
            float(np.median([g.lon_deg for g in gcps.points])),
            float(np.min([g.alt_m for g in gcps.points])),
        )
    return None


#: What a survey without any GPS tag or control point needs.
NO_GEO_HINT = (
    "none of the photos has GPS tags (EXIF GPSLatitude/GPSLongitude/GPSAltitude); give ground control "
    "points with --gcp FILE"
)


class NotGeoreferenced(InputError):
    """The photos made a model, but nothing places it on the Earth: no GPS tags and no control
    points, tags that cannot fix a similarity (all at one place, as on a tripod, or on a line),
    or control points that match no registered photo, without GPS to fall back on.

    Attributes:
        model: the structure-from-motion model in its own gauge (arbitrary frame and scale).
        unregistered: photo name -> why it is not in the model.
        warnings: what the stages before georeferencing had to say.
    """

    def __init__(
        self, message: str, model: Reconstruction, unregistered: dict[str, str], warnings: list[str]
    ):
        super().__init__(message)
        self.model = model
        self.unregistered = unregistered
        self.warnings = warnings


def gps_pairs(
    positions: list[np.ndarray | None], neighbors: int, window: int, exhaustive_up_to: int = 0
) -> np.ndarray:
    """Pairs to match for a survey: each tagged photo with its ``neighbors`` nearest tagged photos
    (horizontal GPS distance), and every photo with the next ``window`` photos in flight order (so
    a photo with a wrong tag still meets its true neighbours); every pair when there are at most
    ``exhaustive_up_to`` photos (as ``skyrecon sfm`` does).

    Args:
        positions: per photo, (3,) ENU metres or None (no tag).
    Returns:
        (P, 2) int64 ``i < j`` input indices, unique, sorted.
    """
    n = len(positions)
    if n <= exhaustive_up_to:
        rows, cols = np.triu_indices(n, k=1)
        return np.stack([rows, cols], axis=1).astype(np.int64)
    out: set[tuple[int, int]] = set()
    for i in range(n):
        for d in range(1, window + 1):
            if i + d < n:
                out.add((i, i + d))
    tagged = [i for i, p in enumerate(positions) if p is not None]
    if len(tagged) >= 2 and neighbors > 0:
        from scipy.spatial import cKDTree

        xy = np.stack([np.asarray(positions[i])[:2] for i in tagged])
        k = min(neighbors + 1, len(tagged))
        _, idx = cKDTree(xy).query(xy, k=k)
        for a, row in enumerate(np.atleast_2d(idx)):
            for b in row:
                i, j = tagged[a], tagged[int(b)]
                if i != j:
                    out.add((min(i, j), max(i, j)))
    if not out:
        return np.zeros((0, 2), np.int64)
    return np.array(sorted(out), np.int64)


# ----------------------------------------------------------------------------------------------
# stages
# ----------------------------------------------------------------------------------------------
def _file_key(paths: list[Path]) -> list[tuple[str, int, int]]:
    out = []
    for p in paths:
        st = p.stat()
        out.append((p.name, int(st.st_size), int(st.st_mtime_ns)))
    return out


def _sfm(
    inputs: SurveyInputs,
    cam: Intrinsics,
    camera_source: str,
    pairs: np.ndarray,
    options: SurveyOptions,
    executor: Executor,
    workspace: Path,
    diag: dict[str, Any],
) -> tuple[Reconstruction, dict[str, str], list[str]]:
    """The SfM model (own gauge), left-out photos and warnings; cached in the workspace."""
    settings = SfMSettings(max_image_size=options.sfm_image_size)
    if camera_source == "exif-35mm":
        # a 35 mm equivalent is rounded to a millimetre: refine the focal length. (Not otherwise: over
        # nearly flat ground seen straight down, focal length and flying height trade off, and a
        # refined focal length moves the cameras more than the tags' focal length is off.)
        settings = replace(settings, bundle=replace(settings.bundle, refine_focal_length=True))
    key = task_key(
        (_file_key(inputs.photos), cam.K.tolist(), settings, pairs.tobytes(), options.seed), "survey-sfm"
    )
    cache = workspace / "sfm_model.pkl"
    if cache.is_file():
        try:
            with open(cache, "rb") as f:
                saved = pickle.load(f)
            if saved.get("key") == key:
                diag["sfm_cached"] = True
                return saved["model"], saved["unregistered"], saved["warnings"]
        except Exception:  # noqa: BLE001 - a damaged cache only means recomputing
            pass
    result = run_sfm(
        inputs.photos,
        cam,
        settings,
        executor=executor,
        seed=options.seed,
        workspace=workspace / "sfm",
        pairs=pairs,
    )
    diag["sfm_cached"] = False
    diag["sfm_timings_s"] = {k: round(v, 2) for k, v in result.timings.items()}
    doc = {
        "key": key,
        "model": result.reconstruction,
        "unregistered": dict(result.unregistered),
        "warnings": list(result.warnings),
    }
    write_bytes_atomic(cache, pickle.dumps(doc, protocol=pickle.HIGHEST_PROTOCOL))
    return result.reconstruction, dict(result.unregistered), list(result.warnings)


def _georeference(
    model: Reconstruction,
    gps_enu: dict[str, np.ndarray],
    gcps: GcpList | None,
    origin: GeoOrigin | None,
    options: SurveyOptions,
) -> Georeference:
    """The model into the ENU frame: by the control points when given (by GPS, with a warning, when
    they cannot be used and there are tags), else by GPS.

    Raises:
        InputError: nothing usable places the model (the message says what is needed).
        EstimationError: the tags do not fit one similarity.
    """
    if origin is None:
        raise InputError(NO_GEO_HINT)
    if gcps is not None:
        pts = [
            (g.name, enu_from_lla(origin, g.lat_deg, g.lon_deg, g.alt_m)[0], g.observations)
            for g in gcps.points
        ]
        try:
            geo = georeference_to_gcps(model, pts, options.seed)
        except (InputError, EstimationError) as e:
            if len(gps_enu) < 3:
                raise InputError(f"the control points cannot be used: {e}") from None
            geo = _georeference(model, gps_enu, None, origin, options)  # the tags' own checks
            geo.warnings.insert(0, f"the control points cannot be used ({e}); georeferenced to GPS instead")
            return geo
        if len(gps_enu) >= 3:
            centres = {im.name: geo.enu_from_model.apply(im.center_world) for im in model.images.values()}
            geo.gps_residuals_m = {
                n: float(np.linalg.norm(centres[n] - gps_enu[n])) for n in centres if n in gps_enu
            }
        return geo
    if len(gps_enu) < 3:
        raise InputError(
            f"only {len(gps_enu)} photos have GPS tags; at least 3 are needed to georeference (or give --gcp FILE)"
        )
    spread = float(np.ptp(np.stack(list(gps_enu.values())), axis=0).max())
    if spread < 1.0:
        raise InputError(
            f"the GPS tags of all {len(gps_enu)} photos lie within {spread:.2f} m of each other (a tripod, or "
            "a receiver that did not update): they cannot scale or orient the model; give --gcp FILE"
        )
    return georeference_to_gps(model, gps_enu, options.seed, options.gps_threshold_m)


def _ground_shift(model: Reconstruction) -> float:
    """Height of the ground in the model's ENU frame: the 5th percentile of the sparse points."""
    z = np.array([p.xyz[2] for p in model.points3d.values()])
    return float(np.percentile(z, 5)) if len(z) else 0.0


def _views(model: Reconstruction, inputs: SurveyInputs) -> list[PosedView]:
    by_name = {p.name: p for p in inputs.photos}
    ims = sorted(model.images.values(), key=lambda im: im.image_id)
    return [
        PosedView(im.name, model.cameras[im.camera_id], im.cam_from_world, by_name.get(im.name)) for im in ims
    ]


def _subsampled(depth_m: np.ndarray, cam: Intrinsics, step: int) -> tuple[np.ndarray, Intrinsics]:
    """Every ``step``-th pixel of a depth map (H, W) and the camera of that grid (pixel centres kept)."""
    if step <= 1:
        return depth_m, cam
    d = np.ascontiguousarray(depth_m[::step, ::step])
    sub = Intrinsics(cam.fx / step, cam.fy / step, cam.cx / step, cam.cy / step, d.shape[1], d.shape[0])
    return d, sub


def _build_map(mvs: MVSResult, track: np.ndarray, options: SurveyOptions, max_range_m: float) -> OccupancyMap:
    """The occupancy map of the depth maps (subsampled to about one ray per voxel on the ground)."""
    occ = OccupancyMap(MapConfig(voxel_size_m=options.voxel_m, max_range_m=max_range_m))
    for k, dm in enumerate(progress(list(mvs.depth_maps.values()), desc="map")):
        if k % 25 == 24:  # the ray casting's freed temporaries would otherwise stay resident
            release_free_memory()
        if dm.cam_from_world is None:
            continue
        finite = dm.depth_m[np.isfinite(dm.depth_m)]
        if finite.size == 0:
            continue
        # a ground pixel covers depth / f metres; keep about one ray per half voxel
        footprint = float(np.median(finite)) / dm.intrinsics.fx
        step = max(1, int(0.5 * options.voxel_m / max(footprint, 1e-6)))
        depth, cam = _subsampled(dm.depth_m, dm.intrinsics, step)
        occ.integrate_depth(depth, cam, dm.cam_from_world.inverse().with_frames("world", "cam"))
    if len(track):
        occ.mark_flown_free(track, 1.0)
    occ.grid.shrink_to_fit()  # the finished map keeps only its blocks (the pool grows by half)
    return occ


def run_survey(
    inputs: SurveyInputs,
    workspace: str | Path,
    options: SurveyOptions | None = None,
    executor: Executor | None = None,
) -> SurveyResult:
    """Run every stage of the module docstring.

    Args:
        inputs: photos, camera, GCPs, origin.
        workspace: folder for cached work (features, matches, model, depth maps); a rerun resumes.
        options: see :class:`SurveyOptions`.
        executor: where per-image work runs (default: local processes, ``options.workers``).
    Raises:
        InputError: unreadable photos, no camera.
        NotGeoreferenced: a model was made but nothing places it (no GPS and no GCPs, too few or
            degenerate tags, control points that match no registered photo, tags that do not fit
            one similarity); it carries the unreferenced model.
        EstimationError: no model can be made.
    """
    options = options or SurveyOptions()
    ws = Path(workspace)
    ws.mkdir(parents=True, exist_ok=True)
    timings: dict[str, float] = {}
    diag: dict[str, Any] = {}
    warnings: list[str] = []
    t = time.perf_counter()
    if len(inputs.photos) < 3:
        raise InputError(f"a survey needs at least 3 photos, found {len(inputs.photos)}")
    metas = [read_photo_meta(p) for p in inputs.photos]
    gcps = read_gcp_list(inputs.gcp_file) if inputs.gcp_file is not None else None
    cam, camera_source = _camera(inputs, metas)
    others = [m.path.name for m in metas if (m.width, m.height) != tuple(cam.size)]
    if others:
        sizes = sorted({(m.width, m.height) for m in metas} - {tuple(cam.size)})
        warnings.append(
            f"mixed cameras: {len(others)} photos are not {cam.size[0]}x{cam.size[1]} like the others "
            f"({', '.join(f'{w}x{h}' for w, h in sizes)}: {', '.join(others[:5])}{' ...' if len(others) > 5 else ''}); "
            "the survey leaves them out (survey them on their own)"
        )
    origin = _origin(inputs, metas, gcps)
    gps_enu: dict[str, np.ndarray] = {}
    positions: list[np.ndarray | None] = []
    for m in metas:
        if m.has_gps and origin is not None:  # (a tag gives an origin)
            p = enu_from_lla(origin, m.lat_deg, m.lon_deg, m.alt_m)[0]
            gps_enu[m.path.name] = p
            positions.append(p)
        else:
            positions.append(None)
    untagged = [m.path.name for m in metas if not m.has_gps]
    if untagged and gcps is None:
        warnings.append(
            f"{len(untagged)} photos have no GPS tags ({', '.join(untagged[:5])}{' ...' if len(untagged) > 5 else ''})"
        )
    diag["alt_source"] = sorted({m.alt_source for m in metas if m.alt_source})
    pairs = gps_pairs(positions, options.pair_neighbors, options.pair_window, options.exhaustive_up_to)
    diag["pairs"] = int(len(pairs))
    timings["photos"] = time.perf_counter() - t

    # one local pool for every stage (a plain process executor becomes a persistent pool)
    executor, release = run_scoped_executor(executor or get_executor(None, options.workers))
    try:
        t = time.perf_counter()
        try:
            model0, unregistered, sfm_warnings = _sfm(
                inputs, cam, camera_source, pairs, options, executor, ws, diag
            )
        except (InputError, EstimationError) as e:
            if origin is None:  # say both: no model, and nothing to georeference one with
                if isinstance(e, InputError):
                    raise InputError(f"{e.reason}; and {NO_GEO_HINT}", e.path) from None
                raise EstimationError(f"{e}; and {NO_GEO_HINT}") from None
            raise
        warnings.extend(sfm_warnings)
        release_free_memory()  # the matcher's and mapper's freed arrays
        timings["sfm"] = time.perf_counter() - t

        t = time.perf_counter()
        try:
            geo = _georeference(model0, gps_enu, gcps, origin, options)
        except (InputError, EstimationError) as e:
            why = e.reason if isinstance(e, InputError) else str(e)
            raise NotGeoreferenced(why, model0, unregistered, warnings) from None
        assert origin is not None  # _georeference needs one
        model = geo.enu_from_model.transform_reconstruction(model0)
        if inputs.origin is None:  # move the origin down to the ground, so heights are above ground
            dz = _ground_shift(model)
            origin = GeoOrigin(origin.lat_deg, origin.lon_deg, origin.alt_m + dz)
            shift = Sim3(np.eye(3), np.array([0.0, 0.0, -dz]), 1.0)
            geo.enu_from_model = shift @ geo.enu_from_model
            model = shift.transform_reconstruction(model)
            gps_enu = {n: p - np.array([0.0, 0.0, dz]) for n, p in gps_enu.items()}
        warnings.extend(geo.warnings)
        if geo.set_aside:
            warnings.insert(
                0,
                f"{len(geo.set_aside)} GPS tags do not fit the others and were set aside: "
                + ", ".join(f"{n} ({r:.1f} m off)" for n, r in list(geo.set_aside.items())[:10]),
            )
        timings["georef"] = time.perf_counter() - t

        t = time.perf_counter()
        views = _views(model, inputs)
        mvs_settings = MVSSettings(
            max_image_size=options.mvs_image_size,
            seed=options.seed,
            # nadir photos: every plain roof hides the street beyond its edges, so the prior's
            # band-hidden test would set roofs aside (see PlanarPriorSettings.hidden_band)
            planar_prior=PlanarPriorSettings(enabled=options.planar_prior, hidden_band=False),
        )
        # the model's own points give the depth ranges and sources: no second feature matching
        mvs = run_mvs(
            views,
            None,
            mvs_settings,
            executor=executor,
            workspace=ws / "mvs",
            known_points=model.points_array()[0],
        )
        release_free_memory()  # the working images and depths' intermediates MVS freed
        warnings.extend(mvs.warnings)
        timings["mvs"] = time.perf_counter() - t
        diag["mvs_timings_s"] = {k: round(v, 2) for k, v in mvs.timings_s.items()}
    finally:
        release()

    t = time.perf_counter()
    order = {p.name: k for k, p in enumerate(inputs.photos)}
    ims = sorted(model.images.values(), key=lambda im: order.get(im.name, 0))
    track = np.array([im.center_world for im in ims]).reshape(-1, 3)
    heights = track[:, 2] if len(track) else np.zeros(1)
    max_range = float(max(60.0, 1.5 * (np.max(heights) - _ground_shift(model) + 10.0)))
    occ = _build_map(mvs, track, options, max_range)
    # the depth maps are in the map now and nothing after reads them (1.2 MB a photo)
    mvs.depth_maps.clear()
    release_free_memory()
    timings["map"] = time.perf_counter() - t
    return SurveyResult(
        origin,
        cam,
        camera_source,
        metas,
        gps_enu,
        model,
        unregistered,
        geo,
        mvs,
        occ,
        track,
        gcps,
        timings,
        diag,
        warnings,
    )
