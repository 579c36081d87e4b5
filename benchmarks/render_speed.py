"""Milliseconds per 640x480 stereo pair rendered from the synthetic city (after JIT warm-up).

Run: ``.venv/bin/python benchmarks/render_speed.py [--seed N] [--repeats N]``. Prints one table;
never fails for being slow. Also reports the compile (or cache-load) time of the first pair.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    args = ap.parse_args()

    t0 = time.perf_counter()
    from skyrecon.sim import default_rig, flight_poses, generate_city, render_stereo, street_view_pose
    from skyrecon.sim._jit import num_threads

    city = generate_city(args.seed)
    t_gen = time.perf_counter() - t0
    rig = default_rig(args.width, args.height)
    poses = [street_view_pose(city, args.seed + k) for k in range(3)]
    poses += [p.inverse() for p in flight_poses(city, 60, args.seed)[::20]]
    t0 = time.perf_counter()
    render_stereo(city, rig, poses[0])
    t_first = time.perf_counter() - t0

    rows = []
    for k, pose in enumerate(poses):
        times, cpu = [], []
        for _ in range(args.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            frame = render_stereo(city, rig, pose)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        valid = np.isfinite(frame.depth_left_m).mean()
        rows.append((k, 1000 * min(times), 1000 * float(np.median(times)), 1000 * min(cpu), 100 * valid))

    print(
        f"city seed {args.seed}: {len(city.boxes)} boxes ({city.num_buildings} buildings), "
        f"{len(city.cylinders)} cylinders; generated + imported in {1000 * t_gen:.0f} ms"
    )
    print(f"threads: {num_threads()}; first pair (JIT compile or cache load): {1000 * t_first:.0f} ms")
    print(f"{'view':>4} {'min ms/pair':>12} {'median ms/pair':>15} {'CPU ms/pair':>12} {'valid %':>8}")
    for k, best, med, cpu, valid in rows:
        print(f"{k:>4} {best:>12.1f} {med:>15.1f} {cpu:>12.1f} {valid:>8.1f}")
    allbest = np.median([r[1] for r in rows])
    allcpu = np.median([r[3] for r in rows])
    print(
        f"median over views of the best time: {allbest:.1f} ms per {args.width}x{args.height} stereo pair "
        f"({allcpu:.1f} ms of CPU time over all threads; other load on the machine inflates the wall time)"
    )


if __name__ == "__main__":
    main()
