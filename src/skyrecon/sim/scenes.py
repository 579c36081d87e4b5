"""Ready-made cameras for the synthetic city: a stereo rig, street views, drone flights, rings
and orbits around an object. All poses are deterministic functions of their seed.

Conventions: world frame z up, metres; cameras OpenCV (x right, y down, z forward).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyrecon.core import Intrinsics, PosedView, Rigid3, StereoRig
from skyrecon.errors import EstimationError, InputError
from skyrecon.sim.city import City
from skyrecon.sim.render import render_views
from skyrecon.sim.texture import MAT_PLAIN

__all__ = [
    "default_rig",
    "street_view_pose",
    "flight_poses",
    "flight_path",
    "ring_views",
    "orbit_views",
    "render_views",
    "look_from",
]


def default_rig(
    width: int = 640, height: int = 480, hfov_deg: float = 90.0, baseline_m: float = 0.12
) -> StereoRig:
    """A rectified stereo rig (square pixels, principal point at the centre, horizontal field of view
    ``hfov_deg``), the right camera ``baseline_m`` metres to the right of the left one."""
    return StereoRig.rectified(Intrinsics.from_fov(width, height, hfov_deg), baseline_m)


def look_from(eye_world: np.ndarray, yaw_rad: float, pitch_down_rad: float) -> Rigid3:
    """``cam_from_world`` of a level camera at ``eye`` (3,) heading ``yaw`` (radians from +x towards +y),
    tilted down by ``pitch_down`` radians (no roll)."""
    eye = np.asarray(eye_world, dtype=np.float64)
    fwd = np.array(
        [
            math.cos(pitch_down_rad) * math.cos(yaw_rad),
            math.cos(pitch_down_rad) * math.sin(yaw_rad),
            -math.sin(pitch_down_rad),
        ]
    )
    return Rigid3.look_at(eye, eye + fwd)


def _probe(city: City, cam_from_world: Rigid3, hfov_deg: float, aspect: float = 0.75, n: int = 40):
    """Cast a coarse grid of rays; returns (z-depths of the hits on obstacles, fraction on obstacles,
    fraction of sky, minimum z-depth of any hit, fraction on plain low-texture facades)."""
    cam = Intrinsics.from_fov(n, max(2, int(round(n * aspect))), hfov_deg)
    d_cam = cam.ray_directions().reshape(-1, 3)
    d_unit = d_cam / np.linalg.norm(d_cam, axis=1, keepdims=True)
    hits = city.raycast_hits(cam_from_world.center, cam_from_world.inverse().rotate(d_unit))
    z = hits.distance_m * d_unit[:, 2]
    obstacle = hits.object_id > 0
    finite = np.isfinite(z)
    box = hits.object_id[(hits.object_id > 0) & (hits.object_id <= len(city.boxes))] - 1
    plain = np.isin(city.box_material[box], (MAT_PLAIN,)).sum() / len(z)
    zmin = float(z[finite].min()) if finite.any() else np.inf
    return z[obstacle], obstacle.mean(), 1.0 - finite.mean(), zmin, plain


def street_view_pose(
    city: City, seed: int, hfov_deg: float = 90.0, altitude_m: tuple[float, float] = (10.0, 30.0)
) -> Rigid3:
    """A good left-camera pose for a street-level stereo pair.

    The camera hovers over a street at ``altitude_m`` (metres), looks along it with a yaw offset of
    up to 35 degrees towards the facades and a 5-20 degree downward pitch; it is at least 2 m from
    every obstacle, sees obstacles in at least a third of the image with a median depth of 8-60 m
    and nothing closer than 2.5 m, with at most a fifth of the image on plain (low-texture) facades.
    Deterministic in ``seed``.

    Returns:
        ``cam_from_world`` (OpenCV camera axes), metres.
    """
    rng = np.random.default_rng(seed)
    xs, ys = city.street_centers
    wx, wy = city.street_widths
    if len(xs) == 0 or len(ys) == 0:  # no streets: look at the centre from the view radius
        a = rng.uniform(0, 2 * np.pi)
        eye = city.center + city.view_radius_m * np.array([np.cos(a), np.sin(a), 0.5])
        return Rigid3.look_at(eye, city.center)
    x0, y0, x1, y1 = city.extent
    best, best_score = None, -np.inf
    for _ in range(80):
        along_x = rng.random() < 0.5
        lines, widths = (ys, wy) if along_x else (xs, wx)
        k = int(rng.integers(len(lines)))
        lateral = lines[k] + rng.uniform(-0.2, 0.2) * widths[k]
        lo, hi = (x0, x1) if along_x else (y0, y1)
        pos = rng.uniform(lo + 0.15 * (hi - lo), hi - 0.15 * (hi - lo))
        sign = 1.0 if (pos < (lo + hi) / 2) == (rng.random() < 0.8) else -1.0  # mostly look into the city
        z = rng.uniform(*altitude_m)
        eye = np.array([pos, lateral, z]) if along_x else np.array([lateral, pos, z])
        base_yaw = (0.0 if sign > 0 else np.pi) if along_x else (np.pi / 2 if sign > 0 else -np.pi / 2)
        yaw = base_yaw + np.radians(rng.uniform(-35.0, 35.0))
        pose = look_from(eye, yaw, np.radians(rng.uniform(5.0, 20.0)))
        if city.distance(eye, include_ground=True)[0] < 2.0:
            continue
        z_obj, frac_obj, frac_sky, zmin, frac_plain = _probe(city, pose, hfov_deg)
        if len(z_obj) == 0:
            continue
        med = float(np.median(z_obj))
        ok = frac_obj >= 0.35 and 8.0 <= med <= 60.0 and frac_sky < 0.4 and zmin >= 2.5 and frac_plain < 0.2
        score = (
            frac_obj
            - abs(np.log(med / 25.0))
            - 2 * max(0.0, frac_sky - 0.3)
            - 5 * (zmin < 2.5)
            - 2 * max(0.0, frac_plain - 0.2)
        )
        if ok:
            return pose
        if score > best_score:
            best, best_score = pose, score
    if best is None:
        raise EstimationError("street_view_pose: found no free viewpoint over the streets of this city")
    return best


# ----- flights -----------------------------------------------------------------------------
@dataclass
class _Segment:
    kind: str  # "line" or "arc"
    length: float
    a: np.ndarray  # line: start; arc: centre
    b: np.ndarray  # line: unit direction; arc: (start angle, signed sweep)
    r: float = 0.0


def _route(city: City, rng: np.random.Generator, min_length: float) -> list[_Segment]:
    """A random walk over street intersections, corners rounded with half the street width."""
    xs, ys = city.street_centers
    wx, wy = city.street_widths
    # keep to the inner streets when there are at least two of them (the border looks at empty land)
    ilo, ihi = (1, len(xs) - 2) if len(xs) >= 4 else (0, len(xs) - 1)
    jlo, jhi = (1, len(ys) - 2) if len(ys) >= 4 else (0, len(ys) - 1)
    i, j = int(rng.integers(ilo, ihi + 1)), int(rng.integers(jlo, jhi + 1))
    moves = [(1, 0), (-1, 0), (0, 1), (0, -1)]

    def valid(ii, jj, m):
        return ilo <= ii + m[0] <= ihi and jlo <= jj + m[1] <= jhi

    move = [m for m in moves if valid(i, j, m)][int(rng.integers(sum(valid(i, j, m) for m in moves)))]
    nodes = [(i, j)]
    dirs = []
    length = 0.0
    while length < min_length + 40.0:
        i, j = i + move[0], j + move[1]
        length += abs(xs[i] - xs[nodes[-1][0]]) + abs(ys[j] - ys[nodes[-1][1]])
        nodes.append((i, j))
        dirs.append(move)
        straight = move
        turns = [(move[1], move[0]), (-move[1], -move[0])]
        options = [m for m in turns if valid(i, j, m)]
        if valid(i, j, straight) and (rng.random() < 0.55 or not options):
            move = straight
        elif options:
            move = options[int(rng.integers(len(options)))]
        else:
            move = (-move[0], -move[1])  # dead end (a 1-street city): turn back
    pts = [np.array([xs[a], ys[b]]) for a, b in nodes]
    width_at = [min(wx[a], wy[b]) for a, b in nodes]
    segs: list[_Segment] = []
    cur = pts[0]
    for k in range(1, len(pts) - 1):
        d_in = (pts[k] - pts[k - 1]) / np.linalg.norm(pts[k] - pts[k - 1])
        d_out = (pts[k + 1] - pts[k]) / np.linalg.norm(pts[k + 1] - pts[k])
        if np.dot(d_in, d_out) > 0.999:
            continue
        if np.dot(d_in, d_out) < -0.999:  # U-turn: just reverse in place (rare)
            segs.append(_Segment("line", float(np.linalg.norm(pts[k] - cur)), cur, d_in))
            cur = pts[k]
            continue
        r = 0.5 * width_at[k]
        p_start = pts[k] - d_in * r
        segs.append(_Segment("line", float(np.linalg.norm(p_start - cur)), cur, d_in))
        centre = p_start + d_out * r
        a0 = math.atan2(p_start[1] - centre[1], p_start[0] - centre[0])
        turn = np.sign(d_in[0] * d_out[1] - d_in[1] * d_out[0])  # +1 left (counter-clockwise)
        segs.append(_Segment("arc", r * np.pi / 2, centre, np.array([a0, turn * np.pi / 2]), r))
        cur = pts[k] + d_out * r
    d_last = (pts[-1] - pts[-2]) / np.linalg.norm(pts[-1] - pts[-2])
    segs.append(_Segment("line", float(np.linalg.norm(pts[-1] - cur)), cur, d_last))
    return segs


def _sample(segs: list[_Segment], s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions (K, 2) and headings (K,) radians at arc lengths s (K,) along the route."""
    ends = np.cumsum([g.length for g in segs])
    pos = np.zeros((len(s), 2))
    yaw = np.zeros(len(s))
    for k, sk in enumerate(s):
        i = min(int(np.searchsorted(ends, sk, side="right")), len(segs) - 1)
        g = segs[i]
        local = sk - (ends[i] - g.length)
        if g.kind == "line":
            pos[k] = g.a + g.b * local
            yaw[k] = math.atan2(g.b[1], g.b[0])
        else:
            a0, sweep = g.b
            ang = a0 + sweep * (local / g.length)
            pos[k] = g.a + g.r * np.array([math.cos(ang), math.sin(ang)])
            yaw[k] = ang + math.copysign(np.pi / 2, sweep)
    return pos, yaw


