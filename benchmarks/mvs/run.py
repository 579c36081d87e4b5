"""Dense MVS: skyrecon's default (PatchMatch + consistency fusion) vs the write-up's method (rectified
SGBM per ``360`` pair, clouds concatenated: ``MVSSettings.writeup_baseline()``), in one run.

Methods: ``skyrecon`` (default settings), ``concat`` (the write-up's SGBM parameters: the baseline
of the targets), ``concat+`` (the same concatenation with the stereo engine's default SGBM: a
stronger baseline, shown for transparency); on the plain rings also ``sky-noprior`` (the default
without the planar prior).

Scenes:
  ring-a, ring-b  synthetic monuments (skyrecon.sim) seen by a camera ring, exact geometry:
                  accuracy uses the exact distance to the surface (City.distance), completeness
                  the surface sampled from the ground-truth depth maps (points seen by >= 2 views),
                  both inside a box around the monument. tau = 1 % (and 0.5 %) of the scene size
                  (the diagonal of the reference's bounding box).
                  Also at 1 % of the ring radius, and the completeness of the ground alone
                  (reference samples at z < 2 cm).
  ring-plain-a .. ring-plain-g
                  the same with ``generate_object_scene(plain=True)``: plain grey ground, plain
                  walls, one glass face (low texture, like a real city's walls and roads); other
                  seeds, ring radii, heights and fields of view. The summary checks them against
                  the targets (F at 1 % of the ring radius >= 0.9, ground completeness >= 0.8).
  ring-plain-sN   (``--plain-seeds N ...``) a plain ring drawn from seed N: 12, 14 or 16
                  cameras, radius 8-9.5 m, 3-5 m above the centre, field of view 55-60 degrees:
                  rings nothing was tuned on (sessions 60-61 held out 50, 61, 72, 83, 94).
  rock            robovision-rock, 12 cameras 1280x1024, against reference.ply (PMVS2 pseudo ground
                  truth), cropped to its bounding box + 2 mm; tau = 0.5, 1, 2 mm.
  temple          Middlebury templeSparseRing (16 views): fraction of points outside the published
                  bounding box (noise figure); a picture of both clouds from one camera.

Usage:
  .venv/bin/python benchmarks/mvs/run.py                        # everything
  .venv/bin/python benchmarks/mvs/run.py --scenes rock temple --workers 2
  .venv/bin/python benchmarks/mvs/run.py --plain-seeds 50 61 72 83 94   # held-out plain rings
Prints one row per scene and method and a summary of ratios; writes benchmarks/mvs/results.json
and pictures in benchmarks/mvs/out/. Wall times depend on the machine's load: the CPU seconds
(this process and its workers) are printed beside them.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from functools import partial
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from skyrecon.core import DepthMap, Intrinsics, PointCloud  # noqa: E402
from skyrecon.eval.mvs_metrics import (  # noqa: E402
    evaluate_cloud,
    fraction_outside_box,
    reference_from_depth_maps,
)
from skyrecon.executor import get_executor  # noqa: E402
from skyrecon.io import read_ply, write_ply  # noqa: E402
from skyrecon.io.atomic import write_text_atomic  # noqa: E402
from skyrecon.mvs import MVSSettings, load_views_and_images, run_mvs  # noqa: E402
from skyrecon.mvs.planar_prior import PlanarPriorSettings  # noqa: E402
from skyrecon.mvs.preview import render_cloud  # noqa: E402
from skyrecon.sim import generate_object_scene, render_views, ring_views  # noqa: E402

DATA = Path(os.environ.get("SKYRECON_DATA", ROOT.parent / "shared" / "data"))
OUT = Path(__file__).resolve().parent / "out"
GROUND_Z_M = 0.02  # reference samples below this height are the ground
TEMPLE_BOX = ((-0.073568, 0.021728, -0.012445), (0.028855, 0.181892, 0.062736))

METHODS = {
    "skyrecon": MVSSettings(),
    "concat": MVSSettings.writeup_baseline(),  # the write-up's SGBM parameters (the targets' baseline)
    "concat+": MVSSettings.tuned_concat_baseline(),  # engine-default SGBM: a stronger concatenation
}

#: the synthetic rings: name -> (seed, cameras, ring radius m, height above the centre m,
#: horizontal field of view degrees, plain surfaces)
RINGS: dict[str, tuple[int, int, float, float, float, bool]] = {
    "ring-a": (0, 12, 8.0, 5.0, 60.0, False),
    "ring-b": (3, 16, 9.0, 3.0, 55.0, False),
    # plain ground and walls, one glass face (seeds not used while developing: 0, 1, 2)
    "ring-plain-a": (5, 12, 8.0, 5.0, 60.0, True),
    "ring-plain-b": (8, 16, 9.0, 3.0, 55.0, True),
    # more plain rings: c and d were looked at while developing the prior's visibility tests,
    # e was run once, afterwards
    "ring-plain-c": (11, 12, 8.5, 4.0, 60.0, True),
    "ring-plain-d": (12, 14, 9.0, 3.5, 55.0, True),
    "ring-plain-e": (21, 12, 8.0, 4.5, 58.0, True),
    # f and g were added after the prior's second pass was chosen, and run once, unchanged
    "ring-plain-f": (30, 12, 8.5, 4.5, 60.0, True),
    "ring-plain-g": (41, 14, 9.5, 3.5, 56.0, True),
}


def cloud_scores(m) -> dict:
    """The row fields of one :func:`evaluate_cloud` result (per threshold where a list)."""
    return dict(
        precision=m.precision,
        recall=m.recall,
        fscore=m.fscore,
        acc_mean_m=m.accuracy_mean,
        acc_median_m=m.accuracy_median,
        acc90_m=m.accuracy_90,
        comp_median_m=m.completeness_median,
    )


def timed_run(views, images, settings, workers):
    ex = get_executor("process", workers)
    t0 = time.perf_counter()
    res = run_mvs(views, images, settings, executor=ex, progress=False)
    return res, time.perf_counter() - t0, res.diagnostics["cpu_s"]


def picture(clouds: dict, view, path: Path) -> None:
    tiles = []
    for name, cloud in clouds.items():
        if cloud.colors is not None and len(cloud):  # brighten dark sets (the rock) for display
            hi = max(float(np.percentile(cloud.colors, 99)), 1.0)
            cloud = PointCloud(cloud.points, np.clip(cloud.colors * (230.0 / hi), 0, 255), cloud.normals)
        img = render_cloud(cloud, view.intrinsics, view.cam_from_world, point_px=2)
        img = np.ascontiguousarray(img)
        cv2.putText(img, name, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (200, 0, 0), 2)
        tiles.append(img)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(np.hstack(tiles), cv2.COLOR_RGB2BGR))


def ring_scene(
    name: str,
    seed: int,
    n: int,
    radius: float,
    height: float,
    hfov: float,
    plain: bool = False,
    width: int = 640,
):
    city = generate_object_scene(seed, plain=plain)
    intr = Intrinsics.from_fov(width, width * 3 // 4, hfov)
    views = ring_views(city.center, radius, city.center[2] + height, n, intr)
    renders = render_views(city, views)
    top = 2 * city.center[2]
    box = (np.array([-5.0, -5.0, -0.05]), np.array([5.0, 5.0, top + 0.2]))
    maps = [DepthMap(r.depth_m, v.intrinsics, v.cam_from_world) for v, r in zip(views, renders)]
    ref = reference_from_depth_maps(maps, min_views=2, voxel_m=0.01, crop=box)
    size = float(np.linalg.norm(ref.max(0) - ref.min(0)))
    return city, views, [r.image for r in renders], ref, box, size


def ground_recall(points: np.ndarray, ref: np.ndarray, box, taus: list[float]) -> list[float]:
    """Completeness on the ground alone: the reference samples at z < 2 cm (the ground is z = 0)."""
    ground = ref[ref[:, 2] < GROUND_Z_M]
    return evaluate_cloud(points, ground, taus, crop=box).recall


def ring_metrics(city, points: np.ndarray, ref: np.ndarray, box, size: float, radius: float) -> dict:
    """Accuracy/completeness/F at 0.5 and 1 % of the scene size and at 1 % of the ring radius, and
    the ground's completeness at the same thresholds."""
    taus = [0.005 * size, 0.01 * size]
    dist = lambda p: np.abs(city.distance(p, include_ground=True))  # noqa: E731
    m = evaluate_cloud(points, ref, taus, crop=box, reference_distance=dist)
    tr = 0.01 * radius
    mr = evaluate_cloud(points, ref, [tr], crop=box, reference_distance=dist)
    return dict(
        scene_size_m=size,
        tau_m=taus,
        **cloud_scores(m),
        tau_radius_m=tr,
        precision_r1=mr.precision[0],
        recall_r1=mr.recall[0],
        fscore_r1=mr.fscore[0],
        ground_recall=ground_recall(points, ref, box, taus),
        ground_recall_r1=ground_recall(points, ref, box, [tr])[0],
    )


