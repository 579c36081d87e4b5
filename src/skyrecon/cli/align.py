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
from typing import Any

import numpy as np

from skyrecon.cli.common import add_cloud_format, add_command, info, output_dir, positive_float, positive_int
from skyrecon.core.depth import PointCloud
from skyrecon.core.reconstruction import Reconstruction
from skyrecon.core.rigid import orthonormalize
from skyrecon.errors import InputError
from skyrecon.io.colmap import read_colmap_text, write_colmap_text
from skyrecon.io.jsonio import write_json
from skyrecon.io.las import write_point_cloud
from skyrecon.io.ply import read_ply
from skyrecon.sfm.align import Sim3
from skyrecon.sfm.model_align import AlignOptions, AlignResult, align_model, merged_cloud
from skyrecon.sfm.model_align import match_names as match_names  # re-exported: tests and users import it here
from skyrecon.sfm.outputs import sparse_cloud

EXAMPLES = """  skyrecon align model/ --positions gps_enu.txt --out model_metric/
  skyrecon align flight2/sparse --to-model flight1/sparse --merge --out flight2_in_flight1/
  skyrecon align model_metric/ --to-cloud lidar.ply --no-scale --max-distance 0.5 --out refined/
  skyrecon align model/ --to-cloud scan.ply --init model_metric/align.json --out refined/
"""


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
    add_cloud_format(p)
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


def read_model(path: str | Path) -> tuple[Reconstruction, Path]:
    """The COLMAP text model of ``path`` (see :func:`model_directory`) and its directory; every
    registered image must have a finite pose."""
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


def read_init(path: str | Path) -> Sim3:
    """A Sim3 ``world_from_model`` from an align.json or a text file of 12 / 16 numbers."""
    p = Path(path)
    if not p.is_file():
        raise InputError("--init file not found; check the path", p)
    text = p.read_text(encoding="utf-8", errors="replace")
    M: Any = None
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
    rows = A.reshape(-1, 4)
    sR, t = rows[:3, :3], rows[:3, 3]
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
# the command
# ----------------------------------------------------------------------------------------------
def _read_reference(
    args: argparse.Namespace,
) -> tuple[dict[str, np.ndarray] | Reconstruction | PointCloud, str]:
    """The reference the arguments name, and its label."""
    if args.positions:
        if args.init:
            raise InputError(
                "--init is for --to-model and --to-cloud; --positions needs no initial alignment"
            )
        return read_positions(args.positions), str(Path(args.positions))
    if args.to_model:
        ref, ref_dir = read_model(args.to_model)
        return ref, str(ref_dir)
    return read_ply(args.to_cloud), str(Path(args.to_cloud))


def run(args: argparse.Namespace) -> int:
    t_start = time.perf_counter()
    if args.merge and args.positions:
        raise InputError("--merge needs --to-model or --to-cloud (positions have no points to merge)")
    rec, model_dir = read_model(args.model_dir)
    xyz, _ = rec.points_array()
    if len(xyz) and not np.all(np.isfinite(xyz)):
        raise InputError("the model has NaN or infinite 3D points", model_dir)
    options = AlignOptions(
        with_scale=not args.no_scale,
        max_distance=args.max_distance,
        init=read_init(args.init) if args.init else None,
        refine_with_icp=not args.no_icp,
        max_iterations=args.max_iterations,
        seed=args.seed,
    )
    reference, reference_label = _read_reference(args)
    result = align_model(rec, reference, options, model_label=str(model_dir), reference_label=reference_label)

    out = output_dir(args.out)
    aligned = result.world_from_model.transform_reconstruction(rec)
    write_colmap_text(out / "sparse", aligned)
    cloud_out = sparse_cloud(aligned, args.frusta)
    if len(cloud_out) and float(np.abs(cloud_out.points).max()) > 1e5:
        result.warnings.append(
            "coordinates above 100 km: sparse.ply stores float32 (about 1 cm or worse at this size); "
            "sparse/ keeps full precision"
        )
    write_point_cloud(out / "sparse.ply", cloud_out, args.format)
    files = ["sparse/cameras.txt", "sparse/images.txt", "sparse/points3D.txt", "sparse.ply", "align.json"]
    if args.merge and result.reference_points is not None:
        write_point_cloud(out / "merged.ply", merged_cloud(aligned, result.reference_points), args.format)
        files.append("merged.ply")
    summary = {**result.to_json_dict(), "files": files, "seconds": time.perf_counter() - t_start}
    write_json(out / "align.json", summary)
    _say(args, result, out)
    return 0


def _say(args: argparse.Namespace, result: AlignResult, out: Path) -> None:
    for w in result.warnings:
        if not args.quiet or w.startswith("ICP did not converge"):
            info(f"warning: {w}")
    if not args.quiet:
        info(result.summary_line())
        info(
            f"wrote {out}/sparse/ (COLMAP text), sparse.ply"
            + (", merged.ply" if args.merge else "")
            + ", align.json"
        )
