"""Build a :class:`ViewerScene` from any skyrecon output on disk.

Accepted (see :data:`ACCEPTS`):

* a point cloud file: ``.ply`` (:func:`skyrecon.io.ply.read_ply`), ``.las``/``.laz``
  (:func:`skyrecon.io.las.read_las`, the ``geo`` extra);
* a COLMAP text model directory (``cameras.txt`` + ``images.txt``, optional ``points3D.txt``),
  or an ``skyrecon sfm`` output holding one in ``sparse/``: its points and camera frusta;
* a map directory (``map.json`` + ``blocks.npz``, written by ``skyrecon map``): its occupied voxels
  and, when present, the flown track (``flown_path.json``);
* a ``path.json`` (``skyrecon plan`` or a mission), or a directory holding one: the path, and the
  last planned path of a mission;
* a mission directory (``skyrecon demo``: ``mission.json``, ``path.json``, ``map/``): the drone's
  map, the flown track and the last planned path;
* an ``skyrecon mvs`` or ``stereo`` output directory: its ``fused.ply`` or ``points.ply``.

Frames and units are those of the files (world metres for maps, paths, missions and fused clouds).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from skyrecon.errors import InputError
from skyrecon.viewer.scene import Polyline, ViewerScene, frustum_segments

ACCEPTS = (
    "a .ply/.las/.laz cloud, a COLMAP text model (cameras.txt + images.txt), a map directory (map.json), "
    "a path.json, or a mission / sfm / mvs / plan output directory"
)

FLOWN_RGB = (255, 70, 50)
PLANNED_RGB = (80, 160, 255)
PATH_RGB = (255, 200, 40)
_CLOUD_NAMES = ("fused.ply", "points.ply", "sparse.ply", "occupied.ply")


def load_scene(path: str | Path) -> ViewerScene:
    """The scene of the output at ``path`` (see the module for what is accepted).

    Raises:
        InputError: ``path`` does not exist or is not an output the viewer reads (one line naming
            the path and listing what it accepts), or its files are corrupt.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(f"not found; the viewer opens {ACCEPTS}", p)
    if p.is_file():
        return _load_file(p)
    return _load_dir(p)


def _load_file(p: Path) -> ViewerScene:
    suffix = p.suffix.lower()
    if suffix == ".ply":
        from skyrecon.io.ply import read_ply

        cloud = read_ply(p)
        return ViewerScene(str(p), cloud.points, cloud.colors)
    if suffix in (".las", ".laz"):
        from skyrecon.io.las import read_las

        pts, colors = read_las(p)
        return ViewerScene(str(p), pts, colors)
    if suffix == ".json":
        if p.name == "mission.json":
            return _load_dir(p.parent)
        if p.name == "map.json":
            return _load_map(p.parent, str(p.parent))
        return ViewerScene(str(p), paths=_read_path_json(p))
    raise InputError(f"not a file the viewer reads; it opens {ACCEPTS}", p)


def _load_dir(d: Path) -> ViewerScene:
    if (d / "mission.json").is_file() or ((d / "path.json").is_file() and (d / "map" / "map.json").is_file()):
        return _load_mission(d)
    if (d / "map.json").is_file():
        return _load_map(d, str(d))
    for model in (d, d / "sparse"):
        if (model / "cameras.txt").is_file() and (model / "images.txt").is_file():
            return _load_colmap(model, str(d))
    if (d / "path.json").is_file():
        return ViewerScene(str(d), paths=_read_path_json(d / "path.json"))
    for name in _CLOUD_NAMES:
        if (d / name).is_file():
            return _load_file(d / name)
    raise InputError(f"not an output the viewer reads; it opens {ACCEPTS}", d)


