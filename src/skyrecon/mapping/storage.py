"""The map directory format: reading and writing its files (the map class itself is not needed here:
:meth:`skyrecon.mapping.OccupancyMap.save` / ``load`` call these).

A map directory holds two files, each written atomically (temporary file + rename), the
blocks first and the header last, so that a directory with a header always has its blocks:

``map.json`` (UTF-8 JSON)::

    {"format": "skyrecon.occupancy", "version": 1,
     "frame": "world", "units": "m",
     "voxel_size_m": 0.2, "block_size": 8,
     "num_blocks": 1234, "blocks_file": "blocks.npz",
     "config": {... MapConfig fields ...},
     "layout": "..."}

``blocks.npz`` (numpy ``savez``, uncompressed):

* ``coords``: (N, 3) int32 block coordinates ``b``;
* ``log_odds``: (N, B, B, B) float32, ``log_odds[n, i, j, k]`` is the natural-log odds of voxel
  ``coords[n] * B + (i, j, k)`` (x, y, z order), NaN where unknown.

Voxel ``v`` spans ``[v, v + 1) * voxel_size_m`` in the world frame; its centre is
``(v + 0.5) * voxel_size_m``.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from skyrecon.core.depth import PointCloud
from skyrecon.errors import InputError
from skyrecon.io.atomic import atomic_write, write_text_atomic
from skyrecon.io.ply import write_ply
from skyrecon.mapping.config import MapConfig

FORMAT = "skyrecon.occupancy"
VERSION = 1
HEADER = "map.json"
BLOCKS = "blocks.npz"


@dataclass(frozen=True)
class StoredBlocks:
    """The content of a map directory, as arrays.

    Attributes:
        config: the map's settings.
        coords: (N, 3) int block coordinates ``b``.
        log_odds: (N, B, B, B) float log-odds, ``log_odds[n, i, j, k]`` of voxel
            ``coords[n] * B + (i, j, k)``, NaN where unknown.
    """

    config: MapConfig
    coords: np.ndarray
    log_odds: np.ndarray


class HasOccupiedCenters(Protocol):
    """Anything that lists the centres of its occupied voxels (an ``OccupancyMap``)."""

    def occupied_centers(self) -> np.ndarray: ...


def write_map_files(
    directory: str | Path, config: MapConfig, coords: np.ndarray, log_odds: np.ndarray, compress: bool = False
) -> None:
    """Write a map directory (created if missing): the blocks first, then the header.

    Args:
        config: the map's settings.
        coords: (N, 3) int32 block coordinates.
        log_odds: (N, B, B, B) float32 log-odds (NaN unknown), B = ``config.block_size``.
        compress: ``savez_compressed`` instead of ``savez``.
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    with atomic_write(d / BLOCKS, "wb") as f:
        (np.savez_compressed if compress else np.savez)(f, coords=coords, log_odds=log_odds)
    header = {
        "format": FORMAT,
        "version": VERSION,
        "frame": "world",
        "units": "m",
        "voxel_size_m": config.voxel_size_m,
        "block_size": config.block_size,
        "num_blocks": int(len(coords)),
        "blocks_file": BLOCKS,
        "config": config.to_dict(),
        "layout": "log_odds[n, i, j, k] is voxel coords[n] * block_size + (i, j, k); "
        "voxel v spans [v, v + 1) * voxel_size_m in the world frame; NaN = unknown",
    }
    write_text_atomic(d / HEADER, json.dumps(header, indent=2) + "\n")


def _read_header(d: Path) -> dict:
    hp = d / HEADER
    if not hp.is_file():
        raise InputError(f"no {HEADER} here; is this a map directory written by 'skyrecon map'?", d)
    try:
        header = json.loads(hp.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"corrupt map header ({e}); rebuild the map", hp) from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise InputError(f"not a skyrecon occupancy map header (format != {FORMAT!r})", hp)
    if header.get("version") != VERSION:
        raise InputError(
            f"unsupported map version {header.get('version')!r} (this skyrecon reads {VERSION})", hp
        )
    return header


