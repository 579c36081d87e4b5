"""Small synthetic scenes for the mapping tests."""

from __future__ import annotations

import pytest

from skyrecon.core import Intrinsics
from skyrecon.sim import generate_city, render
from skyrecon.sim.scenes import flight_poses


@pytest.fixture(scope="session")
def small_city():
    return generate_city(11, 60.0)


@pytest.fixture(scope="session")
def city_frames(small_city):
    """(intrinsics, [depth], [world_from_cam]) of a short low-resolution flight over ``small_city``."""
    cam = Intrinsics.from_fov(160, 120, 90.0)
    poses = flight_poses(small_city, 6, seed=3, speed_mps=8.0, fps=2.0)
    depths = [render(small_city, cam, p.inverse()).depth_m for p in poses]
    return cam, depths, poses