def run_ring(
    name: str,
    seed: int,
    n: int,
    radius: float,
    height: float,
    hfov: float,
    workers: int,
    plain: bool = False,
) -> list[dict]:
    city, views, images, ref, box, size = ring_scene(name, seed, n, radius, height, hfov, plain)
    rows, clouds = [], {}
    methods = dict(METHODS)
    if plain:  # the planar prior's own effect
        methods["sky-noprior"] = MVSSettings(planar_prior=PlanarPriorSettings(enabled=False))
    for method, settings in methods.items():
        res, wall, cpu = timed_run(views, images, settings, workers)
        m = ring_metrics(city, res.cloud.points, ref, box, size, radius)
        clouds[method] = res.cloud
        rows.append(
            dict(
                scene=name,
                method=method,
                points=len(res.cloud),
                wall_s=wall,
                cpu_s=cpu,
                **m,
                planar_prior=res.diagnostics.get("planar_prior"),
                warnings=res.warnings,
            )
        )
    picture(clouds, views[0], OUT / f"{name}.png")
    return rows


def seeded_plain_ring(seed: int) -> tuple[int, int, float, float, float, bool]:
    """A :data:`RINGS` entry for a plain ring drawn from ``seed`` (cameras, radius, height and field
    of view as the module docstring says)."""
    rng = np.random.default_rng(seed)
    n = int(rng.choice([12, 14, 16]))
    radius, height, hfov = (
        float(rng.uniform(8.0, 9.5)),
        float(rng.uniform(3.0, 5.0)),
        float(rng.uniform(55.0, 60.0)),
    )
    return seed, n, radius, height, hfov, True


