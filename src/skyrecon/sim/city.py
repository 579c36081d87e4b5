"""The synthetic city: obstacles as boxes and vertical cylinders on the ground plane z = 0,
with exact ground-truth queries (signed distance, occupancy, ray casting).

World frame: right-handed, z up, metres. Everything stands on or above the ground plane.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from skyrecon.errors import InputError
from skyrecon.sim import raycast as _rc
from skyrecon.sim._jit import run_chunks
from skyrecon.sim.accel import UniformGrid, build_grid
from skyrecon.sim.texture import GROUND_PLAZA, MAT_METAL, MAT_STONE

# Semantic kinds (``City.box_kind`` / ``City.cyl_kind``).
KIND_BUILDING = 0
KIND_ROOF_UNIT = 1
KIND_TREE_TRUNK = 2
KIND_TREE_CANOPY = 3
KIND_BEAM = 4
KIND_MONUMENT = 5
KIND_POLE = 0  # cylinders
KIND_COLUMN = 1  # cylinders
BOX_KIND_NAMES = ("building", "roof_unit", "tree_trunk", "tree_canopy", "beam", "monument")


def _points(points: np.ndarray, what: str = "points") -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim == 1 and p.shape[0] == 3:
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"{what} must have shape (N, 3), got {np.shape(points)}")
    if not np.all(np.isfinite(p)):
        raise InputError(f"{what} contain NaN or infinite values")
    return np.ascontiguousarray(p)


@dataclass(eq=False)
class RayHits:
    """First hits of a batch of rays.

    Attributes:
        distance_m: (N,) float64 distance from the origin along the unit ray, metres; inf for a miss.
        object_id: (N,) int32: -1 miss, 0 ground, ``1 + i`` box i, ``1 + N_boxes + j`` cylinder j.
        normal: (N, 3) float64 outward unit normal at the hit, world frame (NaN for a miss).
    """

    distance_m: np.ndarray
    object_id: np.ndarray
    normal: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(N,) bool: the ray hit something."""
        return np.isfinite(self.distance_m)


