"""Georeferencing a model: to noisy GPS tags with a few wrong ones, and to control points."""

import numpy as np
import pytest

from skyrecon.core import Image, Intrinsics, Point3D, Reconstruction, Rigid3
from skyrecon.errors import InputError
from skyrecon.sfm.align import Sim3, umeyama
from skyrecon.survey.georef import georeference_to_gcps, georeference_to_gps, triangulate_observations

CAM = Intrinsics.from_fov(640, 480, 74.0)


def _survey(n_side=10, seed=0):
    """A lawn-mower grid of nadir cameras at 80 m (ENU truth) and the same model in a random gauge."""
    rng = np.random.default_rng(seed)
    centres = [
        np.array([x, y, 80.0]) for x in np.linspace(-100, 100, n_side) for y in np.linspace(-100, 100, n_side)
    ]
    R = np.diag([1.0, -1.0, -1.0])  # camera looking down, image top to the north
    truth = {f"IMG_{k:04d}.jpg": c for k, c in enumerate(centres)}
    q = rng.normal(size=3)
    ang = np.linalg.norm(q)
    K = np.array([[0, -q[2], q[1]], [q[2], 0, -q[0]], [-q[1], q[0], 0]]) / ang
    Rg = np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K
    model_from_enu = Sim3(Rg, rng.normal(size=3) * 5, 0.137)
    rec = Reconstruction(cameras={1: CAM})
    for k, (name, c) in enumerate(truth.items(), start=1):
        pose = Rigid3(R, -R @ c, "cam", "world")
        rec.images[k] = Image(k, name, 1, pose)
    return truth, model_from_enu.transform_reconstruction(rec)


def test_wrong_tags_are_named_and_do_not_move_the_fit():
    truth, model = _survey()
    rng = np.random.default_rng(1)
    names = list(truth)
    gps = {n: truth[n] + rng.normal(0, 1, 3) * [3.0, 3.0, 4.5] for n in names}
    wrong = [names[5], names[50], names[77]]
    for k, n in enumerate(wrong):
        gps[n] = gps[n] + [40.0 + 20 * k, -35.0, 10.0]
    geo = georeference_to_gps(model, gps, seed=0)
    assert set(geo.set_aside) >= set(wrong)
    assert len(set(geo.set_aside) - set(wrong)) <= 2  # a 3-sigma noise draw may join them
    # at least as good as a least-squares fit to the right tags only (the nadir prior fixes the
    # tilt the tags' height noise leaves loose: these cameras look exactly straight down)
    good = [n for n in names if n not in wrong]
    S = np.stack([model.image_by_name(n).center_world for n in good])
    T = np.stack([truth[n] for n in good])
    oracle = umeyama(S, np.stack([gps[n] for n in good]), True).transform
    err = np.linalg.norm(geo.enu_from_model.apply(S) - T, axis=1)
    err_oracle = np.linalg.norm(oracle.apply(S) - T, axis=1)
    assert np.median(err) <= np.median(err_oracle) + 0.05 and err.max() <= err_oracle.max() + 0.05
    # (this draw's mean height noise is -1.3 m: no fit to these tags does better than that)
    assert np.median(err) < 1.5 and geo.level is not None and geo.level["weight"] > 0.9
    assert geo.gps_residuals_m[wrong[0]] > 30
    # without the prior: the GPS fit's own tilt, the oracle's figures (the same tags kept), and
    # worse at the edges of the area, where a tilt error lifts or lowers the cameras most
    plain = georeference_to_gps(model, gps, seed=0, nadir_prior=False)
    err_plain = np.linalg.norm(plain.enu_from_model.apply(S) - T, axis=1)
    assert plain.level is None and set(plain.set_aside) == set(geo.set_aside)
    assert abs(np.median(err_plain) - np.median(err_oracle)) < 0.05
    assert err_plain.max() > err.max() + 0.1


def test_too_few_tags_is_an_input_error():
    truth, model = _survey(n_side=3)
    gps = {n: truth[n] for n in list(truth)[:2]}
    with pytest.raises(InputError):
        georeference_to_gps(model, gps)


