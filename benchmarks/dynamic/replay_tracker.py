"""Replay the mover tracker on recorded detections: tracker settings judged in seconds, not hours.

Flying the 50 dynamic missions takes about 25 minutes on 2 cores, and every flight changes when
the tracker does. The tracker's own figures (the movers' position error and recall) can be judged
on what the detector saw in recorded flights instead: ``record`` flies missions (``--camera-noise``
as the benchmark's) and keeps, per depth frame, the detections (world centre, half size, number
of points, and the cluster's points themselves) and the camera centre, and per visible
mover-frame the mover's true centre (the world monitor's sightings: within 20 m, at least 30
pixels). ``replay`` makes each detection's box anew from its points with the settings given
(``box_quantile``, ``ray_extent_per_width``, ``gate_inflate_m``; recordings made before session 57
hold no points and keep their boxes), runs :meth:`skyrecon.perception.MoverTracker.track` over
them with the recorded settings and the overrides given, and scores the tracks as the world monitor does
(the nearest confirmed, not static track within 1.5 m of the true centre detects the mover; its
distance is the position error). The flights themselves (what the drone would have seen had it
flown otherwise) are not replayed: a change chosen here must still be flown
(``benchmarks/dynamic/run.py``).

Usage:
  .venv/bin/python benchmarks/dynamic/replay_tracker.py record --seeds 300-317 --out /tmp/rec
  .venv/bin/python benchmarks/dynamic/replay_tracker.py replay /tmp/rec --set max_push_m=0 \\
      --set max_push_m=None,side_view_cos=1
  # session 57: the detection centre under camera noise (MoverSettings.ray_extent_per_width)
  .venv/bin/python benchmarks/dynamic/replay_tracker.py record --seeds 100-109 --camera-noise 1.5 --out /tmp/rec_noisy
  .venv/bin/python benchmarks/dynamic/replay_tracker.py replay /tmp/rec_noisy --set ray_extent_per_width=0 \\
      --set ray_extent_per_width=0.75 --set ray_extent_per_width=0,box_quantile=0.2,robust_box_range_m=0

``replay`` prints one row per variant (the recorded settings first): the median over missions of
the missions' median position error (the benchmark's figure), the pooled median and p95,
recall within 20 and 10 m, the planner's track-frames (tracks it keeps clear of) and the share
of them that are phantoms (farther than 3 m from every mover, as ``mission.json`` counts them).
Only the tracker is replayed: a confirmed mover's gate, which in flight makes the detector take
points over non-free space, is not.
"""

from __future__ import annotations

import argparse
import bisect
import os
import pickle
import sys
from dataclasses import asdict, fields, replace
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "passive")

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

import numpy as np  # noqa: E402

from skyrecon.mission.world_monitor import detection_error, phantom_tracks  # noqa: E402
from skyrecon.perception import MoverSettings, MoverTracker  # noqa: E402
from skyrecon.perception.movers import MoverDetection, _cluster_box, parse_mover_overrides  # noqa: E402


def parse_seeds(text: str) -> list[int]:
    """``"300-317"`` or ``"101,105,110"`` -> seeds."""
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return out


def record_one(seed: int, out_dir: Path, camera_noise: float = 0.0) -> Path:
    """Fly one dynamic mission (the benchmark's settings, with ``camera_noise`` grey levels of
    camera noise) and write ``seed_NNNN.pkl``."""
    import skyrecon.mission.world_monitor as wm
    import skyrecon.perception.movers as movers_mod
    from skyrecon.mission import MissionConfig
    from skyrecon.mission.batch import fly_and_write

    frames: list[dict] = []
    settings: list[MoverSettings] = []
    monitors: list = []
    clusters: dict[bytes, tuple] = {}  # a box's centre -> the cluster's points, this frame
    track_fn, init_fn, box_fn = MoverTracker._track, wm.WorldMonitor.__init__, movers_mod._cluster_box

    def cluster_box(q, core, cam_center, s):  # keep each cluster's points with its box
        lo, hi, center = box_fn(q, core, cam_center, s)
        clusters[center.tobytes()] = (q.astype(np.float32), core.copy())
        return lo, hi, center

    def track(self, dets, time_s, cam_center):  # the detections of every frame, before tracking
        if not settings:
            settings.append(self.settings)
        frames.append(
            {
                "t": float(time_s),
                "cam": np.asarray(cam_center, dtype=np.float64).copy(),
                "dets": [(d.center.copy(), d.half_size.copy(), int(d.n_points)) for d in dets],
                "points": [clusters.get(d.center.tobytes()) for d in dets],
            }
        )
        clusters.clear()
        return track_fn(self, dets, time_s, cam_center)

    def init(self, *a, **k):
        init_fn(self, *a, **k)
        monitors.append(self)

    MoverTracker._track, wm.WorldMonitor.__init__, movers_mod._cluster_box = track, init, cluster_box
    try:
        cfg = MissionConfig(movers=True, city_changes=True, prior_map="earlier", camera_noise=camera_noise)
        outcome = fly_and_write(seed, out_dir / f"seed_{seed:04d}", cfg)
    finally:
        MoverTracker._track, wm.WorldMonitor.__init__, movers_mod._cluster_box = track_fn, init_fn, box_fn
    sightings = [(t, i, d, np.asarray(c)) for t, i, d, c in (monitors[0].sighting_log if monitors else [])]
    doc = {
        "seed": seed,
        "camera_noise": camera_noise,
        "settings": asdict(settings[0]) if settings else asdict(MoverSettings()),
        "frames": frames,
        "sightings": sightings,
        "flown_error_m": (outcome.doc.get("dynamic") or {}).get("mover_position_error_m"),
        # the movers' true geometry, for counting phantom tracks (poses are true: no frame change)
        "mover_scene": monitors[0].scene if monitors else None,
    }
    path = out_dir / f"seed_{seed:04d}.pkl"
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(pickle.dumps(doc))
    tmp.replace(path)
    return path


