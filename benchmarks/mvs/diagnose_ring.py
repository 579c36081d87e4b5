"""Where a synthetic ring's MVS cloud falls short: per-view depth errors and the missed surface.

The MVS benchmark (``run.py``) scores a ring by its F-score; this tool shows *what* is missing
and *why*, for one ring of :data:`run.RINGS` with the default settings:

* ``depth_errors.png``: per view, the image beside its final depth map (after the planar
  prior): green within 1 % of the true depth, red wrong, dark grey none. A plain wall filled
  with a wrong plane is red there, a wall left empty grey; the fused cloud keeps neither.
* ``missed.png``: the reference samples (the true surface seen by at least two views) drawn
  from four of the ring's cameras, red where the cloud has no point within the threshold
  (1 % of the ring radius, the benchmark's).
* printed: precision, recall and F at that threshold, the missed share of the ground and of
  the other surfaces by facing direction (world axes) and height (normals from the scene's exact distance
  function), and per view the depth's valid and wrong shares and the planar prior's report.

Usage:
  .venv/bin/python benchmarks/mvs/diagnose_ring.py ring-plain-e
  .venv/bin/python benchmarks/mvs/diagnose_ring.py ring-plain-d --out /tmp/diag
Writes into benchmarks/mvs/out/diagnose/RING/ by default.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))

import run as bench  # noqa: E402  (benchmarks/mvs/run.py; it puts src/ on the path)

from skyrecon.core import PointCloud  # noqa: E402
from skyrecon.mvs import MVSSettings  # noqa: E402
from skyrecon.mvs.preview import render_cloud  # noqa: E402
from skyrecon.sim import render_views  # noqa: E402

GREEN, RED, GREY = (0, 180, 0), (255, 0, 0), (40, 40, 40)
DEPTH_TOL = 0.01  # relative depth error counted right in the depth pictures


def depth_classes(depth: np.ndarray, true_depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((h, w) bool with a depth, (h, w) bool within ``DEPTH_TOL`` of the truth) of a depth map
    (h, w) metres, NaN none, against the rendered true depth (any size, resized to it)."""
    h, w = depth.shape
    truth = cv2.resize(true_depth, (w, h), interpolation=cv2.INTER_NEAREST)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.isfinite(depth), np.abs(depth - truth) <= DEPTH_TOL * truth


def depth_error_picture(image: np.ndarray, valid: np.ndarray, right: np.ndarray) -> np.ndarray:
    """(h, 2w, 3) uint8: the image beside the depth's classes (:func:`depth_classes`): green
    right, red wrong, grey none."""
    h, w = valid.shape
    out = np.empty((h, w, 3), np.uint8)
    out[:] = GREY
    out[valid] = RED
    out[valid & right] = GREEN
    return np.hstack([cv2.resize(np.ascontiguousarray(image), (w, h)), out])


def surface_normals(city, points: np.ndarray, step_m: float = 0.01) -> np.ndarray:
    """(N, 3) unit normals of surface points from the central differences of the scene's
    exact (unsigned) distance to its objects, ground excluded."""
    grads = []
    for axis in np.eye(3):
        hi = np.abs(city.distance(points + step_m * axis, include_ground=False))
        lo = np.abs(city.distance(points - step_m * axis, include_ground=False))
        grads.append((hi - lo) / (2 * step_m))
    g = np.stack(grads, axis=1)
    return g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)


