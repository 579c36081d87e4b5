"""Small synthetic camera rings with exact geometry for the MVS tests."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from skyrecon.core import Intrinsics, PosedView
from skyrecon.sim import City, generate_object_scene, render_views, ring_views


@dataclass(frozen=True)
class Ring:
    """A rendered ring: views, RGB images, exact depth maps (metres, NaN sky), the scene."""

    views: list[PosedView]
    images: list[np.ndarray]
    depths: list[np.ndarray]
    city: City

    @property
    def eval_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The region evaluated: the monument and the plaza around it (world, metres)."""
        return np.array([-4.0, -4.0, -0.05]), np.array([4.0, 4.0, 2 * self.city.center[2] + 0.2])


@lru_cache(maxsize=4)
def make_ring(n: int = 10, width: int = 192, height: int = 144, seed: int = 0, plain: bool = False) -> Ring:
    """``n`` cameras on a ring around a generated monument, looking down at about 30 degrees
    (``plain``: the plain-surface variant of the scene)."""
    city = generate_object_scene(seed, plain=plain)
    intr = Intrinsics.from_fov(width, height, 60.0)
    views = ring_views(city.center, 8.0, city.center[2] + 5.0, n, intr)
    renders = render_views(city, views)
    return Ring(views, [r.image for r in renders], [r.depth_m for r in renders], city)