@dataclass(eq=False)
class City:
    """A generated scene with exact geometry.

    Attributes:
        seed: the generator's seed.
        extent: (4,) ``[xmin, ymin, xmax, ymax]`` of the built area, metres (all obstacles lie inside).
        boxes: (N, 6) float64 axis-aligned boxes ``[xmin, ymin, zmin, xmax, ymax, zmax]``, metres.
        box_material: (N,) int32 material id (``skyrecon.sim.texture.MAT_*``).
        box_kind: (N,) int32 semantic kind (``KIND_*``: building, roof unit, tree, beam, monument).
        box_albedo: (N, 3) float64 base RGB albedo in [0, 1].
        box_accent: (N, 3) float64 secondary RGB (window frames, mullions) in [0, 1].
        box_params: (N, 6) float64 ``[floor_height_m, column_period_m, window_width_frac,
            window_height_frac, roof_kind, texture_scale]``.
        cylinders: (M, 5) float64 vertical cylinders ``[x, y, radius, zmin, zmax]``, metres.
        cyl_material, cyl_kind, cyl_albedo, cyl_accent, cyl_params: as for boxes, (M, ...).
        blocks_x: (P, 2) x intervals of the block columns; between them (and at the border) run streets.
        blocks_y: (Q, 2) y intervals of the block rows.
        sidewalk_m: width of the pavement around each block, metres.
        ground_style: 0 streets and blocks, 1 a paved plaza (object scenes), 2 streets and
            blocks in plain greys (``generate_city(..., plain=True)``), 3 one plain grey (object scenes
            with ``plain=True``).
        center: (3,) point of interest (the monument of an object scene; the middle of the city), metres.
        view_radius_m: a good camera distance from ``center`` for orbits and rings, metres.

    Ground-truth queries are exact up to floating point: :meth:`distance`, :meth:`is_occupied`,
    :meth:`box_occupied`, :meth:`occupancy_grid`, :meth:`raycast`. Object ids used by the renderer:
    0 ground, ``1 + i`` box i, ``1 + N + j`` cylinder j, -1 sky.
    """

    seed: int
    extent: np.ndarray
    boxes: np.ndarray
    box_material: np.ndarray
    box_kind: np.ndarray
    box_albedo: np.ndarray
    box_accent: np.ndarray
    box_params: np.ndarray
    cylinders: np.ndarray
    cyl_material: np.ndarray
    cyl_kind: np.ndarray
    cyl_albedo: np.ndarray
    cyl_accent: np.ndarray
    cyl_params: np.ndarray
    blocks_x: np.ndarray
    blocks_y: np.ndarray
    sidewalk_m: float = 3.0
    ground_style: int = 0
    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    view_radius_m: float = 30.0
    grid: UniformGrid = field(init=False, repr=False)

    def __post_init__(self) -> None:
        f64 = lambda a, cols: np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape(-1, cols))  # noqa: E731
        i32 = lambda a: np.ascontiguousarray(np.asarray(a, dtype=np.int32).reshape(-1))  # noqa: E731
        self.extent = np.asarray(self.extent, dtype=np.float64).reshape(4)
        self.boxes = f64(self.boxes, 6)
        self.cylinders = f64(self.cylinders, 5)
        nb, nc = len(self.boxes), len(self.cylinders)
        self.box_material, self.box_kind = i32(self.box_material), i32(self.box_kind)
        self.cyl_material, self.cyl_kind = i32(self.cyl_material), i32(self.cyl_kind)
        self.box_albedo, self.box_accent = f64(self.box_albedo, 3), f64(self.box_accent, 3)
        self.cyl_albedo, self.cyl_accent = f64(self.cyl_albedo, 3), f64(self.cyl_accent, 3)
        self.box_params, self.cyl_params = f64(self.box_params, 6), f64(self.cyl_params, 6)
        self.blocks_x, self.blocks_y = f64(self.blocks_x, 2), f64(self.blocks_y, 2)
        self.center = np.asarray(self.center, dtype=np.float64).reshape(3)
        for name, arr, n in (
            ("box_material", self.box_material, nb),
            ("box_kind", self.box_kind, nb),
            ("box_albedo", self.box_albedo, nb),
            ("box_accent", self.box_accent, nb),
            ("box_params", self.box_params, nb),
            ("cyl_material", self.cyl_material, nc),
            ("cyl_kind", self.cyl_kind, nc),
            ("cyl_albedo", self.cyl_albedo, nc),
            ("cyl_accent", self.cyl_accent, nc),
            ("cyl_params", self.cyl_params, nc),
        ):
            if len(arr) != n:
                raise InputError(f"City.{name} has {len(arr)} rows for {n} objects")
        if np.any(self.boxes[:, 3:] < self.boxes[:, :3]):
            raise InputError("City.boxes: every box needs min <= max on each axis")
        if np.any(self.cylinders[:, 2] <= 0) or np.any(self.cylinders[:, 4] < self.cylinders[:, 3]):
            raise InputError("City.cylinders: radius must be > 0 and zmin <= zmax")
        self.grid = build_grid(self.boxes, self.cylinders)

    @classmethod
    def from_obstacles(
        cls,
        boxes: np.ndarray,
        cylinders: np.ndarray | None = None,
        seed: int = 0,
        extent: np.ndarray | None = None,
    ) -> City:
        """A scene made of given obstacles on a paved ground (for tests with hand-made geometry).

        Args:
            boxes: (N, 6) ``[xmin, ymin, zmin, xmax, ymax, zmax]``, metres, world frame.
            cylinders: (M, 5) ``[x, y, radius, zmin, zmax]``, or None.
            seed: seeds the textures (every box gets a stone texture, every cylinder a metal one).
            extent: (4,) paved area ``[xmin, ymin, xmax, ymax]``; by default the obstacles' footprint
                plus 20 m (grass beyond).
        """
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 6)
        c = np.zeros((0, 5)) if cylinders is None else np.asarray(cylinders, dtype=np.float64).reshape(-1, 5)
        nb, nc = len(b), len(c)
        if extent is None:
            lo = np.min(np.concatenate([b[:, :2], c[:, :2] - c[:, 2:3], np.zeros((1, 2))]), axis=0) - 20.0
            hi = np.max(np.concatenate([b[:, 3:5], c[:, :2] + c[:, 2:3], np.zeros((1, 2))]), axis=0) + 20.0
            extent = np.array([lo[0], lo[1], hi[0], hi[1]])
        tops = np.concatenate([b[:, 5], c[:, 4], [0.0]])
        params = np.tile([3.0, 0.0, 0.5, 0.5, 0.0, 1.0], (nb, 1))
        return cls(
            seed=int(seed),
            extent=extent,
            boxes=b,
            box_material=np.full(nb, MAT_STONE),
            box_kind=np.zeros(nb),
            box_albedo=np.tile([0.62, 0.58, 0.52], (nb, 1)),
            box_accent=np.tile([0.5, 0.5, 0.5], (nb, 1)),
            box_params=params,
            cylinders=c,
            cyl_material=np.full(nc, MAT_METAL),
            cyl_kind=np.zeros(nc),
            cyl_albedo=np.tile([0.45, 0.46, 0.48], (nc, 1)),
            cyl_accent=np.tile([0.5, 0.5, 0.5], (nc, 1)),
            cyl_params=np.tile([3.0, 0.0, 0.5, 0.5, 0.0, 1.0], (nc, 1)),
            blocks_x=np.zeros((0, 2)),
            blocks_y=np.zeros((0, 2)),
            sidewalk_m=0.0,
            ground_style=GROUND_PLAZA,
            center=np.array([(extent[0] + extent[2]) / 2, (extent[1] + extent[3]) / 2, tops.max() / 2]),
            view_radius_m=float(max(extent[2] - extent[0], extent[3] - extent[1]) / 2),
        )

    # ----- summary -----------------------------------------------------------------
    @property
    def num_buildings(self) -> int:
        """Number of building boxes (towers on top of a base count separately)."""
        return int(np.sum(self.box_kind == KIND_BUILDING))

    @property
    def street_centers(self) -> tuple[np.ndarray, np.ndarray]:
        """Centre lines of the streets: (xs, ys), x positions of streets running along y and
        y positions of streets running along x, world metres (border streets included)."""
        return _gap_centers(self.blocks_x, self.extent[0], self.extent[2]), _gap_centers(
            self.blocks_y, self.extent[1], self.extent[3]
        )

    @property
    def street_widths(self) -> tuple[np.ndarray, np.ndarray]:
        """Widths (metres) of the streets listed by :attr:`street_centers`."""
        return _gap_widths(self.blocks_x, self.extent[0], self.extent[2]), _gap_widths(
            self.blocks_y, self.extent[1], self.extent[3]
        )

    @property
    def max_height_m(self) -> float:
        """Top of the highest obstacle, metres."""
        tops = [self.boxes[:, 5], self.cylinders[:, 4]]
        return float(max((t.max() for t in tops if len(t)), default=0.0))

    def fingerprint(self) -> str:
        """SHA-256 of every array and setting: equal fingerprints mean identical cities."""
        h = hashlib.sha256()
        settings = (int(self.seed), float(self.sidewalk_m), int(self.ground_style), float(self.view_radius_m))
        h.update(repr(settings).encode())
        for a in (
            self.extent,
            self.boxes,
            self.box_material,
            self.box_kind,
            self.box_albedo,
            self.box_accent,
            self.box_params,
            self.cylinders,
            self.cyl_material,
            self.cyl_kind,
            self.cyl_albedo,
            self.cyl_accent,
            self.cyl_params,
            self.blocks_x,
            self.blocks_y,
            self.center,
        ):
            h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()

    # ----- ground truth ----------------------------------------------------------------
    def distance(self, points_world: np.ndarray, include_ground: bool = False) -> np.ndarray:
        """Signed Euclidean distance from points to the nearest obstacle surface.

        Args:
            points_world: (N, 3) world points, metres.
            include_ground: treat the half-space z <= 0 as an obstacle too.
        Returns:
            (N,) float64 metres: > 0 in free space, 0 on a surface, < 0 inside an obstacle (minus
            the depth below that obstacle's surface). inf when the city is empty and the ground is excluded.
        """
        p = _points(points_world)
        g = self.grid
        out = np.empty(len(p))
        run_chunks(
            _rc.signed_distance,
            len(p),
            p,
            bool(include_ground),
            self.boxes,
            self.cylinders,
            g.x0,
            g.y0,
            g.cell_m,
            g.ncx,
            g.ncy,
            g.cell_start,
            g.cell_items,
            out,
        )
        return out

    def is_occupied(self, points_world: np.ndarray, include_ground: bool = False) -> np.ndarray:
        """(N,) bool: the point lies inside or on an obstacle (distance <= 0); (N, 3) world metres."""
        return self.distance(points_world, include_ground) <= 0.0

    def box_occupied(self, lo: np.ndarray, hi: np.ndarray, include_ground: bool = False) -> bool:
        """Whether any obstacle overlaps the open axis-aligned box (lo, hi), each (3,) world metres.

        Touching faces do not count. With ``include_ground`` the box overlaps the ground when lo_z < 0.
        """
        lo = np.asarray(lo, dtype=np.float64).reshape(3)
        hi = np.asarray(hi, dtype=np.float64).reshape(3)
        if include_ground and lo[2] < 0.0:
            return True
        b = self.boxes
        if np.any(np.all((b[:, :3] < hi) & (b[:, 3:] > lo), axis=1)):
            return True
        c = self.cylinders
        if len(c) == 0:
            return False
        zok = (c[:, 3] < hi[2]) & (c[:, 4] > lo[2])
        qx = np.clip(c[:, 0], lo[0], hi[0]) - c[:, 0]
        qy = np.clip(c[:, 1], lo[1], hi[1]) - c[:, 1]
        return bool(np.any(zok & (qx * qx + qy * qy < c[:, 2] ** 2)))

    def occupancy_grid(
        self, origin: np.ndarray, voxel_size: float, shape: tuple[int, int, int], include_ground: bool = False
    ) -> np.ndarray:
        """Which voxels of a regular grid overlap an obstacle.

        Args:
            origin: (3,) world position of the grid's lowest corner (not a voxel centre), metres.
            voxel_size: voxel side, metres. Voxel (i, j, k) spans ``origin + [i, i+1) * voxel_size`` etc.
            shape: (nx, ny, nz).
            include_ground: voxels reaching below z = 0 are occupied.
        Returns:
            (nx, ny, nz) bool, the same answer as :meth:`box_occupied` on each voxel (open overlap).
        """
        o = np.asarray(origin, dtype=np.float64).reshape(3)
        vs = float(voxel_size)
        if not np.isfinite(vs) or vs <= 0:
            raise InputError(f"voxel_size must be positive, got {voxel_size}")
        nx, ny, nz = (int(s) for s in shape)
        if min(nx, ny, nz) < 0:
            raise InputError(f"the grid shape must be non-negative, got {shape}")
        occ = np.zeros((nx, ny, nz), dtype=bool)
        dims = np.array([nx, ny, nz])

        def index_range(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            # voxel i overlaps (lo, hi) iff o + (i+1) vs > lo and o + i vs < hi
            i0 = np.floor((lo - o) / vs).astype(np.int64)
            i1 = np.ceil((hi - o) / vs).astype(np.int64)
            # settle floating-point ties with the exact voxel bounds
            i0 += o + (i0 + 1) * vs <= lo
            i1 -= o + (i1 - 1) * vs >= hi
            return np.clip(i0, 0, dims), np.clip(i1, 0, dims)

        for b in self.boxes:
            a, e = index_range(b[:3], b[3:])
            if np.all(e > a):
                occ[a[0] : e[0], a[1] : e[1], a[2] : e[2]] = True
        for c in self.cylinders:
            a, e = index_range(
                np.array([c[0] - c[2], c[1] - c[2], c[3]]), np.array([c[0] + c[2], c[1] + c[2], c[4]])
            )
            if not np.all(e > a):
                continue
            xs0 = o[0] + np.arange(a[0], e[0]) * vs
            ys0 = o[1] + np.arange(a[1], e[1]) * vs
            qx = np.clip(c[0], xs0, xs0 + vs) - c[0]
            qy = np.clip(c[1], ys0, ys0 + vs) - c[1]
            col = (qx[:, None] ** 2 + qy[None, :] ** 2) < c[2] ** 2
            occ[a[0] : e[0], a[1] : e[1], a[2] : e[2]] |= col[:, :, None]
        if include_ground:
            k = np.arange(nz)
            occ[:, :, o[2] + k * vs < 0.0] = True
        return occ

    def _trace(
        self,
        origins: np.ndarray,
        dirs: np.ndarray,
        include_ground: bool,
        t_lo: float = 0.0,
        t_hi: float = np.inf,
        rot: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """First hits (t, kind, index, face) of rays ``origins + t * rot @ dirs``; see ``raycast.trace_rays``."""
        g = self.grid
        rot = np.eye(3) if rot is None else np.ascontiguousarray(rot, dtype=np.float64)
        n = len(dirs)
        t = np.empty(n)
        kind = np.empty(n, np.int32)
        index = np.empty(n, np.int32)
        face = np.empty(n, np.int32)
        run_chunks(
            _rc.trace_rays,
            n,
            origins,
            dirs,
            rot,
            float(t_lo),
            float(t_hi),
            bool(include_ground),
            self.boxes,
            self.cylinders,
            g.x0,
            g.y0,
            g.cell_m,
            g.ncx,
            g.ncy,
            g.z_lo,
            g.z_hi,
            g.cell_start,
            g.cell_items,
            g.cell_zmax,
            t,
            kind,
            index,
            face,
        )
        return t, kind, index, face

    def _rays(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        o = _points(origins, "ray origins")
        d = _points(dirs, "ray directions")
        if len(o) != len(d) and len(o) != 1:
            raise InputError(f"{len(o)} ray origins for {len(d)} directions")
        norm = np.linalg.norm(d, axis=1)
        if np.any(norm == 0):
            raise InputError("ray directions must be non-zero")
        return o, np.ascontiguousarray(d / norm[:, None])

    def raycast(
        self, origins: np.ndarray, dirs: np.ndarray, include_ground: bool = True, max_range_m: float = np.inf
    ) -> np.ndarray:
        """Distance to the first surface along each ray.

        Args:
            origins: (N, 3) or (3,) world ray origins, metres (one origin may serve all rays).
            dirs: (N, 3) world directions (normalised here).
            include_ground: the plane z = 0 stops rays (as in the renderer).
            max_range_m: hits farther than this count as misses.
        Returns:
            (N,) float64 Euclidean distance in metres, inf where nothing is hit.
            A ray starting inside an obstacle reports the next surface it *enters*.
        """
        o, d = self._rays(origins, dirs)
        t, _, _, _ = self._trace(o, d, include_ground, 0.0, max_range_m)
        return t

    def raycast_hits(
        self, origins: np.ndarray, dirs: np.ndarray, include_ground: bool = True, max_range_m: float = np.inf
    ) -> RayHits:
        """As :meth:`raycast`, also returning the object id and surface normal of each hit."""
        o, d = self._rays(origins, dirs)
        t, kind, index, face = self._trace(o, d, include_ground, 0.0, max_range_m)
        nb = len(self.boxes)
        oid = np.where(kind == 0, -1, np.where(kind == 1, 0, np.where(kind == 2, 1 + index, 1 + nb + index)))
        normal = np.full((len(t), 3), np.nan)
        box_normals = np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]], float)
        m = kind == 1
        normal[m] = [0.0, 0.0, 1.0]
        m = kind == 2
        normal[m] = box_normals[face[m]]
        m = kind == 3
        if np.any(m):
            p = (o if len(o) > 1 else np.broadcast_to(o, d.shape))[m] + t[m, None] * d[m]
            c = self.cylinders[index[m]]
            side = face[m] == 6
            nrm = np.zeros((int(m.sum()), 3))
            radial = p[:, :2] - c[:, :2]
            nrm[:, :2] = radial / np.linalg.norm(radial, axis=1, keepdims=True)
            nrm[~side] = 0.0
            nrm[~side, 2] = np.where(face[m][~side] == 7, 1.0, -1.0)
            normal[m] = nrm
        return RayHits(t, oid.astype(np.int32), normal)


def _gap_edges(blocks: np.ndarray, lo: float, hi: float) -> list[tuple[float, float]]:
    edges = [lo, *np.asarray(blocks, dtype=np.float64).ravel().tolist(), hi]
    return [
        (edges[2 * i], edges[2 * i + 1]) for i in range(len(edges) // 2) if edges[2 * i + 1] > edges[2 * i]
    ]


def _gap_centers(blocks: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return np.array([(a + b) / 2 for a, b in _gap_edges(blocks, lo, hi)])


def _gap_widths(blocks: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return np.array([b - a for a, b in _gap_edges(blocks, lo, hi)])