def _observe(model, truth_model_from_enu_inverse, point_enu, names):
    """Pixels of a world point in the named images of the ENU-frame cameras."""
    obs = {}
    for im in truth_model_from_enu_inverse.images.values():
        if im.name in names:
            pc = im.cam_from_world.apply(point_enu[None])[0]
            obs[im.name] = CAM.project(pc[None])[0]
    return obs


def test_gcps_fit_to_a_millimetre_and_set_a_bad_point_aside():
    truth, model = _survey(n_side=5)
    enu_rec = Reconstruction(cameras={1: CAM})
    R = np.diag([1.0, -1.0, -1.0])
    for k, (name, c) in enumerate(truth.items(), start=1):
        enu_rec.images[k] = Image(k, name, 1, Rigid3(R, -R @ c, "cam", "world"))
    names = list(truth)
    pts = [
        np.array(p) for p in ([-40, -40, 0.0], [40, -30, 0.0], [0, 45, 12.0], [-30, 20, 0.0], [35, 35, 3.0])
    ]
    gcps = []
    for k, p in enumerate(pts):
        near = [n for n in names if np.linalg.norm(truth[n][:2] - p[:2]) < 60]
        known = p + ([0, 0, 2.5] if k == 4 else 0)  # the last point's coordinates are wrong by 2.5 m
        gcps.append((f"g{k}", known, _observe(model, enu_rec, p, near)))
    geo = georeference_to_gcps(model, gcps)
    assert geo.rms_m < 1e-3
    assert [g["used"] for g in geo.gcps] == [True, True, True, True, False]
    for n in names:
        c = geo.enu_from_model.apply(model.image_by_name(n).center_world)
        assert np.linalg.norm(c - truth[n]) < 0.01


def test_triangulation_needs_two_registered_views():
    truth, model = _survey(n_side=3)
    from skyrecon.errors import EstimationError

    with pytest.raises(EstimationError, match="at least 2"):
        triangulate_observations(model, {"IMG_0000.jpg": np.array([10.0, 10.0]), "nope.jpg": np.zeros(2)})


def test_points_do_not_matter_for_the_fit():
    truth, model = _survey(n_side=3)
    model.points3d[1] = Point3D(1, np.zeros(3), np.zeros(3, np.uint8), 0.0, np.zeros((0, 2), np.int64))
    geo = georeference_to_gps(model, truth)
    assert geo.rms_m < 1e-6 and not geo.set_aside


def test_control_points_matching_no_photo_fall_back_to_gps_with_a_warning(tmp_path):
    """A GCP file whose image names match none of the registered photos: with GPS tags the survey
    is georeferenced to them and says why; without tags it is an input error naming the cause."""
    from skyrecon.survey.gcp import GcpList, GroundControlPoint
    from skyrecon.survey.geo import GeoOrigin
    from skyrecon.survey.pipeline import SurveyOptions, _georeference

    truth, model = _survey()
    rng = np.random.default_rng(2)
    gps = {n: c + rng.normal(0, 1, 3) for n, c in truth.items()}
    points = [
        GroundControlPoint(
            f"gcp{k}", np.zeros(3), 47.0, 8.0 + 1e-4 * k, 400.0, {"DSC_9999.JPG": np.array([10.0, 20.0])}
        )
        for k in range(4)
    ]
    gcps = GcpList(tmp_path / "gcp_list.txt", "WGS84", points)
    origin = GeoOrigin(47.0, 8.0, 400.0)
    geo = _georeference(model, gps, gcps, origin, SurveyOptions())
    assert geo.method == "gps" and "control points cannot be used" in geo.warnings[0]
    good = [n for n in truth]
    err = np.linalg.norm(
        geo.enu_from_model.apply(np.stack([model.image_by_name(n).center_world for n in good]))
        - np.stack([truth[n] for n in good]),
        axis=1,
    )
    assert np.median(err) < 0.5
    with pytest.raises(InputError, match="control points cannot be used"):
        _georeference(model, {}, gcps, origin, SurveyOptions())
    with pytest.raises(InputError, match="tripod"):
        _georeference(model, {n: np.zeros(3) for n in truth}, None, origin, SurveyOptions())
