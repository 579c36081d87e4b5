"""Where phantom mover tracks come from: the planner's tracks that lie on no mover, by cause.

The dynamic benchmark (``run.py``) reports ``phantom_track_share``: of the track-frames the
planner keeps clear of (confirmed, not static, moving once), the share whose centre lies more
than 3 m from every mover (the world monitor's ``mover_tracks``). This tool flies dynamic
missions (the benchmark's settings, with ``--tracker`` overrides) and sorts every such
track-frame by what lies at the track's centre at the true time:

  real      within 3 m of a mover (crane included);
  static    a phantom within 1 m of the static city (a building or the ground: a surface
            detected as a mover, typically in space the map had carved free);
  air       a phantom in free air (a chain of chance clusters of stereo outliers, or a
            track coasting along a chance velocity);

and by whether the track was seen in that frame or coasting; and the points of the phantoms'
detections.

Usage:
  .venv/bin/python benchmarks/dynamic/probe_phantoms.py --seeds 102-103
  .venv/bin/python benchmarks/dynamic/probe_phantoms.py --seeds 103 --tracker refute_frames=2
  .venv/bin/python benchmarks/dynamic/probe_phantoms.py --seeds 103 --camera-noise 1.5

Session 43, seed 103 with ``refute_frames=2`` (304 planner track-frames):

     kind  frames  share coasting tracks median hits
     real      98   0.32     0.70      3           9
   static      44   0.14     0.91      3           5
      air     162   0.53     0.93      9           4

Two thirds of the keep-outs the planner avoided lay on nothing; the air phantoms are short
tracks (median 4 hits, confirmed at 3) that coast for the rest of ``coast_s``. Static ones
were the roof and wall of the building beside the start: clusters of up to 2241 points 4 m
away, the first of them a frame after an air phantom there was confirmed moving (a confirmed
mover's gate takes points in over space the map does not hold free).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "passive")

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

import numpy as np  # noqa: E402

import skyrecon.mission.world_monitor as wm  # noqa: E402
import skyrecon.perception.movers as movers  # noqa: E402
from skyrecon.cli.common import add_camera_noise_option  # noqa: E402
from skyrecon.mission import MissionConfig  # noqa: E402
from skyrecon.mission.batch import fly_and_write  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from replay_tracker import parse_seeds  # noqa: E402  (benchmarks/dynamic/replay_tracker.py)

ON_STATIC_M = 1.0  # a phantom this close to the static city lies on a surface of it


def fly(seed: int, out: Path, tracker: str, camera_noise: float = 0.0) -> list[dict]:
    """Fly one mission; per planner track-frame: time, track id, position, coasting, hits, the
    points of its detection in that frame (None when coasting) and its kind (see the module
    docstring)."""
    rows: list[dict] = []
    monitors: list = []
    update, init = movers.MoverTracker.update, wm.WorldMonitor.__init__

    def init_probe(self, *a, **k):
        init(self, *a, **k)
        monitors.append(self)

    def update_probe(self, time_s, *args, **kwargs):
        mf = update(self, time_s, *args, **kwargs)
        dets = {d.track_id: d for d in mf.detections}
        for t in mf.tracks:
            if t.avoided:
                d = dets.get(t.track_id)
                rows.append(
                    {
                        "t": float(time_s),
                        "id": int(t.track_id),
                        "pos": t.position.copy(),
                        "coasting": bool(t.coasting),
                        "hits": int(t.hits),
                        "n_points": None if d is None else int(d.n_points),
                    }
                )
        return mf

    movers.MoverTracker.update, wm.WorldMonitor.__init__ = update_probe, init_probe
    try:
        cfg = MissionConfig(
            movers=True,
            city_changes=True,
            prior_map="earlier",
            tracker_settings=tracker,
            camera_noise=camera_noise,
        )
        fly_and_write(seed, out / f"seed_{seed:04d}", cfg)
    finally:
        movers.MoverTracker.update, wm.WorldMonitor.__init__ = update, init
    mon = monitors[0]
    if not rows or mon.scene is None or not mon.scene.movers:
        return []
    pos = np.array([r["pos"] for r in rows])
    to_mover = mon.scene.mover_distance(pos, np.array([r["t"] for r in rows]))
    to_static = mon.static.distance(pos)
    for r, dm, ds in zip(rows, to_mover, to_static):
        r["kind"] = "real" if dm <= wm.PHANTOM_TRACK_M else ("static" if ds <= ON_STATIC_M else "air")
    return rows


def report(rows: list[dict]) -> None:
    n = len(rows)
    print(f"{'kind':>7} {'frames':>7} {'share':>6} {'coasting':>8} {'tracks':>6} {'median hits':>11}")
    for kind in ("real", "static", "air"):
        sel = [r for r in rows if r["kind"] == kind]
        if not sel:
            continue
        ids = {(r["seed"], r["id"]) for r in sel}
        last_hits = {(r["seed"], r["id"]): r["hits"] for r in sel}
        print(
            f"{kind:>7} {len(sel):7d} {len(sel) / n:6.2f} {np.mean([r['coasting'] for r in sel]):8.2f} "
            f"{len(ids):6d} {np.median(list(last_hits.values())):11.0f}"
        )
    pts = [r["n_points"] for r in rows if r["kind"] != "real" and r["n_points"] is not None]
    if pts:
        print(
            f"phantom detections: {len(pts)}, points median {np.median(pts):.0f}, p90 {np.percentile(pts, 90):.0f}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="103", help="e.g. 103 or 100-105")
    ap.add_argument("--tracker", default="", help="MoverSettings overrides, e.g. refute_frames=0")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "dynamic" / "out_phantoms")
    add_camera_noise_option(ap)
    args = ap.parse_args()
    rows: list[dict] = []
    for seed in parse_seeds(args.seeds):
        got = fly(seed, args.out, args.tracker, args.camera_noise)
        for r in got:
            r["seed"] = seed
        rows += got
        print(f"seed {seed}: {len(got)} planner track-frames", flush=True)
    if rows:
        report(rows)


if __name__ == "__main__":
    main()