def missed_breakdown(city, ref: np.ndarray, missed: np.ndarray) -> list[str]:
    """Lines: the missed share of the ground, the level tops and the walls by facing direction
    and height, each with its share of all misses."""
    total = max(int(missed.sum()), 1)
    lines = []

    def row(label: str, sel: np.ndarray) -> None:
        if sel.any():
            lines.append(
                f"  {label:<22} samples {int(sel.sum()):>8}  missed {missed[sel].mean():6.3f}"
                f"  share of misses {(missed & sel).sum() / total:6.3f}"
            )

    ground = ref[:, 2] < bench.GROUND_Z_M
    row("ground", ground)
    rest = ~ground
    n = np.zeros_like(ref)
    n[rest] = surface_normals(city, ref[rest])
    level = rest & (np.abs(n[:, 2]) > 0.7)
    row("level tops", level)
    wall = rest & ~level
    azimuth = np.degrees(np.arctan2(n[:, 1], n[:, 0]))
    quadrant = np.floor(((azimuth + 45.0) % 360.0) / 90.0).astype(int)  # centred on the axes
    for q, label in enumerate(("+x", "+y", "-x", "-y")):
        row(f"walls facing {label}", wall & (quadrant == q))
    top = float(ref[wall, 2].max()) if wall.any() else 0.0
    for z0 in np.arange(0.0, top + 0.5, 0.5):
        row(f"walls z {z0:.1f}-{z0 + 0.5:.1f} m", wall & (ref[:, 2] >= z0) & (ref[:, 2] < z0 + 0.5))
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("ring", choices=sorted(bench.RINGS))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None, help="default benchmarks/mvs/out/diagnose/RING")
    args = ap.parse_args()
    out = args.out or bench.OUT / "diagnose" / args.ring
    out.mkdir(parents=True, exist_ok=True)
    seed, n, radius, height, hfov, plain = bench.RINGS[args.ring]
    city, views, images, ref, box, size = bench.ring_scene(args.ring, seed, n, radius, height, hfov, plain)
    res, wall_s, _ = bench.timed_run(views, images, MVSSettings(), args.workers)
    m = bench.ring_metrics(city, res.cloud.points, ref, box, size, radius)
    tau = m["tau_radius_m"]
    print(
        f"{args.ring}: {len(res.cloud)} points in {wall_s:.0f} s; at {tau:.3f} m (1 % of the ring radius): "
        f"precision {m['precision_r1']:.3f}, recall {m['recall_r1']:.3f}, F {m['fscore_r1']:.3f}, "
        f"ground recall {m['ground_recall_r1']:.3f}"
    )
    inside = np.all((ref >= box[0]) & (ref <= box[1]), axis=1)
    ref = ref[inside]
    dist, _ = cKDTree(res.cloud.points).query(ref, distance_upper_bound=tau)
    missed = ~np.isfinite(dist)
    print(f"missed reference samples: {missed.mean():.3f} of {len(ref)}")
    print("\n".join(missed_breakdown(city, ref, missed)))

    truths = render_views(city, views)
    prior = res.diagnostics.get("planar_prior", {}).get("views", {})
    tiles = []
    print(f"{'view':<10} {'valid':>6} {'wrong':>6}  planar prior")
    for view, image, truth in zip(views, images, truths):
        stem = Path(view.name).stem
        depth = res.depth_maps[stem].depth_m
        valid, right = depth_classes(depth, truth.depth_m)
        tiles.append(depth_error_picture(image, valid, right))
        wrong = valid & ~right
        rep = prior.get(stem, {})
        what = (
            rep.get("fallback") or f"{rep.get('filled_segments', 0)}/{rep.get('segments', 0)} segments filled"
        )
        print(f"{stem:<10} {valid.mean():6.3f} {wrong.mean():6.3f}  {what}")
    cols = 3
    while len(tiles) % cols:
        tiles.append(np.zeros_like(tiles[0]))
    grid = np.vstack([np.hstack(tiles[i : i + cols]) for i in range(0, len(tiles), cols)])
    cv2.imwrite(str(out / "depth_errors.png"), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))

    colours = np.where(missed[:, None], np.array([[220.0, 0.0, 0.0]]), np.array([[200.0, 200.0, 200.0]]))
    order = np.argsort(missed, kind="stable")  # misses drawn last, on top
    cloud = PointCloud(ref[order], colours[order])
    picks = np.linspace(0, len(views), 4, endpoint=False).astype(int)
    shots = [
        np.ascontiguousarray(render_cloud(cloud, views[i].intrinsics, views[i].cam_from_world, point_px=2))
        for i in picks
    ]
    cv2.imwrite(str(out / "missed.png"), cv2.cvtColor(np.hstack(shots), cv2.COLOR_RGB2BGR))
    print(f"wrote {out / 'depth_errors.png'} and {out / 'missed.png'}")


if __name__ == "__main__":
    main()
