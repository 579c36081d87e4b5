"""A surface mesh from the depth maps: TSDF fusion on a voxel grid, then naive surface nets.

1. A voxel grid covers the fused cloud's bounding box (padded by a few voxels).
2. Every depth map is integrated into a truncated signed distance field (TSDF): for each voxel
   centre projected into a view, ``sdf = depth(pixel) - z_voxel`` (positive in front of the
   surface), truncated to ``+-trunc`` and averaged over the views that see the voxel (voxels more
   than ``trunc`` behind the surface are left alone).
3. The zero level set is extracted with naive surface nets (one vertex per cell with a sign
   change, at the mean of its edge crossings; one quad per grid edge with a sign change, split
   into two triangles, oriented so that normals point to free space). Cells whose corners were
   seen by fewer than ``min_weight`` views are skipped, which drops single-view junk.
4. Vertex colours come from the nearest point of the fused cloud.

World frame, metres. The Numba kernel is compiled once (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from skyrecon.core import PointCloud
from skyrecon.mvs.frames import WorkingView

__all__ = ["tsdf_volume", "surface_nets", "mesh_from_depth_maps"]


@njit(cache=True, nogil=True, boundscheck=False, error_model="numpy")
def _integrate(tsdf, weight, origin, voxel, depth, R, t, fx, fy, cx, cy, trunc):  # pragma: no cover - jit
    nx, ny, nz = tsdf.shape
    H, W = depth.shape
    for i in range(nx):
        x = origin[0] + (i + 0.5) * voxel
        for j in range(ny):
            y = origin[1] + (j + 0.5) * voxel
            for k in range(nz):
                z = origin[2] + (k + 0.5) * voxel
                zc = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
                if zc <= 1e-9:
                    continue
                xc = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]
                yc = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]
                u = int(np.floor(fx * xc / zc + cx + 0.5))
                v = int(np.floor(fy * yc / zc + cy + 0.5))
                if u < 0 or v < 0 or u >= W or v >= H:
                    continue
                d = depth[v, u]
                if not (d > 0.0):
                    continue
                sdf = d - zc
                if sdf < -trunc:
                    continue
                if sdf > trunc:
                    sdf = trunc
                w = weight[i, j, k]
                tsdf[i, j, k] = (tsdf[i, j, k] * w + sdf / trunc) / (w + 1.0)
                weight[i, j, k] = w + 1.0


def tsdf_volume(
    views: list[WorkingView],
    depths: list[np.ndarray | None],
    lo: np.ndarray,
    hi: np.ndarray,
    voxel_m: float,
    trunc_voxels: float = 3.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Integrate depth maps into a TSDF grid covering the box [lo, hi] (world, metres).

    Returns:
        (tsdf (nx, ny, nz) float32 in [-1, 1] (units of the truncation, positive in front),
        weight (nx, ny, nz) float32 number of views, origin (3,) world corner of voxel (0, 0, 0)).
    """
    lo = np.asarray(lo, np.float64)
    hi = np.asarray(hi, np.float64)
    shape = np.maximum(np.ceil((hi - lo) / voxel_m).astype(np.int64), 2)
    tsdf = np.ones(tuple(int(s) for s in shape), np.float32)
    weight = np.zeros_like(tsdf)
    for v, d in zip(views, depths):
        if d is None:
            continue
        K = v.intrinsics
        _integrate(
            tsdf,
            weight,
            lo,
            float(voxel_m),
            np.ascontiguousarray(d, np.float32),
            v.cam_from_world.R,
            v.cam_from_world.t,
            K.fx,
            K.fy,
            K.cx,
            K.cy,
            float(trunc_voxels * voxel_m),
        )
    return tsdf, weight, lo


