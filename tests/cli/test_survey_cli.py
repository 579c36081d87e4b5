"""End to end: ``skyrecon render survey`` then ``skyrecon survey`` on a tiny survey, then ``skyrecon plan`` on its map."""

import json
import shutil

import numpy as np
import pytest

from skyrecon.cli.main import main

pytest.importorskip("pyproj")
pytest.importorskip("rasterio")
laspy = pytest.importorskip("laspy")


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    out = tmp_path_factory.mktemp("survey_photos")
    args = ["render", "survey", "--photos", "12", "--width", "320", "--height", "240", "--altitude", "50"]
    args += ["--gps-noise", "0.5", "--wrong-tags", "1", "--seed", "0", "--quiet", "--out", str(out)]
    assert main(args) == 0
    return out


@pytest.fixture(scope="module")
def survey(photos, tmp_path_factory):
    out = tmp_path_factory.mktemp("survey_out")
    args = ["survey", str(photos / "images"), "--out", str(out), "--max-image-size", "320"]
    args += ["--mvs-image-size", "200", "--no-planar-prior", "--workers", "2", "--quiet"]
    assert main(args) == 0
    return out


def _true(photos):
    rows = [
        ln.split() for ln in (photos / "cameras_true.txt").read_text().splitlines() if not ln.startswith("#")
    ]
    return {r[0]: np.array([float(v) for v in r[1:4]]) for r in rows}


def test_outputs_are_georeferenced_and_the_wrong_tag_is_named(photos, survey, capsys):
    from skyrecon.survey.geo import GeoOrigin, enu_from_lla

    for name in (
        "model/images.txt",
        "cloud.laz",
        "dsm.tif",
        "ortho.tif",
        "footprint.geojson",
        "map/map.json",
    ):
        assert (survey / name).exists(), name
    assert "IMG_0" in (survey / "report.html").read_text()
    doc = json.loads((survey / "survey.json").read_text())
    truth = json.loads((photos / "survey_truth.json").read_text())
    assert [s["name"] for s in doc["set_aside"]] == truth["wrong_tags"]
    origin = GeoOrigin.from_json(truth["origin"])
    true = _true(photos)
    cams = doc["cameras"]
    assert len(cams) == 12 and {"name", "lat", "lon", "alt", "gps_residual_m"} <= set(cams[0])
    est = enu_from_lla(origin, [c["lat"] for c in cams], [c["lon"] for c in cams], [c["alt"] for c in cams])
    err = np.linalg.norm(est - np.stack([true[c["name"]] for c in cams]), axis=1)
    assert np.median(err) < 1.0, err  # GPS noise 0.5 m on 11 photos
    # the cloud and the DSM are in UTM 32N, where the synthetic city's origin lies
    assert laspy.read(survey / "cloud.laz").header.parse_crs().to_epsg() == 32632
    import rasterio

    with rasterio.open(survey / "dsm.tif") as ds:
        assert ds.crs.to_epsg() == 32632
        assert 465_000 < ds.bounds.left < 466_000 and 5_247_000 < ds.bounds.bottom < 5_248_000
        dsm = ds.read(1)
    ground = np.nanpercentile(np.where(np.isfinite(dsm), dsm, np.nan), 10)
    assert abs(ground - truth["origin"]["alt"]) < 1.0  # the streets are at the origin's height


def test_rerun_resumes_and_plan_writes_a_mission_in_real_coordinates(photos, survey, tmp_path):
    args = ["survey", str(photos / "images"), "--out", str(survey), "--max-image-size", "320"]
    args += ["--mvs-image-size", "200", "--no-planar-prior", "--workers", "2", "--quiet"]
    assert main(args) == 0
    doc = json.loads((survey / "survey.json").read_text())
    assert doc["diagnostics"]["sfm_cached"] is True
    cams = {c["name"]: c["enu_m"] for c in doc["cameras"]}
    a, b = cams["IMG_0001.jpg"], cams["IMG_0012.jpg"]
    route = tmp_path / "route"
    # from the first photo's position to the last one's: the map knows the flown track as free
    plan = ["plan", str(survey / "map"), "--start", *map(str, a), "--goal", *map(str, b)]
    plan += ["--out", str(route), "--quiet"]
    assert main(plan) == 0
    mission = json.loads((route / "mission.plan").read_text())
    items = mission["mission"]["items"]
    lat = [it["params"][4] for it in items if it.get("params") and it["params"][4]]
    assert lat and all(abs(v - 47.3769) < 0.01 for v in lat)


