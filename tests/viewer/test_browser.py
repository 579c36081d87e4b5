"""The viewer page in a real browser: headless Chromium (WebGL through SwiftShader) opens the saved
page from disk, the page reports ready with no error, and the screenshot shows the points.

Skips when no Chromium / Chrome executable is installed (CI installs Debian's ``chromium``).
"""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest

from skyrecon.cli.main import main
from skyrecon.io.ply import write_ply
from skyrecon.viewer import READY_TITLE
from tests.viewer.conftest import make_cloud

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
BACKGROUND = np.array([0x15, 0x17, 0x1C])  # the page's clear colour
# Chromium's own log lines that are not page errors (SwiftShader performance notes, e.g. the
# screenshot's read-back stall).
BENIGN = ("GPU stall due to ReadPixels", "GL Driver Message (OpenGL, Performance")


def _browser() -> str:
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("no headless Chromium/Chrome found (install Debian's 'chromium' to run this test)")


def _run(
    browser: str, url: str, tmp_path, width: int = 800, height: int = 600
) -> tuple[str, str, np.ndarray]:
    from PIL import Image

    shot = tmp_path / "shot.png"
    cmd = [
        browser,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--enable-unsafe-swiftshader",
        "--use-angle=swiftshader",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-extensions",
        "--no-first-run",
        "--no-default-browser-check",
        "--hide-scrollbars",
        f"--user-data-dir={tmp_path / 'profile'}",
        "--virtual-time-budget=8000",
        f"--window-size={width},{height}",
        f"--screenshot={shot}",
        "--dump-dom",
        "--enable-logging=stderr",
        "--v=0",
        url,
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=90)
    assert shot.is_file(), f"no screenshot; chromium said:\n{proc.stderr[-3000:]}"
    return proc.stdout, proc.stderr, np.asarray(Image.open(shot).convert("RGB"))


def _page_errors(dom: str, log: str) -> list[str]:
    errors = re.findall(r"<li>(.*?)</li>", dom.split('id="errors"', 1)[1].split("</ul>", 1)[0])
    for line in log.splitlines():
        if ("CONSOLE" in line or "WebGL" in line) and not any(b in line for b in BENIGN):
            if re.search(r"error|uncaught|invalid|warning: webgl|context lost", line, re.I):
                errors.append(line)
    return errors


def test_points_are_drawn_in_headless_chromium(tmp_path):
    browser = _browser()
    ply = tmp_path / "cloud.ply"
    write_ply(ply, make_cloud(20_000, offset=(500_000.0, 5_200_000.0, 300.0)))
    assert main(["view", str(ply), "--save", str(tmp_path / "view"), "--quiet"]) == 0
    dom, log, img = _run(browser, (tmp_path / "view" / "index.html").resolve().as_uri(), tmp_path)
    title = re.search(r"<title>(.*?)</title>", dom)
    assert not _page_errors(dom, log)
    assert title and title.group(1) == READY_TITLE, (title and title.group(1), log[-3000:])
    assert 'data-ready="1"' in dom
    # The cloud fills the middle of the view: many pixels there differ from the background.
    h, w, _ = img.shape
    centre = img[h // 4 : 3 * h // 4, w // 4 : 3 * w // 4].astype(int)
    drawn = np.abs(centre - BACKGROUND).sum(axis=2) > 30
    assert drawn.mean() > 0.15, f"only {drawn.mean():.1%} of the centre differs from the background"
    # ...and the colours are the points' (many distinct colours, not one flat fill)
    assert len(np.unique(centre[drawn].reshape(-1, 3), axis=0)) > 100


def test_report_errors_are_listed(tmp_path):
    """The error hook works: a page whose script fails says so (title and list), so the test above
    would see a broken viewer."""
    browser = _browser()
    ply = tmp_path / "cloud.ply"
    write_ply(ply, make_cloud(100))
    assert main(["view", str(ply), "--save", str(tmp_path / "view"), "--quiet"]) == 0
    page = tmp_path / "view" / "index.html"
    page.write_bytes(page.read_bytes().replace(b"new THREE.OrbitControls(", b"new THREE.NoSuchControls("))
    dom, log, _ = _run(browser, page.resolve().as_uri(), tmp_path, 320, 240)
    assert "<title>skyrecon-view: error</title>" in dom
    assert _page_errors(dom, log)
