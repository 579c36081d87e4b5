"""Readers and writers for the formats skyrecon users already have. See DESIGN.md (Formats)."""

from skyrecon.io.calib import (
    KittiCalib,
    MiddleburyCalib,
    read_K_txt,
    read_kitti_calib,
    read_middlebury_calib,
    write_K_txt,
    write_kitti_calib,
)
from skyrecon.io.colmap import read_colmap_text, write_colmap_text, write_nerfstudio_transforms
from skyrecon.io.disparity import (
    colorize_depth,
    colorize_disparity,
    read_disparity,
    read_kitti_disparity_png,
    read_middlebury_disparity_pgm,
    write_kitti_disparity_png,
)
from skyrecon.io.images import read_image, read_image_with_alpha, write_image
from skyrecon.io.jsonio import dumps_json, to_jsonable, write_json
from skyrecon.io.multiview import (
    read_cameras,
    read_halcon_cameras,
    read_middlebury_par,
    read_strecha_cameras,
)
from skyrecon.io.pfm import read_pfm, write_pfm
from skyrecon.io.ply import read_ply, write_ply
from skyrecon.io.sequence import StereoSequence, is_sequence_dir, read_sequence, write_sequence

__all__ = [
    "KittiCalib",
    "MiddleburyCalib",
    "StereoSequence",
    "colorize_depth",
    "colorize_disparity",
    "dumps_json",
    "is_sequence_dir",
    "read_K_txt",
    "read_cameras",
    "read_colmap_text",
    "read_disparity",
    "read_halcon_cameras",
    "read_image",
    "read_image_with_alpha",
    "read_kitti_calib",
    "read_kitti_disparity_png",
    "read_middlebury_calib",
    "read_middlebury_disparity_pgm",
    "read_middlebury_par",
    "read_pfm",
    "read_ply",
    "read_sequence",
    "read_strecha_cameras",
    "to_jsonable",
    "write_K_txt",
    "write_colmap_text",
    "write_image",
    "write_json",
    "write_kitti_calib",
    "write_kitti_disparity_png",
    "write_nerfstudio_transforms",
    "write_pfm",
    "write_ply",
    "write_sequence",
]
