"""The scene, the self-contained page, the server and the ``skyrecon view`` command."""

from __future__ import annotations

import base64
import json
import os
import re
import signal
import subprocess
import sys
import threading
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from skyrecon.cli.main import main
from skyrecon.io.ply import write_ply
from skyrecon.viewer import READY_TITLE, Polyline, ViewerScene, make_server, render_page, server_url
from tests.viewer.conftest import make_cloud

SRC = Path(__file__).resolve().parents[2] / "src"


def _blocks(page: bytes) -> tuple[dict, dict[str, bytes]]:
    text = page.decode("utf-8")
    meta = json.loads(re.search(r"<script type='application/json' id='meta'>(.*?)</script>", text).group(1))
    blocks = {
        m.group(1): base64.b64decode(m.group(2))
        for m in re.finditer(r"<script type='application/octet-stream' id='([\w-]+)'>([^<]*)</script>", text)
    }
    return meta, blocks


def test_subsample_is_deterministic_and_uniform():
    cloud = make_cloud(10_000)
    scene = ViewerScene("s", cloud.points, cloud.colors)
    a, b, c = scene.subsampled(1000, 0), scene.subsampled(1000, 0), scene.subsampled(1000, 1)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.colors, b.colors)
    assert not np.array_equal(a.points, c.points)
    assert len(a.points) == 1000 and a.total_points == 10_000
    # kept points are distinct rows of the original, in the original order, with their own colours
    idx = np.flatnonzero(np.isin(cloud.points[:, 0], a.points[:, 0]))
    assert len(idx) == 1000
    np.testing.assert_array_equal(cloud.points[idx], a.points)
    np.testing.assert_array_equal(cloud.colors[idx], a.colors)
    # uniform: both halves of the x range keep about half
    assert 400 < np.sum(a.points[:, 0] < 0) < 600
    assert scene.subsampled(20_000).points is scene.points


def test_page_embeds_centred_float32_with_the_offset():
    offset = np.array([500_000.0, 5_200_000.0, 400.0])  # UTM-like: float32 alone would lose ~0.5 m
    cloud = make_cloud(2000, offset=offset)
    pts = cloud.points.astype(np.float64)
    path = Polyline("flown", pts[:5], (1, 2, 3))
    page = render_page(ViewerScene("big coords", pts, cloud.colors, paths=(path,)))
    meta, blocks = _blocks(page)
    np.testing.assert_allclose(meta["offset"], offset + [0, 0, 3], atol=25)
    got = np.frombuffer(blocks["b-points"], "<f4").reshape(-1, 3) + np.array(meta["offset"])
    np.testing.assert_allclose(got, pts, atol=1e-4)
    np.testing.assert_array_equal(np.frombuffer(blocks["b-colors"], np.uint8).reshape(-1, 3), cloud.colors)
    assert meta["counts"]["points"] == 2000 and meta["color_mode"] == "rgb" and meta["has_rgb"]
    assert meta["paths"] == [
        {
            "name": "flown",
            "color": [1, 2, 3],
            "count": 5,
            "length_m": pytest.approx(path_len(pts[:5]), rel=1e-6),
        }
    ]
    text = page.decode()
    assert "OrbitControls" in text and "THREE.WebGLRenderer" in text and READY_TITLE in text
    # no network: no external scripts, styles or fetches
    assert not re.search(
        r"<script[^>]+src=|<link |https?://(?!www\.w3\.org)", text.split("/* three.min.js */")[0]
    )


def path_len(p):
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def test_height_colour_when_no_rgb_and_on_request():
    cloud = make_cloud(100)
    meta, blocks = _blocks(render_page(ViewerScene("z", cloud.points)))
    assert meta["color_mode"] == "height" and not meta["has_rgb"] and "b-colors" not in blocks
    meta, _ = _blocks(render_page(ViewerScene("z", cloud.points, cloud.colors), color="height"))
    assert meta["color_mode"] == "height" and meta["has_rgb"]


def test_cli_save_writes_one_page_atomically(tmp_path, ply_file, capsys):
    out = tmp_path / "view"
    assert main(["view", str(ply_file), "--save", str(out), "--max-points", "1000", "--seed", "3"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["index.html"]  # no temporary file left
    meta, blocks = _blocks((out / "index.html").read_bytes())
    assert meta["counts"] == {
        "points": 1000,
        "total_points": 5000,
        "voxels": 0,
        "total_voxels": 0,
        "cameras": 0,
    }
    assert len(blocks["b-points"]) == 1000 * 12
    err = capsys.readouterr().err
    assert "1,000 points of 5,000" in err and "index.html" in err
    # same seed, same page
    assert (
        main(
            [
                "view",
                str(ply_file),
                "--save",
                str(tmp_path / "v2"),
                "--max-points",
                "1000",
                "--seed",
                "3",
                "--quiet",
            ]
        )
        == 0
    )
    assert (tmp_path / "v2" / "index.html").read_bytes() == (out / "index.html").read_bytes()


def test_cli_save_of_a_map_and_a_mission(tmp_path, map_dir, mission_dir):
    for src, name in ((map_dir, "m"), (mission_dir, "mi")):
        assert main(["view", str(src), "--save", str(tmp_path / name), "--quiet"]) == 0
        meta, blocks = _blocks((tmp_path / name / "index.html").read_bytes())
        assert (
            meta["counts"]["voxels"] == 96
            and meta["voxel_size"] == 0.5
            and len(blocks["b-voxels"]) == 96 * 12
        )
    assert [p["name"] for p in meta["paths"]] == ["flown", "planned"]


@pytest.mark.parametrize("bad", ["nothing_here.ply", "notes.txt"])
def test_cli_bad_input_exits_2_with_one_line(tmp_path, capsys, bad):
    p = tmp_path / bad
    if bad.endswith(".txt"):
        p.write_text("hello")
    assert main(["view", str(p), "--save", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and str(p) in err[0] and ".ply" in err[0]
    assert not (tmp_path / "out").exists()


def test_cli_save_onto_a_file_exits_2(tmp_path, ply_file, capsys):
    f = tmp_path / "taken"
    f.write_text("x")
    assert main(["view", str(ply_file), "--save", str(f)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--save must be a directory" in err[0] and f.read_text() == "x"


def test_server_serves_the_page():
    page = render_page(ViewerScene("s", make_cloud(50).points))
    server = make_server(page, 0)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        url = server_url(server)
        assert re.fullmatch(r"http://127\.0\.0\.1:\d+/", url)
        for u in (url, url + "index.html"):
            with urllib.request.urlopen(u, timeout=10) as r:
                assert (
                    r.status == 200 and r.headers["Content-Type"].startswith("text/html") and r.read() == page
                )
        with pytest.raises(urllib.error.HTTPError) as e:
            urllib.request.urlopen(url + "secret.txt", timeout=10)
        assert e.value.code == 404
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5)


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to a child process")
def test_cli_serves_prints_the_address_and_exits_130_on_ctrl_c(tmp_path):
    p = tmp_path / "c.ply"
    write_ply(p, make_cloud(200))
    env = {**os.environ, "PYTHONPATH": str(SRC) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "skyrecon", "view", str(p), "--port", "0", "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        # a shell starts background jobs (CI under nohup, say) with SIGINT ignored, which the child
        # would inherit: give it the default a user's terminal gives
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        url = proc.stdout.readline().strip()
        assert re.fullmatch(r"http://127\.0\.0\.1:\d+/", url), url
        with urllib.request.urlopen(url, timeout=10) as r:
            assert b"skyrecon-view" in r.read()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 130
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