def load(path: Path) -> dict:
    doc = pickle.loads(path.read_bytes())
    s = doc["settings"]
    known = {f.name for f in fields(MoverSettings)}
    s = s if isinstance(s, dict) else asdict(s)
    doc["settings"] = MoverSettings(**{k: v for k, v in s.items() if k in known})
    doc["sightings"] = [tuple(x[:4]) for x in doc["sightings"]]
    return doc


def replay(doc: dict, **overrides) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """(position errors of the detected mover-frames (m), detected flags, distances (m), planner
    track-frames, phantom ones) of one recorded mission replayed with ``overrides`` on its
    recorded settings. A planner track (:attr:`MoverTrack.avoided`) is a phantom farther than
    3 m (``PHANTOM_TRACK_M``) from every mover, as the world monitor counts them (0, 0 for
    recordings made before the movers' geometry was kept)."""
    settings = replace(doc["settings"], **overrides)
    tracker = MoverTracker(settings)
    scene = doc.get("mover_scene")
    times, live = [], []
    track_frames = phantom_frames = 0
    for f in doc["frames"]:
        dets = []
        for (c, h, n), pts in zip(f["dets"], f.get("points") or [None] * len(f["dets"])):
            if pts is not None:  # recorded with its points: the box under these settings
                lo, hi, c = _cluster_box(pts[0].astype(np.float64), pts[1], f["cam"], settings)
                h = np.maximum(c - lo, hi - c)
            dets.append(MoverDetection(c.copy(), h.copy(), n, np.zeros((1, 1), bool)))
        tracks = tracker.track(f["t"], dets, f["cam"])
        times.append(f["t"])
        live.append([t.position for t in tracks if t.confirmed and not t.static])
        planner = np.array([t.position for t in tracks if t.avoided], dtype=np.float64).reshape(-1, 3)
        if scene is not None and scene.movers and len(planner):
            track_frames += len(planner)
            phantom_frames += phantom_tracks(scene, planner, f["t"])
    errs, hits, dists = [], [], []
    for t, _i, d, c in doc["sightings"]:
        k = bisect.bisect_right(times, t + 1e-9) - 1
        e = detection_error(live[k] if k >= 0 else [], c)
        if e is not None:
            errs.append(e)
        hits.append(e is not None)
        dists.append(d)
    return np.array(errs), np.array(hits, bool), np.array(dists), track_frames, phantom_frames


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    rec = sub.add_parser("record", help="fly missions and record the detections")
    rec.add_argument("--seeds", default="300-317")
    rec.add_argument("--out", type=Path, required=True)
    rec.add_argument("--camera-noise", type=float, default=0.0, help="grey levels of camera noise (sigma)")
    rep = sub.add_parser("replay", help="replay recordings with other tracker settings")
    rep.add_argument("folder", type=Path)
    rep.add_argument("--set", action="append", default=[], help="overrides, e.g. max_push_m=0 (repeatable)")
    args = ap.parse_args()
    if args.cmd == "record":
        args.out.mkdir(parents=True, exist_ok=True)
        for seed in parse_seeds(args.seeds):
            p = record_one(seed, args.out, args.camera_noise)
            print(f"seed {seed}: {p}", flush=True)
        return
    docs = [load(p) for p in sorted(args.folder.glob("*.pkl"))]
    if not docs:
        print(f"no recordings (*.pkl) in {args.folder}: run the record command first", file=sys.stderr)
        raise SystemExit(2)
    print(f"{len(docs)} recorded missions, {sum(len(d['sightings']) for d in docs)} mover-frames within 20 m")
    print(
        f"{'variant':40s} {'err med':>8} {'pooled':>7} {'p95':>6} {'rec20':>6} {'rec10':>6} "
        f"{'tracks':>7} {'phantom':>7}"
    )
    for text in ["", *args.set]:
        ov = parse_mover_overrides(text)
        meds, pooled, hits, dists = [], [], [], []
        n_tracks = n_phantoms = 0
        for d in docs:
            e, h, dist, nt, nph = replay(d, **ov)
            n_tracks, n_phantoms = n_tracks + nt, n_phantoms + nph
            if len(e):
                meds.append(float(np.median(e)))
            pooled += list(e)
            hits += list(h)
            dists += list(dist)
        h, dist = np.array(hits, bool), np.array(dists)
        name = text or "as recorded"

        def fmt(x):
            return f"{x:.3f}" if x is not None and np.isfinite(x) else "-"

        print(
            f"{name:40s} {fmt(np.median(meds) if meds else None):>8} "
            f"{fmt(np.median(pooled) if pooled else None):>7} "
            f"{fmt(np.percentile(pooled, 95) if pooled else None):>6} "
            f"{fmt(h.mean() if len(h) else None):>6} {fmt(h[dist <= 10].mean() if (dist <= 10).any() else None):>6} "
            f"{n_tracks:>7d} {fmt(n_phantoms / n_tracks if n_tracks else None):>7}"
        )


if __name__ == "__main__":
    main()
