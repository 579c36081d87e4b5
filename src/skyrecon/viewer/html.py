"""The viewer page: one self-contained HTML file that opens from disk with no server and no network.

The page inlines three.js r149 (``static/three.min.js``, MIT, see ``static/LICENSE.three.txt``),
OrbitControls made a plain script (``static/OrbitControls.js``) and the page's own script
(``static/viewer.js``). The data are embedded as base64 little-endian typed arrays in
``<script type="application/octet-stream" id="b-...">`` elements:

* ``b-points``: (N, 3) float32 point positions minus ``offset``, world metres;
* ``b-colors``: (N, 3) uint8 RGB (only when the points have colours);
* ``b-voxels``: (M, 3) float32 occupied voxel centres minus ``offset``;
* ``b-cameras``: (S * 2, 3) float32 frustum segment end points minus ``offset``;
* ``b-paths``: every path's points (sum K, 3) float32 minus ``offset``, one after the other;

and a JSON ``#meta`` element: ``offset`` (3,) float64 world metres (the centre of the data,
subtracted in float64 before the conversion to float32 so large coordinates keep their
precision), counts, the radius of the data, point size, height range, paths (name, colour, count,
length). The page sets ``document.title`` to ``skyrecon-view: ready`` after its first frame, and
lists any script error in ``#errors`` (title ``skyrecon-view: error``).
"""

from __future__ import annotations

import base64
import html
import json
from importlib import resources
from pathlib import Path

import numpy as np

from skyrecon.io.atomic import write_bytes_atomic
from skyrecon.viewer.scene import ViewerScene

READY_TITLE = "skyrecon-view: ready"
#: Above this many voxels they are drawn as points the size of a voxel instead of cubes.
MAX_CUBES = 250_000

_CSS = """
html, body { margin: 0; height: 100%; overflow: hidden; background: #15171c; }
canvas { display: block; }
#info { position: absolute; top: 8px; left: 8px; padding: 6px 10px; color: #e8e8e8; background: rgba(20,22,28,0.78);
        font: 12px/1.5 -apple-system, 'Segoe UI', Helvetica, Arial, sans-serif; border-radius: 4px; max-width: 46em; }
#info small { color: #aaa; } #info button { font-size: 11px; margin-left: 6px; }
.sw { display: inline-block; width: 16px; height: 3px; vertical-align: middle; margin-right: 5px; }
#errors { position: absolute; bottom: 8px; left: 8px; margin: 0; padding: 6px 10px 6px 24px; color: #ffb4b4;
          background: rgba(60,10,10,0.85); font: 12px monospace; max-width: 90%; }
#errors[data-count="0"] { display: none; }
"""

# Runs first, so that errors while loading three.js are listed too.
_ERROR_HOOK = """
window.skyreconErrors = [];
(function () {
  function report(msg) {
    window.skyreconErrors.push(String(msg));
    var ul = document.getElementById('errors');
    var li = document.createElement('li');
    li.textContent = String(msg);
    ul.appendChild(li);
    ul.setAttribute('data-count', String(window.skyreconErrors.length));
    document.title = 'skyrecon-view: error';
  }
  window.addEventListener('error', function (e) { report(e.message || e); });
  window.addEventListener('unhandledrejection', function (e) { report('unhandled rejection: ' + e.reason); });
  var orig = console.error;
  console.error = function () {
    report(Array.prototype.slice.call(arguments).join(' '));
    return orig.apply(console, arguments);
  };
})();
"""


def _static(name: str) -> str:
    return resources.files("skyrecon.viewer").joinpath("static", name).read_text(encoding="utf-8")


def _b64(a: np.ndarray, dtype: str) -> bytes:
    return base64.b64encode(np.ascontiguousarray(a, dtype=dtype).tobytes())


