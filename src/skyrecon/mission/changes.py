"""The city changed since the last flight: a new obstacle today, one that is gone.

:func:`city_changes` turns one generated city into *yesterday's* city (what the prior map was
built from) and *today's* (what the drone flies through), deterministically from the seed:

* **added**: a scaffold tower (about 3 x 3 m, from the ground to 22-26 m, so it reaches through
  the flight band) standing over the street on the shortest path, 35-70 % of the way: the prior
  says the street is open, the drone must see the tower and go round it;
* **removed**: a container stack / temporary tower of the same kind that stood yesterday 5-9 m
  beside the path, 15-35 % of the way: the prior says it is there (so the first plan avoids
  it), the drone's cameras see it is gone and free its voxels.

Both are checked against the endpoints (kept ``endpoint_clearance_m`` away); a candidate that
would make the mission impossible is dropped by :func:`~skyrecon.mission.scenario.make_scenario`,
which re-plans the shortest path in today's city.

Frames and units: world frame (z up), metres.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from skyrecon.mission.config import MissionConfig
from skyrecon.sim import City
from skyrecon.sim.city import KIND_BEAM
from skyrecon.sim.texture import MAT_METAL


@dataclass(frozen=True)
class CityChange:
    """One difference between yesterday's city and today's.

    Attributes:
        kind: "added" (there today, not in the prior) or "removed" (in the prior, gone today).
        name: what it is ("scaffold tower", "container stack").
        box: (6,) ``[xmin, ymin, zmin, xmax, ymax, zmax]`` world metres.
    """

    kind: str
    name: str
    box: tuple[float, ...]

    def to_dict(self) -> dict:
        return {"kind": self.kind, "name": self.name, "box": [round(float(v), 3) for v in self.box]}


def with_boxes(city: City, boxes: np.ndarray, albedo: tuple[float, float, float]) -> City:
    """``city`` plus textured metal boxes (K, 6) (kind ``beam``); the city itself is not modified."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 6)
    k = len(b)
    if k == 0:
        return city
    return replace(
        city,
        boxes=np.vstack([city.boxes, b]),
        box_material=np.concatenate([city.box_material, np.full(k, MAT_METAL)]),
        box_kind=np.concatenate([city.box_kind, np.full(k, KIND_BEAM)]),
        box_albedo=np.vstack([city.box_albedo, np.tile(albedo, (k, 1))]),
        box_accent=np.vstack([city.box_accent, np.tile([0.2, 0.2, 0.22], (k, 1))]),
        box_params=np.vstack([city.box_params, np.tile([3.0, 1.5, 0.5, 0.5, 0.0, 1.0], (k, 1))]),
    )


def _point_along(path: np.ndarray, frac: float) -> tuple[np.ndarray, np.ndarray]:
    """The point at ``frac`` of the polyline's length and the unit horizontal direction there."""
    seg = np.diff(path, axis=0)
    L = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(L)])
    s = frac * cum[-1]
    k = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1))
    p = path[k] + (s - cum[k]) / max(L[k], 1e-9) * seg[k]
    d = seg[k].copy()
    d[2] = 0.0
    n = np.linalg.norm(d)
    return p, (d / n if n > 1e-9 else np.array([1.0, 0.0, 0.0]))


def city_changes(
    city: City, seed: int, path: np.ndarray, start: np.ndarray, goal: np.ndarray, cfg: MissionConfig
) -> tuple[City, City, list[CityChange]]:
    """Today's city, yesterday's city and what changed between them (see the module docstring).

    Args:
        city: the generated city (what stayed the same).
        seed: the scenario's seed (the changes are deterministic in it).
        path: (K, 3) the shortest path in ``city``, world metres.
        start, goal: (3,) the mission's endpoints.
    Returns:
        (today, yesterday, changes); a change is left out when no place for it was found.
    """
    rng = np.random.default_rng([int(seed), 4243])
    ends = np.stack([start, goal])
    keep = cfg.endpoint_clearance_m + 2.0

    def fits(box: np.ndarray, base: City) -> bool:
        corners = np.array([[box[0], box[1]], [box[3], box[4]]])
        lo, hi = corners.min(axis=0), corners.max(axis=0)
        c = np.clip(ends[:, :2], lo, hi)
        if np.min(np.linalg.norm(ends[:, :2] - c, axis=1)) < keep:
            return False
        centre = np.array([[(box[0] + box[3]) / 2, (box[1] + box[4]) / 2, 1.0]])
        half = 0.5 * max(box[3] - box[0], box[4] - box[1])
        return bool(base.distance(centre, include_ground=False)[0] > half + 2.0)  # over the street

    def tower(p: np.ndarray, half: float, top: float) -> np.ndarray:
        return np.array([p[0] - half, p[1] - half, 0.0, p[0] + half, p[1] + half, top])

    changes: list[CityChange] = []
    added, removed = np.zeros((0, 6)), np.zeros((0, 6))
    for _ in range(40):
        p, _d = _point_along(path, float(rng.uniform(0.35, 0.7)))
        box = tower(p, float(rng.uniform(1.2, 1.8)), float(rng.uniform(22.0, 26.0)))
        if fits(box, city):
            added = box[None]
            changes.append(CityChange("added", "scaffold tower", tuple(float(v) for v in box)))
            break
    for _ in range(40):
        p, d = _point_along(path, float(rng.uniform(0.15, 0.35)))
        side = np.array([-d[1], d[0], 0.0]) * (1.0 if rng.random() < 0.5 else -1.0)
        q = p + side * float(rng.uniform(5.0, 9.0))
        box = tower(q, float(rng.uniform(1.2, 2.0)), float(rng.uniform(18.0, 24.0)))
        if fits(box, city):
            removed = box[None]
            changes.append(CityChange("removed", "container stack", tuple(float(v) for v in box)))
            break
    today = with_boxes(city, added, (0.78, 0.52, 0.18))
    yesterday = with_boxes(city, removed, (0.3, 0.42, 0.58))
    return today, yesterday, changes
