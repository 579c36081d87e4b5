"""path.json and QGroundControl .plan output, ENU -> WGS-84 conversion."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.planning import PlanResult, enu_to_geodetic, write_path_json, write_qgc_plan
from skyrecon.planning.mission import ecef_to_geodetic, geodetic_to_ecef

ORIGIN = (47.3769, 8.5417, 408.0)  # Zurich


def test_enu_to_geodetic_is_exact():
    enu = np.array([[0.0, 0.0, 0.0], [1000.0, 0.0, 0.0], [0.0, 1000.0, 0.0], [120.0, -340.0, 55.0]])
    geo = enu_to_geodetic(enu, ORIGIN)
    assert np.allclose(geo[0], ORIGIN, atol=1e-9)
    # back to ENU through ECEF
    o = geodetic_to_ecef(*ORIGIN)
    la, lo = np.radians(ORIGIN[0]), np.radians(ORIGIN[1])
    R = np.array(
        [
            [-np.sin(lo), np.cos(lo), 0],
            [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)],
            [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)],
        ]
    )
    back = np.array([R @ (geodetic_to_ecef(*g) - o) for g in geo])
    np.testing.assert_allclose(back, enu, atol=1e-6)
    # 1 km east is about 1000 / (R cos(lat)) radians of longitude
    assert geo[1, 1] - ORIGIN[1] == pytest.approx(np.degrees(1000 / (6388838.3 * np.cos(la))), rel=2e-3)
    assert np.allclose(ecef_to_geodetic(geodetic_to_ecef(*ORIGIN))[0], ORIGIN, atol=1e-9)


def test_path_json(tmp_path):
    w = np.array([[0.0, 0, 5], [3, 4, 5], [3, 4, 10]])
    r = PlanResult(True, w, 10.0, clearance_m=2.0, margin_m=0.2, min_distance_m=2.5)
    write_path_json(tmp_path / "path.json", r, start=w[0], goal=w[-1])
    doc = json.loads((tmp_path / "path.json").read_text())
    assert doc["waypoints"] == w.tolist() and doc["frame"] == "world" and doc["units"] == "m"
    assert doc["length_m"] == pytest.approx(10.0) and doc["success"] is True and doc["clearance_m"] == 2.0
    assert doc["start"] == [0.0, 0.0, 5.0]
    write_path_json(tmp_path / "plain.json", w)
    assert json.loads((tmp_path / "plain.json").read_text())["num_waypoints"] == 3
    failed = PlanResult.failure("goal_enclosed", "test")
    write_path_json(tmp_path / "failed.json", failed)
    doc = json.loads((tmp_path / "failed.json").read_text())
    assert doc["success"] is False and doc["waypoints"] == [] and doc["reason"] == "goal_enclosed"


def test_qgc_plan(tmp_path):
    w = np.array([[0.0, 0, 5], [100, 0, 20], [100, 50, 30]])
    write_qgc_plan(tmp_path / "m.plan", w, ORIGIN, takeoff=True)
    doc = json.loads((tmp_path / "m.plan").read_text())
    assert doc["fileType"] == "Plan" and doc["version"] == 1 and doc["mission"]["version"] == 2
    items = doc["mission"]["items"]
    assert [it["command"] for it in items] == [22, 16, 16]
    assert [it["doJumpId"] for it in items] == [1, 2, 3]
    assert all(it["frame"] == 3 and it["type"] == "SimpleItem" for it in items)
    geo = enu_to_geodetic(w, ORIGIN)
    for it, g, z in zip(items, geo, w[:, 2]):
        assert it["params"][4:6] == pytest.approx(g[:2].tolist(), abs=1e-12)
        assert it["params"][6] == pytest.approx(z) and it["Altitude"] == pytest.approx(z)
    assert doc["mission"]["plannedHomePosition"] == list(ORIGIN)
    write_qgc_plan(tmp_path / "amsl.plan", w, ORIGIN, altitude_mode="amsl")
    items = json.loads((tmp_path / "amsl.plan").read_text())["mission"]["items"]
    assert items[0]["frame"] == 0 and items[0]["Altitude"] == pytest.approx(408.0 + 5.0)


def test_mission_bad_input(tmp_path):
    with pytest.raises(InputError):
        write_qgc_plan(tmp_path / "x.plan", np.zeros((0, 3)), ORIGIN)
    with pytest.raises(InputError, match="latitude"):
        write_qgc_plan(tmp_path / "x.plan", np.zeros((2, 3)), (95.0, 0.0, 0.0))
    with pytest.raises(InputError, match="NaN"):
        write_qgc_plan(tmp_path / "x.plan", np.array([[0.0, np.nan, 1.0]]), ORIGIN)
    with pytest.raises(InputError, match="altitude_mode"):
        write_qgc_plan(tmp_path / "x.plan", np.zeros((2, 3)), ORIGIN, altitude_mode="agl")
    assert not (tmp_path / "x.plan").exists()
