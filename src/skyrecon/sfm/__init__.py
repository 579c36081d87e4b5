"""Structure from motion: features at scale, pair selection, tracks, an incremental mapper with
our own sparse bundle adjustment, and alignment (Umeyama, ICP).

    from skyrecon.sfm import run_sfm, write_sfm_outputs, SfMSettings
    result = run_sfm(paths, intrinsics, SfMSettings(sequential=True), seed=0, workspace="out/ws")
    write_sfm_outputs("out", result, frusta=True)
    result.unregistered          # name -> why an image was left out

Conventions (DESIGN.md): metres (or the reconstruction's own units before alignment), OpenCV
camera axes, pixel (0, 0) = centre of the top-left pixel, poses ``cam_from_world``.
"""

from skyrecon.sfm.align import (
    AlignmentResult,
    ICPResult,
    Sim3,
    align_reconstruction,
    estimate_normals,
    icp,
    robust_umeyama,
    umeyama,
)
from skyrecon.sfm.bundle import BundleProblem, BundleReport, BundleSolverOptions, bundle_adjust
from skyrecon.sfm.outputs import write_sfm_outputs
from skyrecon.sfm.pipeline import run_sfm
from skyrecon.sfm.pnp import AbsolutePose, estimate_absolute_pose
from skyrecon.sfm.result import ImageStatus, SfMResult
from skyrecon.sfm.settings import (
    BundleSettings,
    MapperSettings,
    PairingSettings,
    SfMSettings,
    VerificationSettings,
)
from skyrecon.sfm.tracks import Tracks, UnionFind, build_tracks
from skyrecon.sfm.triangulation import triangulate_tracks

__all__ = [
    "run_sfm",
    "write_sfm_outputs",
    "SfMResult",
    "ImageStatus",
    "SfMSettings",
    "PairingSettings",
    "VerificationSettings",
    "MapperSettings",
    "BundleSettings",
    "BundleSolverOptions",
    "BundleProblem",
    "BundleReport",
    "bundle_adjust",
    "Sim3",
    "AlignmentResult",
    "umeyama",
    "robust_umeyama",
    "align_reconstruction",
    "ICPResult",
    "icp",
    "estimate_normals",
    "AbsolutePose",
    "estimate_absolute_pose",
    "Tracks",
    "UnionFind",
    "build_tracks",
    "triangulate_tracks",
]
