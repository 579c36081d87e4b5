import numpy as np
import pytest

from skyrecon.core import DepthMap, Intrinsics, PointCloud, Rigid3
from skyrecon.errors import InputError


def test_depth_to_points_projects_back_to_pixels():
    cam = Intrinsics.from_fov(32, 24, 70)
    depth = np.full((24, 32), 5.0, np.float32)
    depth[0, 0] = np.nan
    depth[1, 1] = -1
    dm = DepthMap(depth, cam)
    image = np.zeros((24, 32, 3), np.uint8)
    image[..., 0] = 200
    cloud = dm.to_points_cam(image)
    assert len(cloud) == 24 * 32 - 2
    assert (cloud.colors[:, 0] == 200).all()
    v, u = np.nonzero(dm.valid)
    np.testing.assert_allclose(cam.project(cloud.points), np.stack([u, v], 1), atol=1e-3)


def test_world_points_use_pose():
    cam = Intrinsics.from_fov(16, 12, 60)
    cam_from_world = Rigid3.look_at([0, -10, 2], [0, 0, 2])
    dm = DepthMap(np.full((12, 16), 10.0, np.float32), cam, cam_from_world)
    pts = dm.to_points_world().points
    assert np.allclose(pts[:, 1], 0.0, atol=1e-4)  # the plane y = 0 in the world


def test_size_mismatch_and_missing_pose():
    cam = Intrinsics.from_fov(16, 12, 60)
    with pytest.raises(InputError):
        DepthMap(np.zeros((10, 16), np.float32), cam)
    with pytest.raises(InputError):
        DepthMap(np.ones((12, 16), np.float32), cam).to_points_world()


def test_point_cloud_ops():
    a = PointCloud(np.zeros((3, 3)), np.full((3, 3), 255.0))
    b = PointCloud(np.ones((2, 3)), np.zeros((2, 3), np.uint8))
    c = PointCloud.concatenate([a, b])
    assert len(c) == 5 and c.colors.dtype == np.uint8 and c.points.dtype == np.float32
    assert PointCloud.concatenate([a, PointCloud(np.ones((1, 3)))]).colors is None
    assert len(c.select(c.points[:, 0] > 0.5)) == 2
    with pytest.raises(InputError):
        PointCloud(np.zeros((3, 3)), np.zeros((2, 3)))
    moved = c.transformed(Rigid3(np.eye(3), [1, 2, 3]))
    np.testing.assert_allclose(moved.points[0], [1, 2, 3])
