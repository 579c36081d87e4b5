"""A browser 3D viewer for skyrecon outputs: point clouds, COLMAP models, maps, paths, missions.

    scene = load_scene("mission_out/")                 # ViewerScene (world frame, metres)
    write_page(scene.subsampled(2_000_000), "view/")   # view/index.html, opens from disk offline

Built on a vendored three.js (r149, MIT) inlined into the page: no Python dependency, no network.
"""

from skyrecon.viewer.html import READY_TITLE, render_page, write_page
from skyrecon.viewer.load import ACCEPTS, load_scene, map_scene
from skyrecon.viewer.scene import Polyline, ViewerScene
from skyrecon.viewer.serve import make_server, server_url

__all__ = [
    "ACCEPTS",
    "READY_TITLE",
    "Polyline",
    "ViewerScene",
    "load_scene",
    "make_server",
    "map_scene",
    "render_page",
    "server_url",
    "write_page",
]
