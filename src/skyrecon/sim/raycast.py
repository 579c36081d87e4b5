"""Numba kernels: ray casting through the uniform grid and signed distances to obstacles.

Hit kinds: 0 nothing, 1 ground plane z = 0, 2 box, 3 cylinder.
Box faces: 0 -x, 1 +x, 2 -y, 3 +y, 4 -z (bottom), 5 +z (top). Cylinder faces: 6 side,
7 top cap, 8 bottom cap. The ground reports face 5.
"""

from __future__ import annotations

import math

import numpy as np

from skyrecon.sim._jit import jit

TINY = 1e-30


@jit()
def _hit_box(boxes, k, ox, oy, oz, ix, iy, iz, t_lo, t_hi):
    """Entry distance of the ray into box k within [t_lo, t_hi), and the entry face; (inf, -1) if none."""
    t1 = (boxes[k, 0] - ox) * ix
    t2 = (boxes[k, 3] - ox) * ix
    if t1 <= t2:
        tn, tf, fn = t1, t2, 0
    else:
        tn, tf, fn = t2, t1, 1
    t1 = (boxes[k, 1] - oy) * iy
    t2 = (boxes[k, 4] - oy) * iy
    if t1 <= t2:
        a, b, f = t1, t2, 2
    else:
        a, b, f = t2, t1, 3
    if a > tn:
        tn, fn = a, f
    if b < tf:
        tf = b
    t1 = (boxes[k, 2] - oz) * iz
    t2 = (boxes[k, 5] - oz) * iz
    if t1 <= t2:
        a, b, f = t1, t2, 4
    else:
        a, b, f = t2, t1, 5
    if a > tn:
        tn, fn = a, f
    if b < tf:
        tf = b
    if tn <= tf and tn >= t_lo and tn < t_hi:
        return tn, fn
    return np.inf, -1


@jit()
def _hit_cyl(cyls, k, ox, oy, oz, dx, dy, dz, t_lo, t_hi):
    """Entry distance of the ray into vertical cylinder k within [t_lo, t_hi) and the face; (inf, -1) if none."""
    cx, cy, r, z0, z1 = cyls[k, 0], cyls[k, 1], cyls[k, 2], cyls[k, 3], cyls[k, 4]
    px = ox - cx
    py = oy - cy
    best = t_hi
    face = -1
    a = dx * dx + dy * dy
    if a > 0.0:
        b = px * dx + py * dy
        c = px * px + py * py - r * r
        disc = b * b - a * c
        if disc >= 0.0:
            sq = math.sqrt(disc)
            q = -(b + sq) if b >= 0.0 else sq - b
            if q != 0.0:
                ta = q / a
                tb = c / q
                tn = ta if ta < tb else tb
                if tn >= t_lo and tn < best:
                    z = oz + tn * dz
                    if z >= z0 and z <= z1:
                        best = tn
                        face = 6
    if dz < 0.0:
        t = (z1 - oz) / dz
        if t >= t_lo and t < best:
            hx = px + t * dx
            hy = py + t * dy
            if hx * hx + hy * hy <= r * r:
                best = t
                face = 7
    elif dz > 0.0:
        t = (z0 - oz) / dz
        if t >= t_lo and t < best:
            hx = px + t * dx
            hy = py + t * dy
            if hx * hx + hy * hy <= r * r:
                best = t
                face = 8
    if face < 0:
        return np.inf, -1
    return best, face


