"""Small synthetic two-view scenes rendered once per session (skyrecon.sim)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest

from skyrecon.core import Intrinsics, PosedView, Rigid3
from skyrecon.eval.gt_geometry import relative_pose
from skyrecon.features import FeatureSettings
from skyrecon.twoview import TwoViewSettings

sim = pytest.importorskip("skyrecon.sim")


@dataclass
class Scene:
    """Rendered views of one synthetic monument with exact cameras."""

    intr: Intrinsics
    views: list[PosedView]
    images: list[np.ndarray]
    depths: list[np.ndarray]
    city: object

    def gt(self, i: int, j: int) -> Rigid3:
        return relative_pose(self.views[i], self.views[j])


def small_settings(**kw):
    """Pipeline settings for 640x480 test images (fast)."""
    base = TwoViewSettings(features=FeatureSettings(max_image_size=640), dense_max_image_size=640)
    return replace(base, **kw)


@pytest.fixture(scope="session")
def monument() -> Scene:
    intr = Intrinsics.from_fov(640, 480, 60.0)
    city = sim.generate_object_scene(seed=1)
    views = sim.orbit_views(city, 24, intr, seed=1)[:2]
    eye = views[0].cam_from_world.center
    # 2: same centre as 0, turned (pure rotation); 3, 4: looking down at the plaza (a plane)
    views.append(PosedView("rot", intr, Rigid3.look_at(eye, city.center + np.array([1.5, 0.5, 0.3]))))
    views.append(
        PosedView("planeA", intr, Rigid3.look_at(np.array([9.0, 0.0, 6.0]), np.array([10.0, 0.0, 0.0])))
    )
    views.append(
        PosedView("planeB", intr, Rigid3.look_at(np.array([9.0, 1.5, 6.2]), np.array([10.0, 0.5, 0.0])))
    )
    rs = sim.render_views(city, views)
    return Scene(intr, views, [r.image for r in rs], [r.depth_m for r in rs], city)


@pytest.fixture(scope="session")
def other_scene_image() -> np.ndarray:
    intr = Intrinsics.from_fov(640, 480, 60.0)
    city = sim.generate_city(seed=2)
    return sim.render(city, intr, sim.street_view_pose(city, seed=2)).image


@pytest.fixture(scope="session")
def flight() -> Scene:
    """Two frames of a drone flying forward along a street (the epipole is inside the image)."""
    intr = Intrinsics.from_fov(640, 480, 60.0)
    city = sim.generate_city(seed=3)
    poses = sim.flight_poses(city, 8, seed=3, pitch_deg=25.0)
    views = [PosedView(f"f{k}", intr, poses[k].inverse()) for k in (0, 6)]
    rs = sim.render_views(city, views)
    return Scene(intr, views, [r.image for r in rs], [r.depth_m for r in rs], city)
