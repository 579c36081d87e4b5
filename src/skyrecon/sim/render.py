"""Ray-cast rendering of a :class:`City`: colour, exact z-depth, normals and object ids.

One ray per pixel centre (pixel (0, 0) is the centre of the top-left pixel), through the
camera's lens model (``Intrinsics.ray_directions``), cast with Numba over a uniform grid.
Colour is view-independent (see :mod:`skyrecon.sim.texture`), so stereo and multi-view
ground truth (depth, disparity, poses) reproduces the images exactly up to sampling.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from skyrecon.core import DepthMap, Intrinsics, PosedView, Rigid3, StereoRig
from skyrecon.errors import InputError
from skyrecon.sim import texture as _tx
from skyrecon.sim._jit import run_chunks
from skyrecon.sim.city import City


@dataclass(eq=False)
class RenderResult:
    """One rendered view.

    Attributes:
        image: (H, W, 3) uint8 RGB.
        depth_m: (H, W) float32 depth along the optical axis, metres; NaN for sky.
        normal_world: (H, W, 3) float32 outward unit surface normal, world frame; NaN for sky.
        object_id: (H, W) int32: -1 sky, 0 ground, ``1 + i`` box i, ``1 + N_boxes + j`` cylinder j.
        intrinsics: the camera.
        cam_from_world: the camera pose.
    """

    image: np.ndarray
    depth_m: np.ndarray
    normal_world: np.ndarray
    object_id: np.ndarray
    intrinsics: Intrinsics
    cam_from_world: Rigid3

    @property
    def normal(self) -> np.ndarray:
        """Alias of :attr:`normal_world`."""
        return self.normal_world

    @property
    def valid(self) -> np.ndarray:
        """(H, W) bool: the pixel sees a surface (not sky)."""
        return np.isfinite(self.depth_m)

    def depth_map(self) -> DepthMap:
        """The depth as a :class:`DepthMap` carrying this camera and pose."""
        return DepthMap(self.depth_m, self.intrinsics, self.cam_from_world)


@dataclass(eq=False)
class StereoFrame:
    """A rendered stereo pair with exact ground truth.

    Attributes:
        left, right: (H, W, 3) uint8 RGB images.
        depth_left_m, depth_right_m: (H, W) float32 z-depth in each camera, metres; NaN for sky.
        disparity_left_px: (H, W) float32 left disparity, ``x_right = x_left - d``; NaN for sky.
        rig: the stereo rig.
        left_from_world, right_from_world: the camera poses.
        left_result, right_result: the full renders (normals, object ids).
    """

    left: np.ndarray
    right: np.ndarray
    depth_left_m: np.ndarray
    disparity_left_px: np.ndarray
    depth_right_m: np.ndarray
    rig: StereoRig
    left_from_world: Rigid3
    right_from_world: Rigid3
    left_result: RenderResult
    right_result: RenderResult

    @property
    def disparity_right_px(self) -> np.ndarray:
        """(H, W) float32 right disparity (``x_left = x_right + d``) from the right depth; NaN for sky."""
        return self.rig.depth_to_disparity(self.depth_right_m)


@lru_cache(maxsize=16)
def _ray_dirs_cached(key: tuple) -> np.ndarray:
    fx, fy, cx, cy, w, h, dist, skew = key
    cam = Intrinsics(fx, fy, cx, cy, w, h, np.array(dist), skew)
    # (kept writable: a read-only array would make Numba compile a second version of each kernel)
    return np.ascontiguousarray(cam.ray_directions().reshape(-1, 3))


def _ray_dirs(cam: Intrinsics) -> np.ndarray:
    """(H*W, 3) camera-frame directions with z = 1, cached per camera."""
    key = (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height, tuple(float(v) for v in cam.dist), cam.skew)
    return _ray_dirs_cached(key)


def render(city: City, intrinsics: Intrinsics, cam_from_world: Rigid3) -> RenderResult:
    """Render one view of the city.

    Args:
        city: the scene.
        intrinsics: the camera (lens distortion is honoured).
        cam_from_world: pose, world -> camera (OpenCV axes: x right, y down, z forward), metres.
    Returns:
        :class:`RenderResult` with the image, z-depth (NaN for sky), normals and object ids.
    """
    if not isinstance(cam_from_world, Rigid3):
        raise InputError(f"cam_from_world must be a Rigid3, got {type(cam_from_world).__name__}")
    H, W = intrinsics.height, intrinsics.width
    dirs_cam = _ray_dirs(intrinsics)
    world_from_cam_R = np.ascontiguousarray(cam_from_world.R.T)
    origin = cam_from_world.center
    # camera-frame directions have z = 1, so the ray parameter t is the z-depth
    t, kind, index, face = city._trace(origin[None], dirs_cam, True, rot=world_from_cam_R)
    n = H * W
    rgb = np.empty((n, 3), np.uint8)
    depth = np.empty(n, np.float32)
    normal = np.empty((n, 3), np.float32)
    oid = np.empty(n, np.int32)
    # the footprint of a pixel at z-depth z is about z / f metres (use the coarser axis)
    inv_f = 1.0 / min(intrinsics.fx, intrinsics.fy)
    run_chunks(
        _tx.shade,
        n,
        origin,
        dirs_cam,
        world_from_cam_R,
        t,
        kind,
        index,
        face,
        inv_f,
        np.int64(city.seed),
        city.boxes,
        city.box_material,
        city.box_albedo,
        city.box_accent,
        city.box_params,
        city.cylinders,
        city.cyl_material,
        city.cyl_albedo,
        city.cyl_accent,
        city.cyl_params,
        city.blocks_x,
        city.blocks_y,
        city.extent,
        float(city.sidewalk_m),
        int(city.ground_style),
        rgb,
        depth,
        normal,
        oid,
    )
    return RenderResult(
        rgb.reshape(H, W, 3),
        depth.reshape(H, W),
        normal.reshape(H, W, 3),
        oid.reshape(H, W),
        intrinsics,
        cam_from_world.with_frames("cam", "world"),
    )


def render_depth(city: City, intrinsics: Intrinsics, cam_from_world: Rigid3) -> np.ndarray:
    """Only the z-depth of a view (no shading: about twice as fast as :func:`render`).

    Returns:
        (H, W) float32 depth along the optical axis, metres; NaN for sky. Identical to
        ``render(...).depth_m``.
    """
    if not isinstance(cam_from_world, Rigid3):
        raise InputError(f"cam_from_world must be a Rigid3, got {type(cam_from_world).__name__}")
    t, kind, _, _ = city._trace(
        cam_from_world.center[None], _ray_dirs(intrinsics), True, rot=np.ascontiguousarray(cam_from_world.R.T)
    )
    depth = t.astype(np.float32)
    depth[kind == 0] = np.nan
    return depth.reshape(intrinsics.height, intrinsics.width)


def render_stereo(city: City, rig: StereoRig, left_from_world: Rigid3) -> StereoFrame:
    """Render both cameras of a rectified stereo rig.

    Args:
        city: the scene.
        rig: a rectified rig (``StereoRig.rectified``).
        left_from_world: pose of the left camera, world -> left, metres.
    Returns:
        :class:`StereoFrame`; the left disparity is computed from the left depth through the rig
        (``d = fx * B / z - doffs``), so it is exact wherever the depth is.
    """
    if not rig.is_rectified:
        raise InputError("render_stereo needs a rectified rig (StereoRig.rectified)")
    left_from_world = left_from_world.with_frames("left", "world")
    right_from_world = rig.right_from_left @ left_from_world
    left = render(city, rig.left, left_from_world)
    right = render(city, rig.right, right_from_world)
    disparity = rig.depth_to_disparity(left.depth_m)
    return StereoFrame(
        left.image,
        right.image,
        left.depth_m,
        disparity,
        right.depth_m,
        rig,
        left_from_world,
        right_from_world,
        left,
        right,
    )


def render_views(city: City, views: Iterable[PosedView]) -> list[RenderResult]:
    """Render each :class:`PosedView` (its intrinsics and ``cam_from_world``), in order."""
    return [render(city, v.intrinsics, v.cam_from_world) for v in views]