@jit()
def _trace_one(  # noqa: C901  (Numba kernel: one flat loop nest)
    ox,
    oy,
    oz,
    dx,
    dy,
    dz,
    t_lo,
    t_hi,
    ground,
    boxes,
    cyls,
    gx0,
    gy0,
    cs,
    ncx,
    ncy,
    gz_lo,
    gz_hi,
    cell_start,
    cell_items,
    cell_zmax,
):
    """Closest hit of one ray; returns (t, kind, index, face) with t = inf when nothing is hit."""
    if abs(dx) < TINY:
        dx = TINY
    if abs(dy) < TINY:
        dy = TINY
    if abs(dz) < TINY:
        dz = TINY
    best = t_hi
    kind = 0
    index = -1
    face = -1
    if ground and dz < 0.0 and oz >= 0.0:
        tg = -oz / dz
        if tg >= t_lo and tg < best:
            best = tg
            kind = 1
            index = 0
            face = 5
    nb = boxes.shape[0]
    if cell_items.shape[0] == 0:
        if kind == 0:
            return np.inf, 0, -1, -1
        return best, kind, index, face
    ix_ = 1.0 / dx
    iy_ = 1.0 / dy
    iz_ = 1.0 / dz
    # clip the ray to the grid's bounding box
    gx1 = gx0 + ncx * cs
    gy1 = gy0 + ncy * cs
    a = (gx0 - ox) * ix_
    b = (gx1 - ox) * ix_
    ta = min(a, b)
    tb = max(a, b)
    a = (gy0 - oy) * iy_
    b = (gy1 - oy) * iy_
    ta = max(ta, min(a, b))
    tb = min(tb, max(a, b))
    a = (gz_lo - oz) * iz_
    b = (gz_hi - oz) * iz_
    ta = max(ta, min(a, b))
    tb = min(tb, max(a, b))
    ta = max(ta, t_lo)
    tb = min(tb, best)
    if ta <= tb:
        px = ox + ta * dx
        py = oy + ta * dy
        cx = int(math.floor((px - gx0) / cs))
        cy = int(math.floor((py - gy0) / cs))
        cx = min(max(cx, 0), ncx - 1)
        cy = min(max(cy, 0), ncy - 1)
        if dx > 0.0:
            sx = 1
            tmx = (gx0 + (cx + 1) * cs - ox) * ix_
        else:
            sx = -1
            tmx = (gx0 + cx * cs - ox) * ix_
        if dy > 0.0:
            sy = 1
            tmy = (gy0 + (cy + 1) * cs - oy) * iy_
        else:
            sy = -1
            tmy = (gy0 + cy * cs - oy) * iy_
        tdx = cs * abs(ix_)
        tdy = cs * abs(iy_)
        t_enter = ta
        while True:
            t_exit = min(tmx, tmy, tb)
            c = cy * ncx + cx
            za = oz + t_enter * dz
            zb = oz + t_exit * dz
            if min(za, zb) <= cell_zmax[c]:
                for j in range(cell_start[c], cell_start[c + 1]):
                    it = cell_items[j]
                    if it < nb:
                        t, f = _hit_box(boxes, it, ox, oy, oz, ix_, iy_, iz_, t_lo, best)
                        if f >= 0:
                            best = t
                            kind = 2
                            index = it
                            face = f
                    else:
                        t, f = _hit_cyl(cyls, it - nb, ox, oy, oz, dx, dy, dz, t_lo, best)
                        if f >= 0:
                            best = t
                            kind = 3
                            index = it - nb
                            face = f
            if best <= t_exit or t_exit >= tb:
                break
            if tmx < tmy:
                cx += sx
                if cx < 0 or cx >= ncx:
                    break
                t_enter = tmx
                tmx += tdx
            else:
                cy += sy
                if cy < 0 or cy >= ncy:
                    break
                t_enter = tmy
                tmy += tdy
    if kind == 0:
        return np.inf, 0, -1, -1
    return best, kind, index, face


