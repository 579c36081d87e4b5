"""Procedural generators: a street-grid city and a small textured monument on a plaza.

Both are deterministic functions of the seed (``numpy.random.default_rng(seed)``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skyrecon.errors import InputError
from skyrecon.sim.city import (
    KIND_BEAM,
    KIND_BUILDING,
    KIND_COLUMN,
    KIND_MONUMENT,
    KIND_POLE,
    KIND_ROOF_UNIT,
    KIND_TREE_CANOPY,
    KIND_TREE_TRUNK,
    City,
)
from skyrecon.sim.texture import (
    GROUND_CITY,
    GROUND_PLAIN,
    GROUND_PLAIN_PLAZA,
    GROUND_PLAZA,
    MAT_BARK,
    MAT_BRICK,
    MAT_CONCRETE,
    MAT_FOLIAGE,
    MAT_GLASS,
    MAT_METAL,
    MAT_MURAL,
    MAT_PLAIN,
    MAT_STONE,
    ROOF_GRAVEL,
    ROOF_PLAIN,
    WINDOWS_PUNCHED,
    WINDOWS_RIBBON,
)

_BRICK = [(0.55, 0.27, 0.2), (0.62, 0.36, 0.26), (0.47, 0.24, 0.19), (0.72, 0.58, 0.44), (0.6, 0.3, 0.22)]
_CONCRETE = [(0.62, 0.6, 0.56), (0.72, 0.7, 0.64), (0.52, 0.52, 0.52), (0.76, 0.71, 0.6), (0.66, 0.64, 0.66)]
_GLASS = [(0.24, 0.34, 0.44), (0.3, 0.4, 0.38), (0.33, 0.36, 0.42), (0.22, 0.3, 0.36)]
_PLAIN = [
    (0.86, 0.8, 0.7),
    (0.7, 0.76, 0.82),
    (0.9, 0.88, 0.84),
    (0.8, 0.62, 0.5),
    (0.62, 0.72, 0.6),
    (0.9, 0.8, 0.55),
]
# ``generate_city(..., plain=True)``: shares of buildings with plain facades and with glass
PLAIN_FACADE_FRACTION = 0.6
PLAIN_GLASS_FRACTION = 0.2
_ACCENT = [(0.9, 0.9, 0.88), (0.3, 0.3, 0.32), (0.55, 0.55, 0.58), (0.8, 0.78, 0.7)]


class _Builder:
    """Collects boxes and cylinders with their material data."""

    def __init__(self) -> None:
        self.boxes: list[list[float]] = []
        self.box_info: list[tuple[int, int, tuple, tuple, tuple]] = []
        self.cyls: list[list[float]] = []
        self.cyl_info: list[tuple[int, int, tuple, tuple, tuple]] = []

    def box(
        self, lo, hi, material, kind, albedo, accent=(0.5, 0.5, 0.5), params=(3.2, 3.0, 0.5, 0.5, 0.0, 1.0)
    ):
        self.boxes.append([float(v) for v in (*lo, *hi)])
        self.box_info.append((material, kind, tuple(albedo), tuple(accent), tuple(params)))

    def cylinder(
        self,
        x,
        y,
        r,
        z0,
        z1,
        material,
        kind,
        albedo,
        accent=(0.5, 0.5, 0.5),
        params=(3.2, 0.0, 0.5, 0.5, 0.0, 1.0),
    ):
        self.cyls.append([float(x), float(y), float(r), float(z0), float(z1)])
        self.cyl_info.append((material, kind, tuple(albedo), tuple(accent), tuple(params)))

    def arrays(self) -> dict:
        def pack(rows, info, cols):
            a = np.array(rows, dtype=np.float64).reshape(-1, cols)
            mat = np.array([i[0] for i in info], np.int32)
            kind = np.array([i[1] for i in info], np.int32)
            alb = np.array([i[2] for i in info], np.float64).reshape(-1, 3)
            acc = np.array([i[3] for i in info], np.float64).reshape(-1, 3)
            par = np.array([i[4] for i in info], np.float64).reshape(-1, 6)
            return a, mat, kind, alb, acc, par

        b, bm, bk, ba, bc, bp = pack(self.boxes, self.box_info, 6)
        c, cm, ck, ca, cc, cp = pack(self.cyls, self.cyl_info, 5)
        return dict(
            boxes=b,
            box_material=bm,
            box_kind=bk,
            box_albedo=ba,
            box_accent=bc,
            box_params=bp,
            cylinders=c,
            cyl_material=cm,
            cyl_kind=ck,
            cyl_albedo=ca,
            cyl_accent=cc,
            cyl_params=cp,
        )


def _jitter_color(rng: np.random.Generator, palette, amount: float = 0.05) -> tuple:
    c = np.asarray(palette[int(rng.integers(len(palette)))], dtype=np.float64)
    return tuple(np.clip(c * (1.0 + rng.uniform(-amount, amount, 3)), 0.0, 1.0).tolist())


def _layout(rng: np.random.Generator, lo: float, hi: float, block_m, street_m) -> np.ndarray:
    """Block intervals along one axis, separated by streets, with streets at both borders."""
    size = hi - lo
    mean = (block_m[0] + block_m[1]) / 2 + (street_m[0] + street_m[1]) / 2
    n = max(1, int(round((size - (street_m[0] + street_m[1]) / 2) / mean)))
    streets = rng.uniform(street_m[0], street_m[1], n + 1)
    blocks = rng.uniform(block_m[0], block_m[1], n)
    blocks *= (size - streets.sum()) / blocks.sum()
    if np.any(blocks <= 5.0):
        raise InputError(f"size_m={size} is too small for the requested block and street sizes")
    edges = lo + np.cumsum(np.concatenate([[0.0], np.ravel(np.column_stack([streets[:-1], blocks]))]))
    starts = edges[1::2]
    return np.stack([starts, starts + blocks], axis=1)


def _split_lots(rng: np.random.Generator, x0, y0, x1, y1, out: list, threshold: float) -> None:
    """Split a rectangle in two (about the middle of its long side) until its sides are at most
    30 m, and, with probability 0.85 each time, until they are at most ``threshold`` (>= 11.2 m,
    so lots stay >= 5 m wide)."""
    w, h = x1 - x0, y1 - y0
    longest = max(w, h)
    if longest > 30.0 or (longest > threshold and rng.random() < 0.85):
        f = rng.uniform(0.45, 0.55)
        if w >= h:
            xm = x0 + f * w
            _split_lots(rng, x0, y0, xm, y1, out, threshold)
            _split_lots(rng, xm, y0, x1, y1, out, threshold)
        else:
            ym = y0 + f * h
            _split_lots(rng, x0, y0, x1, ym, out, threshold)
            _split_lots(rng, x0, ym, x1, y1, out, threshold)
    else:
        out.append((x0, y0, x1, y1))


def _divide(rng: np.random.Generator, a: float, b: float) -> list[tuple[float, float]]:
    """Cut [a, b] into pieces 5.5-12 m long (the last one absorbs the remainder); none if shorter than 5 m."""
    out: list[tuple[float, float]] = []
    pos = a
    if b - a < 5.0:
        return out
    while b - pos > 1e-9:
        w = rng.uniform(5.5, 12.0)
        if b - (pos + w) < 5.5:
            w = b - pos
        out.append((pos, pos + w))
        pos += w
    return out


def _perimeter_lots(rng: np.random.Generator, x0, y0, x1, y1, out: list) -> None:
    """Lots lining the four edges of a block around an open courtyard (falls back to splitting)."""
    depth = rng.uniform(6.0, 8.5)
    if min(x1 - x0, y1 - y0) < 2 * depth + 4.0:
        _split_lots(rng, x0, y0, x1, y1, out, 11.2)
        return
    for a, b in _divide(rng, x0, x1):
        out.append((a, y0, b, y0 + depth))
    for a, b in _divide(rng, x0, x1):
        out.append((a, y1 - depth, b, y1))
    for a, b in _divide(rng, y0 + depth, y1 - depth):
        out.append((x0, a, x0 + depth, b))
    for a, b in _divide(rng, y0 + depth, y1 - depth):
        out.append((x1 - depth, a, x1, b))


def _building_style(
    rng: np.random.Generator, height: float, low_texture_fraction: float, glass_fraction: float = 0.0
):
    u = rng.random()
    if u < low_texture_fraction:
        mat, alb = MAT_PLAIN, _jitter_color(rng, _PLAIN)
    elif u < low_texture_fraction + glass_fraction:
        mat, alb = MAT_GLASS, _jitter_color(rng, _GLASS)
    elif height > 20 and rng.random() < 0.6:
        mat, alb = MAT_GLASS, _jitter_color(rng, _GLASS)
    elif rng.random() < 0.5:
        mat, alb = MAT_BRICK, _jitter_color(rng, _BRICK)
    else:
        mat, alb = MAT_CONCRETE, _jitter_color(rng, _CONCRETE)
    acc = _jitter_color(rng, _ACCENT, 0.03)
    floor_h = rng.uniform(3.0, 4.0)
    if mat == MAT_GLASS:
        col_p = rng.uniform(1.2, 1.8)
    elif mat == MAT_CONCRETE:
        col_p = rng.uniform(1.2, 2.0)
    else:
        col_p = rng.uniform(2.4, 4.0)
    roof = ROOF_GRAVEL if rng.random() < 0.4 else ROOF_PLAIN
    windows = WINDOWS_RIBBON if (mat == MAT_CONCRETE and rng.random() < 0.6) else WINDOWS_PUNCHED
    params = (floor_h, col_p, rng.uniform(0.42, 0.62), rng.uniform(0.45, 0.6), float(roof + windows), 1.0)
    return mat, alb, acc, params


def _tree(b: _Builder, rng: np.random.Generator, x: float, y: float, scale: float = 1.0) -> None:
    trunk_h = rng.uniform(2.2, 3.2) * scale
    tw = rng.uniform(0.25, 0.4) * scale
    b.box(
        (x - tw / 2, y - tw / 2, 0.0),
        (x + tw / 2, y + tw / 2, trunk_h),
        MAT_BARK,
        KIND_TREE_TRUNK,
        _jitter_color(rng, [(0.36, 0.27, 0.2)]),
        params=(3.0, 0.0, 0.5, 0.5, 0.0, 1.0),
    )
    cw = rng.uniform(2.4, 3.4) * scale
    ch = rng.uniform(2.5, 4.0) * scale
    b.box(
        (x - cw / 2, y - cw / 2, trunk_h),
        (x + cw / 2, y + cw / 2, trunk_h + ch),
        MAT_FOLIAGE,
        KIND_TREE_CANOPY,
        _jitter_color(rng, [(0.22, 0.42, 0.16), (0.28, 0.45, 0.2), (0.2, 0.36, 0.18)]),
        params=(3.0, 0.0, 0.5, 0.5, 0.0, 1.0),
    )


@dataclass(frozen=True)
class _CityStyle:
    """The knobs of :func:`generate_city` that the per-block steps read (metres, fractions)."""

    half: float
    sidewalk_m: float
    max_height_m: float
    pole_spacing_m: tuple[float, float]
    low_texture_fraction: float
    park_fraction: float
    glass_fraction: float = 0.0


_TEX_METAL = (3.0, 0.0, 0.5, 0.5, 0.0, 1.0)  # texture parameters of poles, beams and roof units


def _rooftop(
    b: _Builder,
    rng: np.random.Generator,
    foot: tuple[float, float, float, float],
    h: float,
    facade: tuple,
    max_height_m: float,
) -> None:
    """A tower set back on a tall, wide building, or a few rooftop units (or nothing).

    ``foot`` is the building's footprint ``(x0, y0, x1, y1)`` and ``h`` its height, metres;
    ``facade`` its ``(material, albedo, accent, params)`` (the tower's too).
    """
    fx0, fy0, fx1, fy1 = foot
    mat, alb, acc, params = facade
    wx, wy = fx1 - fx0, fy1 - fy0
    if h > 18.0 and min(wx, wy) > 11.0 and rng.random() < 0.4:
        inset = rng.uniform(2.0, 3.5, 4)
        th = min(max_height_m, h + rng.uniform(5.0, 16.0))
        if th > h + 2.0:
            b.box(
                (fx0 + inset[0], fy0 + inset[1], h),
                (fx1 - inset[2], fy1 - inset[3], th),
                mat,
                KIND_BUILDING,
                alb,
                acc,
                params,
            )
    elif rng.random() < 0.5 and min(wx, wy) > 7.0:
        for _ in range(int(rng.integers(1, 4))):
            uw, ud, uh = rng.uniform(1.5, 3.0), rng.uniform(1.5, 3.0), rng.uniform(1.0, 2.5)
            ux = rng.uniform(fx0 + 1.0, fx1 - 1.0 - uw)
            uy = rng.uniform(fy0 + 1.0, fy1 - 1.0 - ud)
            b.box(
                (ux, uy, h),
                (ux + uw, uy + ud, h + uh),
                MAT_METAL,
                KIND_ROOF_UNIT,
                _jitter_color(rng, [(0.7, 0.7, 0.72), (0.55, 0.56, 0.58)]),
                params=_TEX_METAL,
            )


def _building(
    b: _Builder,
    rng: np.random.Generator,
    lot: tuple[float, float, float, float],
    closeness: float,
    style: _CityStyle,
) -> None:
    """A box building on a lot (some lots stay empty), taller near the centre, with its rooftop."""
    lx0, ly0, lx1, ly1 = lot
    if rng.random() < 0.06:
        return  # an empty lot
    setback = rng.uniform(0.0, 1.2, 4) * (rng.random() < 0.6)
    fx0, fy0, fx1, fy1 = lx0 + setback[0], ly0 + setback[1], lx1 - setback[2], ly1 - setback[3]
    if fx1 - fx0 < 5.0:
        fx0, fx1 = lx0, lx1
    if fy1 - fy0 < 5.0:
        fy0, fy1 = ly0, ly1
    max_h = style.max_height_m
    u = rng.random()
    h = 6.0 * (max_h / 6.0) ** (u**1.2 * (0.6 + 0.4 * closeness))
    h = float(np.clip(h, 6.0, min(max_h, 7.0 * min(fx1 - fx0, fy1 - fy0))))
    mat, alb, acc, params = _building_style(rng, h, style.low_texture_fraction, style.glass_fraction)
    b.box((fx0, fy0, 0.0), (fx1, fy1, h), mat, KIND_BUILDING, alb, acc, params)
    _rooftop(b, rng, (fx0, fy0, fx1, fy1), h, (mat, alb, acc, params), max_h)


def _block(b: _Builder, rng: np.random.Generator, bx: np.ndarray, by: np.ndarray, style: _CityStyle) -> None:
    """One block inside its pavement: a park with trees, or lots with buildings."""
    cx, cy = (bx[0] + bx[1]) / 2, (by[0] + by[1]) / 2
    closeness = 1.0 - min(1.0, np.hypot(cx, cy) / (style.half * 1.1))
    sw = style.sidewalk_m
    x0, y0, x1, y1 = bx[0] + sw, by[0] + sw, bx[1] - sw, by[1] - sw
    if rng.random() < style.park_fraction:
        for _ in range(int(rng.integers(4, 9))):
            _tree(b, rng, rng.uniform(x0 + 2, x1 - 2), rng.uniform(y0 + 2, y1 - 2))
        return
    lots: list[tuple[float, float, float, float]] = []
    # most blocks are lined with narrow lots around a courtyard; some hold a few big buildings
    layout = rng.random()
    if layout < 0.6:
        _perimeter_lots(rng, x0, y0, x1, y1, lots)
    elif layout < 0.85:
        _split_lots(rng, x0, y0, x1, y1, lots, 11.2)
    else:
        _split_lots(rng, x0, y0, x1, y1, lots, 30.0)
    for lot in lots:
        _building(b, rng, lot, float(closeness), style)


def _pavement_side(
    b: _Builder,
    rng: np.random.Generator,
    side: tuple[tuple[float, float], tuple[float, float]],
    block_center: tuple[float, float],
    pole_spacing_m: tuple[float, float],
) -> None:
    """Poles (mostly) and street trees along one kerb line, from ``side[0]`` to ``side[1]``."""
    (ax, ay), (ex, ey) = side
    length = np.hypot(ex - ax, ey - ay)
    pos = rng.uniform(2.0, 6.0)
    while pos < length - 2.0:
        px, py = ax + (ex - ax) * pos / length, ay + (ey - ay) * pos / length
        if rng.random() < 0.8:
            r = rng.uniform(0.1, 0.16) if rng.random() < 0.7 else rng.uniform(0.16, 0.3)
            b.cylinder(
                px,
                py,
                r,
                0.0,
                rng.uniform(4.0, 10.0),
                MAT_METAL,
                KIND_POLE,
                _jitter_color(rng, [(0.42, 0.44, 0.45), (0.3, 0.32, 0.3), (0.5, 0.42, 0.32)]),
                params=_TEX_METAL,
            )
        else:
            # a street tree, set back into the pavement
            nxv, nyv = -(ey - ay) / length, (ex - ax) / length
            ccx, ccy = block_center
            sgn = 1.0 if (ccx - px) * nxv + (ccy - py) * nyv > 0 else -1.0
            _tree(b, rng, px + sgn * nxv * 1.2, py + sgn * nyv * 1.2, 0.85)
        pos += rng.uniform(*pole_spacing_m)


def _pavements(
    b: _Builder, rng: np.random.Generator, bx: np.ndarray, by: np.ndarray, style: _CityStyle
) -> None:
    """Poles and street trees along the four pavements of a block, just inside the kerb."""
    sides = [
        ((bx[0], by[0] + 0.6), (bx[1], by[0] + 0.6)),
        ((bx[0], by[1] - 0.6), (bx[1], by[1] - 0.6)),
        ((bx[0] + 0.6, by[0]), (bx[0] + 0.6, by[1])),
        ((bx[1] - 0.6, by[0]), (bx[1] - 0.6, by[1])),
    ]
    center = ((bx[0] + bx[1]) / 2, (by[0] + by[1]) / 2)
    for side in sides:
        _pavement_side(b, rng, side, center, style.pole_spacing_m)


def _beams(
    b: _Builder,
    rng: np.random.Generator,
    blocks_x: np.ndarray,
    blocks_y: np.ndarray,
    half: float,
    n_beams: int,
) -> None:
    """Overhead beams across inner streets, each between two new poles (border streets stay clear)."""
    xs_c = _street_lines(blocks_x, -half, half)
    ys_c = _street_lines(blocks_y, -half, half)
    for _ in range(n_beams):
        along_x = rng.random() < 0.5
        lines = ys_c if along_x else xs_c
        (lo, hi) = lines[int(rng.integers(len(lines)))]
        if lo <= -half + 1e-9 or hi >= half - 1e-9:
            continue  # keep the border streets clear
        cross = blocks_x if along_x else blocks_y
        blk = cross[int(rng.integers(len(cross)))]
        pos = rng.uniform(blk[0] + 4.0, blk[1] - 4.0)
        ph = rng.uniform(7.0, 9.5)
        thick = rng.uniform(0.08, 0.16)
        a_, b_ = lo - 0.6, hi + 0.6
        for q in (a_, b_):
            x, y = (pos, q) if along_x else (q, pos)
            b.cylinder(x, y, 0.15, 0.0, ph, MAT_METAL, KIND_POLE, (0.35, 0.36, 0.36), params=_TEX_METAL)
        z0 = ph - 0.35
        if along_x:
            lo3, hi3 = (pos - thick / 2, a_, z0), (pos + thick / 2, b_, z0 + thick)
        else:
            lo3, hi3 = (a_, pos - thick / 2, z0), (b_, pos + thick / 2, z0 + thick)
        b.box(lo3, hi3, MAT_METAL, KIND_BEAM, (0.25, 0.25, 0.27), params=_TEX_METAL)


def generate_city(
    seed: int,
    size_m: float = 200.0,
    *,
    block_m: tuple[float, float] = (22.0, 36.0),
    street_m: tuple[float, float] = (10.0, 13.0),
    sidewalk_m: float = 2.5,
    max_height_m: float = 60.0,
    pole_spacing_m: tuple[float, float] = (10.0, 15.0),
    n_beams: int = 6,
    low_texture_fraction: float = 0.12,
    park_fraction: float = 0.08,
    plain: bool = False,
) -> City:
    """Generate a city on the square ``[-size_m/2, size_m/2]^2`` (world frame, z up, metres).

    A grid of blocks separated by streets (streets also run along the border), each block lined
    with a pavement and split into lots carrying box buildings (footprint about 5-30 m, height
    6-``max_height_m`` m, taller near the centre; some with a tower and rooftop units), a few parks
    with trees; poles (radius 0.1-0.3 m, height 4-10 m) and trees along the pavements, and a few
    thin horizontal beams (overhead wires, sign gantries) across streets below 10 m. Street
    corridors are free above 10 m, so a drone can fly along every street at 10-40 m.

    Steps, in this order (each draws from one generator, so the order is part of the city):
    the block grid, every block's park or buildings, every block's pavement poles and trees,
    the overhead beams.

    Args:
        seed: the only source of randomness; the same seed gives the same city.
        size_m: side of the square city, metres.
        block_m, street_m: ranges of block and street widths, metres.
        sidewalk_m: pavement width along block edges, metres.
        max_height_m: tallest building, metres.
        pole_spacing_m: range of spacing between poles along a pavement, metres.
        n_beams: number of overhead beams across streets.
        low_texture_fraction: share of buildings with plain, almost textureless facades.
        park_fraction: share of blocks that are parks.
        plain: a city of plain surfaces: ``PLAIN_FACADE_FRACTION`` of the buildings get plain
            facades (one colour, faint shading, no windows; this replaces
            ``low_texture_fraction``), ``PLAIN_GLASS_FRACTION`` glass curtain walls, the rest
            brick or concrete; streets, pavements and courtyards are plain greys without
            markings, paving or grain. The layout is drawn by the same steps (but not the same
            city as ``plain=False`` with that seed: the facade draws differ).
    """
    if not np.isfinite(size_m) or size_m < 60.0:
        raise InputError(f"size_m must be at least 60 m, got {size_m}")
    rng = np.random.default_rng(seed)
    half = size_m / 2
    style = _CityStyle(
        half,
        sidewalk_m,
        max_height_m,
        pole_spacing_m,
        PLAIN_FACADE_FRACTION if plain else low_texture_fraction,
        park_fraction,
        PLAIN_GLASS_FRACTION if plain else 0.0,
    )
    blocks_x = _layout(rng, -half, half, block_m, street_m)
    blocks_y = _layout(rng, -half, half, block_m, street_m)
    b = _Builder()
    for bx in blocks_x:
        for by in blocks_y:
            _block(b, rng, bx, by, style)
    for bx in blocks_x:
        for by in blocks_y:
            _pavements(b, rng, bx, by, style)
    _beams(b, rng, blocks_x, blocks_y, half, n_beams)
    arrays = b.arrays()
    top = float(arrays["boxes"][:, 5].max()) if len(arrays["boxes"]) else 10.0
    return City(
        seed=int(seed),
        extent=np.array([-half, -half, half, half]),
        blocks_x=blocks_x,
        blocks_y=blocks_y,
        sidewalk_m=float(sidewalk_m),
        ground_style=GROUND_PLAIN if plain else GROUND_CITY,
        center=np.array([0.0, 0.0, top / 3]),
        view_radius_m=size_m / 3,
        **arrays,
    )


def _street_lines(blocks: np.ndarray, lo: float, hi: float) -> list[tuple[float, float]]:
    edges = [lo, *blocks.ravel().tolist(), hi]
    return [(edges[2 * i], edges[2 * i + 1]) for i in range(len(edges) // 2)]


def generate_object_scene(seed: int, size_m: float = 4.0, plain: bool = False) -> City:
    """A single textured monument about ``size_m`` across on a paved plaza, for rings and orbits.

    A stone plinth, a main block with mural-painted faces, a capstone, a few smaller blocks and
    columns around it; the plaza is paved with 0.5 m slabs out to 15 m, grass beyond. All
    surfaces are richly textured at centimetre scale (feature matching and MVS at 2-15 m).

    With ``plain=True`` the same layout has the surfaces of a real city's plain walls and
    roads: the ground is plain grey everywhere (only a faint shading of 12 m wavelength, no
    fine texture), the plinth, the main block and all but one of the small blocks are plain
    (``MAT_PLAIN``: uniform colour with a faint shading), one face of the main block is
    covered by a glass curtain wall (``MAT_GLASS``: mullions and panels); the capstone, the
    columns and one small block stay textured stone or mural (so that the views still share
    some features). The random draws are the same, so the geometry is that of ``plain=False``
    plus a 2 cm glass panel.

    Returns:
        A :class:`City` with ``center`` at the monument's middle and ``view_radius_m`` a good
        camera distance for orbits.
    """
    rng = np.random.default_rng(seed)
    b = _Builder()
    s = float(size_m)
    if not np.isfinite(s) or s <= 0.5:
        raise InputError(f"size_m must be above 0.5 m, got {size_m}")
    stone = lambda: _jitter_color(rng, [(0.62, 0.58, 0.52), (0.7, 0.66, 0.6), (0.55, 0.52, 0.5)], 0.08)  # noqa: E731
    mural = lambda: _jitter_color(rng, [(0.55, 0.45, 0.35), (0.4, 0.5, 0.55), (0.5, 0.4, 0.5)], 0.1)  # noqa: E731
    tex = (3.0, 0.0, 0.5, 0.5, 0.0, 0.35)
    wall = MAT_PLAIN if plain else MAT_STONE
    painted = MAT_PLAIN if plain else MAT_MURAL
    plinth_h = rng.uniform(0.4, 0.7)
    b.box((-s / 2, -s / 2, 0.0), (s / 2, s / 2, plinth_h), wall, KIND_MONUMENT, stone(), params=tex)
    body = s * rng.uniform(0.5, 0.65)
    body_h = s * rng.uniform(0.7, 1.0)
    ox, oy = rng.uniform(-0.08, 0.08, 2) * s
    b.box(
        (ox - body / 2, oy - body / 2, plinth_h),
        (ox + body / 2, oy + body / 2, plinth_h + body_h),
        painted,
        KIND_MONUMENT,
        mural(),
        params=tex,
    )
    cap = body * rng.uniform(0.5, 0.75)
    cap_h = s * rng.uniform(0.2, 0.35)
    top = plinth_h + body_h + cap_h
    b.box(
        (ox - cap / 2, oy - cap / 2, plinth_h + body_h),
        (ox + cap / 2, oy + cap / 2, top),
        MAT_STONE,
        KIND_MONUMENT,
        stone(),
        params=tex,
    )
    for k in range(4):
        a = np.pi / 4 + k * np.pi / 2
        r = s * 0.42
        x, y = r * np.cos(a), r * np.sin(a)
        if rng.random() < 0.5:
            b.cylinder(
                x,
                y,
                s * rng.uniform(0.04, 0.07),
                plinth_h,
                plinth_h + body_h * rng.uniform(0.5, 0.9),
                MAT_STONE,
                KIND_COLUMN,
                stone(),
                params=tex,
            )
        else:
            w = s * rng.uniform(0.08, 0.14)
            b.box(
                (x - w, y - w, plinth_h),
                (x + w, y + w, plinth_h + s * rng.uniform(0.12, 0.3)),
                painted,
                KIND_MONUMENT,
                mural(),
                params=tex,
            )
    for i in range(int(rng.integers(2, 5))):
        a = rng.uniform(0, 2 * np.pi)
        r = s * rng.uniform(0.75, 1.2)
        w = s * rng.uniform(0.06, 0.12)
        x, y = r * np.cos(a), r * np.sin(a)
        b.box(
            (x - w, y - w, 0.0),
            (x + w, y + w, s * rng.uniform(0.1, 0.25)),
            MAT_MURAL if i == 0 or not plain else MAT_PLAIN,
            KIND_MONUMENT,
            mural(),
            params=tex,
        )
    if plain:  # a glass curtain wall on one face of the main block (2 cm proud of it)
        side = int(rng.integers(0, 4))
        x0, y0, x1, y1 = ox - body / 2, oy - body / 2, ox + body / 2, oy + body / 2
        t = 0.02
        lo, hi = {
            0: ((x0 - t, y0, plinth_h), (x0, y1, plinth_h + body_h)),
            1: ((x1, y0, plinth_h), (x1 + t, y1, plinth_h + body_h)),
            2: ((x0, y0 - t, plinth_h), (x1, y0, plinth_h + body_h)),
            3: ((x0, y1, plinth_h), (x1, y1 + t, plinth_h + body_h)),
        }[side]
        glass = _jitter_color(rng, _GLASS)
        b.box(
            lo, hi, MAT_GLASS, KIND_MONUMENT, glass, (0.55, 0.55, 0.58), params=(0.9, 0.7, 0.5, 0.5, 0.0, 1.0)
        )
    arrays = b.arrays()
    e = max(15.0, 4.0 * s)
    return City(
        seed=int(seed),
        extent=np.array([-e, -e, e, e]),
        blocks_x=np.zeros((0, 2)),
        blocks_y=np.zeros((0, 2)),
        sidewalk_m=0.0,
        ground_style=GROUND_PLAIN_PLAZA if plain else GROUND_PLAZA,
        center=np.array([0.0, 0.0, top / 2]),
        view_radius_m=1.7 * s,
        **arrays,
    )
