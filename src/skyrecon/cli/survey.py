"""``skyrecon survey``: from geotagged survey photos to a georeferenced model, DSM, orthophoto and map.

Runs structure from motion on the photos of PHOTOS_DIR (pairs chosen by GPS proximity),
georeferences the model to the photos' EXIF GPS tags (robustly: tags that do not fit are set aside
and named; DJI XMP altitudes are used when present) or to ground control points (``--gcp``,
OpenDroneMap's ``gcp_list.txt``), then multi-view stereo and mapping. Writes into OUT:

* ``model/``: COLMAP text model in the local East-North-Up frame (metres around ``origin``);
* ``cloud.laz`` (``--format las|ply``): the dense cloud in UTM (EPSG in the file), ellipsoidal heights;
* ``dsm.tif`` (highest surface per cell) and ``ortho.tif`` (colour seen from above): GeoTIFFs in UTM;
* ``map/``: an occupancy map in the ENU frame for ``skyrecon plan`` (``map/geo_origin.json`` holds
  the frame's geographic origin: pass it to ``plan --origin`` for QGroundControl missions);
* ``footprint.geojson`` (covered area, lon/lat), ``survey.json`` (``origin``, ``cameras: [{name, lat,
  lon, alt, gps_residual_m}]``, tags set aside, timings) and ``report.html``.

Intermediate work is kept in ``OUT/workspace`` (or ``--workspace``): a rerun resumes from it.

When nothing can place the model (no GPS tags and no ``--gcp``; tags all at one place, as on a
tripod, or on a line), OUT still gets ``model/`` (the SfM model in its own gauge) and ``survey.json``
(``georeferenced: false`` and why), and the command ends with exit status 2 and one line saying
what is needed. Control points that match no registered photo fall back to the GPS tags (a warning).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from skyrecon.cli.common import (
    add_command,
    add_executor_options,
    info,
    open_executor,
    output_dir,
    positive_float,
    positive_int,
)
from skyrecon.errors import InputError

EXAMPLES = """  skyrecon render survey --photos 16 --out flight/ && skyrecon survey flight/images --out survey/
  skyrecon survey photos/ --camera K.txt --out survey/
  skyrecon survey photos/ --gcp photos/gcp_list.txt --out survey_gcp/
  skyrecon plan survey/map --start 0 0 60 --goal 80 60 60 --origin LAT LON ALT --out route/  # from survey.json