def _point_size(lo: np.ndarray, hi: np.ndarray, n: int) -> float:
    """World size of a point: about the mean spacing of ``n`` points spread over the two largest
    extents of the box, within 1e-4 .. 1e-2 of its diagonal."""
    ext = np.sort(np.maximum(hi - lo, 0.0))[::-1]
    diag = float(np.linalg.norm(ext)) or 1.0
    spacing = float(np.sqrt(max(ext[0] * ext[1], 1e-12) / max(n, 1)))
    return float(np.clip(1.5 * spacing, 1e-4 * diag, 1e-2 * diag))


def render_page(scene: ViewerScene, color: str | None = None) -> bytes:
    """The page of ``scene`` as UTF-8 bytes.

    Args:
        scene: what to draw (already subsampled: every point is embedded).
        color: ``rgb`` or ``height`` for the points at start (toggle with ``c`` in the page);
            None: RGB when the points have colours, else height.
    """
    if color not in (None, "rgb", "height"):
        raise ValueError(f"color must be 'rgb' or 'height', got {color!r}")
    lo, hi = scene.bounds()
    offset = (lo + hi) / 2.0
    pts = np.asarray(scene.points, dtype=np.float64) - offset if len(scene.points) else np.zeros((0, 3))
    vox = scene.voxel_centers - offset
    cams = scene.camera_segments.reshape(-1, 3) - offset
    paths = [p.points - offset for p in scene.paths]
    zs = np.concatenate([pts[:, 2], vox[:, 2]]) if len(pts) + len(vox) else np.zeros(1)
    z_range = [float(zs.min()), float(zs.max())]
    has_rgb = scene.colors is not None and len(scene.points) > 0
    mode = color or ("rgb" if has_rgb else "height")
    meta = {
        "title": scene.title,
        "offset": offset.tolist(),
        "radius": max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-3),
        "z_range": z_range,
        "point_size": _point_size(lo, hi, len(pts)),
        "voxel_size": float(scene.voxel_size_m),
        "max_cubes": MAX_CUBES,
        "has_rgb": has_rgb,
        "color_mode": mode if has_rgb else "height",
        "counts": {
            "points": int(len(pts)),
            "total_points": int(scene.total_points),
            "voxels": int(len(vox)),
            "total_voxels": int(scene.total_voxels),
            "cameras": int(len(scene.camera_segments) // 8),
        },
        "paths": [
            {
                "name": p.name,
                "color": [int(c) for c in p.color],
                "count": int(len(p.points)),
                "length_m": float(np.linalg.norm(np.diff(p.points, axis=0), axis=1).sum()),
            }
            for p in scene.paths
        ],
    }
    meta_json = json.dumps(meta).replace("</", "<\\/")
    blocks = [
        ("b-points", _b64(pts, "<f4")),
        ("b-voxels", _b64(vox, "<f4")),
        ("b-cameras", _b64(cams, "<f4")),
    ]
    if scene.colors is not None and has_rgb:
        blocks.append(("b-colors", _b64(scene.colors, "u1")))
    blocks.append(("b-paths", _b64(np.concatenate(paths) if paths else np.zeros((0, 3)), "<f4")))
    head = (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>skyrecon-view: loading {html.escape(scene.title)}</title><style>{_CSS}</style></head>\n<body>"
        "<div id='info'>loading...</div><ul id='errors' data-count='0'></ul>\n"
        f"<script>{_ERROR_HOOK}</script>\n"
        f"<script type='application/json' id='meta'>{meta_json}</script>\n"
    )
    parts = [head.encode("utf-8")]
    for name, data in blocks:
        parts += [f"<script type='application/octet-stream' id='{name}'>".encode(), data, b"</script>\n"]
    for js in ("three.min.js", "OrbitControls.js", "viewer.js"):
        parts.append(f"<script>/* {js} */\n{_static(js)}\n</script>\n".encode())
    parts.append(b"</body></html>\n")
    return b"".join(parts)


def write_page(scene: ViewerScene, directory: str | Path, color: str | None = None) -> Path:
    """Write ``directory/index.html`` (created if missing) atomically; returns its path."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    out = d / "index.html"
    write_bytes_atomic(out, render_page(scene, color))
    return out