def read_map_files(directory: str | Path) -> StoredBlocks:
    """Read a map directory written by :func:`write_map_files`; raises InputError if missing or corrupt."""
    d = Path(directory)
    header = _read_header(d)
    hp = d / HEADER
    try:
        config = MapConfig.from_dict(header["config"])
    except (KeyError, TypeError) as e:
        raise InputError(f"map header lacks a valid config ({e})", hp) from None
    bp = d / str(header.get("blocks_file", BLOCKS))
    if not bp.is_file():
        raise InputError("the map's block file is missing; rebuild the map", bp)
    try:
        with np.load(bp, allow_pickle=False) as z:
            coords = np.asarray(z["coords"])
            logodds = np.asarray(z["log_odds"])
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as e:
        raise InputError(f"corrupt block file ({e}); rebuild the map", bp) from None
    B = config.block_size
    n = int(header.get("num_blocks", -1))
    if coords.shape != (n, 3) or logodds.shape != (n, B, B, B):
        raise InputError(
            f"block file holds coords {coords.shape} and log_odds {logodds.shape}, "
            f"header says {n} blocks of {B}^3; the files do not belong together",
            bp,
        )
    if coords.dtype.kind not in "iu" or logodds.dtype.kind != "f":
        raise InputError("block file has wrong data types (need integer coords, float log_odds)", bp)
    return StoredBlocks(config, coords, logodds)


def export_occupied_ply(
    occ_map: HasOccupiedCenters, path: str | Path, colorize: bool = True, fmt: str = "ply"
) -> int:
    """Write the centres of the occupied voxels (world frame, metres) as a binary PLY (or, with
    ``fmt``, LAS/LAZ at ``path`` with that suffix; see :func:`skyrecon.io.las.write_point_cloud`).

    Colours encode height (blue low, red high) when ``colorize``. Returns the number of points.
    """
    pts = occ_map.occupied_centers().astype(np.float32)
    colors = None
    if colorize and len(pts):
        z = pts[:, 2]
        s = (z - z.min()) / max(float(np.ptp(z)), 1e-6)
        colors = np.stack([255 * s, 255 * (1 - np.abs(2 * s - 1)), 255 * (1 - s)], 1)
    if fmt == "ply":
        write_ply(path, PointCloud(pts, colors))
    else:
        from skyrecon.io.las import write_point_cloud

        write_point_cloud(path, PointCloud(pts, colors), fmt)
    return int(len(pts))


FLOWN = "flown_path.json"


def write_flown_path(directory: str | Path, positions: np.ndarray, vehicle_radius_m: float) -> None:
    """Write ``flown_path.json`` into a map directory: the track (N, 3) world metres the vehicle
    flew while mapping (its camera positions, in order) and its radius. The planner may retrace it
    (:func:`skyrecon.planning.flown.plan_with_flown_path`)."""
    doc = {
        "format": "skyrecon.flown_path",
        "version": 1,
        "frame": "world",
        "units": "m",
        "vehicle_radius_m": float(vehicle_radius_m),
        "positions": np.asarray(positions, dtype=np.float64).reshape(-1, 3).tolist(),
    }
    write_text_atomic(Path(directory) / FLOWN, json.dumps(doc) + "\n")


def read_flown_path(directory: str | Path) -> np.ndarray | None:
    """The flown track (N, 3) world metres of a map directory, or None when it has none."""
    p = Path(directory) / FLOWN
    if not p.is_file():
        return None
    try:
        pos = np.asarray(json.loads(p.read_text())["positions"], dtype=np.float64).reshape(-1, 3)
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise InputError(f"unreadable flown path ({e}); delete it or map again", p) from None
    if not np.all(np.isfinite(pos)):
        raise InputError("the flown path holds non-finite positions; map again", p)
    return pos
