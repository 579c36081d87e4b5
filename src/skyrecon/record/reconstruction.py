"""What the reconstruction commands log: the cameras and sparse points of ``skyrecon sfm``, the
cameras, depth maps and fused cloud of ``skyrecon mvs``. A reconstruction has no timeline of its
own: the cameras are logged in order on the ``frame`` sequence (``time`` = index x 0.1 s), so the
viewer can step through them, and the clouds at the last one.

Names (see :mod:`skyrecon.record.recorder`):

* ``cameras/<image stem>``: each registered camera at its pose with its frustum and a
  thumbnail of its image (at most :data:`THUMBNAIL_WIDTH` pixels wide);
* ``cameras/<image stem>`` depth (mvs): the view's depth map at the working resolution;
* ``sparse/points`` (sfm): the sparse points with their colours;
* ``fused/points`` (mvs): the fused cloud (capped to ``settings.max_points``);
* ``path/cameras``: the camera centres in order.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError
from skyrecon.record import prepare
from skyrecon.record.recorder import Recorder

#: Width of the camera thumbnails, pixels.
THUMBNAIL_WIDTH = 320


def _thumbnail(path: Path | None) -> np.ndarray | None:
    """(h, w, 3) uint8 RGB thumbnail of an image file, or None when it cannot be read."""
    if path is None:
        return None
    from skyrecon.io.images import read_image

    try:
        rgb = read_image(path, "rgb")
    except (InputError, OSError):
        return None
    if rgb.dtype != np.uint8:
        return None
    return prepare.downscale(rgb, prepare.downscale_factor(rgb.shape[1], THUMBNAIL_WIDTH))


def _camera(
    recorder: Recorder, name: str, intrinsics: Intrinsics, cam_from_world: Rigid3, image_path
) -> None:
    thumb = _thumbnail(image_path)
    shown = intrinsics if thumb is None else intrinsics.scaled(thumb.shape[1] / intrinsics.width)
    recorder.log_camera(name, shown, cam_from_world.inverse(), thumb)


def log_sfm(recorder: Recorder, reconstruction: Any, image_paths: Sequence[Path]) -> None:
    """Log an SfM model: each registered image's camera (in name order) and the sparse points.

    Args:
        reconstruction: the :class:`~skyrecon.core.reconstruction.Reconstruction`.
        image_paths: the input image files (matched to the model's images by file name).
    """
    by_name = {p.name: p for p in image_paths}
    images = sorted(reconstruction.images.values(), key=lambda im: im.name)
    centres = []
    for i, im in enumerate(images):
        recorder.set_time(0.1 * i, i)
        cam = reconstruction.cameras[im.camera_id]
        _camera(recorder, f"cameras/{Path(im.name).stem}", cam, im.cam_from_world, by_name.get(im.name))
        centres.append(im.cam_from_world.inverse().t)
    xyz, rgb = reconstruction.points_array()
    if len(centres) >= 2:
        recorder.log_path("path/cameras", np.array(centres), (255, 200, 0))
    recorder.log_points("sparse/points", xyz, rgb)


def log_mvs(recorder: Recorder, views: Sequence[Any], result: Any) -> None:
    """Log an MVS run: each view's camera and depth map (in input order) and the fused cloud.

    Args:
        views: the :class:`~skyrecon.core.view.PosedView` inputs.
        result: the :class:`~skyrecon.mvs.pipeline.MVSResult`.
    """
    centres = []
    for i, v in enumerate(views):
        recorder.set_time(0.1 * i, i)
        name = f"cameras/{Path(v.name).stem}"
        _camera(recorder, name, v.intrinsics, v.cam_from_world, v.image_path)
        dm = result.depth_maps.get(Path(v.name).stem)
        if dm is not None:
            recorder.log_depth(name, dm.depth_m, dm.intrinsics)
        centres.append(v.cam_from_world.inverse().t)
    if len(centres) >= 2:
        recorder.log_path("path/cameras", np.array(centres), (255, 200, 0))
    recorder.log_points("fused/points", result.cloud.points, result.cloud.colors)
