"""Why far movers are not detected: the free-space test's inputs at the movers' own points.

The mover detector (:func:`skyrecon.perception.movers.detect_movers`) takes a depth point for a
motion candidate when the static map holds its voxel, and the voxel ``behind`` it along the ray,
as seen free (log-odds at most ``-free_evidence``), its six axis neighbours too, and it is no depth
edge. This tool flies dynamic missions (the benchmark's settings, ``run.py``) and, in every frame
where a judged mover is visible within 20 m (the world monitor's sightings), looks at the depth
points within 1 m of the mover's true centre: per band of distance, how many there are and which
share passes each part of the test, and what the map holds at them (occupied, seen free, or
neither: the weak prior of the earlier flight).

Usage:
  .venv/bin/python benchmarks/dynamic/probe_free_space.py --seeds 304
  .venv/bin/python benchmarks/dynamic/probe_free_space.py --seeds 300-303 --out /tmp/probe
  .venv/bin/python benchmarks/dynamic/probe_free_space.py --seeds 101 --camera-noise 1.5

Session 42 (seeds 304 and 300; replayed detections of seeds 300-307 show no detection within
1.5 m of a mover beyond 14 m in any frame): the movers' points are there (median 82 and 64
points within 1 m of the centre at 14-16 and 16-18 m), but the test fails on the map:

  band m frames   pts in range here free here occ back free back occ axis free no edge   all
  12-14       16   122     1.00      0.65     0.24      0.36     0.41      0.53    0.59  0.19
  14-16       18    82     0.92      0.22     0.51      0.05     0.33      0.11    0.52  0.01
  16-18       15    64     0.10      0.00     0.02      0.00     0.00      0.00    0.48  0.00

Beyond the map's hit range (17 m, the detector's ``max_range_m``) the map holds nothing from this
flight (the earlier flight's weak prior, -0.2, is not free). Inside it the mover paints itself
into the map before it is found: half its points at 14-16 m lie in voxels its own hits of the
frames before made occupied, and the voxels behind it are occupied once it has come nearer. A
drone coming at ours head-on (closing at 11 m/s) enters at 16-17 m space that was beyond the hit
range a frame earlier, so never seen free. What would find it: free-space evidence beyond the
hit range (carving farther was tried and left, see ``skyrecon.mission.loop``), or points kept
out of the map while they stand in space seen free until they prove static (the see-through
test, ``MoverSettings.history_s``, does the first without the map). Flown again in session 42
on single missions (``MissionConfig.tracker_settings``): with one earlier frame 0.3 s old
(``history_s=0.3``) recall within 20 m rose from 0.10 to 0.43 (seed 304) and 0.28 to 0.58 (seed
300; median position error 0.56 -> 0.80 m), loop p99 53 -> 58 and 41 -> 61 ms, but seed 301,
delivered without it, hovered blocked by movers (993 replans for movers) until its time limit;
with the two ages of ``SEE_THROUGH_AGES_S`` (``history_s=0.3/1.0``) seed 301 delivered (recall
0.10 -> 0.26) but seed 304 gained nothing (0.10 -> 0.09). Not flown over the 50 missions.
"""

from __future__ import annotations

import argparse
import bisect
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
from skyrecon.mapping.inputs import as_world_from_cam  # noqa: E402
from skyrecon.mission import MissionConfig  # noqa: E402
from skyrecon.mission.batch import fly_and_write  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from replay_tracker import parse_seeds  # noqa: E402  (benchmarks/dynamic/replay_tracker.py)

NEAR_M = 1.0  # points this close to a mover's true centre are its points
BANDS_M = (0, 8, 10, 12, 14, 16, 18, 20)


def _probe(depth_m, intrinsics, world_from_cam, occ_map, s) -> dict:
    """The free-space test's parts for every valid depth point of one frame (ranges 0-21 m)."""
    pose = as_world_from_cam(world_from_cam)
    depth = np.asarray(depth_m)
    rays, ray_norm = movers._rays(intrinsics, 1)
    d = depth.astype(np.float32)
    with np.errstate(invalid="ignore"):
        rng = d * ray_norm
        valid = np.isfinite(rng) & (rng >= s.min_range_m) & (rng <= 21.0)
    flat = np.flatnonzero(valid)
    dv = d.reshape(-1)[flat].astype(np.float64)
    rv = rays.reshape(-1, 3)[flat].astype(np.float64)
    pts = (rv * dv[:, None]) @ pose.R.T + pose.t
    unit_w = (rv / ray_norm.reshape(-1)[flat, None]) @ pose.R.T
    rv_m = dv * ray_norm.reshape(-1)[flat]
    behind = s.behind_m + s.noise_sigmas * s.depth_noise_frac * rv_m
    lo = occ_map.log_odds_at(np.concatenate([pts + s.inside_m * unit_w, pts + unit_w * behind[:, None]]))
    around = (pts[None] + movers._AXIS_STEPS[:, None, :] * s.inside_m).reshape(-1, 3)
    edges, _ = movers._depth_edges(depth, s.edge_jump_frac, 0.0)
    return {
        "pts": pts.astype(np.float32),
        "range": rv_m.astype(np.float32),
        "here": lo[: len(flat)].astype(np.float32),
        "back": lo[len(flat) :].astype(np.float32),
        "axis": np.max(occ_map.log_odds_at(around).reshape(6, -1), axis=0).astype(np.float32),
        "edge": edges.reshape(-1)[flat],
        "max_range": float(s.max_range_m),
        "free": float(s.free_evidence),
    }


