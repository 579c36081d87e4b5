"""Vocabulary-free image retrieval: VLAD global descriptors with visual words learnt on the set.

A small codebook (k-means on a random sample of the set's own descriptors, seeded) replaces a
pre-trained vocabulary. Each image's descriptor is the VLAD vector (sum of residuals to the
nearest word), intra-normalised, power-normalised (signed square root) and L2-normalised, so
the cosine similarity of two images is one dot product.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.cluster.vq

from skyrecon.sfm.extract import load_features

__all__ = ["vlad_descriptors", "similarity_matrix"]


def _sample(
    paths: Sequence[str], per_image: int, rng: np.random.Generator, max_images: int = 400
) -> np.ndarray:
    chosen = np.arange(len(paths))
    if len(chosen) > max_images:
        chosen = np.sort(rng.choice(len(paths), max_images, replace=False))
    parts = []
    for k in chosen:
        d = load_features(paths[int(k)], ("descriptors",))["descriptors"]
        if len(d) == 0:
            continue
        sel = rng.choice(len(d), min(per_image, len(d)), replace=False)
        parts.append(d[sel].astype(np.float32))
    return np.concatenate(parts) if parts else np.zeros((0, 128), np.float32)


def vlad_descriptors(
    feature_paths: Sequence[str], n_clusters: int = 64, seed: int = 0, max_features: int = 2000
) -> np.ndarray:
    """VLAD global descriptor of every image.

    Args:
        feature_paths: cached feature files (see :mod:`skyrecon.sfm.extract`), one per image.
        n_clusters: visual words.
        seed: seeds the sampling and k-means.
        max_features: descriptors per image used (a seeded random subset beyond that).
    Returns:
        (n_images, n_clusters * D) float32 unit vectors (zero rows for images without features).
    """
    rng = np.random.default_rng(seed)
    sample = _sample(feature_paths, max(8, 4 * n_clusters * 16 // max(1, len(feature_paths))), rng)
    if len(sample) < n_clusters:
        n_clusters = max(1, len(sample))
    if len(sample) == 0:
        return np.zeros((len(feature_paths), 1), np.float32)
    centres, _ = scipy.cluster.vq.kmeans2(
        sample.astype(np.float64), n_clusters, iter=15, minit="++", seed=np.random.default_rng(seed + 1)
    )
    centres = centres.astype(np.float32)
    c2 = np.sum(centres * centres, axis=1)
    D = centres.shape[1]
    out = np.zeros((len(feature_paths), n_clusters * D), np.float32)
    for k, p in enumerate(feature_paths):
        d = load_features(p, ("descriptors",))["descriptors"].astype(np.float32)
        if len(d) == 0:
            continue
        if len(d) > max_features:
            d = d[rng.choice(len(d), max_features, replace=False)]
        assign = np.argmin(c2[None, :] - 2.0 * d @ centres.T, axis=1)
        v = np.zeros((n_clusters, D), np.float32)
        np.add.at(v, assign, d - centres[assign])
        n = np.linalg.norm(v, axis=1, keepdims=True)
        v = np.where(n > 0, v / np.maximum(n, 1e-12), 0.0)
        v = np.sign(v) * np.sqrt(np.abs(v))
        v = v.reshape(-1)
        nv = np.linalg.norm(v)
        out[k] = v / nv if nv > 0 else v
    return out


def similarity_matrix(descriptors: np.ndarray) -> np.ndarray:
    """(N, N) cosine similarities of unit global descriptors (N, D); the diagonal is set to -inf."""
    S = descriptors @ descriptors.T
    np.fill_diagonal(S, -np.inf)
    return S
