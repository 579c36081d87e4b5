"""A synthetic aerial survey of the city: a lawn-mower flight of nadir photos with GPS tags.

    plan = survey_views(city, SurveySettings(photos=100))      # cameras, true and tagged positions
    write_survey(out, city, plan)                               # geotagged JPEGs + ground truth

The flight covers a square centred on the city's centre in north-south strips (serpentine order,
the camera turning 180 degrees between strips), at ``altitude_m`` above the ground (z = 0), with
the given forward (along a strip) and side (between strips) overlaps of the ground footprints. The
camera looks straight down, tilted by a small seeded random angle (``tilt_deg``). GPS tags: the
true camera centre plus seeded Gaussian noise (``gps_sigma_m`` horizontal, 1.5 times that
vertical), and ``wrong_tags`` photos tagged tens of metres away (a glitching receiver).

World frame = local East-North-Up around ``origin`` (the city's z-up metres, x east, y north).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skyrecon.core import Image, Intrinsics, PosedView, Reconstruction, Rigid3
from skyrecon.errors import InputError
from skyrecon.sim.city import City

__all__ = ["SurveySettings", "SurveyPlan", "SurveyGcp", "survey_views", "write_survey", "DEFAULT_ORIGIN"]

#: (lat deg, lon deg, ellipsoidal height m) of the synthetic city's origin by default (Zurich).
DEFAULT_ORIGIN = (47.3769, 8.5417, 408.0)


@dataclass(frozen=True)
class SurveySettings:
    """How the synthetic survey is flown and tagged.

    Attributes:
        width, height: image size, pixels.
        hfov_deg: horizontal field of view, degrees (73.7: an 8.8 mm lens on a 13.2 mm sensor).
        altitude_m: flight height above the ground, metres.
        forward_overlap, side_overlap: overlap of consecutive photos / neighbouring strips (0..0.95).
        area_m: side of the surveyed square, metres (None: chosen from ``photos``, else the city).
        photos: about how many photos (the area is chosen to give this many; the last strip may be
            cut short); None: as many as ``area_m`` needs.
        tilt_deg: standard deviation of the camera's random tilt from nadir, degrees.
        gps_sigma_m: horizontal GPS noise (standard deviation per axis), metres; vertical 1.5x.
        wrong_tags: photos whose tag is wrong by 30-120 m (None: 2 % of the photos, at least 1).
        num_gcps: ground control points written to ``gcp_list.txt``.
        origin: (lat deg, lon deg, ellipsoidal height m) of the world origin.
        seed: seed of the tilt, the GPS noise, the wrong tags and the GCPs.
    """

    width: int = 640
    height: int = 480
    hfov_deg: float = 73.7
    altitude_m: float = 80.0
    forward_overlap: float = 0.8
    side_overlap: float = 0.7
    area_m: float | None = None
    photos: int | None = None
    tilt_deg: float = 2.0
    gps_sigma_m: float = 3.0
    wrong_tags: int | None = None
    num_gcps: int = 8
    origin: tuple[float, float, float] = DEFAULT_ORIGIN
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("forward_overlap", "side_overlap"):
            v = getattr(self, name)
            if not 0.0 <= v <= 0.95:
                raise InputError(f"{name.replace('_', ' ')} must be between 0 and 0.95, got {v}")
        if not self.altitude_m > 0:
            raise InputError(f"the survey altitude must be positive, got {self.altitude_m} m")
        if self.photos is not None and self.photos < 3:
            raise InputError(f"a survey needs at least 3 photos, got {self.photos}")
        if self.gps_sigma_m < 0 or self.tilt_deg < 0:
            raise InputError("GPS noise and tilt must be non-negative")

    @property
    def camera(self) -> Intrinsics:
        return Intrinsics.from_fov(self.width, self.height, self.hfov_deg)


@dataclass
class SurveyGcp:
    """A ground control point: its true world position and where each photo sees it.

    Attributes:
        name: ``gcpN``.
        xyz_world: (3,) metres, East-North-Up.
        observations: (image name, (2,) pixel (u, v), skyrecon convention: top-left centre at (0, 0)).
    """

    name: str
    xyz_world: np.ndarray
    observations: list[tuple[str, np.ndarray]] = field(default_factory=list)


@dataclass
class SurveyPlan:
    """The photos of a survey and their truth.

    Attributes:
        views: the true cameras (names ``IMG_0001.jpg`` ...), in flight order.
        tagged_enu: (N, 3) the positions the GPS tags say, world metres.
        wrong: names of the photos whose tag is grossly wrong.
        settings: how it was flown.
        area_m: side of the surveyed square, metres.
        gcps: ground control points (observations filled by :func:`write_survey`).
    """

    views: list[PosedView]
    tagged_enu: np.ndarray
    wrong: list[str]
    settings: SurveySettings
    area_m: float
    gcps: list[SurveyGcp] = field(default_factory=list)


def _grid(area: float, dx: float, dy: float) -> tuple[np.ndarray, np.ndarray]:
    nx = max(1, math.ceil(area / dx - 1e-9) + 1)
    ny = max(1, math.ceil(area / dy - 1e-9) + 1)
    xs = (np.arange(nx) - (nx - 1) / 2) * dx
    ys = (np.arange(ny) - (ny - 1) / 2) * dy
    return xs, ys


def _area_for(photos: int, dx: float, dy: float) -> float:
    """The smallest square side whose grid holds at least ``photos`` positions."""
    area = min(dx, dy)
    while True:
        xs, ys = _grid(area, dx, dy)
        if len(xs) * len(ys) >= photos:
            return area
        area += 0.25 * min(dx, dy)


def _nadir(eye: np.ndarray, yaw: float, tilt: np.ndarray) -> Rigid3:
    """``cam_from_world`` of a camera at ``eye`` looking down, image top towards heading ``yaw``
    (radians from north towards east... expressed as the image-up direction), tilted by ``tilt`` (2,) radians."""
    up_img = np.array([math.sin(yaw), math.cos(yaw), 0.0])  # image 'up' on the ground
    z = np.array([math.tan(tilt[0]), math.tan(tilt[1]), -1.0])
    z /= np.linalg.norm(z)
    y = -up_img - np.dot(-up_img, z) * z  # image down = -heading, made orthogonal to z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    world_from_cam = np.stack([x, y, z], axis=1)
    return Rigid3(world_from_cam.T, -world_from_cam.T @ eye, "cam", "world")


def survey_views(city: City, settings: SurveySettings) -> SurveyPlan:
    """The lawn-mower flight over ``city`` (see the module docstring), without rendering."""
    cam = settings.camera
    foot_x = settings.altitude_m * cam.width / cam.fx  # across track (image width), metres
    foot_y = settings.altitude_m * cam.height / cam.fy  # along track
    dx = foot_x * (1.0 - settings.side_overlap)
    dy = foot_y * (1.0 - settings.forward_overlap)
    if settings.photos is not None:
        area = _area_for(settings.photos, dx, dy)
    elif settings.area_m is not None:
        area = float(settings.area_m)
    else:
        ext = city.extent
        area = float(min(ext[2] - ext[0], ext[3] - ext[1]))
    xs, ys = _grid(area, dx, dy)
    cx, cy = float(np.mean(city.extent[[0, 2]])), float(np.mean(city.extent[[1, 3]]))
    rng = np.random.default_rng(settings.seed)
    views: list[PosedView] = []
    for s, x in enumerate(xs):
        north = s % 2 == 0
        for y in ys if north else ys[::-1]:
            if settings.photos is not None and len(views) >= settings.photos:
                break
            eye = np.array([cx + x, cy + y, settings.altitude_m])
            tilt = rng.normal(0.0, math.radians(settings.tilt_deg), 2)
            pose = _nadir(eye, 0.0 if north else math.pi, tilt)
            views.append(PosedView(f"IMG_{len(views) + 1:04d}.jpg", cam, pose))
    n = len(views)
    true = np.stack([v.center_world for v in views])
    sig = settings.gps_sigma_m
    tagged = true + rng.normal(0.0, 1.0, (n, 3)) * np.array([sig, sig, 1.5 * sig])
    n_wrong = settings.wrong_tags if settings.wrong_tags is not None else max(1, round(0.02 * n))
    n_wrong = min(n_wrong, max(0, n - 4))
    wrong_idx = np.sort(rng.choice(n, n_wrong, replace=False)) if n_wrong else np.zeros(0, int)
    for i in wrong_idx:
        ang = rng.uniform(0, 2 * math.pi)
        dist = rng.uniform(30.0, 120.0)
        tagged[i, :2] += dist * np.array([math.cos(ang), math.sin(ang)])
        tagged[i, 2] += rng.uniform(-20.0, 20.0)
    plan = SurveyPlan(views, tagged, [views[i].name for i in wrong_idx], settings, area)
    plan.gcps = _gcp_candidates(city, true, area, (cx, cy), settings.num_gcps, rng)
    return plan


def _gcp_candidates(
    city: City,
    centres: np.ndarray,
    area: float,
    centre: tuple[float, float],
    k: int,
    rng: np.random.Generator,
) -> list[SurveyGcp]:
    """``k`` points on open ground spread over the inner part of the area (not under a building)."""
    if k <= 0:
        return []
    out: list[SurveyGcp] = []
    side = math.ceil(math.sqrt(k))
    offs = (np.arange(side) - (side - 1) / 2) * (0.7 * area / max(side, 1))
    cells = [(a, b) for a in offs for b in offs][:k]
    for a, b in cells:
        for _ in range(50):
            p = np.array([centre[0] + a + rng.uniform(-8, 8), centre[1] + b + rng.uniform(-8, 8), 0.0])
            # open ground: a ray from high above hits the ground (z = 0) first
            t = city.raycast(np.array([p[0], p[1], 500.0]), np.array([[0.0, 0.0, -1.0]]))[0]
            if abs(t - 500.0) < 1e-3:
                out.append(SurveyGcp(f"gcp{len(out) + 1}", p))
                break
    return out


def observe_gcps(plan: SurveyPlan, view: PosedView, depth_m: np.ndarray, margin_px: float = 10.0) -> None:
    """Add to each GCP where ``view`` sees it: inside the image (``margin_px`` from the border)
    and not hidden (the rendered ``depth_m`` (H, W) at its pixel agrees with its depth)."""
    cam = view.intrinsics
    for g in plan.gcps:
        pc = view.cam_from_world.apply(g.xyz_world[None])[0]
        if pc[2] <= 0:
            continue
        uv = cam.project(pc[None])[0]
        if not (
            margin_px <= uv[0] <= cam.width - 1 - margin_px
            and margin_px <= uv[1] <= cam.height - 1 - margin_px
        ):
            continue
        d = depth_m[int(round(uv[1])), int(round(uv[0]))]
        if np.isfinite(d) and abs(float(d) - pc[2]) < 0.02 * pc[2]:
            g.observations.append((view.name, uv))


def survey_truth_model(plan: SurveyPlan) -> Reconstruction:
    """The true cameras as a COLMAP-ready reconstruction (no points)."""
    rec = Reconstruction(cameras={1: plan.settings.camera})
    for k, v in enumerate(plan.views, start=1):
        rec.images[k] = Image(k, v.name, 1, v.cam_from_world)
    return rec


def write_survey(
    out: str | Path, city: City, plan: SurveyPlan, progress_desc: str | None = "render survey"
) -> dict:
    """Render every photo and write the survey (see ``skyrecon render survey``); returns a summary.

    Writes ``images/IMG_NNNN.jpg`` (EXIF GPS from the tags, focal length and sensor width),
    ``cameras_true.txt``, ``gt_sparse/`` (true cameras, COLMAP text), ``K.txt``, ``gcp_list.txt``
    (OpenDroneMap format, UTM) and ``survey_truth.json``.
    """
    import json

    from skyrecon.io.atomic import write_text_atomic
    from skyrecon.io.calib import write_K_txt
    from skyrecon.io.colmap import write_colmap_text
    from skyrecon.progress import progress
    from skyrecon.sim.render import render
    from skyrecon.survey.exif import write_geotagged_jpeg
    from skyrecon.survey.geo import GeoOrigin, lla_from_enu, projected_from_enu

    out = Path(out)
    s = plan.settings
    origin = GeoOrigin(*s.origin)
    cam = s.camera
    sensor_w = 13.2
    focal_mm = cam.fx * sensor_w / cam.width
    lat, lon, alt = lla_from_enu(origin, plan.tagged_enu)
    views = plan.views if progress_desc is None else progress(plan.views, desc=progress_desc)
    for k, view in enumerate(views):
        res = render(city, cam, view.cam_from_world)
        observe_gcps(plan, view, res.depth_m)
        write_geotagged_jpeg(
            out / "images" / view.name,
            res.image,
            float(lat[k]),
            float(lon[k]),
            float(alt[k]),
            focal_mm,
            sensor_w,
        )
    write_K_txt(out / "K.txt", cam)
    write_colmap_text(out / "gt_sparse", survey_truth_model(plan))
    true = np.stack([v.center_world for v in plan.views])
    tl, tn, ta = lla_from_enu(origin, true)
    lines = [
        "# true camera centres and poses of the synthetic survey",
        "# name east_m north_m up_m lat_deg lon_deg alt_m qw qx qy qz tx ty tz (cam_from_world)",
    ]
    for k, v in enumerate(plan.views):
        q = v.cam_from_world.quaternion_wxyz if hasattr(v.cam_from_world, "quaternion_wxyz") else None
        qs = " ".join(f"{x:.9f}" for x in (q if q is not None else _quat(v.cam_from_world.R)))
        t = " ".join(f"{x:.6f}" for x in v.cam_from_world.t)
        lines.append(
            f"{v.name} {true[k, 0]:.4f} {true[k, 1]:.4f} {true[k, 2]:.4f} {tl[k]:.9f} {tn[k]:.9f} {ta[k]:.4f} {qs} {t}"
        )
    write_text_atomic(out / "cameras_true.txt", "\n".join(lines) + "\n")
    gcps = [g for g in plan.gcps if len(g.observations) >= 2]
    gcp_text = ""
    if gcps:
        xyz, epsg = projected_from_enu(origin, np.stack([g.xyz_world for g in gcps]))
        rows = [f"EPSG:{epsg}"]
        for g, p in zip(gcps, xyz):
            for name, uv in g.observations:
                # OpenDroneMap pixels: COLMAP-like, the top-left pixel's corner at (0, 0)
                rows.append(
                    f"{p[0]:.4f} {p[1]:.4f} {p[2]:.4f} {uv[0] + 0.5:.2f} {uv[1] + 0.5:.2f} {name} {g.name}"
                )
        gcp_text = "\n".join(rows) + "\n"
        write_text_atomic(out / "gcp_list.txt", gcp_text)
    truth = {
        "origin": origin.to_json(),
        "frame": "East-North-Up metres around origin (the synthetic city's world frame)",
        "photos": len(plan.views),
        "area_m": round(plan.area_m, 2),
        "altitude_m": s.altitude_m,
        "overlap": {"forward": s.forward_overlap, "side": s.side_overlap},
        "gps_sigma_m": {"horizontal": s.gps_sigma_m, "vertical": 1.5 * s.gps_sigma_m},
        "wrong_tags": plan.wrong,
        "gcps": [
            {"name": g.name, "enu_m": g.xyz_world.tolist(), "observations": len(g.observations)} for g in gcps
        ],
        "city_seed": int(city.seed),
        "city_extent_m": [float(v) for v in city.extent],
    }
    write_text_atomic(out / "survey_truth.json", json.dumps(truth, indent=2) + "\n")
    return {
        "photos": len(plan.views),
        "size": f"{cam.width}x{cam.height}",
        "area_m": round(plan.area_m, 1),
        "altitude_m": s.altitude_m,
        "wrong_tags": ", ".join(plan.wrong) or "none",
        "gcps": len(gcps),
    }


def _quat(R: np.ndarray) -> np.ndarray:
    """(w, x, y, z) unit quaternion of a rotation matrix."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z]) * (1 if w >= 0 else -1)