def map_scene(
    title: str,
    occupied_centers: np.ndarray,
    voxel_size_m: float,
    flown: np.ndarray | None = None,
    planned: np.ndarray | None = None,
) -> ViewerScene:
    """The scene of a map and a flight: occupied voxel centres (M, 3) world metres, the flown
    track and the planned path (each (K, 3) world metres, or None); used for missions' reports."""
    paths = [
        Polyline(name, p, rgb)
        for name, p, rgb in (("flown", flown, FLOWN_RGB), ("planned", planned, PLANNED_RGB))
        if p is not None and len(p)
    ]
    return ViewerScene(title, voxel_centers=occupied_centers, voxel_size_m=voxel_size_m, paths=tuple(paths))


def _load_map(d: Path, title: str, paths: tuple[Polyline, ...] = ()) -> ViewerScene:
    from skyrecon.mapping import load_map, read_flown_path

    occ = load_map(d)
    centers = occ.occupied_centers()
    extra = list(paths)
    if not extra:
        flown = read_flown_path(d)
        if flown is not None and len(flown):
            extra.append(Polyline("flown", flown, FLOWN_RGB))
    return ViewerScene(
        title, voxel_centers=centers, voxel_size_m=float(occ.config.voxel_size_m), paths=tuple(extra)
    )


def _load_mission(d: Path) -> ViewerScene:
    paths = _read_path_json(d / "path.json", flown=True) if (d / "path.json").is_file() else ()
    if (d / "map" / "map.json").is_file():
        return _load_map(d / "map", str(d), paths)
    return ViewerScene(str(d), paths=paths)


def _read_path_json(p: Path, flown: bool = False) -> tuple[Polyline, ...]:
    """The polylines of a ``skyrecon.path`` file: ``waypoints`` (flown track for a mission), and
    ``last_planned_path`` when present."""
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"unreadable JSON ({e}); the viewer opens {ACCEPTS}", p) from None
    if not isinstance(doc, dict) or not (
        doc.get("format") in ("skyrecon.path", "skyrecon.flown_path")
        or "waypoints" in doc
        or "positions" in doc
    ):
        raise InputError(f"not a skyrecon path (no waypoints); the viewer opens {ACCEPTS}", p)
    out = []
    flown = flown or doc.get("kind") == "flown" or doc.get("format") == "skyrecon.flown_path"
    for key, name, rgb in (
        ("waypoints", "flown" if flown else "path", FLOWN_RGB if flown else PATH_RGB),
        ("positions", "flown", FLOWN_RGB),
        ("last_planned_path", "planned", PLANNED_RGB),
    ):
        if key not in doc:
            continue
        try:
            w = np.asarray(doc[key], dtype=np.float64).reshape(-1, 3)
        except (TypeError, ValueError) as e:
            raise InputError(f"'{key}' is not a list of [x, y, z] ({e})", p) from None
        if not np.all(np.isfinite(w)):
            raise InputError(f"'{key}' holds non-finite coordinates", p)
        if len(w):
            out.append(Polyline(name, w, rgb))
    return tuple(out)


def _load_colmap(model: Path, title: str) -> ViewerScene:
    from skyrecon.io.colmap import read_colmap_text

    rec = read_colmap_text(model)
    xyz, rgb = rec.points_array()
    centers = []
    for im in rec.images.values():
        centers.append(-im.cam_from_world.R.T @ im.cam_from_world.t)
    # Frusta drawn at a tenth of the spread of the cameras (or of the points when one camera).
    spread = 0.0
    if len(centers) > 1:
        spread = float(np.linalg.norm(np.ptp(np.array(centers), axis=0)))
    if spread <= 0 and len(xyz):
        spread = float(np.linalg.norm(np.ptp(xyz, axis=0)))
    depth = max(spread / 10.0, 1e-3) if spread > 0 else 1.0
    segs = []
    for im, c in zip(rec.images.values(), centers):
        K = rec.cameras[im.camera_id]
        segs.append(
            frustum_segments(im.cam_from_world.R.T, c, K.fx, K.fy, K.cx, K.cy, K.width, K.height, depth)
        )
    return ViewerScene(
        title,
        xyz,
        rgb if len(xyz) else None,
        camera_segments=np.concatenate(segs) if segs else np.zeros((0, 2, 3)),
    )
