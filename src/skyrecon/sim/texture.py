"""Numba kernel: view-independent surface colour of every hit, and the sky.

Colour is a deterministic function of the surface point, the face and the object's material:
procedural patterns (punched or ribbon windows, curtain-wall panels, bricks, stone blocks,
mosaics, paving, road markings) times multi-octave value noise. Every pattern is
*band-limited by the pixel footprint* at the hit point: noise octaves finer than about 1.5
pixels fade out, stripes and windows are filtered analytically with a tent of 1.5 pixels, and
per-cell random values (bricks, panels, tiles) likewise across cell borders. So the same point
renders to the same colour from nearby viewpoints, and warping an image by exact disparity
reproduces its partner to within a few grey levels. Shading is Lambertian with a fixed sun,
constant over each planar face: it does not depend on the viewpoint either.

A material function returns a pattern colour and up to two noise layers, which the kernel
applies with the only two calls to the fractal noise: ``albedo = pattern * (1 + a1 * n1) +
a2 * n2 * axis``. Few call sites keep the compile time of this kernel short.
"""

from __future__ import annotations

import math

import numpy as np

from skyrecon.sim._jit import jit

# Materials (``City.box_material`` / ``City.cyl_material``).
MAT_GROUND = 0
MAT_BRICK = 1
MAT_GLASS = 2
MAT_CONCRETE = 3
MAT_PLAIN = 4
MAT_METAL = 5
MAT_FOLIAGE = 6
MAT_BARK = 7
MAT_STONE = 8
MAT_MURAL = 9
MATERIAL_NAMES = (
    "ground",
    "brick",
    "glass",
    "concrete",
    "plain",
    "metal",
    "foliage",
    "bark",
    "stone",
    "mural",
)

# ``box_params[:, 4]`` (style flags) for building materials: roof kind + 2 * window style.
ROOF_PLAIN = 0
ROOF_GRAVEL = 1
WINDOWS_PUNCHED = 0
WINDOWS_RIBBON = 2

# Ground styles (``City.ground_style``).
GROUND_CITY = 0
GROUND_PLAZA = 1
GROUND_PLAIN = 2  # the city's streets and blocks in plain greys: no markings, paving or grain
GROUND_PLAIN_PLAZA = 3  # one plain grey, barely textured (object scenes with ``plain=True``)

# Noise octaves fade from full weight at a wavelength of AA_FULL footprints to zero at AA_ZERO.
AA_ZERO = 2.0
AA_FULL = 4.0
# Half-width of the analytic tent filter for stripes, windows and cells, in footprints.
AA_TENT = 1.5

# Sun and fill light (world frame, unit vectors).
_SUN = np.array([0.48, -0.32, 0.817])
_SUN = _SUN / np.linalg.norm(_SUN)
_FILL = np.array([-0.55, 0.62, 0.56])
_FILL = _FILL / np.linalg.norm(_FILL)
SUN_X, SUN_Y, SUN_Z = float(_SUN[0]), float(_SUN[1]), float(_SUN[2])
FILL_X, FILL_Y, FILL_Z = float(_FILL[0]), float(_FILL[1]), float(_FILL[2])

# Per-octave rotation (hides the noise lattice).
_ROT_C = tuple(math.cos(0.7 * o + 0.3) for o in range(16))
_ROT_S = tuple(math.sin(0.7 * o + 0.3) for o in range(16))


@jit()
def _hash(a, b, c):
    """Uniform pseudo-random number in [0, 1) from three integers."""
    h = (a * 1597334677 + b * 843314857 + c * 1103515245 + 12345) & 0xFFFFFFFF
    h = ((h ^ (h >> 16)) * 2146121005) & 0xFFFFFFFF
    h = ((h ^ (h >> 15)) * 1288380493) & 0xFFFFFFFF
    h = h ^ (h >> 16)
    return h / 4294967296.0


