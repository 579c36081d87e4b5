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
    coords = np.zeros((0, 3), np.int32)
    data = np.zeros((0, B**3), np.float32)
    for m in maps:
        mine = m.grid.block_coords.astype(np.int32)
        coords, data = add_block_evidence(coords, data, mine, m.grid.blocks.reshape(len(mine), B**3), lo, hi)
    return OccupancyMap.from_blocks(cfg, coords, data.reshape(len(coords), B, B, B))


def add_block_evidence(
    coords_a: np.ndarray,
    data_a: np.ndarray,
    coords_b: np.ndarray,
    data_b: np.ndarray,
    clamp_lo: float,
    clamp_hi: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The voxel-by-voxel sum of two sets of blocks' log-odds, clamped to [clamp_lo, clamp_hi].

    Args:
        coords_a, coords_b: (Na, 3), (Nb, 3) int block coordinates (each without repeats).
        data_a, data_b: (Na, B^3), (Nb, B^3) float32 log-odds, NaN unknown.
    Returns:
        ``(coords (N, 3) int32, data (N, B^3) float32)`` over the union of the blocks, sorted by
        coordinate; a voxel known in one input only keeps that value, unknown in both stays NaN.
    """
    ca, cb = np.asarray(coords_a, np.int32).reshape(-1, 3), np.asarray(coords_b, np.int32).reshape(-1, 3)
    coords = np.unique(np.concatenate([ca, cb]), axis=0)
    width = data_a.shape[1] if len(data_a) else data_b.shape[1]
    total = np.full((len(coords), width), np.nan, np.float32)
    for c, d in ((ca, data_a), (cb, data_b)):
        if len(c) == 0:
            continue
        rows = _rows_of(coords, c)
        cur = total[rows]
        d = np.asarray(d, np.float32)
        merged = np.where(np.isfinite(cur), cur, d)
        both = np.isfinite(cur) & np.isfinite(d)
        merged[both] = cur[both] + d[both]
        total[rows] = merged
    with np.errstate(invalid="ignore"):
        np.clip(total, clamp_lo, clamp_hi, out=total)
    return coords.astype(np.int32), total


def _rows_of(sorted_unique: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Row index in ``sorted_unique`` (lexicographically sorted (N, 3), as ``np.unique`` gives) of
    each query (M, 3); every query must be present."""
    return np.searchsorted(block_keys(sorted_unique), block_keys(queries))


def block_keys(c: np.ndarray) -> np.ndarray:
    """One sortable int64 per block coordinate (21 bits per axis, offset to non-negative),
    ordered as ``np.unique(..., axis=0)`` orders the coordinates."""
    c = np.asarray(c).reshape(-1, 3).astype(np.int64) + (1 << 20)
    if np.any(c < 0) or np.any(c >= (1 << 21)):
        raise InputError("a map's block coordinates lie more than a million blocks from the origin")
    return (c[:, 0] << 42) | (c[:, 1] << 21) | c[:, 2]
