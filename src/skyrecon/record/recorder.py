"""The backend-neutral recorder: what a run logs on its timeline, and how a file is chosen.

A :class:`Recorder` logs a run on a timeline for a viewer: cameras (pinhole, pose, frustum,
image), depth and disparity maps, point clouds, occupied voxels, paths and poses. The backend
is chosen by the file's extension (:func:`open_recorder`): ``.rrd`` for the Rerun viewer
(``rerun-sdk``), ``.mcap`` with Foxglove schemas for Foxglove / Lichtblick (``foxglove-sdk``).
Both are optional extras; a missing one is an :class:`~skyrecon.errors.InputError` whose
message has the install line.

Conventions (every backend):

* the world frame is ``world`` (metres; z up in the simulated city, whatever the data's
  convention is elsewhere); poses are ``world_from_cam`` / ``world_from_body``
  (:class:`~skyrecon.core.rigid.Rigid3`, ``p_world = R @ p_cam + t``);
* cameras are OpenCV pinholes (x right, y down, z forward; :mod:`skyrecon.core.intrinsics`);
* a name is a slash-separated path such as ``"camera"`` or ``"map/voxels"``: a Rerun entity
  under ``world/`` (2D-only images under ``images/``), an MCAP topic ``/camera``, ``/map/voxels``;
* time: :meth:`Recorder.set_time` sets the ``time`` (seconds) and, optionally, the ``frame``
  (integer) of what is logged next.

The file is written beside the target under a temporary name and renamed onto it by
:meth:`Recorder.close`; :meth:`Recorder.abort` (or leaving the ``with`` block on an exception)
removes it, so an interrupted run never leaves a half-written recording under the final name.

Stages do not open recorders (they write no files): the command line opens one and passes it
down as an optional observer; :class:`NullRecorder` stands in when there is none.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError

#: Accepted recording extensions and the backend each selects.
RECORD_EXTENSIONS = {".rrd": "rerun", ".mcap": "foxglove"}

#: The install line for each backend's optional dependency.
INSTALL_LINES = {
    "rerun": "pip install 'skyrecon[rerun]'  (rerun-sdk)",
    "foxglove": "pip install 'skyrecon[foxglove]'  (foxglove-sdk)",
}


@dataclass(frozen=True)
class RecordSettings:
    """How much of a run goes into a recording (the defaults keep a default demo well under
    150 MB; see the README's "Recordings").

    Attributes:
        image_every: log a camera image every this many frames (the pose and frustum every frame).
        depth_every: log depth and disparity every this many frames.
        map_every: log the map's occupied voxels every this many frames (and at the end).
        max_image_width: images, depth and disparity wider than this are downscaled, pixels.
        max_voxels: at most this many occupied voxels per snapshot (an even, deterministic subset).
        max_points: at most this many points per cloud (an even, deterministic subset).
        jpeg_quality: JPEG quality of colour images and colourised disparity (1-100).
    """

    image_every: int = 1
    depth_every: int = 5
    map_every: int = 20
    max_image_width: int = 640
    max_voxels: int = 60_000
    max_points: int = 200_000
    jpeg_quality: int = 80

    def __post_init__(self) -> None:
        for name in (
            "image_every",
            "depth_every",
            "map_every",
            "max_image_width",
            "max_voxels",
            "max_points",
        ):
            if int(getattr(self, name)) <= 0:
                raise InputError(f"record settings: {name} must be positive, got {getattr(self, name)}")
        if not 1 <= self.jpeg_quality <= 100:
            raise InputError(f"record settings: jpeg_quality must be 1-100, got {self.jpeg_quality}")


class Recorder(ABC):
    """A run's timeline for a viewer (see the module docstring for names, frames and time).

    Use as a context manager: a clean exit closes (renames the file into place), an exception
    aborts (removes it).
    """

    #: False only for :class:`NullRecorder`: lets callers skip work whose only use is logging.
    enabled: bool = True

    def __init__(self, settings: RecordSettings | None = None):
        self.settings = settings or RecordSettings()

    # ----- time ----------------------------------------------------------
    @abstractmethod
    def set_time(self, seconds: float, frame: int | None = None) -> None:
        """Time of what is logged next: ``seconds`` on the ``time`` timeline and, when given,
        ``frame`` on the ``frame`` sequence."""

    # ----- cameras and images -------------------------------------------
    @abstractmethod
    def log_camera(
        self,
        name: str,
        intrinsics: Intrinsics,
        world_from_cam: Rigid3,
        image: np.ndarray | None = None,
    ) -> None:
        """A pinhole camera at its pose with its frustum, and optionally its image.

        Args:
            name: the camera's name (e.g. ``"camera"``, ``"cameras/img_0003"``).
            intrinsics: its pinhole (size ``intrinsics.width`` x ``intrinsics.height``).
            world_from_cam: its pose, world metres.
            image: (H, W, 3) uint8 RGB or (H, W) uint8 grey (of another size than the
                intrinsics', e.g. a thumbnail, the pinhole is scaled to it); downscaled to
                ``settings.max_image_width`` and JPEG-compressed.
        """

    @abstractmethod
    def log_image(self, name: str, image: np.ndarray) -> None:
        """A 2D image with no camera: (H, W, 3) uint8 RGB or (H, W) uint8 grey."""

    @abstractmethod
    def log_depth(self, name: str, depth_m: np.ndarray, intrinsics: Intrinsics) -> None:
        """A depth map of camera ``name`` (log the camera first).

        Args:
            depth_m: (h, w) float depth along the optical axis, metres; NaN, inf or <= 0 invalid.
            intrinsics: the pinhole of the depth grid (may be coarser than the image's).
        """

    @abstractmethod
    def log_disparity(self, name: str, disparity_px: np.ndarray, max_disparity: float | None = None) -> None:
        """A disparity map of camera ``name``, shown colourised (near warm, far cold).

        Args:
            disparity_px: (H, W) float disparity, pixels; NaN or <= 0 invalid.
            max_disparity: the colour scale's top, pixels (default: the map's 99th percentile).
        """

    # ----- 3D ---------------------------------------------------------------
    @abstractmethod
    def log_points(self, name: str, xyz: np.ndarray, rgb: np.ndarray | None = None) -> None:
        """A point cloud: ``xyz`` (N, 3) world metres, ``rgb`` (N, 3) uint8 or None; capped to
        ``settings.max_points`` (an even, deterministic subset)."""

    @abstractmethod
    def log_voxels(self, name: str, centres: np.ndarray, size_m: float) -> None:
        """Occupied voxels: ``centres`` (N, 3) world metres, cubes of edge ``size_m``; capped to
        ``settings.max_voxels``; coloured by height."""

    @abstractmethod
    def log_path(self, name: str, points: np.ndarray, color: tuple[int, int, int] | None = None) -> None:
        """A path: ``points`` (K, 3) world metres joined in order; ``color`` RGB 0-255."""

    @abstractmethod
    def log_pose(self, name: str, world_from_body: Rigid3) -> None:
        """The pose of a body (e.g. an estimated camera or the drone), world metres."""

    # ----- lifetime ---------------------------------------------------------
    @abstractmethod
    def close(self) -> None:
        """Finish the file and move it into place (idempotent)."""

    @abstractmethod
    def abort(self) -> None:
        """Stop recording and remove the unfinished file (idempotent)."""

    def __enter__(self) -> Recorder:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


class NullRecorder(Recorder):
    """Records nothing: the stand-in when no ``--record`` is given, so call sites need no ifs."""

    enabled = False

    def set_time(self, seconds: float, frame: int | None = None) -> None:
        pass

    def log_camera(
        self, name: str, intrinsics: Intrinsics, world_from_cam: Rigid3, image: np.ndarray | None = None
    ) -> None:
        pass

    def log_image(self, name: str, image: np.ndarray) -> None:
        pass

    def log_depth(self, name: str, depth_m: np.ndarray, intrinsics: Intrinsics) -> None:
        pass

    def log_disparity(self, name: str, disparity_px: np.ndarray, max_disparity: float | None = None) -> None:
        pass

    def log_points(self, name: str, xyz: np.ndarray, rgb: np.ndarray | None = None) -> None:
        pass

    def log_voxels(self, name: str, centres: np.ndarray, size_m: float) -> None:
        pass

    def log_path(self, name: str, points: np.ndarray, color: tuple[int, int, int] | None = None) -> None:
        pass

    def log_pose(self, name: str, world_from_body: Rigid3) -> None:
        pass

    def close(self) -> None:
        pass

    def abort(self) -> None:
        pass


class FileRecorder(Recorder):
    """A recorder writing one file: a temporary file beside ``path`` until :meth:`close`."""

    def __init__(self, path: str | Path, settings: RecordSettings | None = None):
        super().__init__(settings)
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # named as skyrecon.io.atomic names temporaries (hidden, with the pid), so that one left by
        # a killed run is swept by sweep_stale_temps
        fd, tmp = tempfile.mkstemp(
            prefix=f".{self.path.name}.{os.getpid()}.", suffix=".tmp", dir=self.path.parent
        )
        os.close(fd)
        os.unlink(tmp)  # the backend creates the file itself (foxglove refuses an existing one)
        self.tmp_path = Path(tmp)
        self.closed = False

    @abstractmethod
    def _finish(self) -> None:
        """Flush and close the backend's file at ``tmp_path``."""

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self._finish()
            os.chmod(self.tmp_path, 0o666 & ~_umask())
            os.replace(self.tmp_path, self.path)
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.tmp_path)
            raise

    def abort(self) -> None:
        if self.closed:
            return
        self.closed = True
        with contextlib.suppress(Exception):
            self._finish()
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.tmp_path)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def check_record_path(path: str | Path) -> str:
    """The backend (``"rerun"`` or ``"foxglove"``) a recording path selects by its extension;
    an unknown extension is an :class:`InputError` naming the file and the accepted ones."""
    p = Path(path)
    backend = RECORD_EXTENSIONS.get(p.suffix.lower())
    if backend is None:
        accepted = ", ".join(f"{ext} ({name})" for ext, name in RECORD_EXTENSIONS.items())
        raise InputError(f"unknown recording extension {p.suffix or '(none)'!r}; use {accepted}", p)
    if p.exists() and p.is_dir():
        raise InputError("the recording path is a directory; give a file name", p)
    return backend


def open_recorder(path: str | Path | None, settings: RecordSettings | None = None) -> Recorder:
    """A recorder writing ``path``, chosen by its extension; a :class:`NullRecorder` for None.

    Raises:
        InputError: unknown extension, or the backend's library is not installed (the message
            has the install line).
    """
    if path is None:
        return NullRecorder(settings)
    backend = check_record_path(path)
    if backend == "rerun":
        from skyrecon.record.rerun_backend import RerunRecorder

        return RerunRecorder(path, settings)
    from skyrecon.record.mcap_backend import McapRecorder

    return McapRecorder(path, settings)


def missing_library(backend: str, path: str | Path, error: ImportError) -> InputError:
    """The error for a recording whose backend library cannot be imported."""
    return InputError(
        f"recording to {Path(path).suffix} needs the optional '{backend}' extra ({error}); "
        f"install it with: {INSTALL_LINES[backend]}",
        path,
    )
