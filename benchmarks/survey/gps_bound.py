"""How close GPS alone can put a survey's cameras: the georeferencing on a *perfect* model, over many GPS draws.

``skyrecon survey`` places its model by the photos' GPS tags (``georeference_to_gps``: robust
similarity, wrong tags set aside, the nadir prior on the tilt). Its camera error is the model's own
shape error plus the georeferencing's, and the latter is set by the tags' noise: averaged over N
photos it leaves an offset, a scale, a heading and a tilt error that no model can remove. This
script measures that floor, with the same code the command runs, on the *true* cameras of synthetic
surveys (``skyrecon render survey``'s flight plans, not rendered): the error a survey whose shape
were perfect would have, for each of ``--draws`` seeds of the GPS noise (3 m horizontal and 4.5 m
vertical, 1-sigma, 2 % wrong tags; the camera tilt 2 degrees, as ``render survey``).

It also flies the same georeferencing with the nadir prior off, to show what the prior adds.

Usage:
  .venv/bin/python benchmarks/survey/gps_bound.py                  # 100 and 400 photos, 40 draws each
  .venv/bin/python benchmarks/survey/gps_bound.py --photos 400 --draws 100
Writes benchmarks/survey/results_gps_bound.json. Seed 0 is the draw of ``benchmarks/survey/run.py``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from skyrecon.core.reconstruction import Reconstruction
from skyrecon.io.atomic import write_text_atomic
from skyrecon.sfm.align import Sim3, umeyama
from skyrecon.sim.generate import generate_city
from skyrecon.sim.survey import SurveyPlan, SurveySettings, survey_truth_model, survey_views
from skyrecon.survey.georef import georeference_to_gps

HERE = Path(__file__).resolve().parent


def city_size_m(photos: int) -> float:
    """The city side ``benchmarks/survey/run.py`` renders for ``photos`` photos, metres."""
    return 200.0 if photos <= 120 else float(np.ceil((np.sqrt(photos / 100.0) * 230.0 + 40) / 10) * 10)


def median_error_m(rec: Reconstruction, plan: SurveyPlan, enu_from_model: Sim3) -> float:
    """Median distance of the placed true cameras from their true centres, metres."""
    by_name = {im.name: im for im in rec.images.values()}
    est = np.stack([enu_from_model.apply(by_name[v.name].center_world) for v in plan.views])
    true = np.stack([v.center_world for v in plan.views])
    return float(np.median(np.linalg.norm(est - true, axis=1)))


def one_draw(plan: SurveyPlan) -> dict[str, float]:
    """The floor for one GPS draw: the command's georeferencing on the true model, with and without
    the nadir prior, and the least-squares similarity onto the right tags only (an oracle that knows
    which tags are wrong and has no prior)."""
    rec = survey_truth_model(plan)
    tags = {v.name: plan.tagged_enu[i] for i, v in enumerate(plan.views)}
    with_prior = georeference_to_gps(rec, tags)
    without_prior = georeference_to_gps(rec, tags, nadir_prior=False)
    right = [i for i, v in enumerate(plan.views) if v.name not in set(plan.wrong)]
    true = np.stack([v.center_world for v in plan.views])
    oracle = umeyama(true[right], plan.tagged_enu[right]).transform
    return {
        "command": median_error_m(rec, plan, with_prior.enu_from_model),
        "no_nadir_prior": median_error_m(rec, plan, without_prior.enu_from_model),
        "oracle_similarity": float(np.median(np.linalg.norm(oracle.apply(true) - true, axis=1))),
        "set_aside": float(len(with_prior.set_aside)),
        "wrong_tags": float(len(plan.wrong)),
    }


def summary(values: list[float], target_m: float) -> dict[str, float]:
    v = np.asarray(values)
    return {
        "median_m": round(float(np.median(v)), 3),
        "mean_m": round(float(np.mean(v)), 3),
        "p90_m": round(float(np.percentile(v, 90)), 3),
        "worst_m": round(float(np.max(v)), 3),
        f"draws_within_{target_m}m": int(np.sum(v <= target_m)),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--photos", type=int, nargs="*", default=[100, 400])
    ap.add_argument("--draws", type=int, default=40, help="GPS draws (seeds 0..draws-1)")
    ap.add_argument("--target", type=float, default=0.5, help="the issue's target, metres")
    ap.add_argument("--out", default=str(HERE / "results_gps_bound.json"))
    args = ap.parse_args()
    t0 = time.perf_counter()
    rows = []
    for n in args.photos:
        city = generate_city(0, size_m=city_size_m(n))  # the flight plan needs only its extent
        draws = []
        for seed in range(args.draws):
            plan = survey_views(
                city, SurveySettings(width=1600, height=1200, hfov_deg=73.7, photos=n, seed=seed)
            )
            draws.append(one_draw(plan))
        row = {
            "photos": n,
            "draws": args.draws,
            "benchmark_draw_seed0": {k: round(v, 3) for k, v in draws[0].items()},
            "command": summary([d["command"] for d in draws], args.target),
            "no_nadir_prior": summary([d["no_nadir_prior"] for d in draws], args.target),
            "oracle_similarity": summary([d["oracle_similarity"] for d in draws], args.target),
            "nadir_prior_better_on": int(sum(d["command"] < d["no_nadir_prior"] for d in draws)),
            "good_tags_set_aside": int(sum(max(0.0, d["set_aside"] - d["wrong_tags"]) for d in draws)),
        }
        rows.append(row)
        c, o = row["command"], row["no_nadir_prior"]
        print(
            f"{n:>4} photos, {args.draws} GPS draws: perfect model placed by GPS, median camera error "
            f"median {c['median_m']:.3f} m, p90 {c['p90_m']:.3f}, worst {c['worst_m']:.3f}; "
            f"draws within {args.target} m: {c[f'draws_within_{args.target}m']}/{args.draws} "
            f"(without the nadir prior: median {o['median_m']:.3f}, "
            f"{o[f'draws_within_{args.target}m']}/{args.draws}); the benchmark's draw (seed 0): "
            f"{row['benchmark_draw_seed0']['command']:.3f} m",
            flush=True,
        )
    doc = {
        "what": "georeference_to_gps on the true cameras of synthetic surveys: the camera error GPS alone leaves",
        "gps_sigma_m": {"horizontal": 3.0, "vertical": 4.5},
        "rows": rows,
        "wall_s": round(time.perf_counter() - t0, 1),
    }
    write_text_atomic(Path(args.out), json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
