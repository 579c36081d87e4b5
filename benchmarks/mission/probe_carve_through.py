"""Does the flight depth carve free space through walls? Its depth against the truth, on random noisy views.

The delivery map carves free space along every depth pixel up to its depth (up to the map's
range for open air, +inf). A pixel whose depth lies well beyond the true surface carves free
space inside that surface: enough of them and a wall turns to air in the map, and a plan may
go through it. This tool renders random views of generated cities (positions 3 m or more from
any obstacle at 7-30 m, any heading, the camera 5 degrees up to 40 degrees down: close looks at
walls included), adds the camera noise, runs the loop's stereo stage (with the horizon and the
ground plane, as the loop does) and compares every depth pixel with the true range along its
ray. A pixel "carves through" when it would carve free space more than ``--margin`` metres
(default 3) beyond the true surface, the surface within the map's range. It prints, per city
kind and noise, those pixels by where their depth came from (open air: sky or ground prior;
the plane fill; measured), the views with more than 2 % of their pixels carving through, and
what the depth gets right (pixels within 5 % or 0.5 m of the truth; open-air pixels whose ray
meets nothing within the range).

Usage:
  .venv/bin/python benchmarks/mission/probe_carve_through.py
  .venv/bin/python benchmarks/mission/probe_carve_through.py --cities 40-49 --noise 1.5 3 --out carve.json

Session 54 (``--cities 40-49 --views 10``, 1.5 grey levels, cities not looked at while mending;
``results_carve_through_session54.json``), before -> after the plane fill's and the open sky's
mends: textured 4560 -> 2703 pixels carving through per million (open air 25311 -> 11173; 5 -> 4
views over 2 %), plain 1099 -> 1276 (open air 1877 -> 1254, but the plane fill 512 -> 2494, one
view over 2 %: city 40, a plane 1622 pixels wrong, not looked at yet); good depth +0 % / +2.8 %.

Session 55 (``results_carve_through_session55.json``), open sky framed through plain bands (the
first measured pixel under the rim is near; a red sign band over a plain band on a tower, city
45): held-out cities 50-59 textured 975 -> 631 per million (open air 4176 -> 1535), plain
unchanged (2430: the plane fill, 9941 pixels, is most of it); open air right -0.001 %.
"""

from __future__ import annotations

import math
import sys
from functools import partial
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from skyrecon.mapping.rays import camera_rays  # noqa: E402
from skyrecon.mission.config import MissionConfig  # noqa: E402
from skyrecon.mission.perception import flight_perception, mission_rig  # noqa: E402
from skyrecon.perception import GroundPlane, StereoDepth  # noqa: E402
from skyrecon.sim import generate_city  # noqa: E402
from skyrecon.sim.render import render_depth  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from probe_horizon_band import CITY_KINDS, _seeds, kind, noisy_views, probe_arguments, run_probes  # noqa: E402  (benchmarks/mission/)

#: a view with more than this share of its depth pixels carving through counts as a bad view
BAD_VIEW_SHARE = 0.02


class _PlaneSpy:
    """Wraps a StereoDepth's plane fill to keep the last frame's accepted mask (full resolution)."""

    def __init__(self, stereo: StereoDepth):
        self.accepted: np.ndarray | None = None
        self._fill = stereo._plane_fill
        stereo._plane_fill = self  # type: ignore[method-assign]

    def __call__(self, *args, **kwargs):
        out = self._fill(*args, **kwargs)
        self.accepted = out[1]
        return out


