"""A prior map from an earlier flight, and how much the drone trusts it today.

A delivery drone rarely flies a street for the first time: yesterday's map (``skyrecon map``,
a previous ``skyrecon demo``, or a survey) tells it where the buildings are. But the city
changes: scaffolding goes up, a crane arrives, a container stack is gone. So the prior seeds
the drone's map with *weak* beliefs:

* a prior-occupied voxel gets log-odds :data:`PRIOR_OCCUPIED_LOG_ODDS` (occupied, so the planner
  avoids it from the first cycle), and the first miss of this flight's cameras frees it
  (:attr:`~skyrecon.mapping.MapConfig.stale_log_odds`: one look through yesterday's obstacle
  disproves it). Until session 31 that took three misses (two were tried and freed the worst
  voxel no sooner): in 150 dynamic missions the removed stacks' worst voxel was freed 5-14 s
  after its first miss, because the slow ones are seen through once, at the top edge of a
  camera pitched down, then not again until the drone is past them. Its first hit, likewise,
  gives it the log-odds of a first hit, as if the prior had not known it: a stray match, or a
  mover passing through yesterday's obstacle, used to confirm it for five misses (session 36:
  on dynamic seed 107 the removed stack's two slowest voxels, 5-6 m from any building, were
  such voxels);
* a prior-free voxel gets :data:`PRIOR_FREE_LOG_ODDS` (free, so the planner plans through it,
  but one hit of its own cameras makes it occupied);
* unknown stays unknown.

Planning uses the prior; flying does not trust it blindly: the "observed before entered" rule
(:meth:`~skyrecon.mission.navigator.Navigator.verified_distance`) only counts a voxel as seen free
when its log-odds is at most :data:`OBSERVED_FREE_LOG_ODDS`, which takes at least one miss from
this flight. Hence the speed near a stale prior is still set by what the cameras see.

Frames and units: the prior must be in the mission's world frame (z up, metres) with the
mission's voxel size.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from skyrecon.errors import InputError
from skyrecon.mapping import MapConfig, OccupancyMap, load_map
from skyrecon.mission.config import MissionConfig
from skyrecon.mission.scenario import MapBox
from skyrecon.sim import City

#: Log-odds of a voxel the prior says is occupied (p = 0.73: occupied, freed by its first miss).
PRIOR_OCCUPIED_LOG_ODDS = 1.0
#: Log-odds of a voxel the prior says is free (p = 0.45: free, made occupied by 1 hit).
PRIOR_FREE_LOG_ODDS = -0.2
#: A voxel counts as observed free this flight at or below this log-odds (one miss from the prior).
OBSERVED_FREE_LOG_ODDS = -0.3


@dataclass(eq=False)
class PriorMap:
    """A prior map over the mission's box.

    Attributes:
        log_odds: (X, Y, Z) float32 weak log-odds over ``box`` (NaN unknown), ready to seed the
            drone's map.
        box: the mission's map box (origin, shape, voxel size).
        source: where it came from ("truth of the earlier city", or a directory).
        known_fraction: share of the box's voxels the prior knows.
        occupied: (X, Y, Z) bool, what the prior believed occupied (for the change report).
    """

    log_odds: np.ndarray
    box: MapBox
    source: str
    known_fraction: float
    occupied: np.ndarray

    def seed_map(self, config: MapConfig) -> OccupancyMap:
        """The drone's starting map with ``config`` (voxel size, ranges): the prior's weak beliefs
        over the box (blocks popped); its occupied beliefs are freed by their first miss
        (``stale_log_odds``, see the module docstring)."""
        config = replace(config, stale_log_odds=PRIOR_OCCUPIED_LOG_ODDS)
        m = OccupancyMap.from_dense_log_odds(self.log_odds, self.box.origin, config)
        m.pop_changed_blocks()
        m.pop_changed_blocks(occupied_only=True)
        return m


def weaken(dense_log_odds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weak prior log-odds and the prior's occupied mask of a dense (X, Y, Z) log-odds box (NaN unknown)."""
    known = np.isfinite(dense_log_odds)
    with np.errstate(invalid="ignore"):
        occupied = known & (dense_log_odds >= 0.0)
    out = np.where(occupied, PRIOR_OCCUPIED_LOG_ODDS, PRIOR_FREE_LOG_ODDS).astype(np.float32)
    out[~known] = np.nan
    return out, occupied


