"""A mission's report embeds the same 3D view of the map and the flown and planned paths."""

from __future__ import annotations

import json
import re

import numpy as np

from skyrecon.mission import small_test_config
from skyrecon.mission.loop import run_mission
from skyrecon.mission.outputs import write_mission_outputs
from skyrecon.mission.scenario import make_scenario
from skyrecon.report.mission_report import _view_3d
from skyrecon.viewer import load_scene


def test_view_section_is_an_iframe_of_the_page():
    assert _view_3d(None) == []
    html = "".join(_view_3d("view/index.html"))
    assert "<iframe src='view/index.html'" in html and "<h2>In 3D</h2>" in html


def test_mission_writes_and_embeds_its_view(tmp_path):
    cfg = small_test_config(
        width=160,
        height=120,
        max_disparity=16,
        city_size_m=60.0,
        min_goal_distance_m=20.0,
        max_goal_distance_m=35.0,
        map_padding_m=15.0,
        movers=False,
        pose_source="truth",
    )
    result = run_mission(make_scenario(1, cfg), cfg)
    doc = write_mission_outputs(result, tmp_path)
    assert doc["files"]["view"] == "view/index.html"
    report = (tmp_path / "report.html").read_text()
    assert re.search(r"<iframe src='view/index.html'", report)
    page = (tmp_path / "view" / "index.html").read_text()
    meta = json.loads(re.search(r"id='meta'>(.*?)</script>", page).group(1))
    assert meta["counts"]["voxels"] == len(result.occ_map.occupied_centers()) > 0
    assert [p["name"] for p in meta["paths"]][0] == "flown"
    assert meta["paths"][0]["count"] == len(result.flown_path())
    # `skyrecon view` of the mission directory shows the same map and paths
    scene = load_scene(tmp_path)
    assert len(scene.voxel_centers) == meta["counts"]["voxels"]
    np.testing.assert_allclose(scene.paths[0].points, result.flown_path(), atol=1e-6)
