"""A plain wall in the stereo map: with the plane-supported fill the wall is a wall, without it
a hole (the matcher measures only its outline), and the fill puts no obstacle in the air."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from skyrecon.core import Rigid3
from skyrecon.mapping import StereoMapper
from skyrecon.mapping.occupancy import FREE
from skyrecon.sim import default_rig, render_stereo
from skyrecon.sim.city import City
from skyrecon.sim.texture import GROUND_PLAIN, MAT_PLAIN

VOXEL = 0.5
WALL_Y = 8.0  # the wall's front face (facing the cameras at y = 0), metres


@pytest.fixture(scope="module")
def plain_wall():
    """(city, rig, poses, frames): a plain wall 10 m wide and 6 m tall, 8 m in front of three
    320x240 stereo views (0.3 m baseline) from 3 m up, on plain grey ground."""
    city = City.from_obstacles(np.array([[-5.0, WALL_Y, 0.0, 5.0, WALL_Y + 2.0, 6.0]]), seed=1)
    city = dataclasses.replace(
        city,
        box_material=np.full(1, MAT_PLAIN),
        box_albedo=np.array([[0.8, 0.75, 0.65]]),
        ground_style=GROUND_PLAIN,
    )
    rig = default_rig(320, 240, 90.0, 0.3)
    poses = [
        Rigid3.look_at(np.array([x, 0.0, 3.0]), np.array([0.5 * x, WALL_Y, 3.0])).inverse()
        for x in (-1.0, 0.0, 1.0)
    ]
    return city, rig, poses, [render_stereo(city, rig, p.inverse()) for p in poses]


def _map(plain_wall, **overrides) -> StereoMapper:
    _, rig, poses, frames = plain_wall
    mapper = StereoMapper(rig, voxel_size_m=VOXEL, **overrides)
    for f, p in zip(frames, poses):
        mapper.add_frame(f.left, f.right, p)
    return mapper


def _face_voxels(centres: np.ndarray) -> np.ndarray:
    """(x, z) columns of the wall's face, away from its rim, with an occupied voxel in one of the
    two layers that touch the face (y in [7.5, 8) or [8, 8.5)): the face lies on a voxel face,
    and the stereo map takes a measured surface a fifth of a voxel nearer the camera."""
    on_face = (
        (np.abs(np.abs(centres[:, 1] - WALL_Y) - 0.5 * VOXEL) < 1e-6)
        & (np.abs(centres[:, 0]) < 4.5)
        & (centres[:, 2] > 0.5)
        & (centres[:, 2] < 5.5)
    )
    return np.unique(np.floor(centres[on_face][:, [0, 2]] / VOXEL).astype(np.int64), axis=0)


def test_the_hole_in_a_plain_wall_is_filled_only_with_the_plane_fill(plain_wall):
    city, rig, _, frames = plain_wall
    face_total = 18 * 10  # voxels of the face layer with |x| < 4.5 m, 0.5 < z < 5.5 m
    filled = _map(plain_wall, guess_min_frames=0)  # the plane fill alone
    centres = filled.map.occupied_centers()
    assert len(_face_voxels(centres)) >= 0.8 * face_total
    assert len(_face_voxels(_map(plain_wall).map.occupied_centers())) >= 0.8 * face_total
    # the wall's middle is unmeasured: without the plane fill (nor guesses) it stays a hole
    holed = _map(plain_wall, plane_fill=False, guess_min_frames=0)
    assert len(_face_voxels(holed.map.occupied_centers())) <= 0.1 * face_total
    # what the fill adds is on the wall or the ground, not in the air
    old = {tuple(v) for v in holed.map.occupied_voxels().tolist()}
    added = np.array(
        [c for c, v in zip(centres, filled.map.occupied_voxels().tolist()) if tuple(v) not in old]
    )
    assert len(added) > 100
    assert np.mean(np.abs(city.distance(added, include_ground=True)) <= VOXEL) > 0.97
    frame = filled.stereo.compute(frames[1].left, frames[1].right)
    assert frame.plane_fraction > 0.1 and frame.measured_fraction < 0.1


def test_the_plain_wall_is_not_carved_free(plain_wall):
    # free space is carved only along trusted depth: no ray passes through the plain face
    xs, zs = np.meshgrid(np.arange(-4.25, 4.5, VOXEL), np.arange(0.75, 5.5, VOXEL))
    face = np.stack([xs.ravel(), np.full(xs.size, WALL_Y + 0.5 * VOXEL), zs.ravel()], axis=1)
    for overrides in ({}, {"plane_fill": False, "guess_min_frames": 0}):
        state = _map(plain_wall, **overrides).map.state_at(face)
        assert not (state == FREE).any(), overrides
