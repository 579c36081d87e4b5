"""District-scale maps: an occupancy map stored as square tiles on disk, loaded on demand.

A city district at 0.5 m (1 km x 1 km, 100 m high) is up to 800 million voxels: more than a
flight computer or a small server should hold at once. A :class:`TiledMap` keeps the same blocks
as :class:`~skyrecon.mapping.OccupancyMap` (same voxel grid, same log-odds, NaN unknown), grouped
into tiles of ``tile_blocks x tile_blocks`` block columns (all heights) and stored one file per tile.
A query reads only the block coordinates of the tiles it touches and the voxels it asks for: the
log-odds files are memory-mapped, so a point query anywhere costs a file open and a binary search,
and a region (for planning) reads only its blocks. Tiles' coordinates stay in a cache bounded in bytes.

Directory layout (``map.json`` is the usual map header with ``"layout": "tiles"``)::

    map.json                 {"format": "skyrecon.occupancy", "version": 1, "layout": "tiles",
                              "voxel_size_m", "block_size", "tile_blocks", "config",
                              "tiles": {"tx_ty": {"generation": g, "blocks": n}}, "sources": [...]}
    tiles/tx_ty.g<g>.coords.npy     (N, 3) int32 block coordinates, sorted (x, then y, then z)
    tiles/tx_ty.g<g>.log_odds.npy   (N, B, B, B) float32 log-odds of those blocks, NaN unknown

Tile ``(tx, ty)`` holds the blocks with ``floor(bx / tile_blocks) == tx`` and likewise for y.
Adding evidence (:meth:`TiledMap.add_map`, a flight's map) writes every touched tile as a new
generation and then the header, atomically; the old generations are removed afterwards. A run
killed in between leaves the header pointing at the complete old tiles (the orphans are swept on
the next open), so the map is always the sum of the flights whose addition finished, which the
header lists in ``sources``.

Frames and units: world frame, metres, as every map.
"""

from __future__ import annotations

import json
import os
import re
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from skyrecon.errors import InputError
from skyrecon.io.atomic import atomic_write, write_text_atomic
from skyrecon.mapping.config import MapConfig, logit
from skyrecon.mapping.merge import add_block_evidence, block_keys, check_mergeable
from skyrecon.mapping.occupancy import OccupancyMap
from skyrecon.mapping.storage import FORMAT, HEADER, VERSION

LAYOUT = "tiles"
TILES_DIR = "tiles"
_TILE_FILE = re.compile(r"^(-?\d+)_(-?\d+)\.g(\d+)\.(coords|log_odds)\.npy$")


def is_tiled_map(directory: str | Path) -> bool:
    """Whether ``directory`` holds a tiled map (its header says ``"layout": "tiles"``)."""
    hp = Path(directory) / HEADER
    if not hp.is_file():
        return False
    try:
        return json.loads(hp.read_text(encoding="utf-8")).get("layout") == LAYOUT
    except (OSError, ValueError, AttributeError):
        return False