"""

GEO_HINT = "skyrecon survey needs the 'geo' extra (pyproj, rasterio, laspy): pip install 'skyrecon[geo]'"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = add_command(
        subparsers,
        "survey",
        help="georeferenced model, cloud, DSM, orthophoto and map from geotagged survey photos",
        description=__doc__.split("\n\n")[0].split(": ", 1)[1],
        examples=EXAMPLES,
    )
    p.add_argument(
        "photos_dir", metavar="PHOTOS_DIR", help="folder of the survey photos (JPEG with EXIF GPS)"
    )
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    p.add_argument(
        "--camera",
        metavar="K.txt",
        help="3x3 camera matrix for the photos' size (default: from EXIF focal length)",
    )
    p.add_argument("--gcp", metavar="FILE", help="ground control points, OpenDroneMap gcp_list.txt format")
    p.add_argument(
        "--origin",
        type=float,
        nargs=3,
        metavar=("LAT", "LON", "ALT"),
        help="geographic origin of the local frame (degrees, degrees, ellipsoidal metres; default: the "
        "photos' median position at ground level)",
    )
    p.add_argument(
        "--max-image-size",
        type=positive_int,
        default=1600,
        metavar="PX",
        help="longer side of the images for SfM features, pixels (default 1600)",
    )
    p.add_argument(
        "--mvs-image-size",
        type=positive_int,
        default=640,
        metavar="PX",
        help="longer side of the depth maps, pixels (default 640)",
    )
    p.add_argument(
        "--no-planar-prior",
        action="store_true",
        help="faster: leave plain surfaces (flat roofs) without depth instead of giving them the plane "
        "their surroundings support (holes in the DSM, unknown in the map)",
    )
    p.add_argument(
        "--voxel-size", type=positive_float, default=0.5, help="map voxel edge, metres (default 0.5)"
    )
    p.add_argument(
        "--cell", type=positive_float, help="DSM/orthophoto cell size, metres (default: from the cloud)"
    )
    p.add_argument(
        "--epsg", type=positive_int, help="projected system of the cloud and rasters (default: UTM zone)"
    )
    p.add_argument(
        "--gps-threshold",
        type=positive_float,
        metavar="M",
        help="GPS tags farther than this from the fit are set aside, metres (default: adaptive)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice (default 0)")
    add_executor_options(
        p, "workers for features, matching and depth (default: all cores, or $SKYRECON_WORKERS)"
    )
    p.add_argument("--workspace", help="cache of intermediate work, reused by reruns (default OUT/workspace)")
    p.add_argument(
        "--format",
        choices=("laz", "las", "ply"),
        default="laz",
        help="the dense cloud: LAZ (default) or LAS in UTM with the CRS, or PLY in the local ENU frame",
    )
    return p


def _check_geo_extra() -> None:
    try:
        import laspy  # noqa: F401
        import pyproj  # noqa: F401
        import rasterio  # noqa: F401
    except ImportError:
        raise InputError(GEO_HINT) from None


def run(args: argparse.Namespace) -> int:
    _check_geo_extra()
    from skyrecon.cli.sfm import list_images
    from skyrecon.survey.geo import GeoOrigin
    from skyrecon.survey.outputs import write_survey_outputs, write_unreferenced_outputs
    from skyrecon.survey.pipeline import NotGeoreferenced, SurveyInputs, SurveyOptions, run_survey

    t0 = time.perf_counter()
    photos = list_images(args.photos_dir)
    out = output_dir(args.out)
    workspace = Path(args.workspace) if args.workspace else out / "workspace"
    for what, value in (("--camera", args.camera), ("--gcp", args.gcp)):
        if value is not None and not Path(value).is_file():
            raise InputError(f"{what} file not found; check the path", value)
    inputs = SurveyInputs(
        photos,
        Path(args.camera) if args.camera else None,
        Path(args.gcp) if args.gcp else None,
        GeoOrigin(*args.origin) if args.origin else None,
    )
    options = SurveyOptions(
        sfm_image_size=args.max_image_size,
        mvs_image_size=args.mvs_image_size,
        voxel_m=args.voxel_size,
        gps_threshold_m=args.gps_threshold,
        seed=args.seed,
        workers=args.workers,
        planar_prior=not args.no_planar_prior,
    )
    if not args.quiet:
        info(f"{len(photos)} photos in {args.photos_dir}; workspace {workspace}")
    with open_executor(args) as executor:
        try:
            result = run_survey(inputs, workspace, options, executor)
        except NotGeoreferenced as e:  # the model it could make, then the one line of what is needed
            write_unreferenced_outputs(e.model, e.unregistered, e.warnings, e.reason, len(photos), out)
            raise InputError(
                f"{e.reason}; wrote the unreferenced model of {len(e.model.images)} photos to {out / 'model'}",
                args.photos_dir,
            ) from None
    files = write_survey_outputs(result, out, args.format, args.cell, args.epsg, release_map=True)
    geo = result.georef
    if geo.set_aside:
        info(
            f"warning: {len(geo.set_aside)} GPS tags set aside: "
            + ", ".join(f"{n} ({r:.1f} m off)" for n, r in geo.set_aside.items())
        )
    if result.unregistered:
        info(
            f"warning: {len(result.unregistered)} photos not in the model: "
            + ", ".join(list(result.unregistered)[:8])
        )
    if not args.quiet:
        for w in result.warnings:
            if "set aside" not in w:
                info(f"warning: {w}")
        o = result.origin
        info(
            f"registered {len(result.model.images)} of {len(photos)} photos, georeferenced to "
            f"{'control points' if geo.method == 'gcp' else 'GPS'} (RMS {geo.rms_m:.2f} m), "
            f"{len(result.mvs.cloud)} dense points, in {time.perf_counter() - t0:.1f} s"
        )
        info(f"origin {o.lat_deg:.7f} {o.lon_deg:.7f} {o.alt_m:.2f} (pass to 'skyrecon plan --origin')")
        info(f"wrote {out}/" + ", ".join(files))
    return 0