def flight_path(
    city: City,
    n_frames: int,
    seed: int,
    speed_mps: float = 5.0,
    fps: float = 10.0,
    altitude_m: float = 15.0,
    altitude_wobble_m: float = 1.5,
    clearance_m: float = 2.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The positions (n, 3) (world, metres) and headings (n,) (radians from +x) of :func:`flight_poses`."""
    if n_frames < 1:
        raise InputError(f"n_frames must be at least 1, got {n_frames}")
    if speed_mps <= 0 or fps <= 0:
        raise InputError(f"speed_mps and fps must be positive, got {speed_mps}, {fps}")
    xs, ys = city.street_centers
    if len(xs) < 2 or len(ys) < 2:
        raise InputError("flight_poses needs a city with streets (generate_city)")
    rng = np.random.default_rng(seed)
    step = speed_mps / fps
    s = np.arange(n_frames) * step
    for _ in range(100):
        segs = _route(city, rng, float(s[-1]))
        offset = rng.uniform(0.0, 20.0)
        pos2, yaw = _sample(segs, s + offset)
        phase = rng.uniform(0, 2 * np.pi)
        z = altitude_m + altitude_wobble_m * np.sin(2 * np.pi * (s + offset) / 45.0 + phase)
        pos = np.column_stack([pos2, z])
        # check the positions and the straight hops between them
        mid = (pos[1:] + pos[:-1]) / 2 if len(pos) > 1 else pos
        if np.all(city.distance(np.vstack([pos, mid]), include_ground=True) >= clearance_m):
            return pos, yaw
    raise EstimationError(
        f"flight_poses: no route at {altitude_m} m keeps {clearance_m} m clear of obstacles"
    )


def flight_poses(
    city: City,
    n_frames: int,
    seed: int,
    speed_mps: float = 5.0,
    fps: float = 10.0,
    altitude_m: float = 15.0,
    pitch_deg: float = 12.0,
    altitude_wobble_m: float = 1.5,
    clearance_m: float = 2.0,
) -> list[Rigid3]:
    """Camera poses of a drone flying a smooth route along the streets.

    The route is a random walk over intersections (rounded corners of half a street's width) at
    ``altitude_m`` plus a slow vertical wobble of ``altitude_wobble_m``, flown at ``speed_mps`` and
    sampled at ``fps``; the camera looks forward along the route, pitched down by ``pitch_deg``.
    Every sample (and the midpoint between samples) is at least ``clearance_m`` from every
    obstacle and the ground (checked with :meth:`City.distance`).

    Returns:
        ``n_frames`` poses ``world_from_cam`` (OpenCV camera axes), metres. For a stereo rig these
        are the left camera's.
    """
    pos, yaw = flight_path(city, n_frames, seed, speed_mps, fps, altitude_m, altitude_wobble_m, clearance_m)
    pitch = np.radians(pitch_deg)
    return [look_from(p, a, pitch).inverse().with_frames("world", "cam") for p, a in zip(pos, yaw)]


# ----- rings and orbits ------------------------------------------------------------------------
def ring_views(
    center: np.ndarray,
    radius_m: float,
    height_m: float,
    n: int,
    intrinsics: Intrinsics,
    start_deg: float = 0.0,
    name_prefix: str = "ring",
) -> list[PosedView]:
    """``n`` cameras evenly spaced on a horizontal circle, each looking at ``center``.

    Args:
        center: (3,) world point every camera looks at, metres.
        radius_m: horizontal distance of the cameras from ``center``, metres (> 0).
        height_m: world z of the cameras, metres.
        n: number of views.
        intrinsics: the camera of every view.
        start_deg: azimuth of the first camera (degrees from +x, counter-clockwise seen from above).
    Returns:
        PosedViews named ``ring_000.png``, ``ring_001.png``, ... (``cam_from_world`` poses).
    """
    c = np.asarray(center, dtype=np.float64).reshape(3)
    if not radius_m > 0:
        raise InputError(f"radius_m must be positive, got {radius_m}")
    if n < 1:
        raise InputError(f"n must be at least 1, got {n}")
    views = []
    for k in range(n):
        a = np.radians(start_deg) + 2 * np.pi * k / n
        eye = np.array([c[0] + radius_m * np.cos(a), c[1] + radius_m * np.sin(a), height_m])
        views.append(PosedView(f"{name_prefix}_{k:03d}.png", intrinsics, Rigid3.look_at(eye, c)))
    return views


def orbit_views(
    city: City | np.ndarray,
    n: int,
    intrinsics: Intrinsics,
    seed: int = 0,
    radius_m: float | None = None,
    heights_m: tuple[float, ...] | None = None,
    arc_deg: float = 360.0,
    name_prefix: str = "orbit",
) -> list[PosedView]:
    """A monocular photo set around an object: an orbit at varying heights with a little jitter.

    Args:
        city: a scene (its ``center`` and ``view_radius_m`` are used) or a (3,) centre point.
        n: number of views.
        intrinsics: the camera of every view.
        seed: jitter of azimuth (up to 15 % of the step), distance (up to 8 %) and aim (up to 4 %).
        radius_m: orbit radius, metres (default ``city.view_radius_m``, or 8 m for a bare point).
        heights_m: world z of the cameras, cycled through (default 0.3, 0.6 and 0.9 radius above
            the centre, varying smoothly around the orbit).
        arc_deg: the azimuth range covered (360: a full orbit).
    Returns:
        PosedViews named ``orbit_000.png``, ... in order along the orbit.
    """
    if isinstance(city, City):
        c = city.center.copy()
        radius = float(radius_m if radius_m is not None else city.view_radius_m)
    else:
        c = np.asarray(city, dtype=np.float64).reshape(3)
        radius = float(radius_m if radius_m is not None else 8.0)
    if n < 1:
        raise InputError(f"n must be at least 1, got {n}")
    if not radius > 0:
        raise InputError(f"radius_m must be positive, got {radius}")
    rng = np.random.default_rng(seed)
    full = abs(arc_deg - 360.0) < 1e-9
    step = np.radians(arc_deg) / (n if full or n == 1 else n - 1)
    views = []
    for k in range(n):
        a = k * step + rng.uniform(-0.15, 0.15) * step
        r = radius * (1.0 + rng.uniform(-0.08, 0.08))
        if heights_m is None:
            z = c[2] + radius * (0.6 + 0.3 * np.sin(2 * np.pi * k / max(n, 1) * 2))
        else:
            z = float(heights_m[k % len(heights_m)])
        eye = np.array([c[0] + r * np.cos(a), c[1] + r * np.sin(a), z])
        target = c + rng.uniform(-0.04, 0.04, 3) * radius
        views.append(PosedView(f"{name_prefix}_{k:03d}.png", intrinsics, Rigid3.look_at(eye, target)))
    return views
