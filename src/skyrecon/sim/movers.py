"""Moving obstacles: drones, street vehicles and a slewing tower crane, with exact geometry at every instant.

Every mover's geometry at time t is a set of axis-aligned boxes ``[xmin, ymin, zmin, xmax, ymax, zmax]``
(world frame, z up, metres; time in seconds), so the static city's ray tracer and signed distance apply
unchanged: :meth:`MovingScene.snapshot` is the static :class:`City` plus every mover's boxes at t.

* drone: a 1.0 x 1.0 x 0.4 m box flying a polyline back and forth (ping-pong) at a fixed altitude.
* vehicle: a 4.5 x 1.9 x 1.6 m box (long axis along its street) looping along a street: one lane
  out, a lane change at the city's end, the other lane back (right-hand traffic).
* crane: a 2 x 2 m tower plus a boom of 1 m cubes along the boom direction, rotating about the
  tower top (the chain of cubes IS the boom's exact geometry).

Everything is deterministic in its parameters; :func:`make_movers` draws them from a seed.

    scene = make_movers(city, seed, start, goal, path)
    snap = scene.snapshot(t)                       # a City (MoverSnapshot) with the movers at t
    scene.distance(points, times)                  # exact signed distance, each point at its own time
    mover_of_object_id(snap, render(snap, cam, pose).object_id)   # (H, W) mover index or -1
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import numpy as np

from skyrecon.errors import InputError
from skyrecon.sim.city import City, _points
from skyrecon.sim.texture import MAT_METAL, MAT_PLAIN

KIND_MOVER = 6  # ``box_kind`` of mover boxes in a snapshot (after the static kinds of ``sim.city``)
MOVER_KINDS = ("drone", "vehicle", "crane")
DRONE_SIZE_M = (1.0, 1.0, 0.4)
VEHICLE_SIZE_M = (4.5, 1.9, 1.6)
DRONE_MAX_SPEED_MPS = 4.5
DRONE_CLEARANCE_M = 2.5  # a drone's polyline keeps this far from every static obstacle
_SEED_TAG = 0x6D6F76  # "mov": the generator is default_rng([seed, _SEED_TAG])


# ----- geometry helpers ---------------------------------------------------------------------------
def box_sdf(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Signed distance of points to boxes, metres (< 0 inside), the formula of ``City.distance``.

    Args:
        points: (N, 3) world points, metres.
        boxes: (K, 6) boxes shared by every point, or (N, K, 6) boxes per point.
    Returns:
        (N, K) float64.
    """
    p = np.asarray(points, dtype=np.float64)[:, None, :]
    b = np.asarray(boxes, dtype=np.float64)
    if b.ndim == 2:
        b = b[None]
    q = np.maximum(b[..., :3] - p, p - b[..., 3:])
    outside = np.sqrt(np.sum(np.maximum(q, 0.0) ** 2, axis=-1))
    return outside + np.minimum(np.max(q, axis=-1), 0.0)