@jit()
def trace_rays(
    start,
    stop,
    origins,
    dirs,
    rot,
    t_lo,
    t_hi,
    ground,
    boxes,
    cyls,
    gx0,
    gy0,
    cs,
    ncx,
    ncy,
    gz_lo,
    gz_hi,
    cell_start,
    cell_items,
    cell_zmax,
    out_t,
    out_kind,
    out_index,
    out_face,
):
    """Cast rays ``start .. stop-1`` of N: ``origin + t * dir`` (t in [t_lo, t_hi)); write the first hit of each.

    Args:
        origins: (N, 3) or (1, 3) world points, metres (one row is shared by every ray).
        dirs: (N, 3) directions (any length; t is in units of that length) in a frame rotated
            into the world by ``rot`` (3, 3): ``d_world = rot @ d`` (identity for world directions).
        ground: whether the plane z = 0 is solid.
        out_t: (N,) float64 hit parameter, inf for a miss; out_kind, out_index, out_face: (N,) int32.
    """
    shared = origins.shape[0] == 1
    for i in range(start, stop):
        if shared:
            ox, oy, oz = origins[0, 0], origins[0, 1], origins[0, 2]
        else:
            ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        a, b, c = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        dx = rot[0, 0] * a + rot[0, 1] * b + rot[0, 2] * c
        dy = rot[1, 0] * a + rot[1, 1] * b + rot[1, 2] * c
        dz = rot[2, 0] * a + rot[2, 1] * b + rot[2, 2] * c
        t, kind, index, face = _trace_one(
            ox,
            oy,
            oz,
            dx,
            dy,
            dz,
            t_lo,
            t_hi,
            ground,
            boxes,
            cyls,
            gx0,
            gy0,
            cs,
            ncx,
            ncy,
            gz_lo,
            gz_hi,
            cell_start,
            cell_items,
            cell_zmax,
        )
        out_t[i] = t
        out_kind[i] = kind
        out_index[i] = index
        out_face[i] = face


@jit()
def _sdf_box(boxes, k, x, y, z):
    qx = max(boxes[k, 0] - x, x - boxes[k, 3])
    qy = max(boxes[k, 1] - y, y - boxes[k, 4])
    qz = max(boxes[k, 2] - z, z - boxes[k, 5])
    ox = max(qx, 0.0)
    oy = max(qy, 0.0)
    oz = max(qz, 0.0)
    return math.sqrt(ox * ox + oy * oy + oz * oz) + min(max(qx, qy, qz), 0.0)


@jit()
def _sdf_cyl(cyls, k, x, y, z):
    ddx = x - cyls[k, 0]
    ddy = y - cyls[k, 1]
    qr = math.sqrt(ddx * ddx + ddy * ddy) - cyls[k, 2]
    qz = max(cyls[k, 3] - z, z - cyls[k, 4])
    a = max(qr, 0.0)
    b = max(qz, 0.0)
    return math.sqrt(a * a + b * b) + min(max(qr, qz), 0.0)


@jit()
def signed_distance(
    start, stop, points, ground, boxes, cyls, gx0, gy0, cs, ncx, ncy, cell_start, cell_items, out
):
    """Signed distance of points ``start .. stop-1`` of (N, 3) to the union of obstacles, metres (< 0 inside).

    Searches rings of grid cells around each point until no unvisited cell can hold anything closer.
    With ``ground`` the half-space z <= 0 is an obstacle too. inf when there is nothing at all.
    """
    nb = boxes.shape[0]
    nitems = cell_items.shape[0]
    for i in range(start, stop):
        x = points[i, 0]
        y = points[i, 1]
        z = points[i, 2]
        best = np.inf
        if ground:
            best = z
        if nitems > 0:
            cx = min(max(int(math.floor((x - gx0) / cs)), 0), ncx - 1)
            cy = min(max(int(math.floor((y - gy0) / cs)), 0), ncy - 1)
            max_ring = max(cx, ncx - 1 - cx, cy, ncy - 1 - cy)
            for ring in range(max_ring + 1):
                for jy in range(cy - ring, cy + ring + 1):
                    if jy < 0 or jy >= ncy:
                        continue
                    edge_row = jy == cy - ring or jy == cy + ring
                    step = 1 if edge_row else 2 * ring
                    jx = cx - ring
                    while jx <= cx + ring:
                        if jx >= 0 and jx < ncx:
                            c = jy * ncx + jx
                            for j in range(cell_start[c], cell_start[c + 1]):
                                it = cell_items[j]
                                if it < nb:
                                    d = _sdf_box(boxes, it, x, y, z)
                                else:
                                    d = _sdf_cyl(cyls, it - nb, x, y, z)
                                if d < best:
                                    best = d
                        jx += step
                # anything not yet seen lies in rings > ring: at least ring * cs away in x or y
                if best <= ring * cs:
                    break
        out[i] = best
