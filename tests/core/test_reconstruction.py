import numpy as np
import pytest

from skyrecon.core import Image, Intrinsics, Point3D, Reconstruction, Rigid3
from skyrecon.errors import InputError


def small_reconstruction():
    cam = Intrinsics.from_fov(200, 100, 60)
    rec = Reconstruction(cameras={1: cam})
    xyz = np.array([[0.0, 0.0, 5.0], [0.5, -0.2, 6.0]])
    for image_id, x in ((1, 0.0), (2, 0.5)):
        pose = Rigid3(np.eye(3), [-x, 0, 0])
        uv = cam.project(pose.apply(xyz))
        rec.images[image_id] = Image(image_id, f"im{image_id}.png", 1, pose, uv, [10, 11])
    for k, pid in enumerate((10, 11)):
        rec.points3d[pid] = Point3D(pid, xyz[k], [1, 2, 3], 0.0, [[1, k], [2, k]])
    return rec


def test_reprojection_errors_zero_for_exact_data():
    rec = small_reconstruction()
    rec.validate()
    errs = rec.reprojection_errors()
    assert errs.shape == (4,) and errs.max() < 1e-9
    xyz, rgb = rec.points_array()
    assert xyz.shape == (2, 3) and rgb.dtype == np.uint8
    assert rec.image_by_name("im2.png").image_id == 2


def test_validate_catches_dangling_ids():
    rec = small_reconstruction()
    rec.points3d[10].track = np.array([[3, 0]])
    with pytest.raises(InputError, match="missing image"):
        rec.validate()
    rec = small_reconstruction()
    rec.points3d[10].track = np.array([[1, 7]])
    with pytest.raises(InputError, match="out of range"):
        rec.validate()
