"""``skyrecon view``: look at any output in 3D in a browser (clouds, COLMAP models, maps, paths, missions).

PATH is a ``.ply``/``.las``/``.laz`` cloud, a COLMAP text model (``cameras.txt`` + ``images.txt``;
points and camera frusta), a map directory from ``skyrecon map`` (occupied voxels, and the flown
track), a ``path.json``, or a mission (``skyrecon demo``: map, flown and planned paths), sfm, mvs or
plan output directory. Without ``--save`` it serves the page on 127.0.0.1 and prints its address
until Ctrl-C; with ``--save DIR`` it writes ``DIR/index.html``, one self-contained file that opens
from disk with no server and no network (three.js is inlined). Points beyond ``--max-points`` are
subsampled (uniformly, reproducibly with ``--seed``) so that large clouds stay interactive. In the
page: drag to orbit, right-drag to pan, wheel to zoom, ``c`` toggles RGB / height colours, ``+``/``-``
the point size, ``r`` resets the view.
"""

from __future__ import annotations

import argparse
import time
import webbrowser
from pathlib import Path

from skyrecon.cli.common import add_command, info, positive_int
from skyrecon.errors import InputError

EXAMPLES = """  skyrecon view mvs_out/fused.ply                   # serves http://127.0.0.1:8765/
  skyrecon view flight_map/ --port 9000 --open
  skyrecon view demo_out/ --save demo_view/          # demo_view/index.html, opens from disk
  skyrecon view big.laz --max-points 1000000 --color height --save big_view/
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = add_command(
        subparsers,
        "view",
        help="3D viewer in the browser for any output",
        description=__doc__.split("\n\n")[0].split(": ", 1)[1],
        examples=EXAMPLES,
    )
    p.add_argument("path", metavar="PATH", help="a cloud, COLMAP model, map, path.json or output directory")
    p.add_argument("--save", metavar="DIR", help="write DIR/index.html (self-contained) instead of serving")
    p.add_argument(
        "--port", type=int, default=8765, help="port on 127.0.0.1 to serve on (default 8765; 0: any free)"
    )
    p.add_argument(
        "--max-points",
        type=positive_int,
        default=2_000_000,
        metavar="N",
        help="draw at most N points (and N voxels), a uniform subsample beyond (default 2000000)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the subsample (default 0)")
    p.add_argument(
        "--color",
        choices=("rgb", "height"),
        help="colour the points by their RGB or by height (default: RGB when the points have colours)",
    )
    p.add_argument("--open", action="store_true", help="also open the page in the default browser")
    return p


def run(args: argparse.Namespace) -> int:
    from skyrecon.viewer import load_scene, make_server, render_page, server_url, write_page

    if args.save and Path(args.save).exists() and not Path(args.save).is_dir():
        raise InputError(
            "--save must be a directory (index.html is written into it), but a file of that name exists",
            args.save,
        )
    t0 = time.perf_counter()
    full = load_scene(args.path)
    if full.is_empty:
        raise InputError("nothing to show: no points, voxels, cameras or paths", args.path)
    scene = full.subsampled(args.max_points, args.seed)
    if not args.quiet:
        what = [
            f"{len(scene.points):,} points"
            + (f" of {full.total_points:,}" if full.total_points > len(scene.points) else ""),
            f"{len(scene.voxel_centers):,} voxels" if full.total_voxels else "",
            f"{len(scene.camera_segments) // 8} cameras" if len(scene.camera_segments) else "",
            f"{len(scene.paths)} paths" if scene.paths else "",
        ]
        info(f"read {args.path}: " + ", ".join(w for w in what if w) + f" ({time.perf_counter() - t0:.1f} s)")
    if args.save:
        out = write_page(scene, args.save, args.color)
        if not args.quiet:
            info(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB, opens from disk)")
        return 0
    page = render_page(scene, args.color)
    try:
        server = make_server(page, args.port)
    except OSError as e:
        raise InputError(
            f"cannot serve on 127.0.0.1:{args.port} ({e.strerror or e}); try another --port"
        ) from None
    url = server_url(server)
    print(url, flush=True)
    if not args.quiet:
        info("serving the viewer; Ctrl-C to stop")
    if args.open:
        webbrowser.open(url)
    try:
        server.serve_forever()
    finally:
        server.server_close()
    return 0
