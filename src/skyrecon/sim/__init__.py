"""Synthetic city for testing: generation, exact ground-truth queries, rendering and camera paths.

World frame right-handed, z up, metres; cameras in OpenCV axes (x right, y down, z forward);
poses named ``b_from_a``. Everything is deterministic in its seed.

    city = generate_city(seed=3)                       # boxes, poles, streets
    rig = default_rig()                                # 640x480, 90 deg, 0.12 m baseline
    frame = render_stereo(city, rig, street_view_pose(city, seed=3))
    frame.left, frame.right, frame.depth_left_m, frame.disparity_left_px
    city.distance(points), city.raycast(origins, dirs), city.occupancy_grid(origin, 0.5, shape)
    scene = make_movers(city, seed, start, goal, path)   # drones, vehicles, a crane; scene.snapshot(t)
"""

from skyrecon.sim.city import City, RayHits
from skyrecon.sim.generate import generate_city, generate_object_scene
from skyrecon.sim.movers import Mover, MoverSnapshot, MovingScene, make_movers, mover_of_object_id
from skyrecon.sim.render import RenderResult, StereoFrame, render, render_depth, render_stereo, render_views
from skyrecon.sim.scenes import (
    default_rig,
    flight_path,
    flight_poses,
    look_from,
    orbit_views,
    ring_views,
    street_view_pose,
)

__all__ = [
    "City",
    "RayHits",
    "generate_city",
    "generate_object_scene",
    "Mover",
    "MoverSnapshot",
    "MovingScene",
    "make_movers",
    "mover_of_object_id",
    "RenderResult",
    "StereoFrame",
    "render",
    "render_depth",
    "render_stereo",
    "render_views",
    "default_rig",
    "street_view_pose",
    "flight_poses",
    "flight_path",
    "look_from",
    "ring_views",
    "orbit_views",
]
