"""The synthetic survey: a lawn-mower flight with the asked overlaps, noisy and wrong GPS tags, GCPs."""

import json

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.sim import generate_city
from skyrecon.sim.survey import SurveySettings, survey_views, write_survey


@pytest.fixture(scope="module")
def city():
    return generate_city(0, size_m=100.0)


def test_flight_has_the_photos_and_overlaps_asked_for(city):
    s = SurveySettings(
        photos=40, forward_overlap=0.8, side_overlap=0.7, tilt_deg=0.0, gps_sigma_m=0.0, wrong_tags=0
    )
    plan = survey_views(city, s)
    assert len(plan.views) == 40
    c = np.stack([v.center_world for v in plan.views])
    assert np.allclose(c[:, 2], 80.0)
    cam = s.camera
    step = np.linalg.norm(np.diff(c[:4], axis=0), axis=1)  # along the first strip
    assert np.allclose(step, 80.0 * cam.height / cam.fy * 0.2)
    xs = np.unique(np.round(c[:, 0], 6))
    assert np.allclose(np.diff(xs), 80.0 * cam.width / cam.fx * 0.3)
    # straight down, image top to the north on the first strip
    R = plan.views[0].cam_from_world.R
    assert np.allclose(R[2], [0, 0, -1]) and np.allclose(R[1], [0, -1, 0])
    assert np.allclose(plan.tagged_enu, c)


def test_tags_are_noisy_and_a_few_are_wrong_seeded(city):
    s = SurveySettings(photos=60, gps_sigma_m=3.0, wrong_tags=3, seed=5)
    a, b = survey_views(city, s), survey_views(city, s)
    assert a.wrong == b.wrong and np.array_equal(a.tagged_enu, b.tagged_enu)
    c = np.stack([v.center_world for v in a.views])
    d = a.tagged_enu - c
    wrong = np.array([v.name in a.wrong for v in a.views])
    assert wrong.sum() == 3 and np.all(np.linalg.norm(d[wrong, :2], axis=1) >= 20)  # 30-120 m, plus the noise
    assert 2.0 < np.std(d[~wrong, :2]) < 4.0


def test_bad_settings_are_input_errors():
    with pytest.raises(InputError):
        SurveySettings(forward_overlap=0.99)
    with pytest.raises(InputError):
        SurveySettings(photos=2)


def test_written_survey_reads_back(city, tmp_path):
    from skyrecon.survey.exif import intrinsics_from_meta, read_photo_meta
    from skyrecon.survey.gcp import read_gcp_list
    from skyrecon.survey.geo import GeoOrigin, enu_from_lla

    s = SurveySettings(
        width=160, height=120, photos=6, altitude_m=40.0, gps_sigma_m=0.0, wrong_tags=0, num_gcps=4
    )
    plan = survey_views(city, s)
    summary = write_survey(tmp_path, city, plan, progress_desc=None)
    assert summary["photos"] == 6
    truth = json.loads((tmp_path / "survey_truth.json").read_text())
    origin = GeoOrigin.from_json(truth["origin"])
    m = read_photo_meta(tmp_path / "images" / "IMG_0001.jpg")
    assert np.allclose(
        enu_from_lla(origin, m.lat_deg, m.lon_deg, m.alt_m)[0], plan.views[0].center_world, atol=0.01
    )
    assert intrinsics_from_meta(m).fx == pytest.approx(s.camera.fx, rel=1e-4)
    lines = (tmp_path / "cameras_true.txt").read_text().splitlines()
    assert len([ln for ln in lines if not ln.startswith("#")]) == 6
    if (tmp_path / "gcp_list.txt").exists():
        g = read_gcp_list(tmp_path / "gcp_list.txt")
        for p in g.points:
            known = next(t for t in truth["gcps"] if t["name"] == p.name)
            assert np.allclose(
                enu_from_lla(origin, p.lat_deg, p.lon_deg, p.alt_m)[0], known["enu_m"], atol=1e-3
            )
