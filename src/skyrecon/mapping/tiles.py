"""District-scale maps: an occupancy map stored as square tiles on disk, loaded on demand.

A city district at 0.5 m (1 km x 1 km, 100 m high) is up to 800 million voxels: more than a
flight computer or a small server should hold at once. A :class:`TiledMap` keeps the same blocks
as :class:`~skyrecon.mapping.OccupancyMap` (same voxel grid, same log-odds, NaN unknown), grouped
into tiles of ``tile_blocks x tile_blocks`` block columns (all heights) and stored one file per tile.
Only the tiles a query touches are read, through a cache bounded in bytes.

Directory layout (``map.json`` is the usual map header with ``"layout": "tiles"``)::

    map.json                 {"format": "skyrecon.occupancy", "version": 1, "layout": "tiles",
                              "voxel_size_m", "block_size", "tile_blocks", "config",
                              "tiles": {"tx_ty": {"generation": g, "blocks": n}}, "sources": [...]}
    tiles/tx_ty.g<g>.npz     coords (N, 3) int32 block coordinates, log_odds (N, B, B, B) float32

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
import zipfile
from collections import OrderedDict
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from skyrecon.errors import InputError
from skyrecon.io.atomic import atomic_write, write_text_atomic
from skyrecon.mapping.blocks import BlockGrid
from skyrecon.mapping.config import MapConfig, logit
from skyrecon.mapping.merge import add_block_evidence, check_mergeable
from skyrecon.mapping.occupancy import OccupancyMap
from skyrecon.mapping.storage import FORMAT, HEADER, VERSION

LAYOUT = "tiles"
TILES_DIR = "tiles"
_TILE_FILE = re.compile(r"^(-?\d+)_(-?\d+)\.g(\d+)\.npz$")


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
        self._cache: OrderedDict[tuple[int, int], tuple[BlockGrid, int]] = OrderedDict()
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
    def _tile_path(self, key: tuple[int, int], generation: int) -> Path:
        return self.directory / TILES_DIR / f"{key[0]}_{key[1]}.g{generation}.npz"

    def _read_tile(self, key: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """(coords (N, 3) int32, log_odds (N, B^3) float32) of a stored tile; empty when absent."""
        B = self.block_size
        entry = self._header["tiles"].get(_key(key))
        if entry is None:
            return np.zeros((0, 3), np.int32), np.zeros((0, B**3), np.float32)
        p = self._tile_path(key, int(entry["generation"]))
        try:
            with np.load(p, allow_pickle=False) as z:
                coords = np.asarray(z["coords"], np.int32)
                data = np.asarray(z["log_odds"], np.float32).reshape(len(coords), B**3)
        except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as e:
            raise InputError(f"unreadable map tile ({e}); rebuild the map", p) from None
        self.tiles_read += 1
        return coords, data

    def _grid(self, key: tuple[int, int]) -> BlockGrid | None:
        """The tile as a block grid (cached); None when the tile is not stored."""
        hit = self._cache.get(key)
        if hit is not None:
            self._cache.move_to_end(key)
            return hit[0]
        if _key(key) not in self._header["tiles"]:
            return None
        coords, data = self._read_tile(key)
        grid = BlockGrid.from_blocks(self.block_size, np.nan, coords, data)
        self._remember(key, grid)
        return grid

    def _remember(self, key: tuple[int, int], grid: BlockGrid) -> None:
        old = self._cache.pop(key, None)
        if old is not None:
            self._cache_bytes -= old[1]
        size = int(grid.nbytes())
        self._cache[key] = (grid, size)
        self._cache_bytes += size
        while self._cache_bytes > self._cache_limit and len(self._cache) > 1:
            _, (_, s) = self._cache.popitem(last=False)
            self._cache_bytes -= s

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
        order = np.lexsort((tiles[:, 1], tiles[:, 0]))
        tiles, coords, data = tiles[order], coords[order], data[order]
        cuts = np.flatnonzero(np.any(np.diff(tiles, axis=0) != 0, axis=1)) + 1
        lo, hi = logit(self.config.clamp_min), logit(self.config.clamp_max)
        new_entries: dict[str, dict[str, int]] = {}
        written: list[Path] = []
        zmin, zmax = self._header.get("z_blocks", [int(coords[:, 2].min()), int(coords[:, 2].max())])
        try:
            for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(coords)], strict=True):
                key = (int(tiles[a, 0]), int(tiles[a, 1]))
                old_c, old_d = self._read_tile(key)
                c, d = add_block_evidence(old_c, old_d, coords[a:b], data[a:b], lo, hi)
                entry = self._header["tiles"].get(_key(key))
                gen = 0 if entry is None else int(entry["generation"]) + 1
                p = self._tile_path(key, gen)
                with atomic_write(p, "wb") as f:
                    np.savez(f, coords=c, log_odds=d.reshape(len(c), B, B, B))
                written.append(p)
                new_entries[_key(key)] = {"generation": gen, "blocks": int(len(c))}
                self._remember(key, BlockGrid.from_blocks(B, np.nan, c, d))
                zmin = min(zmin, int(c[:, 2].min()))
                zmax = max(zmax, int(c[:, 2].max()))
        except BaseException:
            for p in written:  # not yet referenced by the header: remove, keep the map as it was
                p.unlink(missing_ok=True)
            for k in new_entries:
                self._cache.pop(_parse_key(k), None)
            raise
        old_files = [
            self._tile_path(_parse_key(k), int(v["generation"]))
            for k, v in self._header["tiles"].items()
            if k in new_entries
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
        live = {f"{k}.g{v['generation']}.npz" for k, v in self._header["tiles"].items()}
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
        for key in {(int(a), int(b)) for a, b in tiles}:
            grid = self._grid(key)
            if grid is None:
                continue
            sel = (tiles[:, 0] == key[0]) & (tiles[:, 1] == key[1])
            out[sel] = grid.lookup(vox[sel], fill=np.nan)
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
        grid = self._grid(key)
        assert grid is not None
        c = grid.block_coords
        keep = np.all((c >= blo) & (c <= bhi), axis=1)
        return c[keep], grid.blocks.reshape(len(c), B**3)[keep]


def build_tiled_map(
    directory: str | Path,
    maps: Iterable[tuple[str, OccupancyMap]],
    config: MapConfig,
    tile_size_m: float = 64.0,
) -> TiledMap:
    """Create a tiled map in ``directory`` and add each ``(name, map)`` in turn (one in memory at a time
    when ``maps`` is a generator)."""
    tiled = TiledMap.create(directory, config, tile_size_m)
    for name, occ in maps:
        tiled.add_map(occ, name)
    return tiled


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
