"""Top-view picture of a map: occupied voxels (darker = higher) with paths drawn on top."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from skyrecon.io.images import write_image
from skyrecon.mapping.occupancy import OccupancyMap
from skyrecon.report.figures import height_map_image


def map_preview_image(occ: OccupancyMap, paths: Sequence[np.ndarray] = ()) -> np.ndarray | None:
    """(H, W, 3) uint8 RGB top view of the occupied voxels with ``paths`` ((K, 3) world metres
    each) drawn on top, at up to 8 px per metre; None when the map has no occupied voxel."""
    centers = occ.occupied_centers()
    if len(centers) == 0:
        return None
    lo, hi = centers.min(axis=0) - 5, centers.max(axis=0) + 5
    for track in paths:
        if len(track):
            lo[:2] = np.minimum(lo[:2], np.asarray(track)[:, :2].min(axis=0) - 5)
            hi[:2] = np.maximum(hi[:2], np.asarray(track)[:, :2].max(axis=0) + 5)
    px_per_m = min(8.0, 1600.0 / max(hi[0] - lo[0], hi[1] - lo[1]))
    return height_map_image(centers, (lo[0], lo[1], hi[0], hi[1]), list(paths), px_per_m=px_per_m)


def write_map_preview(occ: OccupancyMap, path: str | Path, paths: Sequence[np.ndarray] = ()) -> None:
    """Write :func:`map_preview_image` as a PNG (nothing when the map has no occupied voxel)."""
    image = map_preview_image(occ, paths)
    if image is not None:
        write_image(path, image)
