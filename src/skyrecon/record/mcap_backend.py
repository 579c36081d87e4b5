"""Recording to an ``.mcap`` file with Foxglove schemas (``foxglove-sdk``; open it in Foxglove
or Lichtblick).

Topics (``NAME`` as given to the recorder, see :mod:`skyrecon.record.recorder`), each with
one schema:

* ``/tf`` (``foxglove.FrameTransform``): the pose of every camera and body, parent ``world``,
  child ``NAME``;
* ``/NAME/calibration`` (``foxglove.CameraCalibration``), ``/NAME/image``
  (``foxglove.CompressedImage``, JPEG, frame ``NAME``) and ``/NAME/frustum``
  (``foxglove.SceneUpdate``, lines in ``world``) of a camera;
* ``/NAME/depth`` (``foxglove.RawImage``, ``32FC1`` metres, 0 invalid) and
  ``/NAME/disparity`` (``foxglove.CompressedImage``, colourised);
* ``/NAME`` for images (``CompressedImage``), clouds (``foxglove.PointCloud``: x, y, z float32
  and red, green, blue, alpha uint8, frame ``world``), voxels (``SceneUpdate`` cubes), paths
  (``SceneUpdate`` line strip); ``/NAME/pose`` (``foxglove.PoseInFrame``) for poses.

Each message's log time is the recorder's time in nanoseconds (from 0), as is its header stamp.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.record import prepare
from skyrecon.record.recorder import FileRecorder, RecordSettings, missing_library


def _import_foxglove() -> tuple[Any, Any, Any]:
    import foxglove  # optional dependency: imported when a .mcap is recorded
    import foxglove.channels
    import foxglove.messages

    return foxglove, foxglove.channels, foxglove.messages


class McapRecorder(FileRecorder):
    """Writes an ``.mcap`` recording with Foxglove schemas (see the module docstring)."""

    def __init__(self, path: str | Path, settings: RecordSettings | None = None):
        try:
            fg, channels, messages = _import_foxglove()
        except ImportError as e:
            raise missing_library("foxglove", path, e) from None
        super().__init__(path, settings)
        self.ch, self.m = channels, messages
        self.context = fg.Context()  # our own: other code logging to the global context stays out
        self.writer = fg.open_mcap(str(self.tmp_path), context=self.context)
        self._channels: dict[tuple[str, str], Any] = {}
        self._calibrated: dict[str, Intrinsics] = {}
        self.time_ns = 0

    # ----- plumbing ---------------------------------------------------------
    def _channel(self, topic: str, kind: str) -> Any:
        key = (topic, kind)
        channel = self._channels.get(key)
        if channel is None:
            channel = getattr(self.ch, f"{kind}Channel")(topic, context=self.context)
            self._channels[key] = channel
        return channel

    def _log(self, topic: str, kind: str, msg: Any) -> None:
        self._channel(topic, kind).log(msg, log_time=self.time_ns)

    def _stamp(self) -> Any:
        return self.m.Timestamp(self.time_ns // 1_000_000_000, self.time_ns % 1_000_000_000)

    def _pose(self, pose: Rigid3) -> Any:
        x, y, z, w = prepare.quaternion_xyzw(pose)
        t = pose.t
        return self.m.Pose(
            position=self.m.Vector3(x=float(t[0]), y=float(t[1]), z=float(t[2])),
            orientation=self.m.Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)),
        )

    def _color(self, rgb: tuple[int, int, int] | np.ndarray, alpha: float = 1.0) -> Any:
        r, g, b = (float(v) / 255.0 for v in rgb)
        return self.m.Color(r=r, g=g, b=b, a=alpha)

    def _jpeg(self, topic: str, rgb: np.ndarray, frame_id: str) -> None:
        rgb = prepare.downscale(rgb, prepare.downscale_factor(rgb.shape[1], self.settings.max_image_width))
        data = prepare.encode_jpeg(rgb, self.settings.jpeg_quality)
        msg = self.m.CompressedImage(timestamp=self._stamp(), frame_id=frame_id, data=data, format="jpeg")
        self._log(topic, "CompressedImage", msg)

    def _transform(self, name: str, pose: Rigid3) -> None:
        x, y, z, w = prepare.quaternion_xyzw(pose)
        t = pose.t
        msg = self.m.FrameTransform(
            timestamp=self._stamp(),
            parent_frame_id="world",
            child_frame_id=name,
            translation=self.m.Vector3(x=float(t[0]), y=float(t[1]), z=float(t[2])),
            rotation=self.m.Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)),
        )
        self._log("/tf", "FrameTransform", msg)

    def _scene(self, topic: str, entity_id: str, **primitives: Any) -> None:
        entity = self.m.SceneEntity(timestamp=self._stamp(), frame_id="world", id=entity_id, **primitives)
        self._log(topic, "SceneUpdate", self.m.SceneUpdate(entities=[entity]))

    # ----- time ----------------------------------------------------------
    def set_time(self, seconds: float, frame: int | None = None) -> None:
        self.time_ns = max(0, int(round(float(seconds) * 1e9)))

    # ----- cameras and images -------------------------------------------
    def log_camera(
        self, name: str, intrinsics: Intrinsics, world_from_cam: Rigid3, image: np.ndarray | None = None
    ) -> None:
        if image is not None and image.shape[1] != intrinsics.width:  # e.g. a thumbnail
            intrinsics = intrinsics.scaled(image.shape[1] / intrinsics.width)
        name = prepare.topic_name(name)
        f = prepare.downscale_factor(intrinsics.width, self.settings.max_image_width)
        shown = intrinsics.scaled(f) if f < 1.0 else intrinsics
        self._transform(name, world_from_cam)
        if self._calibrated.get(name) != shown:
            self._calibrated[name] = shown
            K = shown.K
            P = np.hstack([K, np.zeros((3, 1))])
            msg = self.m.CameraCalibration(
                timestamp=self._stamp(),
                frame_id=name,
                width=shown.width,
                height=shown.height,
                distortion_model="plumb_bob",
                D=[float(v) for v in shown.dist],
                K=[float(v) for v in K.ravel()],
                R=[float(v) for v in np.eye(3).ravel()],
                P=[float(v) for v in P.ravel()],
            )
            self._log(f"/{name}/calibration", "CameraCalibration", msg)
        seg = prepare.frustum_lines(intrinsics, world_from_cam, depth=2.0)
        line = self.m.LinePrimitive(
            type=self.m.LinePrimitiveLineType.LineList,
            thickness=2.0,
            scale_invariant=True,
            points=[self.m.Point3(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in seg],
            color=self._color((255, 200, 0)),
        )
        self._scene(f"/{name}/frustum", name, lines=[line])
        if image is not None:
            self._jpeg(f"/{name}/image", prepare.as_rgb8(image), name)

    def log_image(self, name: str, image: np.ndarray) -> None:
        name = prepare.topic_name(name)
        self._jpeg(f"/{name}", prepare.as_rgb8(image), name)

    def log_depth(self, name: str, depth_m: np.ndarray, intrinsics: Intrinsics) -> None:
        name = prepare.topic_name(name)
        d = prepare.clean_depth(depth_m)
        d = prepare.downscale(
            d, prepare.downscale_factor(d.shape[1], self.settings.max_image_width), nearest=True
        )
        d = np.ascontiguousarray(d, dtype="<f4")
        msg = self.m.RawImage(
            timestamp=self._stamp(),
            frame_id=name,
            width=int(d.shape[1]),
            height=int(d.shape[0]),
            encoding="32FC1",
            step=int(d.shape[1]) * 4,
            data=d.tobytes(),
        )
        self._log(f"/{name}/depth", "RawImage", msg)

    def log_disparity(self, name: str, disparity_px: np.ndarray, max_disparity: float | None = None) -> None:
        name = prepare.topic_name(name)
        self._jpeg(f"/{name}/disparity", prepare.colorize_disparity(disparity_px, max_disparity), name)

    # ----- 3D ---------------------------------------------------------------
    def log_points(self, name: str, xyz: np.ndarray, rgb: np.ndarray | None = None) -> None:
        name = prepare.topic_name(name)
        pts, cols = prepare.cap_points(xyz, rgb, self.settings.max_points)
        if cols is None:
            cols = np.full((len(pts), 3), 255, np.uint8)
        packed = np.zeros(
            len(pts),
            dtype=[
                ("x", "<f4"),
                ("y", "<f4"),
                ("z", "<f4"),
                ("r", "u1"),
                ("g", "u1"),
                ("b", "u1"),
                ("a", "u1"),
            ],
        )
        packed["x"], packed["y"], packed["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
        packed["r"], packed["g"], packed["b"], packed["a"] = cols[:, 0], cols[:, 1], cols[:, 2], 255
        f32, u8 = self.m.PackedElementFieldNumericType.Float32, self.m.PackedElementFieldNumericType.Uint8
        fields = [
            self.m.PackedElementField(name=n, offset=o, type=t)
            for n, o, t in [
                ("x", 0, f32),
                ("y", 4, f32),
                ("z", 8, f32),
                ("red", 12, u8),
                ("green", 13, u8),
                ("blue", 14, u8),
                ("alpha", 15, u8),
            ]
        ]
        msg = self.m.PointCloud(
            timestamp=self._stamp(),
            frame_id="world",
            pose=self._pose(Rigid3()),
            point_stride=16,
            fields=fields,
            data=packed.tobytes(),
        )
        self._log(f"/{name}", "PointCloud", msg)

    def log_voxels(self, name: str, centres: np.ndarray, size_m: float) -> None:
        name = prepare.topic_name(name)
        pts, _ = prepare.cap_points(centres, None, self.settings.max_voxels)
        colors = prepare.height_colors(pts[:, 2])
        s = float(size_m)
        size = self.m.Vector3(x=s, y=s, z=s)
        identity = self.m.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
        cubes = [
            self.m.CubePrimitive(
                pose=self.m.Pose(
                    position=self.m.Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])), orientation=identity
                ),
                size=size,
                color=self._color(c),
            )
            for p, c in zip(pts.tolist(), colors.tolist())
        ]
        self._scene(f"/{name}", name, cubes=cubes)

    def log_path(self, name: str, points: np.ndarray, color: tuple[int, int, int] | None = None) -> None:
        name = prepare.topic_name(name)
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        line = self.m.LinePrimitive(
            type=self.m.LinePrimitiveLineType.LineStrip,
            thickness=3.0,
            scale_invariant=True,
            points=[self.m.Point3(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in pts],
            color=self._color(color or (255, 255, 255)),
        )
        self._scene(f"/{name}", name, lines=[line])

    def log_pose(self, name: str, world_from_body: Rigid3) -> None:
        name = prepare.topic_name(name)
        self._transform(name, world_from_body)
        msg = self.m.PoseInFrame(timestamp=self._stamp(), frame_id="world", pose=self._pose(world_from_body))
        self._log(f"/{name}/pose", "PoseInFrame", msg)

    # ----- lifetime ---------------------------------------------------------
    def _finish(self) -> None:
        self.writer.close()
