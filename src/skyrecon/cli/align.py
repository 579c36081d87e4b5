"""``skyrecon align``: put a model in a metric, georeferenced frame, or in the frame of another model or cloud.

MODEL_DIR is a COLMAP text model (``cameras.txt``, ``images.txt``, ``points3D.txt``), e.g. the
``sparse/`` that ``skyrecon sfm`` writes, or the run directory that contains it. One reference:

* ``--positions FILE``: known camera centres (GPS converted to metres, or ground truth), one line
  per image ``NAME X Y Z`` (``#`` starts a comment). A similarity (scale, rotation, translation;
  Umeyama) is fitted robustly (RANSAC, then least squares on the inliers): a few GPS glitches are
  ignored and listed. At least 3 images must match by name (exact, else by file name, else by
  name without extension) and their positions must not lie on a line.
* ``--to-model MODEL_DIR2``: the camera centres of images with the same names in both models give
  the similarity (Umeyama), then ICP on the 3D points refines it (point-to-plane, robust). Without
  3 common names give ``--init``.
* ``--to-cloud PLY``: ICP (point-to-point with scale, then point-to-plane; robust Huber weights) of
  the model's points to the cloud, starting from ``--init``, else from the model as it is when it
  already overlaps the cloud, else from the centroids and spreads of both (no rotation).

Writes ``sparse/`` (the transformed COLMAP text model), ``sparse.ply`` (its points, with
``--frusta`` the cameras) and ``align.json``: ``scale``, ``R``, ``t`` of ``world_from_model``
(``p_world = scale * R @ p_model + t``), the 4x4 ``matrix``, residual RMS / median in metres (camera
centres for positions and models, point distances for clouds), correspondences, outliers, ICP
convergence. ``--merge`` also writes ``merged.ply`` (the aligned points with the reference's).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from skyrecon.cli.common import add_command, info, output_dir, positive_float, positive_int
from skyrecon.core.rigid import rotation_angle_deg
from skyrecon.errors import EstimationError, InputError
from skyrecon.io.jsonio import write_json

EXAMPLES = """  skyrecon align model/ --positions gps_enu.txt --out model_metric/
  skyrecon align flight2/sparse --to-model flight1/sparse --merge --out flight2_in_flight1/
  skyrecon align model_metric/ --to-cloud lidar.ply --no-scale --max-distance 0.5 --out refined/
  skyrecon align model/ --to-cloud scan.ply --init model_metric/align.json --out refined/