def probe(cities: list[int], views: int, sigma: float, plain: bool, margin_m: float) -> dict:
    """Depth of ``views`` random views per city against the truth; a summary dict."""
    cfg = MissionConfig(camera_noise=sigma)
    rig = mission_rig(cfg)
    K = rig.left
    stereo = StereoDepth(rig, flight_perception(cfg))
    spy = _PlaneSpy(stereo)
    range_m = float(cfg.max_range_m)
    counts = dict.fromkeys(
        ("pixels", "through_open_air", "through_plane", "through_measured", "good", "open_air_ok"), 0
    )
    n_views = 0
    worst: list[dict] = []
    for seed in cities:
        city = generate_city(seed, cfg.city_size_m, plain=plain)
        rng = np.random.default_rng([seed, int(sigma * 100), int(plain), 54])
        for p, yaw, pitch, cam_from_world, left, right in noisy_views(
            city, rig, rng, views, sigma, (7.0, 30.0), (-5.0, 40.0)
        ):
            spy.accepted = None
            ground = (  # as the loop has it (Navigator.ground_plane): none without the ground's height
                None
                if cfg.ground_z_m is None
                else GroundPlane.from_pose(cam_from_world.inverse(), cfg.ground_z_m)
            )
            depth = stereo.compute(left, right, horizon_row_px=K.cy - K.fy * math.tan(pitch), ground=ground)
            n_views += 1
            d = depth.depth_m
            _, lengths = camera_rays(depth.intrinsics)
            true_z = render_depth(city, depth.intrinsics, cam_from_world)
            true_r = np.where(np.isfinite(true_z), true_z, np.inf) * lengths
            with np.errstate(invalid="ignore"):
                r = d * lengths
                carve_end = np.where(np.isnan(d), 0.0, np.minimum(r, range_m))
                through = (carve_end > true_r + margin_m) & (true_r < range_m)
                good = np.isfinite(r) & (np.abs(r - true_r) <= np.maximum(0.5, 0.05 * true_r))
            if spy.accepted is None:  # no plane fill this frame
                plane = np.zeros(d.shape, bool)
            else:  # the fill's mask is at full resolution, the depth on every stride-th pixel
                k = spy.accepted.shape[0] // d.shape[0]
                plane = spy.accepted[::k, ::k]
            open_air = np.isposinf(d)
            counts["pixels"] += d.size
            counts["through_open_air"] += int((through & open_air).sum())
            counts["through_plane"] += int((through & plane & ~open_air).sum())
            counts["through_measured"] += int((through & ~plane & ~open_air).sum())
            counts["good"] += int(good.sum())
            counts["open_air_ok"] += int((open_air & (true_r >= range_m)).sum())
            share = float(through.mean())
            if share > BAD_VIEW_SHARE:
                worst.append(
                    {
                        "city": seed,
                        "position": np.round(p, 2).tolist(),
                        "yaw_deg": round(math.degrees(yaw), 1),
                        "pitch_down_deg": round(math.degrees(pitch), 1),
                        "through_share": round(share, 4),
                        "open_air": int((through & open_air).sum()),
                        "plane": int((through & plane & ~open_air).sum()),
                    }
                )
    through_total = counts["through_open_air"] + counts["through_plane"] + counts["through_measured"]
    return {
        "plain": plain,
        "camera_noise": sigma,
        "cities": f"{cities[0]}-{cities[-1]}",
        "views": n_views,
        "margin_m": margin_m,
        "range_m": range_m,
        **counts,
        "through": through_total,
        "through_per_million": round(1e6 * through_total / max(1, counts["pixels"]), 1),
        "bad_views": len(worst),
        "wrong_views": sorted(worst, key=lambda w: -w["through_share"])[:10],
    }


def main() -> int:
    ap = probe_arguments(__doc__.split("\n")[0], "40-41")
    ap.add_argument("--margin", type=float, default=3.0, help="metres beyond the true surface (default 3)")
    args = ap.parse_args()
    cases = (
        partial(probe, _seeds(args.cities), args.views, sigma, plain, args.margin)
        for plain in CITY_KINDS[args.plain]
        for sigma in args.noise
    )
    return run_probes(
        cases,
        lambda row: (
            f"{kind(row)}: {row['views']:4d} views, carving through {row['through_per_million']:7.1f} "
            f"per million pixels (open air {row['through_open_air']}, plane fill {row['through_plane']}, "
            f"measured {row['through_measured']}), {row['bad_views']} views over "
            f"{100 * BAD_VIEW_SHARE:.0f} %; good depth {row['good']}, open air right {row['open_air_ok']}"
        ),
        "bad_views",
        args.out,
    )


if __name__ == "__main__":
    sys.exit(main())