def run_named_ring(name: str, workers: int) -> list[dict]:
    """:func:`run_ring` on the ring ``name`` of :data:`RINGS`."""
    seed, n, radius, height, hfov, plain = RINGS[name]
    return run_ring(name, seed, n, radius, height, hfov, workers, plain)


def run_rock(workers: int) -> list[dict]:
    d = DATA / "robovision-rock" / "2016_10_25__12_11_32"
    if not d.is_dir():
        print(f"skip rock: {d} not found")
        return []
    views, _ = load_views_and_images(d, d)
    ref = read_ply(d / "reference.ply").points.astype(np.float64)
    box = (ref.min(0) - 0.002, ref.max(0) + 0.002)
    taus = [0.0005, 0.001, 0.002]
    rows, clouds = [], {}
    for method, settings in METHODS.items():
        res, wall, cpu = timed_run(views, None, settings, workers)
        m = evaluate_cloud(res.cloud.points, ref, taus, crop=box)
        clouds[method] = res.cloud
        write_ply(OUT / f"rock_{method}.ply", res.cloud)
        rows.append(
            dict(
                scene="rock",
                method=method,
                points=len(res.cloud),
                wall_s=wall,
                cpu_s=cpu,
                tau_m=taus,
                **cloud_scores(m),
                cropped_out=m.num_cropped_out,
                timings_s=res.timings_s,
                warnings=res.warnings,
            )
        )
    picture(clouds, views[0], OUT / "rock.png")
    return rows


def run_temple(workers: int) -> list[dict]:
    d = DATA / "middlebury-mview-templeSparseRing"
    if not d.is_dir():
        print(f"skip temple: {d} not found")
        return []
    views, _ = load_views_and_images(d, d / "templeSR_par.txt")
    rows, clouds = [], {}
    for method, settings in METHODS.items():
        res, wall, cpu = timed_run(views, None, settings, workers)
        clouds[method] = res.cloud
        write_ply(OUT / f"temple_{method}.ply", res.cloud)
        rows.append(
            dict(
                scene="temple",
                method=method,
                points=len(res.cloud),
                wall_s=wall,
                cpu_s=cpu,
                outside_bbox=fraction_outside_box(res.cloud.points, *TEMPLE_BOX),
                outside_bbox_5mm=fraction_outside_box(res.cloud.points, *TEMPLE_BOX, margin=0.005),
                timings_s=res.timings_s,
                warnings=res.warnings,
            )
        )
    picture(clouds, views[5], OUT / "temple.png")
    return rows


def fmt_row(r: dict) -> str:
    head = f"{r['scene']:<13} {r['method']:<9} {r['points']:>9d} {r['wall_s']:>7.1f} {r['cpu_s']:>7.1f}"
    if "fscore" in r:
        f = " ".join(f"{x:.3f}" for x in r["fscore"])
        p = " ".join(f"{x:.3f}" for x in r["precision"])
        c = " ".join(f"{x:.3f}" for x in r["recall"])
        row = f"{head}  F {f} | P {p} | R {c} | acc90 {r['acc90_m']:.4g} m  acc_mean {r['acc_mean_m']:.4g} m"
        if "fscore_r1" in r:
            g = " ".join(f"{x:.3f}" for x in r["ground_recall"])
            row += (
                f"\n{'':<13} {'':<9} @1% radius ({r['tau_radius_m']:.3g} m): F {r['fscore_r1']:.3f} "
                f"P {r['precision_r1']:.3f} R {r['recall_r1']:.3f} ground R {r['ground_recall_r1']:.3f}"
                f" | ground R {g}"
            )
        return row
    return f"{head}  outside bbox {100 * r['outside_bbox']:.2f} %  (> 5 mm outside: {100 * r['outside_bbox_5mm']:.2f} %)"


