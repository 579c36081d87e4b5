"""Parameters of the probabilistic occupancy map (log-odds, clamping, ranges)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from skyrecon.errors import InputError


def logit(p: float) -> float:
    """Log-odds ``log(p / (1 - p))`` of a probability in (0, 1)."""
    return math.log(p / (1.0 - p))


#: ``max_plausible_depth_m`` for depth from the package's own stereo (the delivery loop, the
#: stereo mapper): in metres by construction, so no frame is refused for being far. A noisy
#: plain city's view over the fields beyond it measured mostly ground 1-5 km away (median
#: 3045 m), and the default check stopped a delivery mission (the noisy plain benchmark's
#: seed 6) with an error about millimetres (session 48)
STEREO_PLAUSIBLE_DEPTH_M = 1e9


@dataclass(frozen=True)
class MapConfig:
    """How measurements update the map. Defaults follow OctoMap.

    Attributes:
        voxel_size_m: voxel edge, metres (the grid is anchored at the world origin).
        block_size: voxels per block edge (storage granularity, 4..32).
        prob_hit: probability that a voxel is occupied given one hit (> 0.5).
        prob_miss: probability that a voxel is occupied given one miss (< 0.5).
        clamp_min, clamp_max: occupancy probabilities at which log-odds are clamped, so that
            the map stays able to change its mind (0 < clamp_min < 0.5 < clamp_max < 1).
        occupancy_threshold: a known voxel with probability >= this is occupied, else free.
        max_range_m: measurements farther than this (Euclidean, from the sensor) carve free
            space up to this range and give no hit.
        min_range_m: measurements nearer than this are ignored.
        grazing_cap_voxels: depth integration marks as hit the voxels that overlap the local
            surface plane; where the view grazes the surface that band is cut to this many
            voxels either side of the measured depth (voxels between the band and the free
            space are left untouched).
        max_plausible_depth_m: if the median valid depth of a frame exceeds this, the depth is
            rejected as not in metres (e.g. millimetres by mistake). For a user's depth
            images; depth from the package's own stereo is in metres by construction, and a
            view over far fields measures kilometres (:data:`STEREO_PLAUSIBLE_DEPTH_M`).
        surface_pull_voxels: each measured surface is taken this many voxels nearer its sensor
            before hits and free space are decided (0: where measured). For noisy depth
            (stereo): the noise that falls behind a surface marks voxels inside the obstacle
            that no later ray can clear, while the noise in front is cleared by the rays of
            other frames; pulling the surface back a fraction of a voxel keeps the hits on the
            surface's own voxel and stops free space short of it. Exact depth should keep 0.
        stale_log_odds: a voxel holding exactly this log-odds, a belief seeded from an earlier
            flight that no measurement of this one has touched yet (see
            :mod:`skyrecon.mission.prior`), takes ``logit(prob_miss)`` at its first miss, as an
            unknown voxel would: one look through yesterday's obstacle disproves it; and at
            its first hit ``logit(prob_hit)``, also as an unknown voxel would (this flight's
            first measurement replaces the earlier belief; a stray hit, a mover passing
            through yesterday's obstacle, no longer confirms it for several misses). After
            that, hits and misses add as usual. None (default): no such voxel.
    """

    voxel_size_m: float = 0.2
    block_size: int = 8
    prob_hit: float = 0.7
    prob_miss: float = 0.4
    clamp_min: float = 0.1192
    clamp_max: float = 0.971
    occupancy_threshold: float = 0.5
    max_range_m: float = 60.0
    min_range_m: float = 0.05
    grazing_cap_voxels: float = 4.0
    max_plausible_depth_m: float = 2000.0
    surface_pull_voxels: float = 0.0
    stale_log_odds: float | None = None

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if v is not None and not np.isfinite(v):
                raise InputError(f"map setting {f.name} must be finite, got {v}")
        if self.voxel_size_m <= 0:
            raise InputError(f"voxel size must be positive, got {self.voxel_size_m} m")
        if not (4 <= int(self.block_size) <= 32) or int(self.block_size) != self.block_size:
            raise InputError(f"block size must be an integer in 4..32, got {self.block_size}")
        if not 0.5 < self.prob_hit < 1:
            raise InputError(f"prob_hit must lie in (0.5, 1), got {self.prob_hit}")
        if not 0 < self.prob_miss < 0.5:
            raise InputError(f"prob_miss must lie in (0, 0.5), got {self.prob_miss}")
        if not 0 < self.clamp_min < self.occupancy_threshold < self.clamp_max < 1:
            raise InputError(
                "need 0 < clamp_min < occupancy_threshold < clamp_max < 1, got "
                f"{self.clamp_min}, {self.occupancy_threshold}, {self.clamp_max}"
            )
        if not 0 <= self.min_range_m < self.max_range_m:
            raise InputError(f"need 0 <= min_range < max_range, got {self.min_range_m}, {self.max_range_m} m")
        if self.grazing_cap_voxels <= 0:
            raise InputError(f"grazing_cap_voxels must be positive, got {self.grazing_cap_voxels}")
        if not 0 <= self.surface_pull_voxels <= 0.5:
            raise InputError(f"surface_pull_voxels must lie in [0, 0.5], got {self.surface_pull_voxels}")
        object.__setattr__(self, "block_size", int(self.block_size))

    @property
    def log_odds(self) -> np.ndarray:
        """(6,) float32: ``l_hit, l_miss, clamp_min, clamp_max, occupied threshold`` in log-odds,
        then ``stale_log_odds`` (NaN: none; such a voxel takes a miss as an unknown one does)."""
        stale = math.nan if self.stale_log_odds is None else self.stale_log_odds
        return np.array(
            [
                logit(self.prob_hit),
                logit(self.prob_miss),
                logit(self.clamp_min),
                logit(self.clamp_max),
                logit(self.occupancy_threshold),
                stale,
            ],
            dtype=np.float32,
        )

    @property
    def block_edge_m(self) -> float:
        return self.voxel_size_m * self.block_size

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> MapConfig:
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known})