def surface_nets(
    tsdf: np.ndarray, valid: np.ndarray, origin: np.ndarray, voxel_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Zero level set of a sampled field by naive surface nets.

    Args:
        tsdf: (nx, ny, nz) field sampled at voxel centres, positive outside (free space).
        valid: (nx, ny, nz) bool, samples that may be used.
        origin: (3,) world corner of voxel (0, 0, 0); voxel centres at ``origin + (i + 0.5) voxel``.
        voxel_m: voxel size, metres.
    Returns:
        (vertices (V, 3) float32 world metres, faces (F, 3) int32), faces wound so that their
        normals (right-hand rule) point to the positive side.
    """
    T = tsdf.astype(np.float32)
    nx, ny, nz = T.shape
    corners = [(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)]
    cshape = (nx - 1, ny - 1, nz - 1)

    def corner(a: int, b: int, c: int, arr: np.ndarray) -> np.ndarray:
        return arr[a : a + nx - 1, b : b + ny - 1, c : c + nz - 1]

    all_valid = np.ones(cshape, bool)
    tmin = np.full(cshape, np.inf, np.float32)
    tmax = np.full(cshape, -np.inf, np.float32)
    for a, b, c in corners:
        all_valid &= corner(a, b, c, valid)
        tv = corner(a, b, c, T)
        tmin = np.minimum(tmin, tv)
        tmax = np.maximum(tmax, tv)
    active = all_valid & (tmin < 0) & (tmax >= 0)
    cells = np.argwhere(active)
    if len(cells) == 0:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)
    cell_id = np.full(cshape, -1, np.int64)
    cell_id[tuple(cells.T)] = np.arange(len(cells))
    # vertex = mean of the zero crossings on the cell's 12 edges
    acc = np.zeros((len(cells), 3))
    cnt = np.zeros(len(cells))
    ci, cj, ck = cells.T
    for (a0, b0, c0), (a1, b1, c1) in [
        ((a, b, c), (a + da, b + db, c + dc))
        for a, b, c in corners
        for da, db, dc in ((1, 0, 0), (0, 1, 0), (0, 0, 1))
        if a + da <= 1 and b + db <= 1 and c + dc <= 1
    ]:
        t0 = T[ci + a0, cj + b0, ck + c0]
        t1 = T[ci + a1, cj + b1, ck + c1]
        cross = (t0 < 0) != (t1 < 0)
        s = np.where(cross, t0 / np.where(t0 - t1 == 0, 1, t0 - t1), 0.0)
        p = np.stack([a0 + s * (a1 - a0), b0 + s * (b1 - b0), c0 + s * (c1 - c0)], axis=1)
        acc += p * cross[:, None]
        cnt += cross
    local = acc / np.maximum(cnt, 1)[:, None]
    verts = origin + (cells + local + 0.5) * voxel_m
    # faces: one quad per grid edge with a sign change, between the 4 cells around it
    faces = []
    for axis in range(3):
        o1, o2 = [a for a in range(3) if a != axis]
        sl0 = [slice(None)] * 3
        sl1 = [slice(None)] * 3
        sl0[axis] = slice(0, T.shape[axis] - 1)
        sl1[axis] = slice(1, T.shape[axis])
        t0, t1 = T[tuple(sl0)], T[tuple(sl1)]
        ok = ((t0 < 0) != (t1 < 0)) & valid[tuple(sl0)] & valid[tuple(sl1)]
        e = np.argwhere(ok)
        e = e[(e[:, o1] >= 1) & (e[:, o2] >= 1) & (e[:, o1] < T.shape[o1] - 1) & (e[:, o2] < T.shape[o2] - 1)]
        if len(e) == 0:
            continue
        quads = []
        for d1, d2 in ((1, 1), (0, 1), (0, 0), (1, 0)):
            c = e.copy()
            c[:, o1] -= d1
            c[:, o2] -= d2
            quads.append(cell_id[tuple(c.T)])
        q = np.stack(quads, axis=1)
        good = np.all(q >= 0, axis=1)
        q, e = q[good], e[good]
        positive_first = T[tuple(e.T)] >= 0  # outside at the lower end: normal along -axis
        tri = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
        pf = np.concatenate([positive_first, positive_first])
        n = np.cross(verts[tri[:, 1]] - verts[tri[:, 0]], verts[tri[:, 2]] - verts[tri[:, 0]])
        flip = (n[:, axis] > 0) == pf
        tri[flip] = tri[flip][:, [0, 2, 1]]
        faces.append(tri)
    F = np.concatenate(faces).astype(np.int32) if faces else np.zeros((0, 3), np.int32)
    return verts.astype(np.float32), F


def mesh_from_depth_maps(
    views: list[WorkingView],
    depths: list[np.ndarray | None],
    cloud: PointCloud,
    voxel_m: float | None = None,
    min_weight: int = 2,
    max_voxels: int = 24_000_000,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mesh the scene inside the fused cloud's bounding box.

    Args:
        views, depths: the working views and their depth maps (metres, NaN invalid).
        cloud: the fused cloud (sets the region and the vertex colours).
        voxel_m: voxel size; default the box diagonal / 250 (enlarged if the grid would exceed
            ``max_voxels``).
        min_weight: views that must have seen every corner of a meshed cell.
    Returns:
        (vertices (V, 3) float32 world metres, faces (F, 3) int32, colours (V, 3) uint8 RGB).
    """
    P = cloud.points.astype(np.float64)
    lo, hi = np.quantile(P, 0.001, axis=0), np.quantile(P, 0.999, axis=0)
    diag = float(np.linalg.norm(hi - lo))
    voxel = float(voxel_m) if voxel_m else diag / 250.0
    while np.prod(np.ceil((hi - lo) / voxel) + 8) > max_voxels:
        voxel *= 1.25
    lo, hi = lo - 4 * voxel, hi + 4 * voxel
    tsdf, weight, origin = tsdf_volume(views, depths, lo, hi, voxel)
    verts, faces = surface_nets(tsdf, weight >= min_weight, origin, voxel)
    if len(verts) and cloud.colors is not None:
        _, idx = cKDTree(P).query(verts, k=1, workers=-1)
        colors = cloud.colors[idx]
    else:
        colors = np.full((len(verts), 3), 160, np.uint8)
    return verts, faces, colors