def summary(rows: list[dict]) -> list[str]:
    out = []
    by = {(r["scene"], r["method"]): r for r in rows}
    for scene, base in [
        (s, b) for s in dict.fromkeys(r["scene"] for r in rows) for b in ("concat", "concat+")
    ]:
        a, b = by.get((scene, "skyrecon")), by.get((scene, base))
        if not a or not b:
            continue
        scene = f"{scene} vs {base}"
        if "fscore" in a:
            i = len(a["fscore"]) - 1 if scene.startswith("ring") else 1  # 1 % of the size; rock: 1 mm
            fr = a["fscore"][i] / max(b["fscore"][i], 1e-9)
            ar = b["acc90_m"] / max(a["acc90_m"], 1e-12)
            am = b["acc_mean_m"] / max(a["acc_mean_m"], 1e-12)
            out.append(
                f"{scene}: F@{a['tau_m'][i]:.4g} m  {a['fscore'][i]:.3f} vs {b['fscore'][i]:.3f} "
                f"(x{fr:.2f});  accuracy90 better x{ar:.1f}, mean x{am:.1f};  recall "
                f"{a['recall'][i]:.3f} vs {b['recall'][i]:.3f};  wall {a['wall_s']:.1f} s (cpu {a['cpu_s']:.1f} s)"
            )
        else:
            out.append(
                f"{scene}: outside bbox {100 * a['outside_bbox']:.2f} % vs {100 * b['outside_bbox']:.2f} %;"
                f"  wall {a['wall_s']:.1f} s (cpu {a['cpu_s']:.1f} s)"
            )
    return out


SCENES = [*RINGS, "rock", "temple"]
#: issue "Hold up on scenes we have not seen": on plain rings F at 1 % of the ring radius and the
#: ground's completeness at that threshold
PLAIN_TARGETS = {"fscore_r1": 0.9, "ground_recall_r1": 0.8}


def plain_summary(rows: list[dict]) -> list[str]:
    """The plain rings against the targets, skyrecon and the no-prior ablation side by side."""
    out = []
    by = {(r["scene"], r["method"]): r for r in rows}
    for scene in dict.fromkeys(r["scene"] for r in rows if r["scene"].startswith("ring-plain")):
        a, off = by.get((scene, "skyrecon")), by.get((scene, "sky-noprior"))
        if not a:
            continue
        cells = []
        for key, target in PLAIN_TARGETS.items():
            ok = "met" if a[key] >= target else "NOT met"
            was = f" (no prior {off[key]:.3f})" if off else ""
            cells.append(f"{key} {a[key]:.3f}{was}, target {target}: {ok}")
        out.append(f"{scene}: precision@r1 {a['precision_r1']:.3f}; " + "; ".join(cells))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--scenes",
        nargs="+",
        default=None,
        choices=SCENES,
        help="the scenes to run (default: all, or none when --plain-seeds is given)",
    )
    ap.add_argument(
        "--plain-seeds",
        nargs="+",
        type=int,
        default=[],
        help="also run the plain rings drawn from these seeds",
    )
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    seeded = {f"ring-plain-s{seed}": seeded_plain_ring(seed) for seed in args.plain_seeds}
    RINGS.update(seeded)
    scenes = (args.scenes if args.scenes is not None else [] if seeded else SCENES) + list(seeded)
    OUT.mkdir(parents=True, exist_ok=True)
    print(f"load average at start: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    rows: list[dict] = []
    results = Path(__file__).resolve().parent / "results.json"
    # the rows of scenes not run this time are kept
    kept = (
        [r for r in json.loads(results.read_text()) if r["scene"] not in scenes] if results.exists() else []
    )
    jobs = {name: partial(run_named_ring, name, args.workers) for name in RINGS}
    jobs.update(rock=partial(run_rock, args.workers), temple=partial(run_temple, args.workers))
    for scene in scenes:
        new = jobs[scene]()
        for r in new:
            print(fmt_row(r), flush=True)
        rows += new
        write_text_atomic(results, json.dumps(kept + rows, indent=2, default=float))
    print(f"{'scene':<13} {'method':<9} {'points':>9} {'wall s':>7} {'cpu s':>7}")
    for r in rows:
        print(fmt_row(r))
    print("\n".join(summary(rows)))
    print("\n".join(plain_summary(rows)))
    print(f"load average at end: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