@jit()
def _vnoise(x, y, seed, period):
    """Value noise in [-1, 1] on the unit lattice, quintic interpolation; x wraps every ``period`` cells if > 0."""
    fx = math.floor(x)
    fy = math.floor(y)
    ix = np.int64(fx)
    iy = np.int64(fy)
    tx = x - fx
    ty = y - fy
    sx = tx * tx * tx * (tx * (tx * 6.0 - 15.0) + 10.0)
    sy = ty * ty * ty * (ty * (ty * 6.0 - 15.0) + 10.0)
    ix1 = ix + 1
    if period > 0:
        ix = ix % period
        ix1 = ix1 % period
    v00 = _hash(ix, iy, seed)
    v10 = _hash(ix1, iy, seed)
    v01 = _hash(ix, iy + 1, seed)
    v11 = _hash(ix1, iy + 1, seed)
    a = v00 + (v10 - v00) * sx
    b = v01 + (v11 - v01) * sx
    return 2.0 * (a + (b - a) * sy) - 1.0


@jit()
def _fbm(u, v, wavelength, octaves, gain, fp, seed, circ):
    """Band-limited fractal value noise, roughly in [-1, 1] (standard deviation about 0.3).

    Args:
        u, v: surface coordinates, metres.
        wavelength: lattice spacing of the coarsest octave, metres (halved per octave).
        octaves: at most this many octaves.
        gain: amplitude ratio between successive octaves.
        fp: pixel footprint at the point, metres; octaves finer than ~1.5 fp are dropped.
        seed: integer seed.
        circ: if > 0, u wraps around with this circumference (cylinder sides), metres.
    """
    total = 0.0
    amp = 1.0
    wl = wavelength
    for o in range(min(octaves, 16)):
        w = min(max((wl / fp - AA_ZERO) / (AA_FULL - AA_ZERO), 0.0), 1.0)
        if w <= 0.0:
            break
        s = seed * 7919 + o * 131
        if circ > 0.0:
            p = max(1, int(round(circ / wl)))
            total += amp * w * _vnoise(u * p / circ, v / wl + 0.37 * o, s, p)
        else:
            x = (_ROT_C[o] * u - _ROT_S[o] * v) / wl + 17.31 * o
            y = (_ROT_S[o] * u + _ROT_C[o] * v) / wl - 9.87 * o
            total += amp * w * _vnoise(x, y, s, 0)
        amp *= gain
        wl *= 0.5
    return total * (1.0 - gain) / (1.0 - gain ** min(octaves, 16))


@jit()
def _pulse_i2(x, period, a, b):
    """Second antiderivative (from 0) of the periodic indicator of ``a <= (x mod period) < b``."""
    n = math.floor(x / period)
    r = x - n * period
    L = b - a
    full = period * L * n * (n - 1) * 0.5 + n * (0.5 * L * L + L * (period - b))
    if r < a:
        part = 0.0
    elif r < b:
        part = 0.5 * (r - a) * (r - a)
    else:
        part = 0.5 * L * L + L * (r - b)
    return full + n * L * r + part


@jit()
def _pulse(x, period, a, b, w):
    """Periodic pulse train (1 on [a, b) of every period) filtered with a tent of half-width w; in [0, 1].

    The tent (a box convolved with itself) keeps edges smooth enough that bilinear resampling
    and small viewpoint changes reproduce them.
    """
    if w <= 1e-9:
        r = x - math.floor(x / period) * period
        return 1.0 if (r >= a and r < b) else 0.0
    v = (
        _pulse_i2(x + w, period, a, b) - 2.0 * _pulse_i2(x, period, a, b) + _pulse_i2(x - w, period, a, b)
    ) / (w * w)
    return min(max(v, 0.0), 1.0)


@jit()
def _tent_cdf(s, h):
    """Fraction of a tent of half-width h (centred at 0) lying below s."""
    if s <= -h:
        return 0.0
    if s <= 0.0:
        return 0.5 * (s + h) * (s + h) / (h * h)
    if s < h:
        return 1.0 - 0.5 * (h - s) * (h - s) / (h * h)
    return 1.0