def fly(seed: int, out: Path, camera_noise: float = 0.0) -> list[tuple[float, dict]]:
    """Fly one mission; per visible mover-frame (distance m, the test's parts at its points)."""
    frames: list[dict] = []
    monitors: list = []
    detect, track, init = movers.detect_movers, movers.MoverTracker._track, wm.WorldMonitor.__init__

    def detect_probe(depth_m, intrinsics, world_from_cam, occ_map, settings=None, *a, **k):
        frames.append(
            _probe(depth_m, intrinsics, world_from_cam, occ_map, settings or movers.MoverSettings())
        )
        return detect(depth_m, intrinsics, world_from_cam, occ_map, settings, *a, **k)

    def track_probe(self, dets, time_s, cam_center):
        if frames and "t" not in frames[-1]:
            frames[-1]["t"] = float(time_s)
        return track(self, dets, time_s, cam_center)

    def init_probe(self, *a, **k):
        init(self, *a, **k)
        monitors.append(self)

    movers.detect_movers, movers.MoverTracker._track, wm.WorldMonitor.__init__ = (
        detect_probe,
        track_probe,
        init_probe,
    )
    try:
        cfg = MissionConfig(movers=True, city_changes=True, prior_map="earlier", camera_noise=camera_noise)
        fly_and_write(seed, out / f"seed_{seed:04d}", cfg)
    finally:
        movers.detect_movers, movers.MoverTracker._track, wm.WorldMonitor.__init__ = detect, track, init
    times = [f.get("t", -1.0) for f in frames]
    rows = []
    for t, _i, dist, centre in monitors[0].sighting_log if monitors else []:
        k = bisect.bisect_right(times, t + 1e-9) - 1
        if k < 0:
            continue
        f = frames[k]
        near = np.linalg.norm(f["pts"] - np.asarray(centre, np.float32), axis=1) <= NEAR_M
        rows.append(
            (float(dist), {key: (v[near] if isinstance(v, np.ndarray) else v) for key, v in f.items()})
        )
    return rows


def report(rows: list[tuple[float, dict]]) -> None:
    print(
        f"{'band m':>8} {'frames':>6} {'pts':>5} {'in range':>8} {'here free':>9} {'here occ':>8} "
        f"{'back free':>9} {'back occ':>8} {'axis free':>9} {'no edge':>7} {'all':>5}"
    )
    for a, b in zip(BANDS_M[:-1], BANDS_M[1:]):
        sel = [r for d, r in rows if a < d <= b]
        if not sel:
            continue
        share: dict[str, list[float]] = {
            k: [] for k in ("range", "here", "here_occ", "back", "back_occ", "axis", "edge", "all")
        }
        npts = []
        for r in sel:
            n = len(r["here"])
            npts.append(n)
            if n == 0:
                continue
            fr = -r["free"]
            in_range = r["range"] <= r["max_range"]
            here, back, axis = r["here"] <= fr, r["back"] <= fr, r["axis"] <= fr
            ok = in_range & here & back & axis & ~r["edge"]
            for k, v in (
                ("range", in_range),
                ("here", here),
                ("here_occ", r["here"] > 0),
                ("back", back),
                ("back_occ", r["back"] > 0),
                ("axis", axis),
                ("edge", ~r["edge"]),
                ("all", ok),
            ):
                share[k].append(float(np.mean(v)))
        m = {k: (np.mean(v) if v else float("nan")) for k, v in share.items()}
        print(
            f"{a:>3}-{b:<4} {len(sel):6d} {np.median(npts):5.0f} {m['range']:8.2f} {m['here']:9.2f} "
            f"{m['here_occ']:8.2f} {m['back']:9.2f} {m['back_occ']:8.2f} {m['axis']:9.2f} {m['edge']:7.2f} "
            f"{m['all']:5.2f}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="304", help="e.g. 304 or 300-303")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "dynamic" / "out_probe")
    add_camera_noise_option(ap)
    args = ap.parse_args()
    rows = []
    for seed in parse_seeds(args.seeds):
        rows += fly(seed, args.out, args.camera_noise)
        print(f"seed {seed}: {len(rows)} visible mover-frames so far", flush=True)
    report(rows)


if __name__ == "__main__":
    main()
