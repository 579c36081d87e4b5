"""Merging maps of separate flights over the same area into one map.

Each map's log-odds are the sum of its measurements' evidence, so maps of independent flights
merge by adding their log-odds voxel by voxel (a voxel unknown in one map takes the other's value;
unknown in every map stays unknown) and clamping to the configured range: the result is the map one
flight seeing everything would have built, up to the clamping. The maps must share the world frame
(the same origin and axes, e.g. all georeferenced to one survey origin or all in one simulated city),
the voxel size, the block size and the sensor model (hit, miss and clamp probabilities): the grids
then coincide voxel for voxel and no resampling is needed.

Work goes one block row at a time over the union of the maps' blocks, so memory is the inputs plus
one output map.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict

import numpy as np

from skyrecon.errors import InputError
from skyrecon.mapping.config import MapConfig, logit
from skyrecon.mapping.occupancy import OccupancyMap

# MapConfig fields that must agree for log-odds to be added voxel for voxel
_MUST_AGREE = ("voxel_size_m", "block_size", "prob_hit", "prob_miss", "clamp_min", "clamp_max")


def check_mergeable(configs: Sequence[MapConfig], names: Sequence[str]) -> None:
    """Raise :class:`InputError` naming the first map whose grid or sensor model differs from the first's."""
    first = asdict(configs[0])
    for cfg, name in zip(configs[1:], names[1:], strict=True):
        d = asdict(cfg)
        for key in _MUST_AGREE:
            if not np.isclose(float(d[key]), float(first[key]), rtol=1e-9, atol=0.0):
                raise InputError(
                    f"cannot merge: its {key} is {d[key]} but {names[0]} has {first[key]}; "
                    "map every flight with the same --voxel-size (and settings)",
                    name,
                )


def merge_maps(maps: Sequence[OccupancyMap], names: Sequence[str] | None = None) -> OccupancyMap:
    """One map holding the evidence of all ``maps`` (same frame and grid; see the module notes).

    Args:
        maps: two or more maps.
        names: what to call each map in error messages (default ``map 1``, ``map 2``, ...).
    Returns:
        A new map with the first map's settings; its blocks are the union of the inputs' blocks.
    """
    if len(maps) == 0:
        raise InputError("nothing to merge: give at least one map")
    labels = list(names) if names is not None else [f"map {k + 1}" for k in range(len(maps))]
    check_mergeable([m.config for m in maps], labels)
    cfg = maps[0].config
    B = cfg.block_size
    lo, hi = logit(cfg.clamp_min), logit(cfg.clamp_max)
    all_coords = np.concatenate([m.grid.block_coords for m in maps]) if maps else np.zeros((0, 3), np.int32)
    coords = np.unique(all_coords.astype(np.int32), axis=0)
    total = np.full((len(coords), B**3), np.nan, np.float32)
    for m in maps:
        mine = m.grid.block_coords.astype(np.int32)
        if len(mine) == 0:
            continue
        rows = _rows_of(coords, mine)
        data = m.grid.blocks.reshape(len(mine), B**3)
        cur = total[rows]
        both = np.isfinite(cur) & np.isfinite(data)
        merged = np.where(np.isfinite(cur), cur, data)
        merged[both] = cur[both] + data[both]
        total[rows] = merged
    with np.errstate(invalid="ignore"):
        np.clip(total, lo, hi, out=total)
    return OccupancyMap.from_blocks(cfg, coords, total.reshape(len(coords), B, B, B))


def _rows_of(sorted_unique: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Row index in ``sorted_unique`` (lexicographically sorted (N, 3), as ``np.unique`` gives) of
    each query (M, 3); every query must be present."""
    keys = _keys(sorted_unique)
    q = _keys(queries)
    rows = np.searchsorted(keys, q)
    return rows


def _keys(c: np.ndarray) -> np.ndarray:
    """One sortable int64 per block coordinate (21 bits per axis, offset to non-negative),
    ordered as ``np.unique(..., axis=0)`` orders the coordinates."""
    c = c.astype(np.int64) + (1 << 20)
    if np.any(c < 0) or np.any(c >= (1 << 21)):
        raise InputError("a map's block coordinates lie more than a million blocks from the origin")
    return (c[:, 0] << 42) | (c[:, 1] << 21) | c[:, 2]