@jit()
def _cellval(u, v, cw, ch, w, seed, bond):
    """A random value in [0, 1) per cell of a (cw x ch) grid, tent-filtered with half-width w.

    With ``bond`` = 1 every odd row is shifted by half a cell (brick bond). Cells smaller than
    the footprint average towards 0.5, as their mean would.
    """
    size = min(cw, ch)
    h = min(w, 0.5 * size)
    if h <= 1e-9:
        j = math.floor(v / ch)
        shift = 0.5 * cw * (j % 2) * bond
        total = _hash(np.int64(math.floor((u + shift) / cw)), np.int64(j), seed)
    else:
        total = 0.0
        j0 = math.floor((v - h) / ch)
        for j in range(j0, j0 + 2):
            wy = _tent_cdf((j + 1) * ch - v, h) - _tent_cdf(j * ch - v, h)
            if wy <= 0.0:
                continue
            us = u + 0.5 * cw * (j % 2) * bond
            i0 = math.floor((us - h) / cw)
            for i in range(i0, i0 + 2):
                wx = _tent_cdf((i + 1) * cw - us, h) - _tent_cdf(i * cw - us, h)
                if wx > 0.0:
                    total += wx * wy * _hash(np.int64(i), np.int64(j), seed)
    if w > 0.5 * size:
        total = 0.5 + (total - 0.5) * min(1.0, 0.5 * size / w)
    return total


