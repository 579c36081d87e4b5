"""Saving an MVS result (for the command line): fused cloud, depth maps, mesh, summary.

Layout written under ``out_dir``::

    fused.ply              world frame, x y z float, red green blue uchar, nx ny nz float
    depth/<stem>.pfm       per view, working resolution, metres, inf = invalid
    mesh.ply               (when a mesh was built) vertices + triangular faces, world frame
    mvs.json               settings, timings, diagnostics, warnings, neighbours, depth ranges
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from skyrecon.io import write_pfm
from skyrecon.io.atomic import write_bytes_atomic
from skyrecon.io.jsonio import write_json
from skyrecon.io.las import write_point_cloud

__all__ = ["save_mvs_result", "encode_mesh_ply", "write_mesh_ply"]


def encode_mesh_ply(vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray | None = None) -> bytes:
    """Binary little-endian PLY bytes of a triangle mesh.

    Args:
        vertices: (V, 3) float positions, metres.
        faces: (F, 3) int vertex indices.
        colors: optional (V, 3) uint8 RGB per vertex.
    """
    V = np.asarray(vertices, np.float32).reshape(-1, 3)
    F = np.asarray(faces, np.int32).reshape(-1, 3)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    vt = np.empty(len(V), np.dtype(fields))
    vt["x"], vt["y"], vt["z"] = V[:, 0], V[:, 1], V[:, 2]
    if colors is not None:
        C = np.asarray(colors, np.uint8).reshape(-1, 3)
        vt["red"], vt["green"], vt["blue"] = C[:, 0], C[:, 1], C[:, 2]
    ft = np.empty(len(F), np.dtype([("n", "u1"), ("i", "<i4", (3,))]))
    ft["n"] = 3
    ft["i"] = F
    lines = [
        "ply",
        "format binary_little_endian 1.0",
        "comment written by skyrecon mvs",
        f"element vertex {len(V)}",
        "property float x",
        "property float y",
        "property float z",
    ]
    if colors is not None:
        lines += ["property uchar red", "property uchar green", "property uchar blue"]
    lines += [f"element face {len(F)}", "property list uchar int vertex_indices", "end_header"]
    return ("\n".join(lines) + "\n").encode("ascii") + vt.tobytes() + ft.tobytes()


def write_mesh_ply(
    path: str | Path, vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray | None = None
) -> None:
    """Write a triangle mesh as a binary PLY file, atomically (see :func:`encode_mesh_ply`)."""
    write_bytes_atomic(Path(path), encode_mesh_ply(vertices, faces, colors))


def save_mvs_result(
    result: Any, out_dir: str | Path, settings: Any = None, cloud_format: str = "ply"
) -> dict[str, Path]:
    """Write an :class:`~skyrecon.mvs.MVSResult` under ``out_dir`` (created if missing).

    ``cloud_format`` (``ply``, ``las`` or ``laz``) is the fused cloud's format (``fused.las`` ...;
    LAS/LAZ keep positions and colours, not normals). The mesh is always PLY.

    Returns:
        The paths written, by role (``fused``, ``depth_dir``, ``mesh``, ``summary``).
    """
    out = Path(out_dir)
    (out / "depth").mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {
        "fused": out / f"fused.{cloud_format}",
        "depth_dir": out / "depth",
        "summary": out / "mvs.json",
    }
    write_point_cloud(paths["fused"], result.cloud, cloud_format)
    for stem, dm in result.depth_maps.items():
        write_pfm(out / "depth" / f"{stem}.pfm", dm.depth_m)
    if result.mesh is not None:
        paths["mesh"] = out / "mesh.ply"
        verts, faces = result.mesh[0], result.mesh[1]
        colors = result.mesh[2] if len(result.mesh) > 2 else None
        write_mesh_ply(paths["mesh"], verts, faces, colors)
    summary = {
        "points": len(result.cloud),
        "timings_s": result.timings_s,
        "warnings": result.warnings,
        "neighbors": result.neighbors,
        "depth_ranges_m": result.depth_ranges,
        "diagnostics": result.diagnostics,
        "depth_maps": {
            stem: {"width": dm.intrinsics.width, "height": dm.intrinsics.height, "K": dm.intrinsics.K}
            for stem, dm in result.depth_maps.items()
        },
    }
    if settings is not None:
        summary["settings"] = settings
    write_json(paths["summary"], summary)
    return paths
