"""Mapping from stereo images: ``skyrecon map`` vs OpenCV SGBM depth fed to OctoMap (octomap-python).

Scenes: ``generate_city(seed, 200 m)`` (the textured city, --seed) and, with --plain or
--plain-seeds, ``generate_city(seed, 200 m, plain=True)`` (issue #13: 60 % of the buildings with
plain facades, 20 % glass, plain grey streets and pavements; what ``skyrecon render sequence
--plain`` writes); each a drone flight (``flight_poses``, 40 frames at 10 frames/s by default), a
rectified stereo rig of 640x480 pixels, 90 degree field of view and 0.3 m baseline, rendered in
memory by ``render_stereo``. The summary gives the worst case over the seeds of each kind.

Methods (same frames, same voxel size 0.5 m, same maximum range --max-range, one process):
  skyrecon        exactly what ``skyrecon map SEQUENCE --voxel-size 0.5`` runs on the sequence:
                  :class:`skyrecon.mapping.StereoMapper` (default settings: the ``skyrecon``
                  matcher with the horizontal paths, measured pixels on texture only, plain
                  segments bounded by one measured plane filled with it unless the matcher's own
                  values inside disagree, the matcher's other values as hits where 3 frames
                  agree next to a found surface, obstacles only within the rig's trusted range,
                  projective integration of the full 640x480 depth with each surface taken a
                  fifth of a voxel nearer the camera, and the flat ground: guesses that agree
                  with the ground level learnt over the flight become hits half a voxel under
                  it, up to the map's range, :mod:`skyrecon.mapping.ground_level`).
  skyrecon-before (--baseline-settings) the same without the texture rule, the plane fill and
                  the multi-frame guesses: ``skyrecon map`` before issue #13.
  no-flat-ground  (--no-flat-ground) skyrecon without the ground level (``skyrecon map
                  --no-flat-ground``).
  LABEL           (--variant LABEL:NAME=VALUE,...) skyrecon with other settings.
  octomap+sgbm    ``create_matcher("opencv-sgbm")`` (cv2.StereoSGBM, 5x5 blocks, 3-way, LR check
                  1 px, uniqueness 10, speckle filter 100 px / 2), depth from every valid disparity,
                  back-projected to world points and inserted with ``OcTree.insertPointCloud(points,
                  camera centre, maxrange=--max-range)`` (OctoMap's default sensor model).
Both search disparities 0..--max-disparity.

Scores against the true geometry (``City.occupancy_grid``, ground z <= 0 included; a voxel is
occupied when it overlaps an obstacle), over one voxel box holding both maps:
  precision       occupied voxels that overlap an obstacle / occupied voxels;
  recall@20m      true surface voxels observed within --near metres (default 20) of the camera in at
                  least one frame / those that are occupied in the map. "Observed" uses the exact
                  rendered depth of the left camera: the voxel holding the true surface point of a
                  pixel (pushed 1 mm into the surface) whose Euclidean distance from the camera is
                  at most 20 m;
  recall@trusted  the same within our trusted range (19.6 m here): the shell between it and 20 m
                  is one our map never marks (ground seen obliquely lies there);
  recall          the same for surface points within --max-range (the far ones are what stereo
                  cannot resolve: ours deliberately leaves them unknown);
  precision@surface  occupied voxels whose centre lies within one voxel of a true surface
                  (|signed distance| <= voxel size) / occupied voxels: phantom obstacles in the air
                  and noise buried deep behind facades both count as wrong;
  precision near / far   precision of the occupied voxels whose centre is within / beyond --near
                  metres of the nearest camera position of the flight;
  free-in-obst.   free voxels that overlap an obstacle / free voxels (unsafe mistakes).
Time: wall time per frame, mean over the frames, of depth (stereo matching, depth, and for the peer
back-projection to world points) and of integration (map update), after a warm-up frame that
compiles the Numba kernels and builds the matchers (not counted). Ours integrates each frame on a
second thread while the next frame's depth is finished after its matcher (``StereoMapper.overlap``,
as ``skyrecon map`` runs): its "depth" then includes that overlap, its "integration" is the wait
for the map update beyond it (and the last frame's update); the total is the wall time either way.
Ratios are ours / peer.

Target (issue #7): precision >= 2x the peer's, recall@20m >= the peer's, total time <= 1/5.
Precision cannot exceed 1, so the precision target needs the peer at 0.5 or below. Here the peer
scores about 0.66-0.71 (seeds 3, 7, 11), not the 0.27 quoted in the issue: the truth counts the
inside of buildings as occupied, and most of the peer's far-range noise lands behind facades,
inside them (its precision beyond 20 m is higher than within 20 m). Its phantom obstacles are
near-range voxels in the air, where ours are fewer (see "precision near").

Issue #13 (plain surfaces) asks for the same targets on the plain city. Which precision: the
stricter ``precision@surface`` (a voxel is right only when it lies on a true surface, so phantom
obstacles in the air and noise buried behind facades both count as wrong). ``precision`` counts
the inside of buildings as right, which rewards depth that is too far: on a plain wall the
matcher's smoothed values often land behind the facade, and their rays carve the facade itself
free (see free-in-obst.); a map that stops doing that loses ``precision`` while it gains on the
surface. Both are reported.

Usage:
  .venv/bin/python benchmarks/mapping/stereo_map.py
  .venv/bin/python benchmarks/mapping/stereo_map.py --frames 20 --seed 3
  .venv/bin/python benchmarks/mapping/stereo_map.py --plain --baseline-settings
  .venv/bin/python benchmarks/mapping/stereo_map.py --plain-seeds 3 7 11 5 13 --no-flat-ground
  .venv/bin/python benchmarks/mapping/stereo_map.py --plain --noise 1.5 --variant fixed:noise_aware_texture=False
Writes benchmarks/mapping/results_stereo.json (with --noise SIGMA: results_stereo_noise<SIGMA>.json).
Camera noise (--noise): the renderer's images are noise-free; real cameras add 1-2 grey levels, which
a fixed texture threshold takes for texture. skyrecon measures the noise on each image and raises
its thresholds above it (PerceptionSettings.noise_aware_texture; the variant
``fixed:noise_aware_texture=False`` flies the fixed threshold).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from skyrecon.io.atomic import write_text_atomic  # noqa: E402
from skyrecon.mapping import OccupancyMap, StereoMapper, StereoMapSettings  # noqa: E402
from skyrecon.sim import default_rig, flight_poses, generate_city, render_stereo  # noqa: E402
from skyrecon.sim.sensor_noise import add_sensor_noise  # noqa: E402
from skyrecon.stereo import create_matcher, disparity_to_depth  # noqa: E402

try:
    import octomap  # type: ignore
except ImportError:  # pragma: no cover - optional peer
    octomap = None


def flight(
    seed: int, frames: int, width: int, height: int, baseline: float, plain: bool = False, noise: float = 0.0
):
    """City, rig, poses (world_from_left) and rendered stereo frames of a flight; with ``noise``,
    camera sensor noise of that many grey levels on both images (seeded by the city seed)."""
    city = generate_city(seed, 200.0, plain=plain)
    rig = default_rig(width, height, 90.0, baseline)
    poses = flight_poses(city, frames, seed)
    rendered = [render_stereo(city, rig, p.inverse()) for p in poses]
    if noise > 0:
        rng = np.random.default_rng([seed, 0x5E4])
        rendered = [
            replace(f, left=add_sensor_noise(f.left, noise, rng), right=add_sensor_noise(f.right, noise, rng))
            for f in rendered
        ]
    return city, rig, poses, rendered


# ----- the two methods -------------------------------------------------------------------
def run_ours(rig, poses, frames, voxel: float, max_range: float, max_disparity: int, **settings):
    """StereoMapper as ``skyrecon map`` uses it; returns (map, depth_s, integrate_s)."""
    s = StereoMapSettings(voxel_size_m=voxel, max_range_m=max_range).with_overrides(
        max_disparity=max_disparity, **settings
    )
    warm = StereoMapper(rig, s)  # compile / load the kernels, build the matcher
    warm.stereo.warm_up()  # as ``skyrecon map`` does (map_stereo_sequence)
    warm.add_frame(frames[0].left, frames[0].right, poses[0])
    mapper = StereoMapper(rig, s, matcher=warm.matcher)
    for f, p in zip(frames, poses):
        mapper.add_frame(f.left, f.right, p)
    mapper.flush()  # the last frame's map update (StereoMapper.overlap), timed with it
    return mapper, np.array(mapper.timings.depth_s), np.array(mapper.timings.integrate_s)


def world_points(rig, depth: np.ndarray, pose) -> np.ndarray:
    """(N, 3) float64 world points of the valid pixels of a (H, W) depth image of the left camera."""
    ok = np.isfinite(depth)
    return pose.apply(rig.left.ray_directions()[ok] * depth[ok, None].astype(np.float64))


def run_peer(rig, poses, frames, voxel: float, max_range: float, max_disparity: int):
    """OpenCV SGBM + OctoMap insertPointCloud; returns (tree, depth_s, integrate_s, points)."""
    matcher = create_matcher("opencv-sgbm", max_disparity)
    matcher.compute(frames[0].left, frames[0].right)  # warm-up
    tree = octomap.OcTree(voxel)
    depth_s, integ_s, npts = [], [], 0
    for f, p in zip(frames, poses):
        t0 = time.perf_counter()
        depth = disparity_to_depth(matcher.compute(f.left, f.right).disparity, rig)
        pts = np.ascontiguousarray(world_points(rig, depth, p))
        t1 = time.perf_counter()
        tree.insertPointCloud(pts, np.ascontiguousarray(p.t, dtype=np.float64), maxrange=max_range)
        t2 = time.perf_counter()
        depth_s.append(t1 - t0)
        integ_s.append(t2 - t1)
        npts += len(pts)
    return tree, np.array(depth_s), np.array(integ_s), npts


# ----- scoring ---------------------------------------------------------------------------
def ours_labels(m: OccupancyMap) -> tuple[np.ndarray, np.ndarray]:
    """(occupied (N, 3), free (M, 3)) int64 voxel indices of our map."""
    B = m.block_size
    blocks = m.grid.blocks
    thr = m.config.log_odds[4]
    out = []
    with np.errstate(invalid="ignore"):
        for sel in (blocks >= thr, blocks < thr):
            k, q = np.nonzero(sel)
            local = np.stack([q // (B * B), (q // B) % B, q % B], axis=1)
            out.append(m.grid.block_coords[k].astype(np.int64) * B + local)
    return out[0], out[1]


def octomap_labels(tree, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """(occupied, free) int64 voxel indices of an OcTree (pruned leaves expanded to voxels)."""
    occ, free = tree.extractPointCloud()
    to_idx = lambda c: np.floor(np.asarray(c, dtype=np.float64).reshape(-1, 3) / voxel).astype(np.int64)  # noqa: E731
    return to_idx(occ), to_idx(free)


class Scorer:
    """Ground truth over a voxel box ``[lo, hi)`` and the surface voxels the flight observed."""

    def __init__(self, city, rig, poses, frames, voxel: float, lo: np.ndarray, hi: np.ndarray):
        self.voxel, self.lo, self.hi, self.city = voxel, lo, hi, city
        self.gt = city.occupancy_grid(lo * voxel, voxel, tuple(hi - lo), include_ground=True).reshape(-1)
        dirs = rig.left.ray_directions()
        norm = np.linalg.norm(dirs, axis=2)
        self._obs = []  # per frame: (flat keys, range of the surface point, metres)
        for f, pose in zip(frames, poses):
            d = f.depth_left_m
            ok = np.isfinite(d)
            pc = dirs[ok] * d[ok, None].astype(np.float64)
            r = d[ok] * norm[ok]
            pc += 1e-3 * pc / r[:, None]
            self._obs.append((self._flat(np.floor(pose.apply(pc) / voxel).astype(np.int64)), r))

    def seen(self, max_range: float) -> np.ndarray:
        """Flat keys of the surface voxels observed within ``max_range`` metres in some frame."""
        k = np.unique(np.concatenate([keys[r <= max_range] for keys, r in self._obs]))
        return k[k >= 0]

    def _flat(self, idx: np.ndarray) -> np.ndarray:
        rel = idx - self.lo
        shape = self.hi - self.lo
        inside = np.all((rel >= 0) & (rel < shape), axis=1)
        out = np.full(len(idx), -1, np.int64)
        out[inside] = np.ravel_multi_index(tuple(rel[inside].T), tuple(shape))
        return out

    def score(
        self,
        occ: np.ndarray,
        free: np.ndarray,
        near: float,
        max_range: float,
        cameras: np.ndarray,
        trusted: float | None = None,
    ) -> dict:
        fo, ff = self._flat(occ), self._flat(free)
        inside = fo >= 0
        fo, ff = fo[inside], ff[ff >= 0]
        centres = (occ[inside] + 0.5) * self.voxel
        d = np.full(len(centres), np.inf)
        for c in cameras:  # distance to the nearest camera position, metres
            np.minimum(d, np.linalg.norm(centres - c, axis=1), out=d)
        is_near = d <= near
        near_keys, all_keys = self.seen(near), self.seen(max_range)
        return {
            "occupied": int(len(fo)),
            "free": int(len(ff)),
            "precision": float(self.gt[fo].mean()) if len(fo) else float("nan"),
            "precision_surface": float(
                np.mean(np.abs(self.city.distance(centres, include_ground=True)) <= self.voxel)
            )
            if len(fo)
            else float("nan"),
            "precision_near": float(self.gt[fo[is_near]].mean()) if is_near.any() else float("nan"),
            "precision_far": float(self.gt[fo[~is_near]].mean()) if (~is_near).any() else float("nan"),
            "occupied_far": int((~is_near).sum()),
            "recall_near": float(np.isin(near_keys, fo).mean()) if len(near_keys) else float("nan"),
            "recall": float(np.isin(all_keys, fo).mean()) if len(all_keys) else float("nan"),
            "recall_trusted": float(np.isin(self.seen(trusted), fo).mean()) if trusted else float("nan"),
            "free_in_obstacle": float(self.gt[ff].mean()) if len(ff) else float("nan"),
            "surface_voxels_near": int(len(near_keys)),
            "surface_voxels": int(len(all_keys)),
        }


def parse_setting(text: str) -> tuple[str, object]:
    """``name=value`` of ``--set``: a number, true/false/none, or a string."""
    name, _, value = text.partition("=")
    low = value.strip().lower()
    if low in ("true", "false"):
        return name, low == "true"
    if low == "none":
        return name, None
    for cast in (int, float):
        try:
            return name, cast(value)
        except ValueError:
            pass
    return name, value


def run_case(args, seed: int, plain: bool, variants: dict[str, dict]) -> dict:
    """One flight: our variants and the peer on the same frames; rows, ratios and target of each."""
    t0 = time.perf_counter()
    city, rig, poses, frames = flight(
        seed, args.frames, args.width, args.height, args.baseline, plain, args.noise
    )
    kind = "plain" if plain else "textured"
    noise = f", camera noise {args.noise:g} grey levels" if args.noise > 0 else ""
    print(
        f"\n== {kind} city, seed {seed}: {len(frames)} stereo frames {args.width}x{args.height}{noise}, rendered in "
        f"{time.perf_counter() - t0:.1f} s; load average {os.getloadavg()[0]:.1f}"
    )
    runs = {}
    for name, overrides in variants.items():
        mapper, d, i = run_ours(
            rig, poses, frames, args.voxel, args.max_range, args.max_disparity, **overrides
        )
        runs[name] = (mapper, d, i, ours_labels(mapper.map))
    tree, p_depth, p_integ, npts = run_peer(
        rig, poses, frames, args.voxel, args.max_range, args.max_disparity
    )
    peer_labels = octomap_labels(tree, args.voxel)
    allv = np.concatenate([np.concatenate(v[3]) for v in runs.values()] + [np.concatenate(peer_labels)])
    lo, hi = allv.min(axis=0), allv.max(axis=0) + 1
    scorer = Scorer(city, rig, poses, frames, args.voxel, lo, hi)
    cams = np.array([p.t for p in poses])

    trusted = next(iter(runs.values()))[0].hit_range_m

    def row(name, d, i, labels):
        s = scorer.score(*labels, args.near, args.max_range, cams, trusted)
        return {
            "method": name,
            "frames": len(d),
            "ms_depth": 1000 * float(d.mean()),
            "ms_integration": 1000 * float(i.mean()),
            "ms_total": 1000 * float((d + i).mean()),
            **s,
        }

    peer = row("octomap+sgbm", p_depth, p_integ, peer_labels)
    rows = [row(name, d, i, lab) for name, (_m, d, i, lab) in runs.items()] + [peer]
    out = {"seed": seed, "plain": plain, "results": rows, "ratios": {}, "target": {}}
    for r in rows[:-1]:
        ratios = {
            k: r[k] / peer[k]
            for k in ("precision", "precision_surface", "recall_near", "recall_trusted", "recall")
        } | {
            "time_depth": r["ms_depth"] / peer["ms_depth"],
            "time_integration": r["ms_integration"] / peer["ms_integration"],
            "time_total": r["ms_total"] / peer["ms_total"],
        }
        out["ratios"][r["method"]] = ratios
        out["target"][r["method"]] = {
            "precision_ratio>=2": ratios["precision"] >= 2.0,
            "precision_surface_ratio>=2": ratios["precision_surface"] >= 2.0,
            "recall_near>=peer": r["recall_near"] >= peer["recall_near"],
            "time_ratio<=0.2": ratios["time_total"] <= 0.2,
        }
    print_table(args, rows, out["ratios"])
    m0 = next(iter(runs.values()))[0]
    print(
        f"skyrecon obstacles within {m0.hit_range_m:.1f} m (trusted range of the rig); surface voxels "
        f"observed: {peer['surface_voxels_near']} within {args.near:g} m, {peer['surface_voxels']} within "
        f"{args.max_range:g} m; peer points inserted per frame: {npts / len(frames):.0f}"
    )
    out["hit_range_m"] = m0.hit_range_m
    out["skyrecon_settings"] = {name: asdict(m.settings) for name, (m, *_r) in runs.items()}
    return out


def print_table(args, rows: list[dict], ratios: dict[str, dict]) -> None:
    near = f"recall@{args.near:g}m"
    print(
        f"{'method':<18}{'precision':>10}{'@surface':>9}{'near/far':>13}{near:>12}{'@trusted':>9}{'recall':>8}{'free-in-obst':>14}"
        f"{'occupied':>10}{'ms depth':>10}{'ms integr.':>11}{'ms total':>10}"
    )
    for r in rows:
        print(
            f"{r['method']:<18}{r['precision']:>10.3f}{r['precision_surface']:>9.3f}{r['precision_near']:>7.3f}/{r['precision_far']:<5.3f}"
            f"{r['recall_near']:>12.3f}{r['recall_trusted']:>9.3f}{r['recall']:>8.3f}{r['free_in_obstacle']:>14.5f}{r['occupied']:>10d}"
            f"{r['ms_depth']:>10.1f}{r['ms_integration']:>11.1f}{r['ms_total']:>10.1f}"
        )
    for name, q in ratios.items():
        label = f"{name}/peer"
        print(
            f"{label:<18}{q['precision']:>10.2f}{q['precision_surface']:>9.2f}{'':>13}{q['recall_near']:>12.3f}{q['recall_trusted']:>9.3f}{q['recall']:>8.3f}"
            f"{'':>14}{'':>10}{q['time_depth']:>10.3f}{q['time_integration']:>11.3f}{q['time_total']:>10.3f}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=7, help="seed of the textured city (default 7)")
    ap.add_argument(
        "--textured-seeds", type=int, nargs="*", default=[], help="fly textured cities of these seeds instead"
    )
    ap.add_argument(
        "--plain-seeds", type=int, nargs="*", default=[], help="also fly plain cities of these seeds"
    )
    ap.add_argument("--plain", action="store_true", help="shorthand for --plain-seeds 3 7 11")
    ap.add_argument("--no-textured", action="store_true", help="skip the textured city")
    ap.add_argument(
        "--baseline-settings",
        action="store_true",
        help="also run skyrecon with the settings before this change (no texture rule, plane fill or guesses)",
    )
    ap.add_argument(
        "--set", action="append", default=[], metavar="NAME=VALUE", help="override a skyrecon map setting"
    )
    ap.add_argument(
        "--variant",
        action="append",
        default=[],
        metavar="LABEL:NAME=VALUE,...",
        help="also run skyrecon with these overrides, e.g. range2.5:max_depth_error_voxels=2.5",
    )
    ap.add_argument(
        "--no-flat-ground",
        action="store_true",
        help="also run skyrecon without the ground level (skyrecon map --no-flat-ground) as 'no-flat-ground'",
    )
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--baseline", type=float, default=0.3, help="metres (skyrecon render's default)")
    ap.add_argument("--voxel", type=float, default=0.5)
    ap.add_argument("--max-range", type=float, default=40.0, help="metres (skyrecon map's default)")
    ap.add_argument("--max-disparity", type=int, default=128)
    ap.add_argument("--near", type=float, default=20.0, help="range of recall@near, metres")
    ap.add_argument(
        "--noise",
        type=float,
        default=0.0,
        metavar="SIGMA",
        help="camera sensor noise on every image, grey levels (default 0: the renderer's noise-free "
        "images; real cameras have about 1-2); results_stereo_noise<SIGMA>.json unless --out",
    )
    ap.add_argument("--out", type=Path, default=None, help="default results_stereo.json (see --noise)")
    args = ap.parse_args()
    if args.out is None:
        name = f"results_stereo_noise{args.noise:g}.json" if args.noise > 0 else "results_stereo.json"
        args.out = Path(__file__).with_name(name)
    if octomap is None:
        sys.exit(
            "octomap-python is not installed (pip install octomap-python); it is the peer of this benchmark"
        )
    plain_seeds = list(args.plain_seeds) or ([3, 7, 11] if args.plain else [])
    variants = {"skyrecon": dict(parse_setting(t) for t in args.set)}
    for text in args.variant:
        label, _, spec = text.partition(":")
        variants[label] = dict(parse_setting(t) for t in spec.split(",") if t)
    if args.baseline_settings:
        variants["skyrecon-before"] = {"min_texture": None, "plane_fill": False, "guess_min_frames": 0}
    if args.no_flat_ground:
        variants["no-flat-ground"] = {"ground": None}
    textured_seeds = list(args.textured_seeds) or [args.seed]
    cases = ([] if args.no_textured else [(s, False) for s in textured_seeds]) + [
        (s, True) for s in plain_seeds
    ]
    print(
        f"voxel {args.voxel} m, max range {args.max_range} m, baseline {args.baseline} m; "
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}"
    )
    results = [run_case(args, seed, plain, variants) for seed, plain in cases]

    # summary: per kind of city, the worst case of each figure (ours relative to the peer)
    print("\n== summary (skyrecon / peer; worst case over the seeds of each kind)")
    summary = {}
    for kind in ("textured", "plain"):
        sel = [r for r in results if r["plain"] == (kind == "plain")]
        if not sel:
            continue
        for name in variants:
            q = [r["ratios"][name] for r in sel]
            worst = {
                "precision_ratio": min(x["precision"] for x in q),
                "precision_surface_ratio": min(x["precision_surface"] for x in q),
                "recall_near_ratio": min(x["recall_near"] for x in q),
                "time_ratio": max(x["time_total"] for x in q),
                "seeds": [r["seed"] for r in sel],
            }
            summary[kind if name == "skyrecon" else f"{kind} {name}"] = worst
            print(
                f"{kind:<9} {name:<12} seeds {worst['seeds']}: precision >= {worst['precision_ratio']:.2f}x, "
                f"precision@surface >= {worst['precision_surface_ratio']:.2f}x, recall@{args.near:g}m >= "
                f"{worst['recall_near_ratio']:.3f}x, time <= {worst['time_ratio']:.3f}x"
            )
    payload = {
        "frames": args.frames,
        "size": [args.width, args.height],
        "baseline_m": args.baseline,
        "voxel_m": args.voxel,
        "max_range_m": args.max_range,
        "near_m": args.near,
        "max_disparity": args.max_disparity,
        "camera_noise": args.noise,
        "cpus": os.cpu_count(),
        "load_average": os.getloadavg()[0],
        "cases": results,
        "summary": summary,
    }
    write_text_atomic(args.out, json.dumps(payload, indent=2, default=str) + "\n")
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
