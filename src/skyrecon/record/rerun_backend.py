"""Recording to a Rerun ``.rrd`` file (``rerun-sdk``; open with ``rerun FILE.rrd``).

Entities (``NAME`` as given to the recorder, see :mod:`skyrecon.record.recorder`):

* ``world``: the world frame, z up (static view coordinates);
* ``world/NAME``: a camera's or a body's pose (``Transform3D``, world_from_cam);
* ``world/NAME/image``: the camera's ``Pinhole`` (OpenCV axes, RDF) and its JPEG image;
* ``world/NAME/depth``: a ``Pinhole`` of the depth grid and a ``DepthImage`` (uint16 millimetres,
  or centimetres beyond 65 m; ``meter`` says which);
* ``images/NAME/disparity``, ``images/NAME``: 2D images (colourised disparity, thumbnails);
* ``world/NAME`` for clouds (``Points3D``), voxels (``Boxes3D``) and paths (``LineStrips3D``).

Timelines: ``time`` (a duration, seconds) and ``frame`` (a sequence) when given.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.record import prepare
from skyrecon.record.recorder import FileRecorder, RecordSettings, missing_library


def _import_rerun() -> Any:
    import rerun  # optional dependency: imported when a .rrd is recorded

    return rerun


class RerunRecorder(FileRecorder):
    """Writes a ``.rrd`` recording (see the module docstring for the entities)."""

    def __init__(
        self, path: str | Path, settings: RecordSettings | None = None, application_id: str = "skyrecon"
    ):
        try:
            rr = _import_rerun()
        except ImportError as e:
            raise missing_library("rerun", path, e) from None
        super().__init__(path, settings)
        self.rr = rr
        self.stream = rr.RecordingStream(application_id, send_properties=False)
        self.stream.save(str(self.tmp_path))
        self.stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self._cameras: dict[str, Intrinsics] = {}  # the pinhole last logged at each entity
        self._axes: set[str] = set()

    # ----- time ----------------------------------------------------------
    def set_time(self, seconds: float, frame: int | None = None) -> None:
        self.stream.set_time("time", duration=float(seconds))
        if frame is not None:
            self.stream.set_time("frame", sequence=int(frame))

    # ----- cameras and images -------------------------------------------
    def _pinhole(self, intrinsics: Intrinsics, image_plane_distance: float | None = None) -> Any:
        return self.rr.Pinhole(
            image_from_camera=intrinsics.K,
            width=intrinsics.width,
            height=intrinsics.height,
            camera_xyz=self.rr.ViewCoordinates.RDF,
            image_plane_distance=image_plane_distance,
        )

    def _transform(self, pose: Rigid3) -> Any:
        return self.rr.Transform3D(translation=pose.t, mat3x3=pose.R)

    def log_camera(
        self, name: str, intrinsics: Intrinsics, world_from_cam: Rigid3, image: np.ndarray | None = None
    ) -> None:
        if image is not None and image.shape[1] != intrinsics.width:  # e.g. a thumbnail
            intrinsics = intrinsics.scaled(image.shape[1] / intrinsics.width)
        path = f"world/{prepare.topic_name(name)}"
        s = self.settings
        f = prepare.downscale_factor(intrinsics.width, s.max_image_width)
        shown = intrinsics.scaled(f) if f < 1.0 else intrinsics
        self.stream.log(path, self._transform(world_from_cam))
        if self._cameras.get(path) != shown:
            self._cameras[path] = shown
            self.stream.log(f"{path}/image", self._pinhole(shown, image_plane_distance=2.0))
        if image is not None:
            rgb = prepare.downscale(prepare.as_rgb8(image), f)
            jpeg = prepare.encode_jpeg(rgb, s.jpeg_quality)
            self.stream.log(f"{path}/image", self.rr.EncodedImage(contents=jpeg, media_type="image/jpeg"))

    def log_image(self, name: str, image: np.ndarray) -> None:
        rgb = prepare.as_rgb8(image)
        rgb = prepare.downscale(rgb, prepare.downscale_factor(rgb.shape[1], self.settings.max_image_width))
        jpeg = prepare.encode_jpeg(rgb, self.settings.jpeg_quality)
        self.stream.log(
            f"images/{prepare.topic_name(name)}", self.rr.EncodedImage(contents=jpeg, media_type="image/jpeg")
        )

    def log_depth(self, name: str, depth_m: np.ndarray, intrinsics: Intrinsics) -> None:
        path = f"world/{prepare.topic_name(name)}/depth"
        d = prepare.clean_depth(depth_m)
        if d.shape != intrinsics.shape:
            d = d[: intrinsics.height, : intrinsics.width]
        f = prepare.downscale_factor(intrinsics.width, self.settings.max_image_width)
        if f < 1.0:
            intrinsics = intrinsics.scaled(f)
            d = prepare.downscale(d, f, nearest=True)
        if self._cameras.get(path) != intrinsics:
            self._cameras[path] = intrinsics
            self.stream.log(path, self._pinhole(intrinsics, image_plane_distance=0.5))
        units, meter = prepare.depth_units(d)
        self.stream.log(path, self.rr.DepthImage(units, meter=meter, colormap="turbo"))

    def log_disparity(self, name: str, disparity_px: np.ndarray, max_disparity: float | None = None) -> None:
        rgb = prepare.colorize_disparity(disparity_px, max_disparity)
        rgb = prepare.downscale(rgb, prepare.downscale_factor(rgb.shape[1], self.settings.max_image_width))
        jpeg = prepare.encode_jpeg(rgb, self.settings.jpeg_quality)
        self.stream.log(
            f"images/{prepare.topic_name(name)}/disparity",
            self.rr.EncodedImage(contents=jpeg, media_type="image/jpeg"),
        )

    # ----- 3D ---------------------------------------------------------------
    def log_points(self, name: str, xyz: np.ndarray, rgb: np.ndarray | None = None) -> None:
        pts, cols = prepare.cap_points(xyz, rgb, self.settings.max_points)
        self.stream.log(f"world/{prepare.topic_name(name)}", self.rr.Points3D(pts, colors=cols, radii=-1.5))

    def log_voxels(self, name: str, centres: np.ndarray, size_m: float) -> None:
        pts, _ = prepare.cap_points(centres, None, self.settings.max_voxels)
        half = np.full(3, 0.5 * float(size_m), np.float32)
        self.stream.log(
            f"world/{prepare.topic_name(name)}",
            self.rr.Boxes3D(
                centers=pts, half_sizes=half, colors=prepare.height_colors(pts[:, 2]), fill_mode="solid"
            ),
        )

    def log_path(self, name: str, points: np.ndarray, color: tuple[int, int, int] | None = None) -> None:
        pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        self.stream.log(
            f"world/{prepare.topic_name(name)}",
            self.rr.LineStrips3D([pts], colors=None if color is None else [color], radii=-2.0),
        )

    def log_pose(self, name: str, world_from_body: Rigid3) -> None:
        path = f"world/{prepare.topic_name(name)}"
        self.stream.log(path, self._transform(world_from_body))
        if path not in self._axes:  # axes once; they follow the transform
            self._axes.add(path)
            self.stream.log(path, self.rr.TransformAxes3D(axis_length=1.0), static=True)

    # ----- lifetime ---------------------------------------------------------
    def _finish(self) -> None:
        self.stream.flush()
        self.stream.disconnect()