def _overlap(a: np.ndarray, b: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """(A, B) bool: box a (A, 6), grown by ``margin``, overlaps box b (B, 6) (open overlap)."""
    lo = a[:, None, :3] - margin
    hi = a[:, None, 3:] + margin
    return np.all((b[None, :, :3] < hi) & (b[None, :, 3:] > lo), axis=-1)


def _static_overlap(city: City, boxes: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """(K,) bool: box k (K, 6), grown by ``margin`` metres, overlaps a static box or cylinder (open)."""
    out = np.zeros(len(boxes), dtype=bool)
    if len(boxes) == 0:
        return out
    lo_all = boxes[:, :3].min(axis=0) - margin
    hi_all = boxes[:, 3:].max(axis=0) + margin
    sb = city.boxes
    sb = sb[np.all((sb[:, :3] < hi_all) & (sb[:, 3:] > lo_all), axis=1)]
    for i in range(0, len(boxes), 4096):
        chunk = boxes[i : i + 4096]
        if len(sb):
            out[i : i + 4096] |= _overlap(chunk, sb, margin).any(axis=1)
    c = city.cylinders
    if len(c):
        cb = np.stack(
            [c[:, 0] - c[:, 2], c[:, 1] - c[:, 2], c[:, 3], c[:, 0] + c[:, 2], c[:, 1] + c[:, 2], c[:, 4]], 1
        )
        keep = np.all((cb[:, :3] < hi_all) & (cb[:, 3:] > lo_all), axis=1)
        c = c[keep]
        for ci in c:
            lo = boxes[:, :3] - margin
            hi = boxes[:, 3:] + margin
            zok = (lo[:, 2] < ci[4]) & (hi[:, 2] > ci[3])
            qx = np.clip(ci[0], lo[:, 0], hi[:, 0]) - ci[0]
            qy = np.clip(ci[1], lo[:, 1], hi[:, 1]) - ci[1]
            out |= zok & (qx * qx + qy * qy < ci[2] ** 2)
    return out


# ----- motion models ------------------------------------------------------------------------------
@dataclass(frozen=True)
class PolylineMotion:
    """Constant-speed travel along a polyline: back and forth (``closed=False``) or round a loop.

    Attributes:
        points: (P, 3) vertices, world metres (P >= 2); the body's centre follows them.
        speed_mps: speed along the polyline, m/s (> 0).
        closed: the last vertex joins the first (a loop); otherwise the mover turns back at the ends.
        phase_m: arc position at t = 0 along the unfolded cycle ``[0, cycle_m)``: on an open polyline
            ``s <= length`` is outbound at arc s, ``s > length`` inbound at arc ``2 * length - s``.
    """

    points: np.ndarray
    speed_mps: float
    closed: bool = False
    phase_m: float = 0.0

    def __post_init__(self) -> None:
        p = np.asarray(self.points, dtype=np.float64).reshape(-1, 3)
        if len(p) < 2 or not np.all(np.isfinite(p)):
            raise InputError("a mover's polyline needs at least 2 finite (x, y, z) vertices")
        if not (np.isfinite(self.speed_mps) and self.speed_mps > 0):
            raise InputError(f"a mover's speed must be > 0 m/s, got {self.speed_mps}")
        object.__setattr__(self, "points", p)
        if self.length_m <= 0:
            raise InputError("a mover's polyline has zero length")

    @property
    def _loop(self) -> np.ndarray:
        return np.vstack([self.points, self.points[:1]]) if self.closed else self.points

    @property
    def length_m(self) -> float:
        """Length of the polyline (of the loop when closed), metres."""
        return float(np.linalg.norm(np.diff(self._loop, axis=0), axis=1).sum())

    @property
    def cycle_m(self) -> float:
        """Arc travelled in one period, metres."""
        return self.length_m if self.closed else 2.0 * self.length_m

    @property
    def period_s(self) -> float:
        """Seconds until the motion repeats."""
        return self.cycle_m / self.speed_mps

    def at(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centre (T, 3) metres and velocity (T, 3) m/s at times (T,) seconds."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        pts = self._loop
        seg = np.diff(pts, axis=0)
        seg_len = np.linalg.norm(seg, axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg_len)])
        total = cum[-1]
        s = np.mod(self.phase_m + self.speed_mps * t, self.cycle_m)
        sign = np.ones_like(s)
        if not self.closed:
            back = s > total
            s = np.where(back, 2.0 * total - s, s)
            sign[back] = -1.0
        k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
        while np.any(seg_len[k] == 0):  # zero-length segments: step to the next one
            k = np.where(seg_len[k] == 0, np.minimum(k + 1, len(seg) - 1), k)
        u = seg[k] / seg_len[k, None]
        pos = pts[k] + (s - cum[k])[:, None] * u
        return pos, sign[:, None] * self.speed_mps * u

    def to_dict(self) -> dict:
        return {
            "type": "polyline",
            "points": self.points.tolist(),
            "speed_mps": float(self.speed_mps),
            "closed": bool(self.closed),
            "phase_m": float(self.phase_m),
        }


@dataclass(frozen=True)
class CraneMotion:
    """A tower crane: a static tower and a boom rotating at a constant rate about the tower's axis.

    Attributes:
        pivot: (3,) ``(x, y, h)``: the tower's axis and the height of the boom's axis, world metres.
        base_z: bottom of the tower (0 on the ground, a roof's top on a roof), metres.
        length_m: boom length from the pivot to the tip, metres.
        omega_rad_s: slewing rate, rad/s (> 0 counter-clockwise seen from above).
        theta0_rad: boom heading at t = 0, radians from +x towards +y.
        cube_m: side of the boom's cubes, metres.
        tower_half_m: half the tower's side, metres; the boom starts at the tower's face.
        tower_cap_m: how far the tower rises above the boom's top, metres.
        sweep_rad: ``>= 2 pi``: the boom turns round and round at ``omega_rad_s``; less: it slews back and
            forth over the sector ``[theta0_rad, theta0_rad + sweep_rad]`` at ``|omega_rad_s|`` (a crane
            kept off tall buildings nearby).
        phase_rad: in sector mode, the angle already travelled at t = 0 along the unfolded cycle
            ``[0, 2 * sweep_rad)`` (``<= sweep_rad``: turning away from ``theta0_rad``).
    """

    pivot: np.ndarray
    base_z: float
    length_m: float
    omega_rad_s: float
    theta0_rad: float = 0.0
    cube_m: float = 1.0
    tower_half_m: float = 1.0
    tower_cap_m: float = 1.5
    sweep_rad: float = 2.0 * math.pi
    phase_rad: float = 0.0

    def __post_init__(self) -> None:
        if not (self.sweep_rad > 0 and np.isfinite(self.sweep_rad) and np.isfinite(self.phase_rad)):
            raise InputError(f"a crane's sweep must be a positive angle, got {self.sweep_rad}")
        p = np.asarray(self.pivot, dtype=np.float64).reshape(3)
        object.__setattr__(self, "pivot", p)
        if not np.all(np.isfinite(p)) or not np.isfinite(self.omega_rad_s):
            raise InputError("a crane's pivot and rate must be finite")
        if not self.length_m > self.tower_half_m + self.cube_m:
            raise InputError(f"a crane's boom must be longer than {self.tower_half_m + self.cube_m} m")
        if not (self.cube_m > 0 and self.tower_half_m > 0 and p[2] - self.cube_m / 2 > self.base_z):
            raise InputError("a crane's boom must sit above its tower's base")

    @property
    def radii_m(self) -> np.ndarray:
        """(n,) distances of the boom cubes' centres from the pivot, metres (spacing <= cube_m)."""
        r0 = self.tower_half_m + self.cube_m / 2
        r1 = self.length_m - self.cube_m / 2
        n = int(math.ceil((r1 - r0) / self.cube_m - 1e-9)) + 1
        return np.linspace(r0, r1, n)

    @property
    def tower_box(self) -> np.ndarray:
        """(6,) the tower, metres."""
        x, y, h = self.pivot
        a = self.tower_half_m
        return np.array([x - a, y - a, self.base_z, x + a, y + a, h + self.cube_m / 2 + self.tower_cap_m])

    @property
    def full_turn(self) -> bool:
        """The boom turns round and round (else it slews back and forth over a sector)."""
        return self.sweep_rad >= 2.0 * math.pi

    @property
    def period_s(self) -> float:
        """Seconds until the boom's motion repeats (inf when it stands still)."""
        if self.omega_rad_s == 0:
            return math.inf
        return (2.0 * math.pi if self.full_turn else 2.0 * self.sweep_rad) / abs(self.omega_rad_s)

    def heading_rate(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Boom headings (T,) radians and angular rates (T,) rad/s at times (T,) seconds."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        if self.full_turn:
            return self.theta0_rad + self.omega_rad_s * t, np.full(len(t), float(self.omega_rad_s))
        w = abs(self.omega_rad_s)
        u = np.mod(self.phase_rad + w * t, 2.0 * self.sweep_rad)
        out = u <= self.sweep_rad
        return self.theta0_rad + np.where(out, u, 2.0 * self.sweep_rad - u), np.where(out, w, -w)

    def heading(self, times: np.ndarray) -> np.ndarray:
        """(T,) boom headings at times (T,), radians."""
        return self.heading_rate(times)[0]

    def boom_boxes(self, times: np.ndarray) -> np.ndarray:
        """(T, n, 6) the boom's cubes at times (T,)."""
        th = self.heading(times)
        d = np.stack([np.cos(th), np.sin(th)], axis=1)  # (T, 2)
        r = self.radii_m
        c = np.empty((len(th), len(r), 3))
        c[..., :2] = self.pivot[:2] + r[None, :, None] * d[:, None, :]
        c[..., 2] = self.pivot[2]
        h = self.cube_m / 2
        return np.concatenate([c - h, c + h], axis=-1)

    def tip(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Boom tip ``pivot + length * heading`` (T, 3) metres and its velocity (T, 3) m/s."""
        th, w = self.heading_rate(times)
        d = np.stack([np.cos(th), np.sin(th), np.zeros_like(th)], axis=1)
        perp = np.stack([-np.sin(th), np.cos(th), np.zeros_like(th)], axis=1)
        return self.pivot + self.length_m * d, (w * self.length_m)[:, None] * perp

    def to_dict(self) -> dict:
        return {
            "type": "crane",
            "pivot": self.pivot.tolist(),
            "base_z": float(self.base_z),
            "length_m": float(self.length_m),
            "omega_rad_s": float(self.omega_rad_s),
            "theta0_rad": float(self.theta0_rad),
            "cube_m": float(self.cube_m),
            "tower_half_m": float(self.tower_half_m),
            "tower_cap_m": float(self.tower_cap_m),
            "sweep_rad": float(self.sweep_rad),
            "phase_rad": float(self.phase_rad),
        }


def _motion_from_dict(d: dict) -> PolylineMotion | CraneMotion:
    kind = d.get("type")
    args = {k: v for k, v in d.items() if k != "type"}
    try:
        if kind == "polyline":
            return PolylineMotion(np.asarray(args.pop("points"), dtype=np.float64), **args)
        if kind == "crane":
            return CraneMotion(np.asarray(args.pop("pivot"), dtype=np.float64), **args)
    except (KeyError, TypeError) as exc:
        raise InputError(f"bad mover motion description {d!r}: {exc}") from None
    raise InputError(f"unknown mover motion type {kind!r} (expected 'polyline' or 'crane')")


# ----- movers -------------------------------------------------------------------------------------
@dataclass(eq=False)
class Mover:
    """One moving obstacle.

    Attributes:
        name: unique label (``drone-0``, ``vehicle-2``, ``crane-0``).
        kind: ``"drone"``, ``"vehicle"`` or ``"crane"``.
        motion: :class:`PolylineMotion` (drones, vehicles) or :class:`CraneMotion` (cranes).
        size_m: (3,) full size of the body box along world x, y, z, metres (polyline movers; a
            vehicle's long axis lies along its street). Unused by cranes.
        material: texture material (``sim.texture.MAT_*``) of every box.
        albedo, accent: (3,) RGB in [0, 1].
        texture_scale: texture scale (``box_params[:, 5]``), smaller is finer.
        new_since_map: the obstacle was not there on the last flight (a crane on a building site).
    """

    name: str
    kind: str
    motion: PolylineMotion | CraneMotion
    size_m: np.ndarray = field(default_factory=lambda: np.array(DRONE_SIZE_M))
    material: int = MAT_METAL
    albedo: np.ndarray = field(default_factory=lambda: np.array([0.85, 0.45, 0.12]))
    accent: np.ndarray = field(default_factory=lambda: np.array([0.2, 0.2, 0.22]))
    texture_scale: float = 0.3
    new_since_map: bool = False

    def __post_init__(self) -> None:
        if self.kind not in MOVER_KINDS:
            raise InputError(f"mover {self.name!r}: kind must be one of {MOVER_KINDS}, got {self.kind!r}")
        if (self.kind == "crane") != isinstance(self.motion, CraneMotion):
            raise InputError(
                f"mover {self.name!r}: a crane needs a CraneMotion, other kinds a PolylineMotion"
            )
        self.size_m = np.asarray(self.size_m, dtype=np.float64).reshape(3)
        self.albedo = np.asarray(self.albedo, dtype=np.float64).reshape(3)
        self.accent = np.asarray(self.accent, dtype=np.float64).reshape(3)
        if self.kind != "crane" and not np.all(self.size_m > 0):
            raise InputError(f"mover {self.name!r}: size_m must be positive, got {self.size_m}")

    @property
    def num_boxes(self) -> int:
        """Boxes per instant (constant in time)."""
        return 1 + len(self.motion.radii_m) if isinstance(self.motion, CraneMotion) else 1

    @property
    def period_s(self) -> float:
        """Seconds until the geometry repeats."""
        return self.motion.period_s

    @property
    def max_speed_mps(self) -> float:
        """Fastest speed of any of its points, m/s (the boom tip for a crane)."""
        m = self.motion
        return abs(m.omega_rad_s) * m.length_m if isinstance(m, CraneMotion) else m.speed_mps

    def boxes_many(self, times: np.ndarray) -> np.ndarray:
        """(T, K, 6) the mover's boxes at times (T,) seconds (crane: tower first, then the boom's cubes)."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        m = self.motion
        if isinstance(m, CraneMotion):
            tower = np.broadcast_to(m.tower_box, (len(t), 1, 6))
            return np.concatenate([tower, m.boom_boxes(t)], axis=1)
        c, _ = m.at(t)
        h = self.size_m / 2
        return np.concatenate([c - h, c + h], axis=1)[:, None, :]

    def boxes_at(self, t: float) -> np.ndarray:
        """(K, 6) float64 the mover's axis-aligned boxes at time t seconds, world metres."""
        return self.boxes_many(np.array([float(t)]))[0]

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(centre (3,), velocity (3,), half_size (3,)) at t: the body box for polyline movers; for a
        crane the boom's bounding box centre and half size and the velocity of the boom's tip."""
        m = self.motion
        if isinstance(m, CraneMotion):
            b = m.boom_boxes(np.array([float(t)]))[0]
            lo, hi = b[:, :3].min(axis=0), b[:, 3:].max(axis=0)
            _, v = m.tip(np.array([float(t)]))
            return (lo + hi) / 2, v[0], (hi - lo) / 2
        c, v = m.at(np.array([float(t)]))
        return c[0], v[0], self.size_m / 2

    def tip_at(self, t: float) -> np.ndarray:
        """(3,) the boom tip of a crane at t (the body centre of other movers), metres."""
        m = self.motion
        if isinstance(m, CraneMotion):
            return m.tip(np.array([float(t)]))[0][0]
        return m.at(np.array([float(t)]))[0][0]

    def swept_boxes(self, t0: float, t1: float) -> np.ndarray:
        """(K, 6) boxes covering every box of the mover during [t0, t1] (sampled every 0.1 m of motion and
        padded by 0.1 m, so they contain the true swept volume)."""
        n = max(2, int(math.ceil(abs(t1 - t0) * self.max_speed_mps / 0.1)) + 1)
        b = self.boxes_many(np.linspace(t0, t1, n))
        return np.concatenate([b[..., :3].min(axis=0) - 0.1, b[..., 3:].max(axis=0) + 0.1], axis=1)

    def bounds(self) -> np.ndarray:
        """(6,) a box holding every box of the mover at every time, metres."""
        m = self.motion
        if isinstance(m, CraneMotion):
            r = m.length_m + m.cube_m
            x, y, h = m.pivot
            boom = np.array([x - r, y - r, h - m.cube_m / 2, x + r, y + r, h + m.cube_m / 2])
            t = m.tower_box
            return np.concatenate([np.minimum(boom[:3], t[:3]), np.maximum(boom[3:], t[3:])])
        h = self.size_m / 2
        return np.concatenate([m.points.min(axis=0) - h, m.points.max(axis=0) + h])

    def distance(self, points: np.ndarray, times: np.ndarray) -> np.ndarray:
        """(N,) signed distance of points (N, 3) at their times (N,) to this mover, metres."""
        t = np.asarray(times, dtype=np.float64)
        if t.ndim == 0:
            return box_sdf(points, self.boxes_at(float(t))).min(axis=1)
        return box_sdf(points, self.boxes_many(t)).min(axis=1)

    def to_dict(self) -> dict:
        """JSON-able description (re-create with :meth:`from_dict`)."""
        return {
            "name": self.name,
            "kind": self.kind,
            "motion": self.motion.to_dict(),
            "size_m": self.size_m.tolist(),
            "material": int(self.material),
            "albedo": self.albedo.tolist(),
            "accent": self.accent.tolist(),
            "texture_scale": float(self.texture_scale),
            "new_since_map": bool(self.new_since_map),
        }

    @classmethod
    def from_dict(cls, d: dict) -> Mover:
        """The mover described by ``d`` (as written by :meth:`to_dict`)."""
        try:
            args = dict(d)
            motion = _motion_from_dict(args.pop("motion"))
            return cls(motion=motion, **args)
        except (KeyError, TypeError) as exc:
            raise InputError(f"bad mover description {d!r}: {exc}") from None


@dataclass(eq=False)
class MoverSnapshot(City):
    """A :class:`City` with the movers' boxes at one instant appended after the static boxes.

    Attributes (besides City's):
        time_s: the instant, seconds.
        box_mover: (N,) int32 per box: the index of the mover it belongs to, -1 for static boxes.
    """

    time_s: float = 0.0
    box_mover: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))


def mover_of_object_id(snapshot: MoverSnapshot, object_id: np.ndarray) -> np.ndarray:
    """Which mover each rendered pixel shows.

    Args:
        snapshot: the scene that was rendered (:meth:`MovingScene.snapshot`).
        object_id: (H, W) (or any shape) int object ids of a render / raycast of ``snapshot``.
    Returns:
        int32 array of object_id's shape: the mover index (into ``MovingScene.movers``), -1 elsewhere.
    """
    oid = np.asarray(object_id)
    bm = np.asarray(snapshot.box_mover, dtype=np.int32)
    if len(bm) != len(snapshot.boxes):
        raise InputError("mover_of_object_id needs a MovingScene.snapshot (box_mover has the wrong length)")
    is_box = (oid >= 1) & (oid <= len(bm))
    idx = np.clip(oid - 1, 0, max(len(bm) - 1, 0))
    return np.where(is_box, bm[idx] if len(bm) else -1, -1).astype(np.int32)


# ----- the scene ----------------------------------------------------------------------------------
@dataclass(eq=False)
class MovingScene:
    """A static city and its movers.

    Attributes:
        static: the static city.
        movers: the moving obstacles; index i is the mover id of :func:`mover_of_object_id`.
        seed: the seed that drew the movers (informational).
    """

    static: City
    movers: list[Mover]
    seed: int = 0

    def __post_init__(self) -> None:
        names = [m.name for m in self.movers]
        if len(set(names)) != len(names):
            raise InputError(f"mover names must be unique, got {names}")
        s = self.static
        n = len(s.boxes)
        self._box_mover = np.concatenate(
            [np.full(n, -1, np.int32)]
            + [np.full(m.num_boxes, i, np.int32) for i, m in enumerate(self.movers)]
        )
        k = len(self._box_mover) - n
        mat = np.concatenate([[m.material] * m.num_boxes for m in self.movers]) if k else np.zeros(0)
        alb = [np.tile(m.albedo, (m.num_boxes, 1)) for m in self.movers]
        acc = [np.tile(m.accent, (m.num_boxes, 1)) for m in self.movers]
        par = [np.tile([3.0, 0.0, 0.5, 0.5, 0.0, m.texture_scale], (m.num_boxes, 1)) for m in self.movers]
        self._material = np.concatenate([s.box_material, np.asarray(mat, np.int32)])
        self._kind = np.concatenate([s.box_kind, np.full(k, KIND_MOVER, np.int32)])
        self._albedo = np.concatenate([s.box_albedo, *alb]) if k else s.box_albedo
        self._accent = np.concatenate([s.box_accent, *acc]) if k else s.box_accent
        self._params = np.concatenate([s.box_params, *par]) if k else s.box_params

    # ----- geometry at an instant ----------------------------------------------------------------
    def mover_boxes(self, t: float) -> np.ndarray:
        """(K, 6) every mover's boxes at t seconds, in mover order (see :func:`mover_of_object_id`)."""
        parts = [m.boxes_at(t) for m in self.movers]
        return np.concatenate(parts) if parts else np.zeros((0, 6))

    def snapshot(self, t: float) -> MoverSnapshot:
        """The static city plus every mover's boxes at time t seconds (textured, ``box_kind`` KIND_MOVER).

        Object ids of static boxes are unchanged; cylinder ids shift by the number of mover boxes.
        """
        s = self.static
        same = {f.name: getattr(s, f.name) for f in fields(City) if f.init}  # everything but the boxes
        same.update(
            boxes=np.concatenate([s.boxes, self.mover_boxes(t)]),
            box_material=self._material,
            box_kind=self._kind,
            box_albedo=self._albedo,
            box_accent=self._accent,
            box_params=self._params,
        )
        return MoverSnapshot(**same, time_s=float(t), box_mover=self._box_mover)

    def mover_of_object_id(self, snapshot: MoverSnapshot, object_id: np.ndarray) -> np.ndarray:
        """See :func:`mover_of_object_id`."""
        return mover_of_object_id(snapshot, object_id)

    def mover_states(self, t: float) -> list[dict]:
        """Per mover at t: ``name``, ``kind``, ``center`` (3,), ``velocity`` (3,), ``half_size`` (3,)
        (world metres, m/s; see :meth:`Mover.state_at`)."""
        out = []
        for m in self.movers:
            c, v, h = m.state_at(t)
            out.append({"name": m.name, "kind": m.kind, "center": c, "velocity": v, "half_size": h})
        return out

    @property
    def new_obstacles(self) -> list[Mover]:
        """Movers that were not there on the last flight (the crane's tower and boom)."""
        return [m for m in self.movers if m.new_since_map]

    def new_obstacle_boxes(self, t: float) -> np.ndarray:
        """(K, 6) the boxes of :attr:`new_obstacles` at t."""
        parts = [m.boxes_at(t) for m in self.new_obstacles]
        return np.concatenate(parts) if parts else np.zeros((0, 6))

    # ----- distances -----------------------------------------------------------------------------
    def static_distance(self, points: np.ndarray, include_ground: bool = True) -> np.ndarray:
        """(N,) signed distance of points (N, 3) to the static city, metres."""
        return self.static.distance(points, include_ground)

    def mover_distance(self, points: np.ndarray, times: np.ndarray | float) -> np.ndarray:
        """(N,) signed distance of points (N, 3) to the nearest mover, each point at its own time.

        Args:
            points: (N, 3) world metres.
            times: (N,) seconds, or one time for all points.
        Returns:
            (N,) metres (< 0 inside a mover); inf where there are no movers.
        """
        p = _points(points)
        t = np.asarray(times, dtype=np.float64)
        self._check_times(t, len(p))
        out = np.full(len(p), np.inf)
        chunk = 8192
        for i in range(0, len(p), chunk):
            pc = p[i : i + chunk]
            tc = t if t.ndim == 0 else t[i : i + chunk]
            for m in self.movers:
                out[i : i + chunk] = np.minimum(out[i : i + chunk], m.distance(pc, tc))
        return out

    def distance(
        self, points: np.ndarray, times: np.ndarray | float, include_ground: bool = True
    ) -> np.ndarray:
        """(N,) exact signed distance of points (N, 3) to the nearest static or moving obstacle, metres,
        each point at its own time (times (N,) seconds or one number); ``snapshot(t).distance`` at one t."""
        p = _points(points)
        t = np.asarray(times, dtype=np.float64)
        self._check_times(t, len(p))
        d = self.static_distance(p, include_ground)
        for m in self.movers:
            # the distance to a box holding the mover at all times is a lower bound of the distance to it
            need = box_sdf(p, m.bounds()[None])[:, 0] < d
            if np.any(need):
                d[need] = np.minimum(d[need], m.distance(p[need], t if t.ndim == 0 else t[need]))
        return d

    @staticmethod
    def _check_times(t: np.ndarray, n: int) -> None:
        if t.ndim != 0 and t.shape != (n,):
            raise InputError(f"times must be a number or have shape ({n},), got {t.shape}")
        if not np.all(np.isfinite(t)):
            raise InputError("times contain NaN or infinite values")

    # ----- checks and serialisation --------------------------------------------------------------
    def validate(self, start: np.ndarray, clearance_m: float, horizon_s: float | None = None) -> None:
        """Check user-given movers against the static city and the drone's start.

        Raises :class:`InputError` (one line naming the mover) when a mover's geometry overlaps a static
        obstacle at a sampled instant (every 0.25 m of its motion over one period, or ``horizon_s``),
        or comes within ``clearance_m`` of ``start`` (3,) during the first 3 s.
        """
        start = _points(start, "start")
        for m in self.movers:
            _check_static(self.static, m, horizon_s)
            ts = np.arange(0.0, 3.0 + 1e-9, 0.05)
            d = m.distance(np.repeat(start, len(ts), axis=0), ts)
            if np.any(d < clearance_m):
                k = int(np.argmin(d))
                raise InputError(
                    f"mover {m.name!r} ({m.kind}) comes within {d[k]:.2f} m of the start at t={ts[k]:.2f} s "
                    f"(clearance {clearance_m} m); move it away from the start"
                )

    def to_dict(self) -> dict:
        """JSON-able description of the movers (the static city is re-created from its own seed)."""
        return {"seed": int(self.seed), "movers": [m.to_dict() for m in self.movers]}

    @classmethod
    def from_dict(cls, d: dict, static: City) -> MovingScene:
        """The scene described by ``d`` (from :meth:`to_dict`) over the static city ``static``."""
        if not isinstance(d, dict) or not isinstance(d.get("movers"), list):
            raise InputError("a moving scene description needs a 'movers' list")
        return cls(static, [Mover.from_dict(m) for m in d["movers"]], int(d.get("seed", 0)))


def _sample_times(m: Mover, horizon_s: float | None, step_m: float = 0.25) -> np.ndarray:
    span = m.period_s if horizon_s is None else float(horizon_s)
    if not np.isfinite(span):
        span = 0.0
    n = max(2, int(math.ceil(span * m.max_speed_mps / step_m)) + 1)
    return np.linspace(0.0, span, n)


def _check_static(city: City, m: Mover, horizon_s: float | None = None, margin: float = 0.0) -> None:
    ts = _sample_times(m, horizon_s)
    b = m.boxes_many(ts)
    k = b.shape[1]
    hit = _static_overlap(city, b.reshape(-1, 6), margin)
    if np.any(hit):
        j = int(np.argmax(hit))
        c = (b.reshape(-1, 6)[j, :3] + b.reshape(-1, 6)[j, 3:]) / 2
        raise InputError(
            f"mover {m.name!r} ({m.kind}) lies inside a static obstacle at t={ts[j // k]:.2f} s near "
            f"({c[0]:.1f}, {c[1]:.1f}, {c[2]:.1f}); move its path away from the buildings"
        )


# ----- generation ---------------------------------------------------------------------------------
_DRONE_COLOURS = [
    (0.9, 0.45, 0.1),
    (0.85, 0.15, 0.15),
    (0.15, 0.55, 0.85),
    (0.95, 0.85, 0.2),
    (0.6, 0.2, 0.7),
]
_CAR_COLOURS = [
    (0.8, 0.1, 0.1),
    (0.1, 0.25, 0.6),
    (0.9, 0.9, 0.88),
    (0.15, 0.15, 0.17),
    (0.2, 0.5, 0.25),
    (0.75, 0.6, 0.15),
]
_CRANE_COLOUR = (0.92, 0.72, 0.08)


def _colour(rng: np.random.Generator, palette: list) -> np.ndarray:
    c = np.asarray(palette[int(rng.integers(len(palette)))], dtype=np.float64)
    return np.clip(c * (1.0 + rng.uniform(-0.06, 0.06, 3)), 0.0, 1.0)


def _path_arc(path: np.ndarray) -> np.ndarray:
    """(K,) cumulative 3-D arc length along the waypoints (K, 3), metres."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])


def _path_at(path: np.ndarray, cum: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
    """Point (3,) at arc s and the horizontal unit direction (2,) of its segment."""
    k = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(path) - 2))
    seg = path[k + 1] - path[k]
    f = (s - cum[k]) / max(cum[k + 1] - cum[k], 1e-12)
    d = seg[:2] / max(np.linalg.norm(seg[:2]), 1e-12)
    return path[k] + f * seg, d


def _horizontal_distance_to_polyline(p: np.ndarray, poly: np.ndarray) -> float:
    """Horizontal distance from p (2,) to the polyline (K, >=2), metres."""
    a, b = poly[:-1, :2], poly[1:, :2]
    ab = b - a
    f = np.clip(np.sum((p - a) * ab, axis=1) / np.maximum(np.sum(ab * ab, axis=1), 1e-12), 0.0, 1.0)
    return float(np.min(np.linalg.norm(a + f[:, None] * ab - p, axis=1)))


def _free_run(city: City, p: np.ndarray, u: np.ndarray, max_len: float, clear: float, extra: list) -> float:
    """How far (<= max_len, metres) a point can go from p (3,) along u (3,) keeping ``clear`` metres from
    the static city and from the extra boxes (list of (6,)) and 1 m inside the city's extent."""
    step = 0.5
    s = np.arange(0.0, max_len + 1e-9, step)
    pts = p + s[:, None] * u
    d = city.distance(pts, include_ground=True)
    if extra:
        d = np.minimum(d, box_sdf(pts, np.asarray(extra)).min(axis=1))
    e = city.extent
    inside = (pts[:, 0] > e[0] + 1) & (pts[:, 0] < e[2] - 1) & (pts[:, 1] > e[1] + 1) & (pts[:, 1] < e[3] - 1)
    # between samples 0.5 m apart the distance dips by at most 0.25 m
    bad = np.nonzero((d < clear + step / 2) | ~inside)[0]
    if len(bad) == 0:
        return float(s[-1])
    return float(s[bad[0] - 1]) if bad[0] > 0 else -1.0


def _keeps_off_endpoints(m: Mover, start: np.ndarray, goal: np.ndarray) -> bool:
    """No closer than 6 m to the start in the first 5 s, nor 4 m to the goal ever (sampled)."""
    ts = np.arange(0.0, 5.0 + 1e-9, 0.05)
    if np.any(m.distance(np.repeat(start[None], len(ts), axis=0), ts) < 6.0):
        return False
    ts = _sample_times(m, None, step_m=0.2)
    return bool(np.all(m.distance(np.repeat(goal[None], len(ts), axis=0), ts) >= 4.1))


def _in_city(city: City, m: Mover) -> bool:
    try:
        _check_static(city, m, margin=0.3 if m.kind == "vehicle" else 0.0)
    except InputError:
        return False
    return True


def _conflicts(a: Mover, others: list[Mover], horizon_s: float) -> bool:
    """Whether mover a comes within a margin of another mover during [0, horizon_s] (sampled every 0.1 s;
    a drone against a crane: whether its polyline passes within reach of the boom at its height)."""
    ts = np.arange(0.0, horizon_s, 0.1)
    for b in others:
        if {a.kind, b.kind} == {"drone", "crane"}:
            d, c = (a, b) if a.kind == "drone" else (b, a)
            cm, dm = c.motion, d.motion
            assert isinstance(cm, CraneMotion) and isinstance(dm, PolylineMotion)
            pts = dm._loop
            sample = np.concatenate([np.linspace(p, q, 50) for p, q in zip(pts[:-1], pts[1:])])
            near = np.linalg.norm(sample[:, :2] - cm.pivot[:2], axis=1) < cm.length_m + 2.5
            if np.any(near & (np.abs(sample[:, 2] - cm.pivot[2]) < cm.cube_m / 2 + d.size_m[2] / 2 + 2.0)):
                return True
            if np.min(box_sdf(sample, cm.tower_box[None])) < DRONE_CLEARANCE_M:
                return True
            continue
        margin = 1.5 if "drone" in (a.kind, b.kind) else 0.75
        ba, bb = a.boxes_many(ts), b.boxes_many(ts)
        lo = ba[:, :, None, :3] - margin
        hi = ba[:, :, None, 3:] + margin
        if np.any(np.all((bb[:, None, :, :3] < hi) & (bb[:, None, :, 3:] > lo), axis=-1)):
            return True
    return False


def _crane_sector(
    items: np.ndarray, pivot_xy: np.ndarray, length: float, h: float, extent: np.ndarray, toward: float
) -> tuple[float, float] | None:
    """The widest arc of boom headings containing ``toward`` (radians) over which the boom at height h
    stays >= 3 m above every item (bounds (K, 6)) and inside the extent: (theta0, sweep) radians, sweep
    2 pi for a full circle; None when the arc is narrower than 60 degrees."""
    nbin = 180
    th = np.arange(nbin) * (2.0 * math.pi / nbin)
    r = np.arange(0.0, length + 1e-9, 0.5)
    xy = pivot_xy + r[None, :, None] * np.stack([np.cos(th), np.sin(th)], axis=1)[:, None, :]  # (B, R, 2)
    ok = np.all(
        (xy[..., 0] > extent[0])
        & (xy[..., 0] < extent[2])
        & (xy[..., 1] > extent[1])
        & (xy[..., 1] < extent[3]),
        axis=1,
    )
    q = np.maximum(np.maximum(items[:, :2] - pivot_xy, pivot_xy - items[:, 3:5]), 0.0)
    near = items[(np.linalg.norm(q, axis=1) < length + 2.5) & (items[:, 5] > h - 3.0)]
    if len(near):
        pts = xy.reshape(-1, 2)
        # boom cube half-diagonal 0.71 m + 2 degrees of rotation at the tip (<= 1 m) + sampling
        lo, hi = near[:, :2] - 2.2, near[:, 3:5] + 2.2
        inside = np.any(np.all((pts[:, None] > lo[None]) & (pts[:, None] < hi[None]), axis=2), axis=1)
        ok &= ~inside.reshape(nbin, len(r)).any(axis=1)
    if ok.all():
        return 0.0, 2.0 * math.pi
    k0 = int(np.round(np.mod(toward, 2.0 * math.pi) / (2.0 * math.pi / nbin))) % nbin
    if not ok[k0]:
        return None
    lo_k, hi_k = k0, k0
    while ok[(lo_k - 1) % nbin] and k0 - lo_k < nbin:
        lo_k -= 1
    while ok[(hi_k + 1) % nbin] and hi_k - k0 < nbin:
        hi_k += 1
    lo_k, hi_k = lo_k + 1, hi_k - 1  # one bin of safety at each end
    sweep = (hi_k - lo_k) * 2.0 * math.pi / nbin
    if sweep < math.radians(60.0):
        return None
    return lo_k * 2.0 * math.pi / nbin, sweep


def _place_crane(
    city: City,
    rng: np.random.Generator,
    path: np.ndarray,
    start: np.ndarray,
    goal: np.ndarray,
    band: tuple[float, float],
    attempts: int = 400,
) -> Mover | None:
    """A tower crane on a block (on the ground or on one building's roof) whose boom sweeps over the path
    when such a spot exists (else anywhere), at 16-24 m and >= 3 m above everything it sweeps over: round
    and round when nothing nearby is that tall, else back and forth over a sector (>= 60 degrees)."""
    bx, by, e = city.blocks_x, city.blocks_y, city.extent
    if len(bx) == 0 or len(by) == 0:
        return None
    sb, c = city.boxes, city.cylinders
    cyl_b = np.stack(
        [c[:, 0] - c[:, 2], c[:, 1] - c[:, 2], c[:, 3], c[:, 0] + c[:, 2], c[:, 1] + c[:, 2], c[:, 4]], 1
    )
    items = np.concatenate([sb, cyl_b.reshape(-1, 6)])
    h_cap = min(24.0, band[1] - 2.0)
    cum = _path_arc(path) if len(path) >= 2 else np.zeros(1)
    for attempt in range(attempts):
        near_path = attempt < 3 * attempts // 4 and len(path) >= 2 and cum[-1] > 0
        length = rng.uniform(18.0, 28.0)
        if near_path:  # beside the path, the boom reaching over it
            p, d = _path_at(path, cum, rng.uniform(0.0, cum[-1]))
            off = rng.uniform(6.0, length - 5.0) * rng.choice([-1.0, 1.0])
            x, y = p[0] - d[1] * off, p[1] + d[0] * off
            inb = np.any((bx[:, 0] + 1.5 < x) & (x < bx[:, 1] - 1.5)) and np.any(
                (by[:, 0] + 1.5 < y) & (y < by[:, 1] - 1.5)
            )
            if not inb:
                continue
        else:
            i, j = int(rng.integers(len(bx))), int(rng.integers(len(by)))
            x = rng.uniform(bx[i, 0] + 1.5, bx[i, 1] - 1.5)
            y = rng.uniform(by[j, 0] + 1.5, by[j, 1] - 1.5)
        if len(path) >= 2 and _horizontal_distance_to_polyline(np.array([x, y]), path) < 5.0:
            continue
        # what stands under the tower's footprint (grown by 0.3 m): nothing, or one building's roof
        fp_lo, fp_hi = np.array([x - 1.3, y - 1.3]), np.array([x + 1.3, y + 1.3])
        under = np.all((items[:, :2] < fp_hi) & (items[:, 3:5] > fp_lo), axis=1)
        if np.count_nonzero(under) > 1:
            continue
        base = 0.0
        if np.any(under):
            k = int(np.argmax(under))
            inside = np.all(items[k, :2] <= fp_lo) and np.all(items[k, 3:5] >= fp_hi)
            if k >= len(sb) or not inside:
                continue
            base = float(items[k, 5])
        if near_path:
            kz = int(np.argmin(np.linalg.norm(path[:, :2] - [x, y], axis=1)))
            h = max(16.0, path[kz, 2] + rng.uniform(1.0, 2.5))
            toward = math.atan2(p[1] - y, p[0] - x)
        else:
            h = rng.uniform(16.0, 22.0)
            toward = rng.uniform(0.0, 2.0 * math.pi)
        if h > h_cap or h - 0.5 - base < 6.0:
            continue
        sector = _crane_sector(items, np.array([x, y]), length, h, e, toward)
        if sector is None:
            continue
        theta0, sweep = sector
        omega = math.radians(rng.uniform(2.0, 5.0)) * rng.choice([-1.0, 1.0])
        if sweep >= 2.0 * math.pi:
            theta0, phase = rng.uniform(0.0, 2.0 * math.pi), 0.0
        else:
            phase = rng.uniform(0.0, 2.0 * sweep)
        motion = CraneMotion(
            np.array([x, y, h]), base, length, omega, theta0, sweep_rad=sweep, phase_rad=phase
        )
        m = Mover(
            "crane-0",
            "crane",
            motion,
            np.zeros(3),
            MAT_METAL,
            _colour(rng, [_CRANE_COLOUR]),
            np.array([0.2, 0.2, 0.2]),
            0.5,
            new_since_map=True,
        )
        if _keeps_off_endpoints(m, start, goal) and _in_city(city, m):
            return m
    return None


def _drone_polyline(
    city: City, rng: np.random.Generator, p: np.ndarray, u: np.ndarray, extra: list
) -> tuple[np.ndarray, float] | None:
    """A straight polyline through p (3,) along u (3,), 8-45 m each side, keeping DRONE_CLEARANCE_M;
    returns (vertices (2, 3), arc of p along it) or None."""
    a = _free_run(city, p, -u, rng.uniform(20.0, 45.0), DRONE_CLEARANCE_M, extra)
    b = _free_run(city, p, u, rng.uniform(20.0, 45.0), DRONE_CLEARANCE_M, extra)
    if a < 8.0 or b < 8.0:
        return None
    return np.stack([p - a * u, p + b * u]), a


def _crossing_drone(
    city: City,
    rng: np.random.Generator,
    name: str,
    path: np.ndarray,
    band: tuple[float, float],
    cruise_speed_mps: float,
    extra: list,
    pace: tuple[float, float] = (0.5, 0.7),
) -> Mover | None:
    """A drone whose polyline crosses the path at 45-90 degrees within 1.5 m of its altitude, passing the
    crossing point when a drone flying the path at ``pace`` (a range) x cruise speed would."""
    cum = _path_arc(path)
    total = cum[-1]
    lo, hi = min(max(20.0, 0.15 * total), 0.5 * total), max(total - max(15.0, 0.15 * total), 0.5 * total)
    s = rng.uniform(lo, hi)
    p, d = _path_at(path, cum, s)
    ang = math.radians(rng.uniform(45.0, 90.0)) * rng.choice([-1.0, 1.0])
    u = np.array(
        [d[0] * math.cos(ang) - d[1] * math.sin(ang), d[0] * math.sin(ang) + d[1] * math.cos(ang), 0.0]
    )
    z = float(np.clip(p[2] + rng.uniform(-1.5, 1.5), band[0] + 1.0, band[1] - 1.0))
    if abs(z - p[2]) > 2.0:
        return None
    pc = np.array([p[0], p[1], z])
    line = _drone_polyline(city, rng, pc, u, extra)
    if line is None:
        return None
    pts, arc = line
    speed = rng.uniform(2.0, DRONE_MAX_SPEED_MPS)
    t_cross = s / (rng.uniform(*pace) * cruise_speed_mps)
    length = float(np.linalg.norm(pts[1] - pts[0]))
    s_at_cross = arc if rng.random() < 0.5 else 2.0 * length - arc  # outbound or on the way back
    phase = float(np.mod(s_at_cross - speed * t_cross, 2.0 * length))
    return Mover(
        name,
        "drone",
        PolylineMotion(pts, speed, False, phase),
        np.array(DRONE_SIZE_M),
        MAT_METAL,
        _colour(rng, _DRONE_COLOURS),
        np.array([0.15, 0.15, 0.17]),
        0.3,
    )


def _roaming_drone(
    city: City, rng: np.random.Generator, name: str, band: tuple[float, float], extra: list
) -> Mover | None:
    """A drone flying back and forth along a street (sometimes turning into a cross street)."""
    xs, ys = city.street_centers
    along_x = rng.random() < 0.5
    lines = ys if along_x else xs
    if len(lines) == 0:
        return None
    c = float(lines[int(rng.integers(len(lines)))])
    e = city.extent
    a = rng.uniform(e[0] + 10, e[2] - 10) if along_x else rng.uniform(e[1] + 10, e[3] - 10)
    z = rng.uniform(band[0] + 1.0, band[1] - 1.0)
    p = np.array([a, c, z]) if along_x else np.array([c, a, z])
    u = np.array([1.0, 0.0, 0.0]) if along_x else np.array([0.0, 1.0, 0.0])
    line = _drone_polyline(city, rng, p, u, extra)
    if line is None:
        return None
    pts = line[0]
    if rng.random() < 0.5:  # a second leg at a right angle from the far end
        w = np.array([-u[1], u[0], 0.0]) * rng.choice([-1.0, 1.0])
        b = _free_run(city, pts[1], w, rng.uniform(15.0, 40.0), DRONE_CLEARANCE_M, extra)
        if b >= 8.0:
            pts = np.vstack([pts, pts[1] + b * w])
    motion = PolylineMotion(pts, rng.uniform(2.0, DRONE_MAX_SPEED_MPS), False, 0.0)
    motion = PolylineMotion(pts, motion.speed_mps, False, rng.uniform(0.0, motion.cycle_m))
    return Mover(
        name,
        "drone",
        motion,
        np.array(DRONE_SIZE_M),
        MAT_METAL,
        _colour(rng, _DRONE_COLOURS),
        np.array([0.15, 0.15, 0.17]),
        0.3,
    )


def _vehicle(city: City, rng: np.random.Generator, name: str, used: set) -> Mover | None:
    """A vehicle looping along a street: out in the right-hand lane, across at the city's end, back."""
    xs, ys = city.street_centers
    wx, wy = city.street_widths
    along_x = rng.random() < 0.5
    lines, widths = (ys, wy) if along_x else (xs, wx)
    if len(lines) == 0:
        return None
    k = int(rng.integers(len(lines)))
    if (along_x, k) in used:
        return None
    c, w = float(lines[k]), float(widths[k])
    half = np.array(VEHICLE_SIZE_M) / 2
    if not along_x:
        half = half[[1, 0, 2]]
    off = min(w / 4.0, w / 2.0 - 0.95 - 0.8)
    if off < 1.2:
        return None
    e = city.extent
    a0, a1 = (e[0], e[2]) if along_x else (e[1], e[3])
    a0, a1 = a0 + 2.25 + 0.75, a1 - 2.25 - 0.75
    zc = half[2]
    if along_x:  # eastbound on y = c - off, westbound on y = c + off
        pts = [[a0, c - off, zc], [a1, c - off, zc], [a1, c + off, zc], [a0, c + off, zc]]
    else:  # northbound on x = c + off, southbound on x = c - off
        pts = [[c + off, a0, zc], [c + off, a1, zc], [c - off, a1, zc], [c - off, a0, zc]]
    motion = PolylineMotion(np.array(pts), rng.uniform(5.0, 12.0), True, 0.0)
    motion = PolylineMotion(motion.points, motion.speed_mps, True, rng.uniform(0.0, motion.cycle_m))
    used.add((along_x, k))
    return Mover(
        name,
        "vehicle",
        motion,
        2.0 * half,
        MAT_METAL,
        _colour(rng, _CAR_COLOURS),
        np.array([0.1, 0.1, 0.12]),
        0.5,
    )


def make_movers(
    city: City,
    seed: int,
    start: np.ndarray,
    goal: np.ndarray,
    path: np.ndarray,
    *,
    n_drones: int = 3,
    n_vehicles: int = 4,
    crane: bool = True,
    band: tuple[float, float] = (12.0, 30.0),
    cruise_speed_mps: float = 6.0,
    attempts: int = 200,
    pace: tuple[float, float] = (0.5, 0.7),
    plain: bool = False,
) -> MovingScene:
    """Draw the movers of a delivery mission, deterministically from ``seed``.

    Args:
        city: the static city.
        seed: with the constant ``_SEED_TAG`` seeds ``numpy.random.default_rng``.
        start, goal: (3,) the mission's endpoints, world metres.
        path: (K, 3) the mission's reference path (the shortest feasible path), world metres.
        n_drones: drones; the first ``ceil(n_drones / 2)`` cross the path (45-90 degrees, within 2 m of its
            altitude) when a drone flying it at ``pace`` x ``cruise_speed_mps`` passes; the others roam
            the streets. Each flies at 2-4.5 m/s, its polyline >= 2.5 m from every static obstacle.
        n_vehicles: vehicles on distinct streets at 5-12 m/s.
        crane: place a tower crane (boom 18-28 m at 16-24 m, 2-5 deg/s) whose boom sweeps over the path
            if a spot exists (else anywhere); flagged ``new_since_map``.
        band: the flight band (min, max altitude), metres.
        cruise_speed_mps: the mission's cruise speed, m/s.
        attempts: draws per mover before it is skipped.
        pace: the crossing drones are timed for a drone flying the path at this fraction (a range,
            drawn per drone) of ``cruise_speed_mps`` (faster with a prior map: the drone needs not
            stop to look around).
        plain: every mover's surfaces are plain paint (``MAT_PLAIN``: no texture but their
            outline against what lies behind) instead of metal; the same movers on the same
            paths as with ``plain=False`` and the same seed.
    Returns:
        The :class:`MovingScene`. No mover comes within 6 m of ``start`` in the first 5 s, within 4 m of
        ``goal`` ever, overlaps the static city (sampled), or (within the mission's horizon) another mover.
    """
    rng = np.random.default_rng([int(seed), _SEED_TAG])
    start = _points(start, "start")[0]
    goal = _points(goal, "goal")[0]
    path = _points(path, "path")
    band = (float(band[0]), float(band[1]))
    cum = _path_arc(path)
    horizon = float(np.clip(2.0 * cum[-1] / (0.5 * cruise_speed_mps), 60.0, 240.0))
    movers: list[Mover] = []
    extra: list = []
    if crane:
        m = _place_crane(city, rng, path, start, goal, band)
        if m is not None and isinstance(m.motion, CraneMotion):
            movers.append(m)
            extra.append(m.motion.tower_box)
    n_cross = (n_drones + 1) // 2 if len(path) >= 2 and cum[-1] > 30.0 else 0
    for i in range(n_drones):
        for _ in range(attempts):
            name = f"drone-{i}"
            if i < n_cross:
                m = _crossing_drone(city, rng, name, path, band, cruise_speed_mps, extra, pace)
            else:
                m = _roaming_drone(city, rng, name, band, extra)
            if m is None or not _keeps_off_endpoints(m, start, goal) or _conflicts(m, movers, horizon):
                continue
            movers.append(m)
            break
    used: set = set()
    for i in range(n_vehicles):
        for _ in range(attempts):
            trial = set(used)
            m = _vehicle(city, rng, f"vehicle-{i}", trial)
            if m is None or not _in_city(city, m) or not _keeps_off_endpoints(m, start, goal):
                continue
            if _conflicts(m, movers, horizon):
                continue
            used = trial
            movers.append(m)
            break
    if plain:
        movers = [replace(m, material=MAT_PLAIN) for m in movers]
    return MovingScene(city, movers, int(seed))