class TiledMap:
    """An occupancy map on disk in tiles (see the module notes). Open with :meth:`open` or
    :meth:`create`; the object holds only the header and a bounded cache of tiles.

    Args (of :meth:`open`/:meth:`create`):
        cache_mb: most megabytes of tiles kept in memory (least recently used go first).
    """

    def __init__(self, directory: Path, config: MapConfig, tile_blocks: int, header: dict, cache_mb: float):
        self.directory = directory
        self.config = config
        self.tile_blocks = int(tile_blocks)
        self._header = header
        self._cache: OrderedDict[tuple[int, int], _Tile] = OrderedDict()
        self._cache_bytes = 0
        self._cache_limit = int(cache_mb * 1e6)
        self.tiles_read = 0

    # ----- opening --------------------------------------------------------------------------
    @classmethod
    def create(
        cls, directory: str | Path, config: MapConfig, tile_size_m: float = 64.0, cache_mb: float = 512.0
    ) -> TiledMap:
        """A new, empty tiled map in ``directory`` (created; it must not hold a map already).

        ``tile_size_m`` is rounded to whole blocks (at least one)."""
        d = Path(directory)
        if (d / HEADER).exists():
            raise InputError("a map exists here already; choose a new directory", d)
        block_m = config.voxel_size_m * config.block_size
        tile_blocks = max(1, int(round(tile_size_m / block_m)))
        header = {
            "format": FORMAT,
            "version": VERSION,
            "layout": LAYOUT,
            "frame": "world",
            "units": "m",
            "voxel_size_m": config.voxel_size_m,
            "block_size": config.block_size,
            "tile_blocks": tile_blocks,
            "tile_size_m": tile_blocks * block_m,
            "config": config.to_dict(),
            "tiles": {},
            "sources": [],
        }
        (d / TILES_DIR).mkdir(parents=True, exist_ok=True)
        m = cls(d, config, tile_blocks, header, cache_mb)
        m._write_header()
        return m

    @classmethod
    def open(cls, directory: str | Path, cache_mb: float = 512.0) -> TiledMap:
        """Open an existing tiled map; raises InputError when it is not one or is damaged."""
        d = Path(directory)
        hp = d / HEADER
        if not hp.is_file():
            raise InputError(f"no {HEADER} here; is this a map directory written by 'skyrecon map'?", d)
        try:
            header = json.loads(hp.read_text(encoding="utf-8"))
            if header.get("format") != FORMAT or header.get("layout") != LAYOUT:
                raise InputError("not a tiled skyrecon map (map.json 'layout' is not 'tiles')", hp)
            config = MapConfig.from_dict(header["config"])
            tile_blocks = int(header["tile_blocks"])
            dict(header["tiles"])
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
            raise InputError(f"corrupt tiled map header ({e}); rebuild the map", hp) from None
        m = cls(d, config, tile_blocks, header, cache_mb)
        m._sweep_orphans()
        return m

    # ----- what it holds ----------------------------------------------------------------------
    @property
    def voxel_size(self) -> float:
        return self.config.voxel_size_m

    @property
    def block_size(self) -> int:
        return self.config.block_size

    @property
    def tile_size_m(self) -> float:
        return self.tile_blocks * self.block_size * self.voxel_size

    def tile_ids(self) -> list[tuple[int, int]]:
        """Every stored tile's (tx, ty), sorted."""
        return sorted(_parse_key(k) for k in self._header["tiles"])

    @property
    def num_blocks(self) -> int:
        return int(sum(v["blocks"] for v in self._header["tiles"].values()))

    @property
    def sources(self) -> list[str]:
        """What was added, in order (names given to :meth:`add_map`)."""
        return list(self._header.get("sources", []))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """World (lo, hi) corners (3,) of the stored tiles' XY area, z of the stored blocks; metres."""
        ids = self.tile_ids()
        if not ids:
            return np.zeros(3), np.zeros(3)
        t = np.array(ids, np.float64)
        z = self._header.get("z_blocks", [0, 0])
        bm = self.block_size * self.voxel_size
        lo = np.array([t[:, 0].min() * self.tile_size_m, t[:, 1].min() * self.tile_size_m, z[0] * bm])
        hi = np.array(
            [(t[:, 0].max() + 1) * self.tile_size_m, (t[:, 1].max() + 1) * self.tile_size_m, (z[1] + 1) * bm]
        )
        return lo, hi

    # ----- tiles on disk ------------------------------------------------------------------------
    def _tile_paths(self, key: tuple[int, int], generation: int) -> tuple[Path, Path]:
        stem = self.directory / TILES_DIR / f"{key[0]}_{key[1]}.g{generation}"
        return stem.with_name(stem.name + ".coords.npy"), stem.with_name(stem.name + ".log_odds.npy")

    def _tile(self, key: tuple[int, int]) -> _Tile | None:
        """A stored tile (coordinates in memory, log-odds memory-mapped), cached; None when absent."""
        hit = self._cache.get(key)
        if hit is not None:
            self._cache.move_to_end(key)
            return hit
        entry = self._header["tiles"].get(_key(key))
        if entry is None:
            return None
        B = self.block_size
        pc, pd = self._tile_paths(key, int(entry["generation"]))
        try:
            coords = np.load(pc, allow_pickle=False).astype(np.int32, copy=False)
            data = np.load(pd, mmap_mode="r", allow_pickle=False)
            if coords.ndim != 2 or coords.shape[1] != 3 or data.shape != (len(coords), B, B, B):
                raise ValueError(f"coords {coords.shape} and log_odds {data.shape} do not fit together")
        except (OSError, ValueError) as e:
            raise InputError(f"unreadable map tile ({e}); rebuild the map", pd) from None
        self.tiles_read += 1
        tile = _Tile(coords, block_keys(coords), data.reshape(len(coords), B**3))
        self._remember(key, tile)
        return tile

    def _remember(self, key: tuple[int, int], tile: _Tile) -> None:
        old = self._cache.pop(key, None)
        if old is not None:
            self._cache_bytes -= old.nbytes
        self._cache[key] = tile
        self._cache_bytes += tile.nbytes
        while self._cache_bytes > self._cache_limit and len(self._cache) > 1:
            _, gone = self._cache.popitem(last=False)
            self._cache_bytes -= gone.nbytes

    def drop_cache(self) -> None:
        """Forget every cached tile (the next query reads from disk)."""
        self._cache.clear()
        self._cache_bytes = 0

    def _tiles_of_blocks(self, coords: np.ndarray) -> np.ndarray:
        return np.floor_divide(coords[:, :2], self.tile_blocks)

    # ----- adding evidence ---------------------------------------------------------------------
    def add_map(self, occ: OccupancyMap, name: str = "") -> int:
        """Add a map's evidence (log-odds, voxel by voxel, clamped) to the tiles it touches.

        The map must share the world frame, voxel size, block size and sensor model. Returns the
        number of tiles written. Memory: the map plus one tile at a time."""
        check_mergeable([self.config, occ.config], [str(self.directory), name or "the added map"])
        B = self.block_size
        coords = occ.grid.block_coords.astype(np.int32)
        data = occ.grid.blocks.reshape(len(coords), B**3)
        if len(coords) == 0:
            self._header["sources"].append(name)
            self._write_header()
            return 0
        tiles = self._tiles_of_blocks(coords)
        order = np.lexsort((tiles[:, 1], tiles[:, 0]))  # indices only: the blocks are copied tile by tile
        tiles = tiles[order]
        cuts = np.flatnonzero(np.any(np.diff(tiles, axis=0) != 0, axis=1)) + 1
        lo, hi = logit(self.config.clamp_min), logit(self.config.clamp_max)
        new_entries: dict[str, dict[str, int]] = {}
        written: list[Path] = []
        zmin, zmax = self._header.get("z_blocks", [int(coords[:, 2].min()), int(coords[:, 2].max())])
        try:
            for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(coords)], strict=True):
                key = (int(tiles[a, 0]), int(tiles[a, 1]))
                old = self._tile(key)
                old_c = old.coords if old is not None else np.zeros((0, 3), np.int32)
                old_d = np.asarray(old.data) if old is not None else np.zeros((0, B**3), np.float32)
                rows = order[a:b]
                c, d = add_block_evidence(old_c, old_d, coords[rows], data[rows], lo, hi)
                del old_d
                self._cache.pop(key, None)  # its memory map is about to be replaced
                entry = self._header["tiles"].get(_key(key))
                gen = 0 if entry is None else int(entry["generation"]) + 1
                pc, pd = self._tile_paths(key, gen)
                for path, array in ((pc, c), (pd, d.reshape(len(c), B, B, B))):
                    with atomic_write(path, "wb") as f:
                        np.save(f, array, allow_pickle=False)
                    written.append(path)
                new_entries[_key(key)] = {"generation": gen, "blocks": int(len(c))}
                zmin = min(zmin, int(c[:, 2].min()))
                zmax = max(zmax, int(c[:, 2].max()))
        except BaseException:
            for p in written:  # not yet referenced by the header: remove, keep the map as it was
                p.unlink(missing_ok=True)
            for k in new_entries:
                self._cache.pop(_parse_key(k), None)
            raise
        old_files = [
            p
            for k, v in self._header["tiles"].items()
            if k in new_entries
            for p in self._tile_paths(_parse_key(k), int(v["generation"]))
        ]
        self._header["tiles"].update(new_entries)
        self._header["sources"].append(name)
        self._header["z_blocks"] = [zmin, zmax]
        self._write_header()
        for p in old_files:
            p.unlink(missing_ok=True)
        return len(new_entries)

    def _write_header(self) -> None:
        self._header["num_blocks"] = self.num_blocks
        self._header["num_tiles"] = len(self._header["tiles"])
        write_text_atomic(self.directory / HEADER, json.dumps(self._header, indent=1) + "\n")

    def _sweep_orphans(self) -> None:
        """Remove tile files the header does not reference (left by an interrupted addition)."""
        tiles_dir = self.directory / TILES_DIR
        if not tiles_dir.is_dir():
            return
        live = {
            f"{k}.g{v['generation']}.{part}.npy"
            for k, v in self._header["tiles"].items()
            for part in ("coords", "log_odds")
        }
        for entry in os.scandir(tiles_dir):
            if _TILE_FILE.match(entry.name) and entry.name not in live:
                Path(entry.path).unlink(missing_ok=True)

    # ----- queries ---------------------------------------------------------------------------------
    def log_odds_at(self, points: np.ndarray) -> np.ndarray:
        """Log-odds (N,) float32 of the voxels holding ``points`` (N, 3) world metres; NaN unknown."""
        p = np.asarray(points, np.float64).reshape(-1, 3)
        vox = np.floor(p / self.voxel_size).astype(np.int64)
        out = np.full(len(p), np.nan, np.float32)
        tiles = np.floor_divide(np.floor_divide(vox[:, :2], self.block_size), self.tile_blocks)
        blocks = np.floor_divide(vox, self.block_size)
        local = vox - blocks * self.block_size
        flat = (local[:, 0] * self.block_size + local[:, 1]) * self.block_size + local[:, 2]
        for key in {(int(a), int(b)) for a, b in tiles}:
            tile = self._tile(key)
            if tile is None:
                continue
            sel = np.flatnonzero((tiles[:, 0] == key[0]) & (tiles[:, 1] == key[1]))
            rows = tile.rows(blocks[sel])
            found = rows >= 0
            out[sel[found]] = tile.data[rows[found], flat[sel[found]]]
        return out

    def is_occupied(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: the voxel holding each point is known and occupied."""
        lo = self.log_odds_at(points)
        with np.errstate(invalid="ignore"):
            return lo >= logit(self.config.occupancy_threshold)

    def _blocks_in(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Blocks (coords (N, 3) int32, log_odds (N, B^3)) overlapping the world box [lo, hi] (3,)."""
        parts = [self._blocks_in_tile(key, lo, hi) for key in self.tile_ids()]
        parts = [(c, d) for c, d in parts if len(c)]
        if not parts:
            B = self.block_size
            return np.zeros((0, 3), np.int32), np.zeros((0, B**3), np.float32)
        return np.concatenate([c for c, _ in parts]).astype(np.int32), np.concatenate([d for _, d in parts])

    def region(self, lo: Sequence[float] | np.ndarray, hi: Sequence[float] | np.ndarray) -> OccupancyMap:
        """An in-memory map of the blocks overlapping the world box [lo, hi] (metres)."""
        c, d = self._blocks_in(np.asarray(lo, np.float64), np.asarray(hi, np.float64))
        B = self.block_size
        return OccupancyMap.from_blocks(self.config, c, d.reshape(len(c), B, B, B))

    def tile_map(self, key: tuple[int, int]) -> OccupancyMap:
        """An in-memory map of one stored tile's blocks (all heights)."""
        tile = self._tile(key)
        B = self.block_size
        if tile is None:
            return OccupancyMap(self.config)
        return OccupancyMap.from_blocks(self.config, tile.coords, np.asarray(tile.data).reshape(-1, B, B, B))

    def to_map(self) -> OccupancyMap:
        """Every tile in one in-memory map (for maps that fit in memory)."""
        lo, hi = self.bounds()
        return self.region(lo - 1.0, hi + 1.0)

    def coarse(
        self,
        factor: int,
        lo: Sequence[float] | np.ndarray | None = None,
        hi: Sequence[float] | np.ndarray | None = None,
    ) -> OccupancyMap:
        """A map ``factor`` times coarser (voxel ``factor * voxel_size``) of the box [lo, hi]
        (default: everything), for planning across the whole district.

        A coarse voxel is occupied when any of its fine voxels is, unknown when more than half of
        them are unknown, else free (the largest known log-odds): obstacles are never thinned.
        """
        B = self.block_size
        if factor < 1 or B % factor:
            raise InputError(f"the coarse factor must divide the block size {B}, got {factor}")
        if lo is None or hi is None:
            blo, bhi = self.bounds()
            lo, hi = blo - 1.0, bhi + 1.0
        n = B // factor
        thr = logit(self.config.occupancy_threshold)
        vox, vals = [], []
        lo_a, hi_a = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        for key in self.tile_ids():
            c, d = self._blocks_in_tile(key, lo_a, hi_a)
            if len(c) == 0:
                continue
            cube = d.reshape(len(c), n, factor, n, factor, n, factor)
            cube = cube.transpose(0, 1, 3, 5, 2, 4, 6).reshape(len(c), n, n, n, factor**3)
            known = np.isfinite(cube)
            top = np.max(np.where(known, cube, -np.inf), axis=-1)  # -inf where all are unknown
            occupied = top >= thr
            unknown = known.sum(axis=-1) * 2 < factor**3
            value = np.where(occupied | ~unknown, top, np.nan).astype(np.float32)
            value[~np.isfinite(value)] = np.nan
            idx = np.argwhere(np.isfinite(value))
            if len(idx) == 0:
                continue
            vox.append(c[idx[:, 0]].astype(np.int64) * n + idx[:, 1:])
            vals.append(value[tuple(idx.T)])
        cfg = MapConfig.from_dict({**self.config.to_dict(), "voxel_size_m": self.voxel_size * factor})
        if not vox:
            return OccupancyMap(cfg)
        v = np.concatenate(vox)
        val = np.concatenate(vals)
        bc = np.floor_divide(v, B)
        uniq, inverse = np.unique(bc, axis=0, return_inverse=True)
        data = np.full((len(uniq), B, B, B), np.nan, np.float32)
        loc = v - bc * B
        data[inverse.ravel(), loc[:, 0], loc[:, 1], loc[:, 2]] = val
        return OccupancyMap.from_blocks(cfg, uniq.astype(np.int32), data)

    def _blocks_in_tile(
        self, key: tuple[int, int], lo: np.ndarray, hi: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        B = self.block_size
        bm = B * self.voxel_size
        blo = np.floor(lo / bm).astype(np.int64)
        bhi = np.floor(hi / bm).astype(np.int64)
        t0, t1 = np.floor_divide(blo[:2], self.tile_blocks), np.floor_divide(bhi[:2], self.tile_blocks)
        if not (t0[0] <= key[0] <= t1[0] and t0[1] <= key[1] <= t1[1]):
            return np.zeros((0, 3), np.int32), np.zeros((0, B**3), np.float32)
        tile = self._tile(key)
        assert tile is not None
        keep = np.flatnonzero(np.all((tile.coords >= blo) & (tile.coords <= bhi), axis=1))
        return tile.coords[keep], np.asarray(tile.data[keep])


class _Tile:
    """One tile: its blocks' coordinates (N, 3) int32 and sorted keys (N,) int64 in memory, their
    log-odds (N, B^3) float32 memory-mapped (read only where asked)."""

    def __init__(self, coords: np.ndarray, keys: np.ndarray, data: np.ndarray):
        self.coords, self.keys, self.data = coords, keys, data
        self.nbytes = int(coords.nbytes + keys.nbytes)

    def rows(self, block_coords: np.ndarray) -> np.ndarray:
        """(M,) row of each block coordinate (M, 3), -1 where the tile lacks it."""
        q = block_keys(block_coords)
        if len(self.keys) == 0:
            return np.full(len(q), -1, np.int64)
        r = np.minimum(np.searchsorted(self.keys, q), len(self.keys) - 1)
        return np.where(self.keys[r] == q, r, -1)


def _key(key: tuple[int, int]) -> str:
    return f"{key[0]}_{key[1]}"


def _parse_key(text: str) -> tuple[int, int]:
    a, b = text.split("_")
    return int(a), int(b)


def describe(tiled: TiledMap) -> dict[str, Any]:
    """A JSON-ready summary of a tiled map."""
    lo, hi = tiled.bounds()
    return {
        "layout": LAYOUT,
        "tiles": len(tiled.tile_ids()),
        "tile_size_m": tiled.tile_size_m,
        "blocks": tiled.num_blocks,
        "voxel_size_m": tiled.voxel_size,
        "bounds_m": [lo.tolist(), hi.tolist()],
        "sources": tiled.sources,
    }
