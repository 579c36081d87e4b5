"""``skyrecon survey`` end to end: accuracy, wall time and peak memory; OpenDroneMap's published figures beside.

Scenes:
  synthetic-N  ``skyrecon render survey --photos N`` (1600x1200 by default, 80 m, 80 %/70 % overlap,
               GPS noise 3 m horizontal / 4.5 m vertical, 2 % wrong tags), rendered once into
               ``--data`` and reused; run with the GPS tags and, with ``--gcp``, with the GCP file too.
  fountain, temple
               the real sets in ``$SKYRECON_DATA`` (strecha-fountain-P11, middlebury templeSparseRing):
               the photos re-encoded as JPEG with EXIF GPS made from their ground-truth camera centres
               (standing in for GPS, no noise), K.txt from the ground truth.

Metrics:
  cam err       estimated camera centre (``survey.json`` lat/lon/alt) vs the truth, metres (median, p95)
  GPS limit     the median error of the *true* camera centres placed on the GPS tags by a
                similarity: what a perfect model would reach from these tags (their noise, averaged);
                benchmarks/survey/gps_bound.py gives it over many GPS draws, with the nadir prior
  dsm ok        share of covered DSM cells within 0.3 m of the true highest surface (synthetic only)
  rel.          the same after the similarity that best maps the estimated cameras onto the true
                ones: the model's own shape, without the georeferencing's error
  cloud acc/com accuracy and completeness of ``cloud.laz`` at 0.3 m (synthetic only)
  wall, cpu, peak
                wall time of the command (subprocess), CPU seconds of its process tree (all
                workers; cpu / cores is the wall time on that many idle cores, the honest figure
                on a shared machine) and peak memory of the tree (sum of RSS, sampled every 0.5 s)

OpenDroneMap does not install here: its documentation's hardware table quotes about 16 GB of memory
for 250 images (and 32 GB for 500); those published figures are printed beside ours, not measured.

Usage:
  .venv/bin/python benchmarks/survey/run.py --photos 100            # synthetic-100, GPS
  .venv/bin/python benchmarks/survey/run.py --photos 100 400 --gcp --real --workers 2
  .venv/bin/python benchmarks/survey/run.py --photos 400 --resume   # the same runs again, resumed
Writes benchmarks/survey/results.json (or --out; rows are merged by scene). Never fails for being slow.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from evaluate import camera_errors, cloud_scores, dsm_errors  # noqa: E402

from skyrecon.eval.process_tree import run_measured  # noqa: E402

ODM_PUBLISHED = {"images": 250, "memory_gb": 16.0, "source": "OpenDroneMap docs, hardware recommendations"}


def skyrecon(*args: str) -> list[str]:
    return [sys.executable, "-m", "skyrecon", *args]


def synthetic(n: int, data: Path, width: int, height: int) -> Path:
    root = data / f"synthetic-{n}-{width}"
    if not (root / "survey_truth.json").exists():
        size = 200.0 if n <= 120 else float(np.ceil((np.sqrt(n / 100.0) * 230.0 + 40) / 10) * 10)
        cmd = skyrecon("render", "survey", "--photos", str(n), "--width", str(width), "--height", str(height))
        cmd += ["--city-size", str(size), "--out", str(root), "--quiet"]
        subprocess.run(cmd, check=True)
    return root


def real_set(name: str, data_root: Path, work: Path) -> Path | None:
    """The real set as a geotagged survey folder (images/, K.txt, cameras_true.txt, survey_truth.json)."""
    from skyrecon.io.calib import write_K_txt
    from skyrecon.io.multiview import read_cameras
    from skyrecon.sim.survey import DEFAULT_ORIGIN
    from skyrecon.survey.exif import write_geotagged_jpeg
    from skyrecon.survey.geo import GeoOrigin, lla_from_enu

    src = {
        "fountain": data_root / "strecha-fountain-P11",
        "temple": data_root / "middlebury-mview-templeSparseRing",
    }[name]
    if not src.exists():
        return None
    root = work / name
    if (root / "survey_truth.json").exists():
        return root
    views = read_cameras(src, src / "images" if name == "fountain" else src)
    origin = GeoOrigin(*DEFAULT_ORIGIN)
    centres = np.stack([v.center_world for v in views])
    lat, lon, alt = lla_from_enu(origin, centres)
    import cv2

    lines = ["# name east north up (ground truth standing in for GPS)"]
    for k, v in enumerate(views):
        img = cv2.imread(str(v.image_path), cv2.IMREAD_COLOR)[:, :, ::-1]
        cam = v.intrinsics
        sensor = 10.0
        focal = cam.fx * sensor / cam.width
        name_k = Path(v.name).stem + ".jpg"
        write_geotagged_jpeg(root / "images" / name_k, img, lat[k], lon[k], alt[k], focal, sensor, quality=95)
        lines.append(f"{name_k} {centres[k, 0]:.6f} {centres[k, 1]:.6f} {centres[k, 2]:.6f}")
    write_K_txt(root / "K.txt", views[0].intrinsics)
    (root / "cameras_true.txt").write_text("\n".join(lines) + "\n")
    truth = {"origin": origin.to_json(), "wrong_tags": [], "real": True}
    (root / "survey_truth.json").write_text(json.dumps(truth))
    return root


def one_run(
    label: str,
    root: Path,
    extra: list[str],
    workers: int,
    out_root: Path,
    synthetic_scene: bool,
    resume: bool = False,
) -> dict[str, Any]:
    out = out_root / label
    if not resume:
        shutil.rmtree(out, ignore_errors=True)
    cmd = skyrecon(
        "survey", str(root / "images"), "--out", str(out), "--workers", str(workers), "--quiet", *extra
    )
    m = run_measured(cmd)
    rc, wall, peak, cpu, err = m.returncode, m.wall_s, m.peak_gb, m.cpu_s, m.stderr_tail
    row: dict[str, Any] = {
        "scene": label + (" (resumed from the previous run's workspace)" if resume else ""),
        "rc": rc,
        "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 1),
        "peak_gb": round(peak, 2),
        "workers": workers,
    }
    if rc != 0:
        row["error"] = err.strip().splitlines()[-1] if err.strip() else "failed"
        return row
    row.update(camera_errors(out, root))
    doc = json.loads((out / "survey.json").read_text())
    row["stages_s"] = doc["timings_s"]
    if synthetic_scene:
        row.update(dsm_errors(out, root))
        row.update(cloud_scores(out, root))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--photos", type=int, nargs="*", default=[100])
    ap.add_argument("--width", type=int, default=1600)
    ap.add_argument("--height", type=int, default=1200)
    ap.add_argument("--gcp", action="store_true", help="also run the synthetic surveys with their GCP files")
    ap.add_argument("--real", action="store_true", help="also run the real sets (fountain, temple)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--data", type=Path, default=Path(tempfile.gettempdir()) / "skyrecon-survey-bench")
    ap.add_argument(
        "--resume",
        action="store_true",
        help="keep each run's folder: the survey resumes from its workspace (cached features, matches, "
        "model, depth maps, planar priors): measures the later stages' memory and time",
    )
    ap.add_argument(
        "--out", type=Path, default=HERE / "results.json", help="results file (rows merged by scene)"
    )
    args = ap.parse_args()
    args.data.mkdir(parents=True, exist_ok=True)
    out_root = args.data / "runs"
    rows = []
    for n in args.photos:
        root = synthetic(n, args.data, args.width, args.height)
        rows.append(one_run(f"synthetic-{n}", root, [], args.workers, out_root, True, args.resume))
        print(json.dumps(rows[-1]), flush=True)
        if args.gcp:
            rows.append(
                one_run(
                    f"synthetic-{n}-gcp",
                    root,
                    ["--gcp", str(root / "gcp_list.txt")],
                    args.workers,
                    out_root,
                    True,
                    args.resume,
                )
            )
            print(json.dumps(rows[-1]), flush=True)
    if args.real:
        data_root = Path(os.environ.get("SKYRECON_DATA", HERE.parents[2] / "shared" / "data"))
        for name in ("fountain", "temple"):
            root = real_set(name, data_root, args.data / "real")
            if root is None:
                print(f"{name}: not found under {data_root}; skipped")
                continue
            rows.append(
                one_run(
                    name, root, ["--camera", str(root / "K.txt")], args.workers, out_root, False, args.resume
                )
            )
            print(json.dumps(rows[-1]), flush=True)
    print()
    print(
        f"{'scene':<20}{'cam med/p95 m':>16}{'GPS limit':>10}{'dsm<=0.3m':>11}{'rel.':>8}{'acc/com':>13}"
        f"{'wall s':>9}{'cpu s':>9}{'peak GB':>9}"
    )
    for r in rows:
        if r.get("rc"):
            print(f"{r['scene']:<20} failed: {r.get('error')}")
            continue
        cam = f"{r['cam_err_median_m']:.3f}/{r['cam_err_p95_m']:.3f}"
        dsm = f"{100 * r['dsm_within_0.3m']:.1f} %" if "dsm_within_0.3m" in r else "n/a"
        rel = f"{100 * r['dsm_within_0.3m_relative']:.1f} %" if "dsm_within_0.3m_relative" in r else "n/a"
        lim = r.get("cam_err_median_m_gps_limit")
        lim_s = "n/a" if lim is None or "gcp" in r.get("scene", "") else f"{lim:.3f}"
        cl = (
            f"{r['cloud_accuracy@0.3m']:.2f}/{r['cloud_completeness@0.3m']:.2f}"
            if "cloud_accuracy@0.3m" in r
            else "n/a"
        )
        print(
            f"{r['scene']:<20}{cam:>16}{lim_s:>10}{dsm:>11}{rel:>8}{cl:>13}{r['wall_s']:>9.0f}{r['cpu_s']:>9.0f}"
            f"{r['peak_gb']:>9.2f}"
        )
    print(
        f"OpenDroneMap (published, not measured): about {ODM_PUBLISHED['memory_gb']:.0f} GB of memory for "
        f"{ODM_PUBLISHED['images']} images ({ODM_PUBLISHED['source']})"
    )
    # rows of the scenes run now replace theirs; other rows and keys of the file are kept
    doc = json.loads(args.out.read_text()) if args.out.is_file() else {}
    now = {r["scene"] for r in rows}
    doc["rows"] = [r for r in doc.get("rows", []) if r.get("scene") not in now] + rows
    doc["odm_published"] = ODM_PUBLISHED
    args.out.write_text(json.dumps(doc, indent=2) + "\n")


if __name__ == "__main__":
    main()