"""

#: ICP works on at most this many reference points (a seeded random subset beyond).
MAX_TARGET_POINTS = 400_000


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = add_command(
        subparsers,
        "align",
        help="align a model to known camera positions, another model or a point cloud (Umeyama, ICP)",
        description=__doc__.split("\n\n")[0].split(": ", 1)[1],
        examples=EXAMPLES,
    )
    p.add_argument(
        "model_dir", metavar="MODEL_DIR", help="COLMAP text model directory (or a run directory with sparse/)"
    )
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    ref = p.add_mutually_exclusive_group(required=True)
    ref.add_argument(
        "--positions", metavar="FILE", help="camera centres, one line per image: NAME X Y Z (metres)"
    )
    ref.add_argument("--to-model", metavar="MODEL_DIR2", help="a reference COLMAP text model")
    ref.add_argument("--to-cloud", metavar="PLY", help="a reference point cloud (PLY)")
    p.add_argument("--no-scale", action="store_true", help="rigid alignment (rotation and translation only)")
    p.add_argument(
        "--max-distance",
        type=positive_float,
        metavar="M",
        help="--positions: inlier distance of the robust fit (default 5%% of the positions' extent); "
        "--to-model/--to-cloud: largest ICP correspondence distance (default: automatic)",
    )
    p.add_argument(
        "--init",
        metavar="FILE",
        help="initial world_from_model: an align.json, or 12 or 16 numbers (3x4 or 4x4 [sR | t], rows)",
    )
    p.add_argument("--no-icp", action="store_true", help="--to-model: camera centres only, no ICP refinement")
    p.add_argument(
        "--max-iterations", type=positive_int, default=50, help="ICP iterations per stage (default 50)"
    )
    p.add_argument("--frusta", action="store_true", help="add the camera frusta to sparse.ply")
    p.add_argument(
        "--merge", action="store_true", help="also write merged.ply: aligned points + reference points"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of RANSAC and ICP subsampling (default 0)")
    return p


# ----------------------------------------------------------------------------------------------
# reading
# ----------------------------------------------------------------------------------------------
def model_directory(path: str | Path) -> Path:
    """The COLMAP text model directory of ``path``: itself, or ``sparse/``, ``sparse/0`` inside."""
    p = Path(path)
    if not p.exists():
        raise InputError("model directory not found; check the path", p)
    if p.is_file():
        if p.name in ("cameras.txt", "images.txt", "points3D.txt"):
            return p.parent
        raise InputError("expected a COLMAP text model directory (cameras.txt, images.txt, points3D.txt)", p)
    for cand in (p, p / "sparse", p / "sparse" / "0"):
        if (cand / "cameras.txt").is_file() and (cand / "images.txt").is_file():
            return cand
    raise InputError("no COLMAP text model here (cameras.txt and images.txt, or sparse/ holding them)", p)


def read_model(path: str | Path):
    from skyrecon.io.colmap import read_colmap_text

    d = model_directory(path)
    rec = read_colmap_text(d)
    if not rec.images:
        raise InputError("the model has no registered images", d)
    for im in rec.images.values():
        if not (np.all(np.isfinite(im.cam_from_world.R)) and np.all(np.isfinite(im.cam_from_world.t))):
            raise InputError(f"image {im.name} has a NaN or infinite pose", d)
    return rec, d


def read_positions(path: str | Path) -> dict[str, np.ndarray]:
    """``NAME X Y Z`` lines (whitespace or commas between fields; the last three fields are the
    numbers, so names may contain spaces; ``#`` starts a comment). Returns name -> (3,) metres."""
    p = Path(path)
    if not p.is_file():
        raise InputError("positions file not found; check the path", p)
    try:
        text = p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise InputError("positions file is not text", p) from None
    out: dict[str, np.ndarray] = {}
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        words = line.replace(",", " ").replace(";", " ").split()
        if len(words) < 4:
            raise InputError(f"line {lineno}: expected NAME X Y Z, got {line!r}", p)
        try:
            xyz = np.array([float(w) for w in words[-3:]], np.float64)
        except ValueError:
            raise InputError(
                f"line {lineno}: X Y Z must be numbers, got {' '.join(words[-3:])!r}", p
            ) from None
        if not np.all(np.isfinite(xyz)):
            raise InputError(f"line {lineno}: NaN or infinite position {' '.join(words[-3:])!r}", p)
        name = " ".join(words[:-3])
        if name in out:
            raise InputError(f"line {lineno}: {name} is listed twice", p)
        out[name] = xyz
    if not out:
        raise InputError("positions file has no NAME X Y Z lines", p)
    return out


def match_names(model_names: list[str], other_names: list[str]) -> dict[str, str]:
    """model name -> other name: exact names first, then by file name, then by name without
    extension (only where that key is unique on both sides)."""
    pairs: dict[str, str] = {}
    for key in (lambda n: n, lambda n: Path(n).name, lambda n: Path(n).stem):
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


def read_init(path: str | Path):
    """A Sim3 ``world_from_model`` from an align.json or a text file of 12 / 16 numbers."""
    from skyrecon.core.rigid import orthonormalize
    from skyrecon.sfm.align import Sim3

    p = Path(path)
    if not p.is_file():
        raise InputError("--init file not found; check the path", p)
    text = p.read_text(encoding="utf-8", errors="replace")
    M = None
    if text.lstrip().startswith("{"):
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(f"not valid JSON ({exc.msg}, line {exc.lineno})", p) from None
        block = data.get("world_from_model", data) if isinstance(data, dict) else None
        if isinstance(block, dict) and "matrix" in block:
            M = block["matrix"]
        elif isinstance(block, dict) and {"scale", "R", "t"} <= set(block):
            try:
                return Sim3(np.array(block["R"], float), np.array(block["t"], float), float(block["scale"]))
            except (ValueError, TypeError):
                raise InputError("scale, R and t must be a number, a 3x3 and a 3-vector", p) from None
        else:
            raise InputError("JSON without world_from_model (matrix, or scale R t); use an align.json", p)
    else:
        words = text.replace(",", " ").replace("[", " ").replace("]", " ").split()
        try:
            M = [float(w) for w in words]
        except ValueError:
            raise InputError("expected 12 or 16 numbers (a 3x4 or 4x4 matrix, row by row)", p) from None
    try:
        A = np.array(M, np.float64).reshape(-1)
    except (ValueError, TypeError):
        raise InputError("the matrix must hold numbers", p) from None
    if A.size not in (12, 16) or not np.all(np.isfinite(A)):
        raise InputError(f"expected 12 or 16 finite numbers (3x4 or 4x4 [sR | t]), got {A.size}", p)
    A = A.reshape(-1, 4)
    sR, t = A[:3, :3], A[:3, 3]
    det = float(np.linalg.det(sR))
    if not det > 0:
        raise InputError("the 3x3 part is not a scaled rotation (determinant <= 0)", p)
    s = det ** (1.0 / 3.0)
    R = sR / s
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-3:
        raise InputError(
            "the 3x3 part is not a scaled rotation (its columns are not orthogonal and equally long)", p
        )
    return Sim3(orthonormalize(R), t, s)


# ----------------------------------------------------------------------------------------------
# presentation (the fitting itself is skyrecon.sfm.model_align)
# ----------------------------------------------------------------------------------------------
def _sim_json(T) -> dict:
    return {"scale": T.scale, "R": T.R.tolist(), "t": T.t.tolist(), "matrix": T.matrix.tolist()}


# ----------------------------------------------------------------------------------------------
# the command
# ----------------------------------------------------------------------------------------------
def run(args: argparse.Namespace) -> int:
    from skyrecon.core.depth import PointCloud
    from skyrecon.io.colmap import write_colmap_text
    from skyrecon.io.ply import read_ply, write_ply
    from skyrecon.sfm.model_align import centroid_init as _centroid_init
    from skyrecon.sfm.model_align import fit_camera_centres as _fit_centres
    from skyrecon.sfm.model_align import icp_refine as _icp_refine
    from skyrecon.sfm.model_align import scene_extent as _extent
    from skyrecon.sfm.model_align import subsample_cloud as _subsample
    from skyrecon.sfm.outputs import sparse_cloud

    t_start = time.perf_counter()
    if args.merge and args.positions:
        raise InputError("--merge needs --to-model or --to-cloud (positions have no points to merge)")
    rec, model_dir = read_model(args.model_dir)
    ims = sorted(rec.images.values(), key=lambda im: im.image_id)
    names = [im.name for im in ims]
    centres = {im.name: im.center_world for im in ims}
    xyz, _ = rec.points_array()
    if len(xyz) and not np.all(np.isfinite(xyz)):
        raise InputError("the model has NaN or infinite 3D points", model_dir)
    init = read_init(args.init) if args.init else None
    with_scale = not args.no_scale
    warnings: list[str] = []
    result: dict = {"model": str(model_dir)}
    reference_points = None

    if args.positions:
        if args.init:
            raise InputError(
                "--init is for --to-model and --to-cloud; --positions needs no initial alignment"
            )
        positions = read_positions(args.positions)
        pairs = match_names(names, list(positions))
        if not pairs:
            raise InputError(
                f"none of the {len(positions)} names in the positions file matches one of the {len(names)} model "
                f"images (model: {', '.join(names[:3])}{' ...' if len(names) > 3 else ''}; file: "
                f"{', '.join(list(positions)[:3])}{' ...' if len(positions) > 3 else ''})",
                args.positions,
            )
        matched = [n for n in names if n in pairs]
        if len(matched) < 3:
            raise InputError(
                f"only {len(matched)} model images have a position ({', '.join(matched)}); "
                "at least 3 are needed",
                args.positions,
            )
        src = np.stack([centres[n] for n in matched])
        dst = np.stack([positions[pairs[n]] for n in matched])
        fit, thr = _fit_centres(src, dst, matched, with_scale, args.max_distance, args.seed, "positions")
        T = fit.transform
        res = np.linalg.norm(T.apply(src) - dst, axis=1)
        inl = fit.inliers
        outliers = [n for n, ok in zip(matched, inl) if not ok]
        if outliers:
            warnings.append(
                f"{len(outliers)} positions do not fit the others (more than {thr:.3g} m off) and were "
                f"ignored: "
                + ", ".join(f"{n} ({r:.2f} m)" for n, r, ok in zip(matched, res, inl) if not ok)[:400]
            )
        unmatched = sorted(set(positions) - set(pairs.values()))
        result.update(
            {
                "method": "positions",
                "reference": str(Path(args.positions)),
                "residuals_of": "camera centres",
                "num_correspondences": len(matched),
                "num_inliers": int(inl.sum()),
                "inlier_threshold_m": thr,
                "residual_rms_m": float(np.sqrt(np.mean(res[inl] ** 2))),
                "residual_median_m": float(np.median(res[inl])),
                "residual_max_m": float(res[inl].max()),
                "residuals_m": {n: float(r) for n, r in zip(matched, res)},
                "outliers": outliers,
                "positions_without_image": unmatched,
                "images_without_position": [n for n in names if n not in pairs],
            }
        )
        scale_hint = float(np.ptp(dst[:, :2], axis=0).max())
        if np.all(np.abs(dst[:, 0]) <= 180) and np.all(np.abs(dst[:, 1]) <= 90) and scale_hint < 0.05:
            warnings.append(
                "the positions look like latitude/longitude in degrees; convert them to metres "
                "(e.g. local east-north-up or UTM) first"
            )
    elif args.to_model:
        ref, ref_dir = read_model(args.to_model)
        ref_centres = {im.name: im.center_world for im in ref.images.values()}
        pairs = match_names(names, list(ref_centres))
        matched = [n for n in names if n in pairs]
        ref_xyz, ref_rgb = ref.points_array()
        reference_points = PointCloud(ref_xyz, ref_rgb)
        fit = None
        if len(matched) >= 3:
            src = np.stack([centres[n] for n in matched])
            dst = np.stack([ref_centres[pairs[n]] for n in matched])
            fit, _ = _fit_centres(
                src, dst, matched, with_scale, None, args.seed, "reference model's camera centres"
            )
            T0, init_kind = fit.transform, "camera centres"
            if init is not None:
                warnings.append("--init ignored: the common images give the initial alignment")
        elif init is not None:
            T0, init_kind = init, "file"
        else:
            common = f" ({', '.join(matched)})" if matched else ""
            raise InputError(
                f"the models have {len(matched) or 'no'} image names in common{common}; at least 3 are needed to align "
                "by camera centres: give --init FILE (e.g. the align.json of both models aligned to GPS), or align "
                "each with --positions",
                ref_dir,
            )
        T, icp_stats = T0, None
        if not args.no_icp:
            if len(xyz) < 10 or len(ref_xyz) < 10:
                warnings.append("too few 3D points for ICP; the camera centres alone give the alignment")
            else:
                T, icp_stats = _icp_refine(
                    xyz,
                    _subsample(reference_points, MAX_TARGET_POINTS, args.seed),
                    T0,
                    with_scale and init_kind == "file",
                    args.max_distance,
                    args.max_iterations,
                    args.seed,
                )
        result.update(
            {
                "method": "model",
                "reference": str(ref_dir),
                "init": init_kind,
                "initial_world_from_model": _sim_json(T0),
                "icp": icp_stats,
            }
        )
        if matched:
            src = np.stack([centres[n] for n in matched])
            dst = np.stack([ref_centres[pairs[n]] for n in matched])
            res = np.linalg.norm(T.apply(src) - dst, axis=1)
            inl = fit.inliers if fit is not None else np.ones(len(matched), bool)
            result.update(
                {
                    "residuals_of": "camera centres of common images",
                    "num_correspondences": len(matched),
                    "num_inliers": int(inl.sum()),
                    "residual_rms_m": float(np.sqrt(np.mean(res[inl] ** 2))),
                    "residual_median_m": float(np.median(res[inl])),
                    "residuals_m": {n: float(r) for n, r in zip(matched, res)},
                    "outliers": [n for n, ok in zip(matched, inl) if not ok],
                }
            )
        else:
            result.update(
                {
                    "residuals_of": "point-to-plane distances of the 3D points (ICP)",
                    "num_correspondences": icp_stats["num_correspondences"],
                    "residual_rms_m": icp_stats["point_to_plane_rms_m"],
                    "residual_median_m": icp_stats["point_to_plane_median_m"],
                }
            )
    else:
        cloud = read_ply(args.to_cloud)
        if len(cloud) < 10:
            raise InputError(f"the cloud has only {len(cloud)} points; ICP needs more", args.to_cloud)
        if len(xyz) < 10:
            raise InputError(f"the model has only {len(xyz)} 3D points; ICP needs more", model_dir)
        reference_points = cloud
        target = _subsample(cloud, MAX_TARGET_POINTS, args.seed)
        tgt = np.asarray(target.points, np.float64)
        if init is not None:
            T0, init_kind = init, "file"
        else:
            from scipy.spatial import cKDTree

            from skyrecon.sfm.align import Sim3

            probe = 0.05 * _extent(tgt)
            d, _ = cKDTree(tgt).query(xyz, k=1, distance_upper_bound=probe)
            if np.mean(np.isfinite(d)) >= 0.5:
                T0, init_kind = Sim3(), "identity (the model already overlaps the cloud)"
            else:
                T0, init_kind = _centroid_init(xyz, tgt, with_scale), "centroids and spread (no rotation)"
                warnings.append(
                    "initial alignment from the centroids and spreads of both clouds, without rotation; "
                    "if the model is turned relative to the cloud give --init (or align with "
                    "--positions first)"
                )
        T, icp_stats = _icp_refine(
            xyz, target, T0, with_scale, args.max_distance, args.max_iterations, args.seed
        )
        result.update(
            {
                "method": "cloud",
                "reference": str(Path(args.to_cloud)),
                "init": init_kind,
                "initial_world_from_model": _sim_json(T0),
                "icp": icp_stats,
                "residuals_of": "point-to-plane distances of the model's points to the cloud (within the ICP distance)",
                "num_correspondences": icp_stats["num_correspondences"],
                "residual_rms_m": icp_stats["point_to_plane_rms_m"],
                "residual_median_m": icp_stats["point_to_plane_median_m"],
            }
        )
        if len(target) < len(cloud):
            result["cloud_points_used"] = len(target)
    icp_stats = result.get("icp")
    if icp_stats:
        if not icp_stats["converged"]:
            last = icp_stats["stages"][-1]
            warnings.insert(
                0,
                f"ICP did not converge in {last['iterations']} iterations (RMS {last['rmse_m']:.3g} m); "
                "the alignment may be off: check it, give --init, or raise --max-iterations",
            )
        if icp_stats["fitness"] < 0.2:
            warnings.append(
                f"only {100 * icp_stats['fitness']:.0f} % of the model's points lie within "
                f"{icp_stats['max_distance_m']:.3g} m of the reference after ICP: the two may overlap "
                "little, or the initial alignment was too far off"
            )

    if not (np.all(np.isfinite(T.matrix)) and T.scale > 0):
        raise EstimationError("the alignment is not finite")
    out = output_dir(args.out)
    aligned = T.transform_reconstruction(rec)
    write_colmap_text(out / "sparse", aligned)
    cloud_out = sparse_cloud(aligned, args.frusta)
    if len(cloud_out) and float(np.abs(cloud_out.points).max()) > 1e5:
        warnings.append(
            "coordinates above 100 km: sparse.ply stores float32 (about 1 cm or worse at this size); "
            "sparse/ keeps full precision"
        )
    write_ply(out / "sparse.ply", cloud_out)
    files = ["sparse/cameras.txt", "sparse/images.txt", "sparse/points3D.txt", "sparse.ply", "align.json"]
    if args.merge and reference_points is not None:
        a_xyz, a_rgb = aligned.points_array()
        ref_rgb = (
            reference_points.colors
            if reference_points.colors is not None
            else np.full((len(reference_points), 3), 160, np.uint8)
        )
        merged = PointCloud(
            np.concatenate([a_xyz.astype(np.float32), reference_points.points]),
            np.concatenate([a_rgb, ref_rgb]),
        )
        write_ply(out / "merged.ply", merged)
        files.append("merged.ply")

    R_deg = rotation_angle_deg(T.R)
    summary = {
        **{k: v for k, v in result.items() if k == "method"},
        "world_from_model": _sim_json(T),
        "scale": T.scale,
        "R": T.R.tolist(),
        "t": T.t.tolist(),
        "rotation_deg": R_deg,
        **{k: v for k, v in result.items() if k != "method"},
        "num_images": len(names),
        "num_points": len(xyz),
        "with_scale": with_scale,
        "warnings": warnings,
        "files": files,
        "seconds": time.perf_counter() - t_start,
    }
    write_json(out / "align.json", summary)

    for w in warnings:
        if not args.quiet or w.startswith("ICP did not converge"):
            info(f"warning: {w}")
    if not args.quiet:
        if result["method"] == "positions":
            what = f"{result['num_correspondences']} camera positions ({result['num_inliers']} inliers)"
        elif result["method"] == "model":
            what = f"the model {result['reference']}"
            if result.get("num_inliers") is not None:
                what += f" ({result['num_correspondences']} common images)"
        else:
            what = f"the cloud {result['reference']}"
        icp_note = ""
        if result.get("icp"):
            icp_note = (
                f"; ICP {'converged' if result['icp']['converged'] else 'did NOT converge'}, "
                f"{100 * result['icp']['fitness']:.0f} % of points matched"
            )
        info(
            f"aligned {len(names)} images and {len(xyz)} points to {what}: scale {T.scale:.6g}, rotation "
            f"{R_deg:.2f} deg, residual RMS {result['residual_rms_m']:.4g} m, "
            f"median {result['residual_median_m']:.4g} m{icp_note}"
        )
        info(
            f"wrote {out}/sparse/ (COLMAP text), sparse.ply"
            + (", merged.ply" if args.merge else "")
            + ", align.json"
        )
    return 0