def test_photos_without_gps_and_without_gcps_is_one_clear_error(tmp_path, capsys):
    from PIL import Image

    d = tmp_path / "plain"
    d.mkdir()
    rng = np.random.default_rng(0)
    for k in range(3):
        Image.fromarray(rng.integers(0, 255, (60, 80, 3)).astype(np.uint8)).save(d / f"p{k}.jpg")
    assert (
        main(["survey", str(d), "--out", str(tmp_path / "o"), "--camera", str(tmp_path / "missing.txt")]) == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing.txt" in err[0]
    (tmp_path / "K.txt").write_text("80 0 39.5\n0 80 29.5\n0 0 1\n")
    assert (
        main(["survey", str(d), "--out", str(tmp_path / "o"), "--camera", str(tmp_path / "K.txt"), "--quiet"])
        == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--gcp" in err[0]


def _retagged(photos, out, tag):
    """The survey's photos re-encoded with ``tag(name) -> (lat, lon, alt) or None`` as their GPS."""
    from PIL import Image

    from skyrecon.survey.exif import write_geotagged_jpeg

    out.mkdir()
    for p in sorted((photos / "images").glob("*.jpg")):
        rgb = np.asarray(Image.open(p).convert("RGB"))
        t = tag(p.name)
        if t is None:
            Image.fromarray(rgb).save(out / p.name, quality=95)
        else:
            write_geotagged_jpeg(out / p.name, rgb, *t, focal_mm=8.8, sensor_width_mm=13.2)
    return out


@pytest.mark.parametrize("case", ["no GPS", "tripod"])
def test_a_survey_that_cannot_be_georeferenced_still_writes_its_model(photos, tmp_path, capsys, case):
    """No GPS and no control points, or every tag at one place (a tripod): one clear line (exit 2)
    saying what is needed, and the model that could be made, unreferenced, in ``model/`` with a
    ``survey.json`` that says so."""
    tag = (lambda n: None) if case == "no GPS" else (lambda n: (47.3769, 8.5417, 500.0))
    images = _retagged(photos, tmp_path / "images", tag)
    out = tmp_path / "out"
    args = ["survey", str(images), "--out", str(out), "--camera", str(photos / "K.txt")]
    args += ["--max-image-size", "320", "--workers", "2", "--quiet"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(images) in err[0] and "unreferenced model" in err[0], err
    assert "--gcp" in err[0] and (case == "no GPS" or "tripod" in err[0]), err
    doc = json.loads((out / "survey.json").read_text())
    assert doc["georeferenced"] is False and doc["why"] in err[0]
    assert len(doc["cameras"]) >= 10 and "center_model" in doc["cameras"][0]
    assert (out / "model" / "images.txt").is_file() and not (out / "cloud.laz").exists()


def test_mixed_cameras_are_named_and_left_out(photos, tmp_path, capsys):
    """One photo from another camera (another image size) among the survey's: the survey goes on
    without it, and the warning names it and the size."""
    from PIL import Image

    images = tmp_path / "images"
    shutil.copytree(photos / "images", images)
    odd = images / "IMG_0005.jpg"
    im = Image.open(odd)
    im.resize((400, 300)).save(odd, exif=im.info["exif"], quality=95)
    out = tmp_path / "out"
    args = ["survey", str(images), "--out", str(out), "--max-image-size", "320"]
    args += ["--mvs-image-size", "200", "--no-planar-prior", "--workers", "2", "--quiet"]
    assert main(args) == 0
    doc = json.loads((out / "survey.json").read_text())
    assert list(doc["not_registered"]) == ["IMG_0005.jpg"] and doc["registered"] == 11
    assert any("mixed cameras" in w and "400x300: IMG_0005.jpg" in w for w in doc["warnings"]), doc[
        "warnings"
    ]
