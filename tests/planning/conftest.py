"""Synthetic scenes for the planning tests."""

from __future__ import annotations

import pytest

from skyrecon.core import Intrinsics
from skyrecon.mapping import build_map_from_depth_frames
from skyrecon.sim import generate_city, render
from skyrecon.sim.scenes import flight_poses


@pytest.fixture(scope="session")
def small_city():
    return generate_city(11, 60.0)


@pytest.fixture(scope="session")
def city_depth_map(small_city):
    """A map built from 8 rendered depth frames of a short flight over ``small_city`` (0.5 m voxels)."""
    cam = Intrinsics.from_fov(160, 120, 90.0)
    poses = flight_poses(small_city, 8, seed=3, speed_mps=8.0, fps=2.0)
    depths = [render(small_city, cam, p.inverse()).depth_m for p in poses]
    return build_map_from_depth_frames(depths, cam, poses, voxel_size_m=0.5, max_range_m=40.0)
