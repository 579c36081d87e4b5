"""The five-point solver on exact minimal problems."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.errors import EstimationError
from skyrecon.geometry.epipolar import essential_from_pose
from skyrecon.geometry.five_point import essential_5point, essential_5point_batch
from tests.geometry.synthetic import make_pair


def _dist(E: np.ndarray, Egt: np.ndarray) -> float:
    E = E / np.linalg.norm(E)
    Egt = Egt / np.linalg.norm(Egt)
    return float(min(np.abs(E - Egt).max(), np.abs(E + Egt).max()))


@pytest.mark.parametrize("seed", range(20))
def test_one_solution_is_the_true_essential_matrix(seed):
    p = make_pair(seed=seed, n=5, rotation_deg=25.0)
    x1n, x2n = p.intr1.normalized(p.x1), p.intr2.normalized(p.x2)
    Es = essential_5point(x1n, x2n)
    assert 1 <= len(Es) <= 10
    Egt = essential_from_pose(p.R, p.t)
    assert min(_dist(E, Egt) for E in Es) < 1e-9
    h1 = np.concatenate([x1n, np.ones((5, 1))], 1)
    h2 = np.concatenate([x2n, np.ones((5, 1))], 1)
    for E in Es:  # every solution is an essential matrix through the five matches
        assert np.abs(np.sum(h2 * (h1 @ E.T), axis=1)).max() < 1e-9
        s = np.linalg.svd(E, compute_uv=False)
        assert s[2] < 1e-8 * s[0] and abs(s[0] - s[1]) < 1e-7 * s[0]


def test_batch_matches_single_calls():
    ps = [make_pair(seed=s, n=5) for s in range(6)]
    X1 = np.stack([p.intr1.normalized(p.x1) for p in ps])
    X2 = np.stack([p.intr2.normalized(p.x2) for p in ps])
    Es, idx = essential_5point_batch(X1, X2)
    for k, p in enumerate(ps):
        single = essential_5point(X1[k], X2[k])
        assert np.count_nonzero(idx == k) == len(single)
        Egt = essential_from_pose(p.R, p.t)
        assert min(_dist(E, Egt) for E in Es[idx == k]) < 1e-9


def test_planar_and_sideways_configurations():
    for kw in ({"planar": True}, {"rotation_deg": 0.5}, {"forward": 3.0}):
        p = make_pair(seed=11, n=5, **kw)
        Es = essential_5point(p.intr1.normalized(p.x1), p.intr2.normalized(p.x2))
        assert min(_dist(E, essential_from_pose(p.R, p.t)) for E in Es) < 1e-7


def test_degenerate_samples_do_not_crash():
    x = np.random.default_rng(0).normal(size=(5, 2))
    Es = essential_5point(x, x)  # identical images: a continuum of solutions
    assert all(np.all(np.isfinite(E)) for E in Es)
    Es, idx = essential_5point_batch(np.zeros((3, 5, 2)), np.zeros((3, 5, 2)))
    assert len(Es) == len(idx)
    with pytest.raises(EstimationError):
        essential_5point(x[:4], x[:4])
