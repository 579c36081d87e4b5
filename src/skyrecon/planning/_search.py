"""Numba grid search: Lazy Theta* (any-angle) or A*, 26-connected, on one level of a lattice.

Level ``f`` is the lattice of every f-th safe dual cell (see :mod:`_los`): node ``I`` sits at the
centre of dual cell ``f I``, ``u = f I + 0.5`` in dual units, and is usable when that cell is
safe. On level 1, two 26-adjacent safe cells are joined by a clear segment (it stays inside
their union), so no further check is needed; on coarser levels every edge is checked with
:func:`_los.los`. Lazy Theta* (Nash, Koenig & Tovey 2010) lets a node take its grandparent as
parent when the two see each other (:func:`_los.los` on the fine safe cells), which gives
any-angle paths whose length is close to the Euclidean shortest path, and picks the route
around obstacles by Euclidean length rather than by grid length.

Costs are Euclidean, in fine voxels; the heuristic is the Euclidean distance (Lazy Theta*) or
the 26-grid distance (A*), both consistent. Cells are flat indices
``(I * CY + J) * CZ + K``. Search state is reused across queries: ``g``, ``parent`` and
``stamp`` (reached in this query iff ``stamp >= 2 gen``, closed iff ``stamp == 2 gen + 1``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from skyrecon.planning._los import los


@njit(cache=True)
def _push(hk, hv, n, key, val):
    if n >= hk.shape[0]:
        nk = np.empty(hk.shape[0] * 2, np.float64)
        nv = np.empty(hv.shape[0] * 2, np.int64)
        nk[:n] = hk[:n]
        nv[:n] = hv[:n]
        hk = nk
        hv = nv
    i = n
    hk[i] = key
    hv[i] = val
    while i > 0:
        p = (i - 1) >> 1
        if hk[p] <= hk[i]:
            break
        hk[p], hk[i] = hk[i], hk[p]
        hv[p], hv[i] = hv[i], hv[p]
        i = p
    return hk, hv, n + 1


@njit(cache=True)
def _pop(hk, hv, n):
    val = hv[0]
    n -= 1
    hk[0] = hk[n]
    hv[0] = hv[n]
    i = 0
    while True:
        l = 2 * i + 1
        if l >= n:
            break
        r = l + 1
        m = l if (r >= n or hk[l] <= hk[r]) else r
        if hk[i] <= hk[m]:
            break
        hk[m], hk[i] = hk[i], hk[m]
        hv[m], hv[i] = hv[i], hv[m]
        i = m
    return val, n


@njit(cache=True)
def _pos(c, CY, CZ, f):
    """Node position (dual units) of flat cell c on level f."""
    I = c // (CY * CZ)
    J = (c // CZ) % CY
    K = c % CZ
    return f * I + 0.5, f * J + 0.5, f * K + 0.5


@njit(cache=True)
def _h(x, y, z, gx, gy, gz, any_angle):
    """Euclidean distance (any-angle) or 26-grid distance (A*) between two positions."""
    a = abs(x - gx)
    b = abs(y - gy)
    c = abs(z - gz)
    if any_angle:
        return np.sqrt(a * a + b * b + c * c)
    if a < b:
        a, b = b, a
    if b < c:
        b, c = c, b
    if a < b:
        a, b = b, a
    return np.sqrt(3.0) * c + np.sqrt(2.0) * (b - c) + (a - b)


@njit(cache=True)
def search(
    cells, f, fine_safe, starts, start_costs, goal, weight, any_angle, max_expansions, g, parent, stamp, gen
):
    """Search from several start cells (with initial costs, fine voxels) to the goal cell.

    Args:
        cells: (CX, CY, CZ) uint8 usable nodes of level f; fine_safe: the level-1 safe dual
            cells (for line-of-sight); weight: heuristic weight (>= 1); any_angle: Lazy Theta*
            if True, else A*; max_expansions: give up after this many (<= 0: no limit).
    Returns:
        (path (K,) int64 flat cells from a start to the goal, or empty; cost (fine voxels);
        expansions; status 0 found, 1 exhausted (no path), 2 expansion limit).
    """
    CX, CY, CZ = cells.shape
    flat = cells.reshape(-1)
    open_s = np.int32(2 * gen)
    closed_s = np.int32(2 * gen + 1)
    gx, gy, gz = _pos(goal, CY, CZ, f)
    hk = np.empty(4096, np.float64)
    hv = np.empty(4096, np.int64)
    n = 0
    tie = 1e-6
    for s in range(starts.shape[0]):
        c = starts[s]
        if stamp[c] >= open_s and g[c] <= start_costs[s]:
            continue
        g[c] = start_costs[s]
        parent[c] = -1
        stamp[c] = open_s
        x, y, z = _pos(c, CY, CZ, f)
        h = _h(x, y, z, gx, gy, gz, any_angle) * weight
        hk, hv, n = _push(hk, hv, n, start_costs[s] + h - tie * start_costs[s], c)
    offs = np.empty((26, 3), np.int64)
    step = np.empty(26, np.float64)
    m = 0
    for dx in range(-1, 2):
        for dy in range(-1, 2):
            for dz in range(-1, 2):
                if dx == 0 and dy == 0 and dz == 0:
                    continue
                offs[m, 0] = dx
                offs[m, 1] = dy
                offs[m, 2] = dz
                step[m] = f * np.sqrt(dx * dx + dy * dy + dz * dz)
                m += 1
    expansions = 0
    status = 1
    while n > 0:
        c, n = _pop(hk, hv, n)
        if stamp[c] == closed_s:
            continue
        I = c // (CY * CZ)
        J = (c // CZ) % CY
        K = c % CZ
        cx, cy, cz = _pos(c, CY, CZ, f)
        if any_angle:
            p = parent[c]
            if p >= 0:
                px, py, pz = _pos(p, CY, CZ, f)
                if not los(fine_safe, px, py, pz, cx, cy, cz):
                    # path 1: the best closed neighbour becomes the parent
                    best = np.inf
                    bp = -1
                    for k in range(26):
                        ii = I + offs[k, 0]
                        jj = J + offs[k, 1]
                        kk = K + offs[k, 2]
                        if ii < 0 or jj < 0 or kk < 0 or ii >= CX or jj >= CY or kk >= CZ:
                            continue
                        nb = (ii * CY + jj) * CZ + kk
                        if stamp[nb] != closed_s:
                            continue
                        if f > 1 and not los(fine_safe, cx, cy, cz, f * ii + 0.5, f * jj + 0.5, f * kk + 0.5):
                            continue
                        cand = g[nb] + step[k]
                        if cand < best:
                            best = cand
                            bp = nb
                    if bp >= 0:
                        g[c] = best
                        parent[c] = bp
        stamp[c] = closed_s
        if c == goal:
            status = 0
            break
        expansions += 1
        if max_expansions > 0 and expansions >= max_expansions:
            status = 2
            break
        # path 2: try to inherit this node's parent (any-angle), else this node
        p = parent[c] if any_angle else -1
        if p >= 0:
            px, py, pz = _pos(p, CY, CZ, f)
            gp = g[p]
        for k in range(26):
            ii = I + offs[k, 0]
            jj = J + offs[k, 1]
            kk = K + offs[k, 2]
            if ii < 0 or jj < 0 or kk < 0 or ii >= CX or jj >= CY or kk >= CZ:
                continue
            nb = (ii * CY + jj) * CZ + kk
            if flat[nb] == 0:
                continue
            st = stamp[nb]
            if st == closed_s:
                continue
            nx = f * ii + 0.5
            ny = f * jj + 0.5
            nz = f * kk + 0.5
            if f > 1 and not los(fine_safe, cx, cy, cz, nx, ny, nz):
                continue
            if p >= 0:
                ng = gp + np.sqrt((nx - px) ** 2 + (ny - py) ** 2 + (nz - pz) ** 2)
                newpar = p
            else:
                ng = g[c] + step[k]
                newpar = c
            if st == open_s and g[nb] <= ng:
                continue
            g[nb] = ng
            parent[nb] = newpar
            stamp[nb] = open_s
            h = _h(nx, ny, nz, gx, gy, gz, any_angle) * weight
            hk, hv, n = _push(hk, hv, n, ng + h - tie * ng, nb)
    if status != 0:
        return np.empty(0, np.int64), np.inf, expansions, status
    k = 0
    c = goal
    while c >= 0:
        k += 1
        c = parent[c]
    path = np.empty(k, np.int64)
    c = goal
    for i in range(k - 1, -1, -1):
        path[i] = c
        c = parent[c]
    return path, float(g[goal]), expansions, 0


@njit(cache=True)
def component(cells, start, target, limit, stamp, gen):
    """Flood the usable cells 26-connected to ``start`` (at most ``limit``; edges are not
    line-of-sight checked, so on coarse levels this over-approximates connectivity).

    Returns (cells visited, whether ``target`` was reached, whether the flood stopped at the
    limit). Uses ``stamp`` (marks ``2 gen + 1``) instead of a fresh visited array.
    """
    CX, CY, CZ = cells.shape
    flat = cells.reshape(-1)
    mark = np.int32(2 * gen + 1)
    stack = np.empty(1024, np.int64)
    sp = 0
    stack[sp] = start
    sp += 1
    stamp[start] = mark
    count = 0
    while sp > 0:
        if count >= limit:
            return count, False, True
        sp -= 1
        c = stack[sp]
        count += 1
        if c == target:
            return count, True, False
        x = c // (CY * CZ)
        y = (c // CZ) % CY
        z = c % CZ
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                for dz in range(-1, 2):
                    xx = x + dx
                    yy = y + dy
                    zz = z + dz
                    if xx < 0 or yy < 0 or zz < 0 or xx >= CX or yy >= CY or zz >= CZ:
                        continue
                    nb = (xx * CY + yy) * CZ + zz
                    if flat[nb] == 0 or stamp[nb] == mark:
                        continue
                    stamp[nb] = mark
                    if sp >= stack.shape[0]:
                        ns = np.empty(stack.shape[0] * 2, np.int64)
                        ns[:sp] = stack[:sp]
                        stack = ns
                    stack[sp] = nb
                    sp += 1
    return count, False, False
