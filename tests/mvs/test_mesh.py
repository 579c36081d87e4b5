"""Surface nets on an analytic field, TSDF meshing of hand-made depth maps, and the PLY face writer."""

from __future__ import annotations

import numpy as np

from skyrecon.core import PointCloud
from skyrecon.mvs.export import encode_mesh_ply
from skyrecon.mvs.fusion import depth_to_world
from skyrecon.mvs.mesh import mesh_from_depth_maps, surface_nets
from tests.mvs.test_fusion import plane_views


def test_surface_nets_sphere() -> None:
    n, voxel, r = 40, 0.05, 0.7
    origin = np.array([-1.0, -1.0, -1.0])
    c = -1.0 + (np.arange(n) + 0.5) * voxel
    X, Y, Z = np.meshgrid(c, c, c, indexing="ij")
    field = np.sqrt(X**2 + Y**2 + Z**2) - r  # positive outside
    verts, faces = surface_nets(field, np.ones(field.shape, bool), origin, voxel)
    rad = np.linalg.norm(verts, axis=1)
    assert np.abs(rad - r).max() < 0.5 * voxel
    assert len(faces) > 1000 and faces.max() < len(verts)
    # outward orientation
    v0, v1, v2 = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    nrm = np.cross(v1 - v0, v2 - v0)
    assert np.mean(np.sum(nrm * (v0 + v1 + v2), axis=1) > 0) > 0.99
    # closed surface: every edge is shared by exactly two faces
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    assert np.all(counts == 2)


def test_mesh_from_depth_maps_of_a_plane() -> None:
    views, depths = plane_views()
    pts = []
    for v, d in zip(views, depths):
        pts.append(depth_to_world(v, d)[0])
    P = np.concatenate(pts)
    cloud = PointCloud(P.astype(np.float32), np.full((len(P), 3), 120, np.uint8))
    verts, faces, colors = mesh_from_depth_maps(views, depths, cloud, voxel_m=0.05)
    assert len(faces) > 100 and colors.shape == verts.shape
    assert np.abs(verts[:, 2]).max() < 0.05  # on the plane z = 0 (within a voxel)


def test_mesh_ply_layout() -> None:
    data = encode_mesh_ply(np.zeros((3, 3)), np.array([[0, 1, 2]]), np.zeros((3, 3), np.uint8))
    header, body = data.split(b"end_header\n")
    assert b"element vertex 3" in header and b"element face 1" in header
    assert len(body) == 3 * 15 + 1 + 12
