"""Shared scenes for the simulator tests (small images: the point is correctness)."""

from __future__ import annotations

import pytest

from skyrecon.sim import default_rig, generate_city, generate_object_scene, render_stereo, street_view_pose


@pytest.fixture(scope="session")
def city():
    return generate_city(3)


@pytest.fixture(scope="session")
def small_rig():
    return default_rig(320, 240)


@pytest.fixture(scope="session")
def street_frame(city, small_rig):
    return render_stereo(city, small_rig, street_view_pose(city, 3))


@pytest.fixture(scope="session")
def object_scene():
    return generate_object_scene(2)
