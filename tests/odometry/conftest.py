"""A small rendered stereo flight through the synthetic city, shared by the odometry tests."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from skyrecon.core import Rigid3, StereoRig
from skyrecon.sim import default_rig, flight_poses, generate_city, render_stereo
from skyrecon.sim.scenes import look_from

FPS = 10.0


@dataclass
class Flight:
    """Rendered frames (left, right RGB, left disparity) with their true ``world_from_left``."""

    rig: StereoRig
    left: list[np.ndarray]
    right: list[np.ndarray]
    disparity: list[np.ndarray]
    world_from_left: list[Rigid3]

    @property
    def timestamps(self) -> list[float]:
        return [k / FPS for k in range(len(self.left))]


def _render(city, rig: StereoRig, poses: list[Rigid3]) -> Flight:
    frames = [render_stereo(city, rig, p.inverse().with_frames("left", "world")) for p in poses]
    return Flight(
        rig,
        [f.left for f in frames],
        [f.right for f in frames],
        [f.disparity_left_px for f in frames],
        [p.with_frames("world", "left") for p in poses],
    )


@pytest.fixture(scope="session")
def city():
    return generate_city(seed=3)


@pytest.fixture(scope="session")
def flight(city) -> Flight:
    """40 frames at 320x240 (0.3 m baseline, as the delivery drone), 5 m/s at 10 Hz (about 20 m) along the streets of city 3."""
    rig = default_rig(320, 240, baseline_m=0.3)
    return _render(city, rig, flight_poses(city, 40, seed=3, speed_mps=5.0, fps=FPS))


@pytest.fixture(scope="session")
def sky_view(city, flight) -> Flight:
    """One frame from the flight's first position looking 75 degrees up: sky and little else."""
    eye = flight.world_from_left[0].t
    return _render(city, flight.rig, [look_from(eye, 0.3, np.radians(-75.0)).inverse()])
