"""The k-NN statistics of the cloud clean-up against a plain NumPy reference."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from skyrecon.mvs.cloud_ops import _smallest_eigenvector, knn_mean_distance_and_normals


def test_mean_distances_and_normals_match_numpy() -> None:
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 10, (3000, 2))
    pts = np.column_stack([xy, 0.3 * np.sin(xy[:, 0]) + rng.normal(0, 0.01, len(xy))])
    mean_d, normals = knn_mean_distance_and_normals(pts, k=8)
    dist, idx = cKDTree(pts).query(pts, k=9)
    np.testing.assert_allclose(mean_d, dist[:, 1:].mean(axis=1), rtol=1e-12)
    nb = pts[idx]
    c = nb - nb.mean(axis=1, keepdims=True)
    _, vec = np.linalg.eigh(np.einsum("mki,mkj->mij", c, c))
    cos = np.abs(np.sum(vec[:, :, 0] * normals, axis=1))
    assert normals.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)
    assert cos.min() > 1 - 1e-6


def test_smallest_eigenvector_of_degenerate_neighbourhoods() -> None:
    rng = np.random.default_rng(0)
    for _ in range(200):  # random symmetric matrices of every conditioning
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        lam = np.sort(rng.uniform(0, 1, 3)) * 10.0 ** rng.integers(-6, 3, 3)
        c = q @ np.diag(lam) @ q.T
        w, vec = np.linalg.eigh(c)
        if (w[1] - w[0]) < 1e-6 * w[2]:
            continue
        v = np.array(_smallest_eigenvector(c))
        assert abs(abs(v @ vec[:, 0]) - 1) < 1e-6, (lam, v, vec[:, 0])
    # points on a line: any unit vector across it
    d = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    line = np.outer(np.linspace(-1, 1, 9), d)
    c = (line - line.mean(0)).T @ (line - line.mean(0))
    v = np.array(_smallest_eigenvector(c))
    assert abs(np.linalg.norm(v) - 1) < 1e-9 and abs(v @ d) < 1e-6
    # one point repeated, and nothing at all: +z
    assert _smallest_eigenvector(np.zeros((3, 3))) == (0.0, 0.0, 1.0)
    assert _smallest_eigenvector(np.eye(3) * 2.0) == (0.0, 0.0, 1.0)
