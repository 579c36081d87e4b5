"""Settings of the MVS pipeline."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from skyrecon.errors import InputError
from skyrecon.mvs.fusion import FusionSettings
from skyrecon.mvs.patchmatch import PatchMatchSettings
from skyrecon.mvs.planar_prior import PlanarPriorSettings
from skyrecon.mvs.topology import TOPOLOGIES

__all__ = ["MVSSettings", "DEPTH_METHODS", "FUSION_METHODS", "WRITEUP_SGBM"]

DEPTH_METHODS: tuple[str, ...] = ("patchmatch", "pairwise")
FUSION_METHODS: tuple[str, ...] = ("consistency", "concat")


@dataclass(frozen=True)
class MVSSettings:
    """Everything :func:`skyrecon.mvs.run_mvs` can be told.

    Attributes:
        max_image_size: longer side of the working images, pixels (None: input size). Depth
            maps are produced at this resolution.
        topology: ``auto`` (per-view neighbour selection) or a named ring topology (``360``,
            ``overlapping``, ``adjacent``, ``skipping_1``, ``skipping_2``).
        depth_method: ``patchmatch`` (multi-view, default) or ``pairwise`` (rectified
            two-view stereo with ``matcher`` for every topology pair).
        fusion: ``consistency`` (geometric-consistency fusion, default) or ``concat`` (plain
            concatenation of the clouds, the write-up's merge).
        num_sources: source views per reference view for ``auto``.
        min_angle_deg, max_angle_deg: triangulation angles that count for ``auto``.
        matcher: stereo matcher for ``pairwise`` (``opencv-sgbm``, ``skyrecon``, ...).
        matcher_settings: keyword settings of that matcher.
        depth_range: (near, far) metres for every view instead of the sparse estimate.
        patchmatch: PatchMatch settings.
        planar_prior: depth for the plain segments PatchMatch leaves empty, from the planes
            their surroundings support (``patchmatch`` only; ``enabled=False`` turns it off).
        fusion_settings: consistency thresholds.
        outlier_k: neighbours for statistical outlier removal and normals.
        outlier_std: remove points whose mean neighbour distance exceeds mean + this many
            standard deviations (0: keep all).
        component_min_fraction: drop connected clusters of points holding less than this
            fraction of the cloud (detached floaters and background fragments; 0: keep all).
        component_radius_factor: points closer than this many times the median neighbour
            spacing are connected.
        voxel_size_m: average the fused points within voxels of this size (None: keep all).
        mesh: also build a surface mesh (TSDF fusion of the depth maps + marching cubes).
        mesh_voxel_m: TSDF voxel size (None: automatic, about 1/200 of the cloud's extent).
        seed: seed of every random choice.
        sparse_max_features: SIFT features per image for the sparse depth-range estimate.
    """

    max_image_size: int | None = 640
    topology: str = "auto"
    depth_method: str = "patchmatch"
    fusion: str = "consistency"
    num_sources: int = 4
    min_angle_deg: float = 3.0
    max_angle_deg: float = 65.0
    matcher: str = "opencv-sgbm"
    matcher_settings: dict[str, Any] = field(default_factory=dict)
    depth_range: tuple[float, float] | None = None
    patchmatch: PatchMatchSettings = PatchMatchSettings()
    planar_prior: PlanarPriorSettings = PlanarPriorSettings()
    fusion_settings: FusionSettings = FusionSettings()
    outlier_k: int = 8
    outlier_std: float = 2.0
    component_min_fraction: float = 0.01
    component_radius_factor: float = 3.0
    voxel_size_m: float | None = None
    mesh: bool = False
    mesh_voxel_m: float | None = None
    seed: int = 0
    sparse_max_features: int = 1500

    def __post_init__(self) -> None:
        if self.topology not in TOPOLOGIES:
            raise InputError(f"unknown topology {self.topology!r}; choose one of {', '.join(TOPOLOGIES)}")
        if self.depth_method not in DEPTH_METHODS:
            raise InputError(
                f"unknown depth method {self.depth_method!r}; choose one of {', '.join(DEPTH_METHODS)}"
            )
        if self.fusion not in FUSION_METHODS:
            raise InputError(f"unknown fusion {self.fusion!r}; choose one of {', '.join(FUSION_METHODS)}")
        if self.max_image_size is not None and self.max_image_size < 32:
            raise InputError(f"max_image_size must be at least 32 pixels, got {self.max_image_size}")
        if self.num_sources < 1:
            raise InputError(f"num_sources must be >= 1, got {self.num_sources}")
        if self.depth_range is not None and not (0 < self.depth_range[0] < self.depth_range[1]):
            raise InputError(f"depth_range must be (near, far) with 0 < near < far, got {self.depth_range}")
        if self.outlier_k < 3 or self.outlier_std < 0:
            raise InputError("outlier_k must be >= 3 and outlier_std >= 0")
        if not (0 <= self.component_min_fraction < 1) or not self.component_radius_factor > 0:
            raise InputError("component_min_fraction must be in [0, 1) and component_radius_factor positive")
        if self.voxel_size_m is not None and not self.voxel_size_m > 0:
            raise InputError(f"voxel_size_m must be positive, got {self.voxel_size_m}")

    def with_(self, **changes: Any) -> MVSSettings:
        """A copy with some fields changed (validated)."""
        return replace(self, **changes)

    @classmethod
    def from_names(
        cls, topology: str | None = None, fusion: str | None = None, mesh: bool = False, **changes: Any
    ) -> MVSSettings:
        """Settings for the command line's ``--topology NAME --fusion NAME [--mesh]``.

        ``fusion="concat"`` selects the write-up's whole method (:meth:`writeup_baseline`:
        pairwise SGBM on the topology's pairs, default ``360``, clouds concatenated); otherwise
        the default PatchMatch + consistency fusion with the given topology (default ``auto``).
        """
        if fusion == "concat":
            base = cls.writeup_baseline(mesh=mesh, **changes)
            return base if topology is None else base.with_(topology=topology)
        kw: dict[str, Any] = dict(mesh=mesh, **changes)
        if topology is not None:
            kw["topology"] = topology
        if fusion is not None:
            kw["fusion"] = fusion
        return cls(**kw)

    @classmethod
    def writeup_baseline(cls, **changes: Any) -> MVSSettings:
        """The write-up's method: rectified SGBM per ``360`` pair, clouds concatenated, no filtering.

        The SGBM parameters are the write-up's (``BlockSize`` 21, ``P1 = P2 = 16 * 21 * 21``
        (P2 made one larger, OpenCV needs P2 > P1), ``UniquenessRatio`` 0, no speckle filter,
        no left-right check, mode HH, grey images). Its fixed disparity range (-64..192 at full
        resolution) is replaced by the range of the sparse points both views see, so that every
        pair searches where its scene actually is.
        """
        base: dict[str, Any] = dict(
            topology="360",
            depth_method="pairwise",
            fusion="concat",
            matcher="opencv-sgbm",
            matcher_settings=dict(WRITEUP_SGBM),
            outlier_std=0.0,
            component_min_fraction=0.0,
        )
        base.update(changes)
        return cls(**base)

    @classmethod
    def tuned_concat_baseline(cls, **changes: Any) -> MVSSettings:
        """The write-up's pipeline with the stereo engine's default SGBM (5x5 blocks, uniqueness
        and left-right checks, speckle filter) instead of the write-up's parameters: a stronger
        concatenation baseline."""
        return cls.writeup_baseline(**{"matcher_settings": {}, **changes})


#: The write-up's ``cv2.StereoSGBM`` options, as settings of the ``opencv-sgbm`` matcher.
WRITEUP_SGBM: dict[str, Any] = dict(
    block_size=21,
    P1=16 * 21 * 21,
    P2=16 * 21 * 21 + 1,
    disp12_max_diff=-1,
    pre_filter_cap=0,
    uniqueness_ratio=0,
    speckle_window_size=0,
    speckle_range=0,
    mode="hh",
    use_colour=False,
)