def prior_from_city(city: City, cfg: MissionConfig, box: MapBox, source: str = "earlier flight") -> PriorMap:
    """The prior an earlier flight over ``city`` (the city as it was then) would have left: its
    true occupancy over the whole box, ground included, as weak beliefs."""
    occ = city.occupancy_grid(box.origin, box.voxel_size_m, box.shape, include_ground=True)
    lo = np.where(occ, 1.0, -1.0).astype(np.float32)
    weak, occupied = weaken(lo)
    return PriorMap(weak, box, source, 1.0, occupied)


def load_prior_map(path: str | Path, cfg: MissionConfig, box: MapBox) -> PriorMap:
    """Read a map directory (``skyrecon map`` / ``skyrecon demo`` output) as the mission's prior.

    Raises:
        InputError: not a map, another voxel size, or no overlap with the mission's area (a map
            of another city or another frame); the message names the directory.
    """
    p = Path(path)
    prior = load_map(p)
    if abs(prior.voxel_size - cfg.voxel_size_m) > 1e-9:
        raise InputError(
            f"the prior map has {prior.voxel_size:g} m voxels but the mission uses {cfg.voxel_size_m:g} m; "
            "build the prior with the same voxel size (--voxel) or leave --prior-map out",
            p,
        )
    lo = np.rint(box.origin / box.voxel_size_m).astype(np.int64)
    dense = prior.dense_log_odds(lo, box.shape)
    known = np.isfinite(dense)
    frac = float(known.mean()) if known.size else 0.0
    if not known.any():
        plo, phi = prior.bounds()
        raise InputError(
            f"the prior map covers {np.round(plo, 1).tolist()}..{np.round(phi, 1).tolist()} m, which does not "
            f"overlap the mission's area {np.round(box.origin, 1).tolist()}..{np.round(box.upper, 1).tolist()} m: "
            "is it a map of another city or in another frame?",
            p,
        )
    weak, occupied = weaken(dense)
    return PriorMap(weak, box, str(p), frac, occupied)


def prior_changes(prior: PriorMap, final: OccupancyMap, min_observed_log_odds: float = 0.5) -> dict:
    """What the drone's own cameras changed in the prior: voxels the prior had free that it
    found occupied (``added_voxels``) and prior-occupied ones it found free (``removed_voxels``),
    counted over the voxels it observed this flight (log-odds moved away from the prior's level
    by at least ``min_observed_log_odds``), and the share of observed voxels that disagree.

    A high ``disagreement`` (over 0.3) means the prior probably belongs to another city or frame.
    """
    lo = np.rint(prior.box.origin / prior.box.voxel_size_m).astype(np.int64)
    now = final.dense_log_odds(lo, prior.box.shape)
    known = np.isfinite(prior.log_odds) & np.isfinite(now)
    with np.errstate(invalid="ignore"):
        observed = known & (np.abs(now - prior.log_odds) >= min_observed_log_odds)
        added = observed & ~prior.occupied & (now >= 0.0)
        removed = observed & prior.occupied & (now < 0.0)
    n_obs = int(np.count_nonzero(observed))
    n_bad = int(np.count_nonzero(added) + np.count_nonzero(removed))
    return {
        "source": prior.source,
        "known_fraction": round(prior.known_fraction, 4),
        "observed_voxels": n_obs,
        "added_voxels": int(np.count_nonzero(added)),
        "removed_voxels": int(np.count_nonzero(removed)),
        "disagreement": round(n_bad / n_obs, 4) if n_obs else 0.0,
    }


def mission_prior(scenario, cfg: MissionConfig) -> PriorMap | None:
    """The prior of a mission as ``cfg.prior_map`` says: None (""), the map an earlier flight over
    yesterday's city left ("earlier"; its true occupancy), or a map directory."""
    if not cfg.prior_map:
        return None
    if cfg.prior_map == "earlier":
        city = scenario.prior_city if scenario.prior_city is not None else scenario.city
        return prior_from_city(city, cfg, scenario.box, "earlier flight (simulated)")
    return load_prior_map(cfg.prior_map, cfg, scenario.box)