@jit()
def _surface(mat, face, u, v, fp, seed, ar, ag, ab, cr, cg, cb, floor_h, col_p, wf, hf, style, scale):
    """Pattern colour and noise layers of an obstacle surface at face coordinates (u, v), metres.

    Returns:
        (r, g, b, wl1, oct1, a1, wl2, a2, xr, xg, xb): pattern albedo; layer 1 (luminance noise of
        wavelength wl1 metres, oct1 octaves, amplitude a1); layer 2 (colour noise of wavelength wl2,
        amplitude a2 along the colour axis x).
    """
    w = AA_TENT * fp
    building = mat == MAT_BRICK or mat == MAT_GLASS or mat == MAT_CONCRETE or mat == MAT_PLAIN
    if building and face == 5:
        base = 0.42 + 0.2 * _hash(seed, np.int64(3), np.int64(9))
        if (int(style) % 2) == ROOF_PLAIN:
            return base * 1.02, base, base * 0.97, 12.0, 2, 0.015, 0.0, 0.0, 0.0, 0.0, 0.0
        return base * 1.05, base, base * 0.92, 2.0, 7, 0.25, 0.0, 0.0, 0.0, 0.0, 0.0
    if building and face == 4:
        return 0.3 * ar, 0.3 * ag, 0.3 * ab, 0.0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if mat == MAT_PLAIN:
        return ar, ag, ab, 9.0, 2, 0.02, 0.0, 0.0, 0.0, 0.0, 0.0
    if mat == MAT_GLASS:
        mull = 0.07
        m = _pulse(u, col_p, mull, col_p - mull, w) * _pulse(v, floor_h, 1.3 * mull, floor_h - 1.3 * mull, w)
        k = m * (0.65 + 0.7 * _cellval(u, v, col_p, floor_h, w, seed, 0.0))
        return (
            cr * (1.0 - m) + ar * k,
            cg * (1.0 - m) + ag * k,
            cb * (1.0 - m) + ab * k,
            7.0,
            4,
            0.2,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
        )
    if building:
        if mat == MAT_BRICK:
            bw = 0.24 * scale
            bh = 0.08 * scale
            mo = 0.012 * scale
            row = math.floor(v / bh)
            uo = u + 0.5 * bw * (row % 2)
            mortar = 1.0 - _pulse(uo, bw, mo, bw - mo, w) * _pulse(v, bh, mo, bh, w)
            # thin lines alias even when filtered: fade them to their mean as the bricks shrink
            fb = min(max((bh / fp - 2.0) / 2.0, 0.0), 1.0)
            mortar = fb * mortar + (1.0 - fb) * (1.0 - (1.0 - 2.0 * mo / bw) * (1.0 - mo / bh))
            kb = (0.88 + 0.24 * _cellval(u, v, bw, bh, w, seed + 11, 1.0)) * (1.0 - mortar)
            wr = ar * kb + 0.62 * mortar
            wg = ag * kb + 0.6 * mortar
            wb = ab * kb + 0.56 * mortar
            wl1 = 3.0
            oct1 = 7
            a1 = 0.2
        else:
            joint = 1.0 - 0.25 * (1.0 - _pulse(v, floor_h, 0.05, floor_h, w))
            wr = ar * joint
            wg = ag * joint
            wb = ab * joint
            wl1 = 4.0
            oct1 = 8
            a1 = 0.16
        if (int(style) // 2) * 2 == WINDOWS_RIBBON:
            av = floor_h * (1.0 - hf) * 0.55
            mv = _pulse(v, floor_h, av, av + floor_h * hf, w)
            mm = 1.0 - _pulse(u, col_p, 0.06, col_p - 0.06, w)
            g = 0.55 + 0.8 * _cellval(u, v, col_p, floor_h, w, seed + 5, 0.0)
            gr = 0.16 * g * (1.0 - mm) + cr * mm
            gg = 0.2 * g * (1.0 - mm) + cg * mm
            gb = 0.26 * g * (1.0 - mm) + cb * mm
            return (
                wr * (1.0 - mv) + gr * mv,
                wg * (1.0 - mv) + gg * mv,
                wb * (1.0 - mv) + gb * mv,
                wl1,
                oct1,
                a1,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
            )
        # punched windows with frames
        a = 0.5 * col_p * (1.0 - wf)
        av = floor_h * (1.0 - hf) * 0.6
        m_out = _pulse(u, col_p, a, col_p - a, w) * _pulse(v, floor_h, av, av + floor_h * hf, w)
        a2 = 0.5 * col_p * (1.0 - 0.78 * wf)
        av2 = av + 0.08 * floor_h * hf
        m_in = _pulse(u, col_p, a2, col_p - a2, w) * _pulse(v, floor_h, av2, av2 + 0.84 * floor_h * hf, w)
        frame = max(m_out - m_in, 0.0)
        r = _cellval(u, v, col_p, floor_h, w, seed + 7, 0.0)
        r2 = _cellval(u, v, col_p, floor_h, w, seed + 8, 0.0)
        g = 0.5 + 0.9 * r
        gr = 0.15 * g + 0.25 * r2 * r2
        gg = 0.18 * g + 0.2 * r2 * r2
        gb = 0.24 * g + 0.1 * r2 * r2
        rest = 1.0 - m_out
        return (
            wr * rest + cr * frame + gr * m_in,
            wg * rest + cg * frame + gg * m_in,
            wb * rest + cb * frame + gb * m_in,
            wl1,
            oct1,
            a1,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
        )
    if mat == MAT_FOLIAGE:
        return ar, ag, ab, 1.6 * scale, 8, 0.55, 4.0 * scale, 0.25, 0.6 * ar, 0.1 * ag, -0.5 * ab
    if mat == MAT_BARK:
        return ar, ag, ab, 0.5 * scale, 6, 0.35, 0.0, 0.0, 0.0, 0.0, 0.0
    if mat == MAT_METAL:
        k = 1.0 - 0.25 * _pulse(v, 2.0 * scale, 0.0, 0.15 * scale, w)
        return ar * k, ag * k, ab * k, 1.5 * scale, 5, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0
    if mat == MAT_STONE:
        bw = 0.6 * scale
        bh = 0.3 * scale
        jt = 0.015 * scale
        row = math.floor(v / bh)
        uo = u + 0.5 * bw * (row % 2)
        joint = 1.0 - _pulse(uo, bw, jt, bw - jt, w) * _pulse(v, bh, jt, bh, w)
        fb = min(max((bh / fp - 2.0) / 2.0, 0.0), 1.0)
        joint = fb * joint + (1.0 - fb) * (1.0 - (1.0 - 2.0 * jt / bw) * (1.0 - jt / bh))
        k = (0.8 + 0.4 * _cellval(u, v, bw, bh, w, seed + 13, 1.0)) * (1.0 - 0.45 * joint)
        return ar * k, ag * k, ab * k, 0.5 * scale, 8, 0.25, 2.0 * scale, 0.1, 0.3, 0.1, -0.3
    if mat == MAT_MURAL:
        t = 0.4 * scale
        gt = 0.02 * scale
        grout = 1.0 - _pulse(u, t, gt, t, w) * _pulse(v, t, gt, t, w)
        fb = min(max((t / fp - 2.0) / 2.0, 0.0), 1.0)
        k = 1.0 - 0.5 * (fb * grout + (1.0 - fb) * (1.0 - (1.0 - gt / t) ** 2))
        tl = _cellval(u, v, t, t, w, seed + 17, 0.0) - 0.5
        th = _cellval(u, v, t, t, w, seed + 18, 0.0) - 0.5
        return (
            (ar + 0.35 * tl + 0.2 * th) * k,
            (ag + 0.35 * tl - 0.05 * th) * k,
            (ab + 0.35 * tl - 0.2 * th) * k,
            0.9 * scale,
            7,
            0.3,
            3.0 * scale,
            0.35,
            0.5,
            -0.1,
            -0.4,
        )
    return ar, ag, ab, 0.0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0


@jit()
def _ground_plain(x, y, inside, blocks_x, blocks_y):
    """``GROUND_PLAIN``: plain greys with faint shading of 9 m wavelength (asphalt, blocks, verge)."""
    if not inside:
        return 0.4, 0.41, 0.39, 9.0, 2, 0.02, 0.0, 0.0, 0.0, 0.0, 0.0
    for i in range(blocks_x.shape[0]):
        if x >= blocks_x[i, 0] and x < blocks_x[i, 1]:
            for k in range(blocks_y.shape[0]):
                if y >= blocks_y[k, 0] and y < blocks_y[k, 1]:
                    return 0.55, 0.55, 0.53, 9.0, 2, 0.02, 0.0, 0.0, 0.0, 0.0, 0.0
    return 0.36, 0.36, 0.37, 9.0, 2, 0.02, 0.0, 0.0, 0.0, 0.0, 0.0


@jit()
def _ground(x, y, fp, style, seed, blocks_x, blocks_y, extent, sidewalk):
    """Pattern colour and noise layers of the ground at world (x, y), metres (same tuple as ``_surface``)."""
    w = AA_TENT * fp
    if style == GROUND_PLAIN_PLAZA:  # plain grey everywhere: only a faint shading of 12 m wavelength
        return 0.5, 0.5, 0.49, 12.0, 2, 0.02, 0.0, 0.0, 0.0, 0.0, 0.0
    inside = x >= extent[0] and x <= extent[2] and y >= extent[1] and y <= extent[3]
    if style == GROUND_PLAZA and inside:
        t = 0.5
        row = math.floor(y / t)
        xo = x + 0.5 * t * (row % 2)
        grout = 1.0 - _pulse(xo, t, 0.02, t, w) * _pulse(y, t, 0.02, t, w)
        fb = min(max((t / fp - 2.0) / 2.0, 0.0), 1.0)
        grout = fb * grout + (1.0 - fb) * (1.0 - (1.0 - 0.02 / t) ** 2)
        k = (0.8 + 0.4 * _cellval(x, y, t, t, w, seed + 31, 1.0)) * (1.0 - 0.35 * grout)
        return 0.62 * k, 0.58 * k, 0.52 * k, 0.8, 8, 0.22, 3.0, 0.08, 0.3, 0.1, -0.2
    if style == GROUND_PLAIN:
        return _ground_plain(x, y, inside, blocks_x, blocks_y)
    if not inside:
        return 0.3, 0.42, 0.2, 6.0, 9, 0.3, 25.0, 0.1, 0.3, 0.0, -0.2
    # which block column / row are we in (or which street)?
    bxi = -1
    for i in range(blocks_x.shape[0]):
        if x >= blocks_x[i, 0] and x < blocks_x[i, 1]:
            bxi = i
    byi = -1
    for i in range(blocks_y.shape[0]):
        if y >= blocks_y[i, 0] and y < blocks_y[i, 1]:
            byi = i
    if bxi >= 0 and byi >= 0:
        e = min(x - blocks_x[bxi, 0], blocks_x[bxi, 1] - x, y - blocks_y[byi, 0], blocks_y[byi, 1] - y)
        if e < sidewalk:
            t = 1.2
            grout = 1.0 - _pulse(x, t, 0.03, t, w) * _pulse(y, t, 0.03, t, w)
            kerb = _pulse(e + 1.0, 1000.0, 1.0, 1.25, w)
            k = (
                (0.9 + 0.2 * _cellval(x, y, t, t, w, seed + 50, 0.0))
                * (1.0 - 0.25 * grout)
                * (1.0 - 0.3 * kerb)
            )
            return 0.66 * k, 0.64 * k, 0.6 * k, 1.5, 8, 0.12, 0.0, 0.0, 0.0, 0.0, 0.0
        if _hash(np.int64(bxi), np.int64(byi), seed + 51) < 0.5:
            return 0.28, 0.45, 0.18, 3.0, 9, 0.35, 8.0, 0.1, 0.3, 0.0, -0.2
        return 0.6, 0.55, 0.48, 2.0, 8, 0.15, 0.0, 0.0, 0.0, 0.0, 0.0
    # asphalt with markings
    mark = 0.0
    if bxi >= 0 and byi < 0:  # a street along x, between block rows
        lo = extent[1]
        hi = extent[3]
        for i in range(blocks_y.shape[0]):
            if blocks_y[i, 1] <= y and blocks_y[i, 1] > lo:
                lo = blocks_y[i, 1]
            if blocks_y[i, 0] > y and blocks_y[i, 0] < hi:
                hi = blocks_y[i, 0]
        c = 0.5 * (lo + hi)
        mark = _pulse(y - c + 100.0, 1000.0, 100.0 - 0.08, 100.0 + 0.08, w) * _pulse(x, 6.0, 0.0, 3.0, w)
        x0 = blocks_x[bxi, 0]
        x1 = blocks_x[bxi, 1]
        zone = _pulse(x - x0 + 100.0, 1000.0, 100.8, 103.8, w) + _pulse(
            x1 - x + 100.0, 1000.0, 100.8, 103.8, w
        )
        zebra = (
            zone
            * _pulse(y - c, 1.0, 0.0, 0.5, w)
            * _pulse(y - lo + 100.0, 1000.0, 101.0, 100.0 + hi - lo - 1.0, w)
        )
        mark = max(mark, zebra)
    elif byi >= 0 and bxi < 0:  # a street along y
        lo = extent[0]
        hi = extent[2]
        for i in range(blocks_x.shape[0]):
            if blocks_x[i, 1] <= x and blocks_x[i, 1] > lo:
                lo = blocks_x[i, 1]
            if blocks_x[i, 0] > x and blocks_x[i, 0] < hi:
                hi = blocks_x[i, 0]
        c = 0.5 * (lo + hi)
        mark = _pulse(x - c + 100.0, 1000.0, 100.0 - 0.08, 100.0 + 0.08, w) * _pulse(y, 6.0, 0.0, 3.0, w)
        y0 = blocks_y[byi, 0]
        y1 = blocks_y[byi, 1]
        zone = _pulse(y - y0 + 100.0, 1000.0, 100.8, 103.8, w) + _pulse(
            y1 - y + 100.0, 1000.0, 100.8, 103.8, w
        )
        zebra = (
            zone
            * _pulse(x - c, 1.0, 0.0, 0.5, w)
            * _pulse(x - lo + 100.0, 1000.0, 101.0, 100.0 + hi - lo - 1.0, w)
        )
        mark = max(mark, zebra)
    r = 0.3 * (1.0 - mark) + 0.82 * mark
    b = 0.32 * (1.0 - mark) + 0.66 * mark
    # coarse patches (layer 1) and fine grain (layer 2)
    return r, r, b, 5.0, 10, 0.25, 0.25, 0.25, r, r, b


@jit()
def shade(
    start,
    stop,
    origin,
    dirs,
    rot,
    t,
    kind,
    index,
    face,
    inv_f,
    seed,
    boxes,
    box_mat,
    box_alb,
    box_acc,
    box_par,
    cyls,
    cyl_mat,
    cyl_alb,
    cyl_acc,
    cyl_par,
    blocks_x,
    blocks_y,
    extent,
    sidewalk,
    ground_style,
    out_rgb,
    out_depth,
    out_normal,
    out_id,
):
    """Colour, normal and object id of pixels ``start .. stop-1``.

    Args:
        origin: (3,) camera centre, world frame, metres.
        dirs: (P, 3) camera-frame ray directions with z = 1 (so t is z-depth); ``rot`` (3, 3) is the
            camera-to-world rotation.
        t, kind, index, face: (P,) hits from ``raycast.trace_rays``.
        inv_f: 1 / focal length in pixels: a pixel at z-depth z spans about ``z * inv_f`` metres.
        seed: the city's seed.
        out_rgb: (P, 3) uint8 RGB; out_depth: (P,) float32 t (NaN for sky);
        out_normal: (P, 3) float32 world normals (NaN for sky);
        out_id: (P,) int32: -1 sky, 0 ground, 1 + box index, 1 + N_boxes + cylinder index.
    """
    nb = boxes.shape[0]
    for i in range(start, stop):
        ca, cb, cc = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        dx = rot[0, 0] * ca + rot[0, 1] * cb + rot[0, 2] * cc
        dy = rot[1, 0] * ca + rot[1, 1] * cb + rot[1, 2] * cc
        dz = rot[2, 0] * ca + rot[2, 1] * cb + rot[2, 2] * cc
        k = kind[i]
        dl = math.sqrt(dx * dx + dy * dy + dz * dz)
        if k == 0:
            e = math.sqrt(min(max(dz / dl, 0.0), 1.0))
            out_rgb[i, 0] = np.uint8(255.0 * (0.78 - 0.38 * e) + 0.5)
            out_rgb[i, 1] = np.uint8(255.0 * (0.85 - 0.28 * e) + 0.5)
            out_rgb[i, 2] = np.uint8(255.0 * (0.93 - 0.12 * e) + 0.5)
            out_depth[i] = np.nan
            out_normal[i, 0] = np.nan
            out_normal[i, 1] = np.nan
            out_normal[i, 2] = np.nan
            out_id[i] = -1
            continue
        tt = t[i]
        out_depth[i] = tt
        x = origin[0] + tt * dx
        y = origin[1] + tt * dy
        z = origin[2] + tt * dz
        f = face[i]
        j = index[i]
        nx = 0.0
        ny = 0.0
        nz = 0.0
        circ = 0.0
        u = x
        v = y
        if k == 1:
            nz = 1.0
        elif k == 2:
            if f < 4:
                if f == 0:
                    nx = -1.0
                    u = boxes[j, 4] - y
                elif f == 1:
                    nx = 1.0
                    u = y - boxes[j, 1]
                elif f == 2:
                    ny = -1.0
                    u = x - boxes[j, 0]
                else:
                    ny = 1.0
                    u = boxes[j, 3] - x
                v = z - boxes[j, 2]
                p = box_par[j, 1]
                if p > 0.0:  # centre the window columns on the facade
                    span = boxes[j, 4] - boxes[j, 1] if f < 2 else boxes[j, 3] - boxes[j, 0]
                    u -= 0.5 * (span - math.floor(span / p) * p)
            elif f == 4:
                nz = -1.0
            else:
                nz = 1.0
        else:
            if f == 6:
                r = cyls[j, 2]
                nx = x - cyls[j, 0]
                ny = y - cyls[j, 1]
                nn = math.sqrt(nx * nx + ny * ny)
                nx /= nn
                ny /= nn
                circ = 2.0 * math.pi * r
                u = (math.atan2(ny, nx) + math.pi) * r
                v = z - cyls[j, 3]
            elif f == 7:
                nz = 1.0
            else:
                nz = -1.0
        cosi = abs(nx * dx + ny * dy + nz * dz) / dl
        fp = tt * inv_f / max(cosi, 0.08)
        if k == 1:
            ar, ag, ab, wl1, oct1, a1, wl2, a2, xr, xg, xb = _ground(
                x, y, fp, ground_style, seed, blocks_x, blocks_y, extent, sidewalk
            )
            out_id[i] = 0
            s = seed * 1000003
        elif k == 2:
            s = seed * 1000003 + j * 7 + 1
            ar, ag, ab, wl1, oct1, a1, wl2, a2, xr, xg, xb = _surface(
                box_mat[j],
                f,
                u,
                v,
                fp,
                s,
                box_alb[j, 0],
                box_alb[j, 1],
                box_alb[j, 2],
                box_acc[j, 0],
                box_acc[j, 1],
                box_acc[j, 2],
                box_par[j, 0],
                box_par[j, 1],
                box_par[j, 2],
                box_par[j, 3],
                box_par[j, 4],
                box_par[j, 5],
            )
            out_id[i] = 1 + j
        else:
            s = seed * 1000003 + (nb + j) * 7 + 1
            ar, ag, ab, wl1, oct1, a1, wl2, a2, xr, xg, xb = _surface(
                cyl_mat[j],
                f,
                u,
                v,
                fp,
                s,
                cyl_alb[j, 0],
                cyl_alb[j, 1],
                cyl_alb[j, 2],
                cyl_acc[j, 0],
                cyl_acc[j, 1],
                cyl_acc[j, 2],
                cyl_par[j, 0],
                cyl_par[j, 1],
                cyl_par[j, 2],
                cyl_par[j, 3],
                cyl_par[j, 4],
                cyl_par[j, 5],
            )
            out_id[i] = 1 + nb + j
        if a1 > 0.0:
            m = 1.0 + a1 * _fbm(u, v, wl1, oct1, 0.6, fp, s + 17, circ)
            ar *= m
            ag *= m
            ab *= m
        if a2 > 0.0:
            m = a2 * _fbm(u, v, wl2, 3, 0.5, fp, s + 29, circ)
            ar += m * xr
            ag += m * xg
            ab += m * xb
        li = (
            0.38
            + 0.62 * max(nx * SUN_X + ny * SUN_Y + nz * SUN_Z, 0.0)
            + 0.18 * max(nx * FILL_X + ny * FILL_Y + nz * FILL_Z, 0.0)
        )
        out_rgb[i, 0] = np.uint8(min(max(ar * li * 255.0 + 0.5, 0.0), 255.0))
        out_rgb[i, 1] = np.uint8(min(max(ag * li * 255.0 + 0.5, 0.0), 255.0))
        out_rgb[i, 2] = np.uint8(min(max(ab * li * 255.0 + 0.5, 0.0), 255.0))
        out_normal[i, 0] = nx
        out_normal[i, 1] = ny
        out_normal[i, 2] = nz
