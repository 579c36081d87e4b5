"""Writing a structure-from-motion result: COLMAP text model, coloured PLY (optionally with camera
frusta), nerfstudio ``transforms.json``, an HTML report and a JSON summary. Every file is written
atomically (a crash leaves the previous file or none, never half of one)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from skyrecon.core.depth import PointCloud
from skyrecon.core.reconstruction import Reconstruction
from skyrecon.io.atomic import write_text_atomic
from skyrecon.io.colmap import write_colmap_text, write_nerfstudio_transforms
from skyrecon.io.las import write_point_cloud
from skyrecon.sfm.report import report_html
from skyrecon.sfm.result import SfMResult

__all__ = ["write_sfm_outputs", "frustum_points", "sparse_cloud"]


def frustum_points(
    rec: Reconstruction, depth: float | None = None, samples_per_edge: int = 24
) -> tuple[np.ndarray, np.ndarray]:
    """Points along the edges of every registered camera's viewing frustum (for PLY viewers).

    Args:
        rec: the reconstruction.
        depth: distance of the far rectangle along the optical axis, world units (default: a
            tenth of the median distance between the cameras and the points, or of the camera
            spread).
        samples_per_edge: points per edge.
    Returns:
        ``(points (M, 3) float64 world, colors (M, 3) uint8)``: red frusta, the first image's green.
    """
    ims = sorted(rec.images.values(), key=lambda im: im.image_id)
    if not ims:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    C = np.stack([im.center_world for im in ims])
    if depth is None:
        xyz, _ = rec.points_array()
        if len(xyz):
            sub = xyz[:: max(1, len(xyz) // 2000)]
            d = np.median(np.linalg.norm(sub[None, :, :] - C[:, None, :], axis=2))
        else:
            d = np.linalg.norm(C.max(0) - C.min(0)) if len(C) > 1 else 1.0
        depth = 0.1 * float(d) if d > 0 else 1.0
    pts, cols = [], []
    s = np.linspace(0.0, 1.0, samples_per_edge)[:, None]
    for k, im in enumerate(ims):
        cam = rec.cameras[im.camera_id]
        corners_px = np.array(
            [
                [-0.5, -0.5],
                [cam.width - 0.5, -0.5],
                [cam.width - 0.5, cam.height - 0.5],
                [-0.5, cam.height - 0.5],
            ]
        )
        corners = cam.unproject(corners_px, depth)
        T = im.cam_from_world.inverse()
        cw = T.apply(corners)
        c = im.center_world
        edges = [(c, cw[i]) for i in range(4)] + [(cw[i], cw[(i + 1) % 4]) for i in range(4)]
        for a, b in edges:
            pts.append(a + s * (b - a))
        color = (40, 200, 40) if k == 0 else (230, 40, 40)
        cols.append(np.tile(np.array(color, np.uint8), (len(edges) * samples_per_edge, 1)))
    return np.concatenate(pts), np.concatenate(cols)


def sparse_cloud(rec: Reconstruction, frusta: bool = False, frustum_depth: float | None = None) -> PointCloud:
    """The coloured sparse points (float32, world frame), optionally with camera frusta."""
    xyz, rgb = rec.points_array()
    if frusta:
        fp, fc = frustum_points(rec, frustum_depth)
        xyz = np.concatenate([xyz, fp])
        rgb = np.concatenate([rgb, fc])
    return PointCloud(xyz.astype(np.float32), rgb.astype(np.uint8))


def write_sfm_outputs(
    out_dir: str | Path,
    result: SfMResult,
    *,
    frusta: bool = False,
    frustum_depth: float | None = None,
    report: bool = True,
    image_prefix: str = "images/",
    title: str = "Structure from motion",
    cloud_format: str = "ply",
) -> dict[str, Path]:
    """Write everything a run produced into ``out_dir`` (created if missing).

    Files:
        ``sparse/cameras.txt``, ``sparse/images.txt``, ``sparse/points3D.txt``: COLMAP text
        model (intrinsics at the input image size, COLMAP's pixel convention);
        ``sparse.ply``: coloured points (binary PLY, world frame of the reconstruction), with
        camera frusta when ``frusta``; ``transforms.json``: nerfstudio cameras (when any image is
        registered); ``report.html``: self-contained report; ``summary.json``: registered and
        left-out images with reasons, warnings, diagnostics, timings.

    Args:
        out_dir: output directory.
        result: the run's result (a partial model is written as it is, with its note).
        frusta: add camera frusta to ``sparse.ply``.
        frustum_depth: their depth, world units (default: automatic).
        report: write ``report.html``.
        image_prefix: prefix of the image paths in ``transforms.json``.
        title: title of the report.
        cloud_format: ``ply``, ``las`` or ``laz`` for the sparse cloud (``sparse.las`` ...).
    Returns:
        name -> path of every file written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rec = result.reconstruction
    written: dict[str, Path] = {}
    write_colmap_text(out / "sparse", rec)
    for f in ("cameras.txt", "images.txt", "points3D.txt"):
        written[f"sparse/{f}"] = out / "sparse" / f
    cloud_path = write_point_cloud(out / "sparse.ply", sparse_cloud(rec, frusta, frustum_depth), cloud_format)
    written[cloud_path.name] = cloud_path
    if rec.images:
        write_nerfstudio_transforms(out / "transforms.json", rec, image_prefix)
        written["transforms.json"] = out / "transforms.json"
    if report:
        write_text_atomic(out / "report.html", report_html(result, title))
        written["report.html"] = out / "report.html"
    write_text_atomic(out / "summary.json", json.dumps(result.to_json_dict(), indent=2) + "\n")
    written["summary.json"] = out / "summary.json"
    return written
