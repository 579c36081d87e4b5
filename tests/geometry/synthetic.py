"""Synthetic two-view correspondences with exact ground truth (shared by the geometry tests)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skyrecon.core import Intrinsics, rotvec_to_matrix


@dataclass
class SyntheticPair:
    """Ground truth and observations of one synthetic two-view problem.

    Attributes:
        K1, K2 intrinsics; R, t: cam2_from_cam1 with |t| = 1 (metres: the baseline is 1);
        X: (N, 3) points in camera 1's frame; x1, x2: (N, 2) observed pixels (noise, outliers);
        x1_true, x2_true: (N, 2) exact projections; outlier: (N,) bool.
    """

    intr1: Intrinsics
    intr2: Intrinsics
    R: np.ndarray
    t: np.ndarray
    X: np.ndarray
    x1: np.ndarray
    x2: np.ndarray
    x1_true: np.ndarray
    x2_true: np.ndarray
    outlier: np.ndarray


def make_pair(
    seed: int = 0,
    n: int = 200,
    noise_px: float = 0.0,
    outlier_ratio: float = 0.0,
    planar: bool = False,
    baseline: float = 1.0,
    rotation_deg: float = 10.0,
    depth: tuple[float, float] = (4.0, 12.0),
    width: int = 1536,
    height: int = 1024,
    forward: float = 0.0,
) -> SyntheticPair:
    """A random scene seen by two cameras looking at the same region.

    ``baseline`` is the camera-centre distance (the scene depth is in the same units);
    ``planar`` puts every point on one tilted plane; ``forward`` adds motion along z.
    """
    rng = np.random.default_rng(seed)
    intr = Intrinsics(1.1 * width, 1.1 * width, (width - 1) / 2 + 7.0, (height - 1) / 2 - 5.0, width, height)
    # points in camera 1, inside its image
    u = rng.uniform(0, width - 1, n)
    v = rng.uniform(0, height - 1, n)
    if planar:
        nrm = np.array([0.2, -0.1, 1.0])
        nrm /= np.linalg.norm(nrm)
        d0 = np.mean(depth)
        rays = intr.unproject(np.stack([u, v], 1), 1.0)
        z = d0 / (rays @ nrm)
        X = rays * z[:, None]
    else:
        X = intr.unproject(np.stack([u, v], 1), rng.uniform(*depth, n))
    # camera 2: centre displaced sideways (plus forward), rotated to look back at the scene centre
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    R = rotvec_to_matrix(axis * np.radians(rotation_deg))
    c2 = np.array([1.0, 0.15, forward])
    c2 = c2 / np.linalg.norm(c2) * baseline
    t = -R @ c2
    X2 = X @ R.T + t
    x1_true = intr.project(X)
    x2_true = intr.project(X2)
    x1 = x1_true + rng.normal(scale=noise_px, size=x1_true.shape) if noise_px > 0 else x1_true.copy()
    x2 = x2_true + rng.normal(scale=noise_px, size=x2_true.shape) if noise_px > 0 else x2_true.copy()
    outlier = rng.random(n) < outlier_ratio
    x2[outlier] = np.stack(
        [rng.uniform(0, width - 1, outlier.sum()), rng.uniform(0, height - 1, outlier.sum())], 1
    )
    tn = np.linalg.norm(t)
    return SyntheticPair(intr, intr, R, t / tn, X / tn, x1, x2, x1_true, x2_true, outlier)
