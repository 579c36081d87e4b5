"""Geometry core: cameras, poses, stereo rigs, depth maps, point clouds, reconstructions."""

from skyrecon.core.depth import DepthMap, PointCloud
from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.reconstruction import Image, Point3D, Reconstruction
from skyrecon.core.rigid import (
    FrameMismatchError,
    Rigid3,
    matrix_to_quaternion,
    matrix_to_rotvec,
    orthonormalize,
    quaternion_to_matrix,
    rotation_angle,
    rotation_angle_deg,
    rotvec_to_matrix,
)
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.core.view import PosedView

__all__ = [
    "DepthMap",
    "PointCloud",
    "Intrinsics",
    "Image",
    "Point3D",
    "Reconstruction",
    "Rigid3",
    "FrameMismatchError",
    "StereoRig",
    "PosedView",
    "matrix_to_quaternion",
    "matrix_to_rotvec",
    "orthonormalize",
    "quaternion_to_matrix",
    "rotation_angle",
    "rotation_angle_deg",
    "rotvec_to_matrix",
]
