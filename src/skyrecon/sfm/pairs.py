"""Which image pairs to match: exhaustive, sequential (flights) or retrieval-based.

Sequential pairing keeps the cost linear in the number of frames: each frame is matched with
the next ``window`` frames, with frames ``2 window, 4 window, ...`` ahead (wider baselines for
a stable geometry), and with its most similar frames far away in the sequence (loop closures,
found with VLAD global descriptors).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skyrecon.errors import InputError
from skyrecon.sfm.retrieval import similarity_matrix
from skyrecon.sfm.settings import PairingSettings, PairMode

__all__ = [
    "PairSelection",
    "select_pairs",
    "resolve_pair_mode",
    "looks_like_sequence",
    "exhaustive_pairs",
    "sequential_pairs",
    "retrieval_pairs",
]


@dataclass
class PairSelection:
    """The pairs to match.

    Attributes:
        pairs: (P, 2) int64 rows ``(i, j)`` with ``i < j``, sorted.
        mode: the pairing actually used.
        num_loop_pairs: pairs added by retrieval (sequential loop candidates or retrieval mode).
        details: extra numbers (window, offsets, ...).
    """

    pairs: np.ndarray
    mode: str
    num_loop_pairs: int = 0
    details: dict = field(default_factory=dict)


def _normalise(pairs: set[tuple[int, int]]) -> np.ndarray:
    if not pairs:
        return np.zeros((0, 2), np.int64)
    arr = np.array(sorted((min(a, b), max(a, b)) for a, b in pairs if a != b), np.int64)
    return np.unique(arr, axis=0)


def exhaustive_pairs(n: int) -> np.ndarray:
    """(n (n - 1) / 2, 2) every pair ``i < j``."""
    i, j = np.triu_indices(n, k=1)
    return np.stack([i, j], axis=1).astype(np.int64)


def sequential_pairs(n: int, window: int, exponential: bool, max_offset: int) -> np.ndarray:
    """Pairs ``(i, i + d)`` for ``d = 1..window`` and, when ``exponential``, ``d = 2 window,
    4 window, ...`` up to ``max_offset``."""
    offsets = list(range(1, window + 1))
    if exponential:
        d = 2 * window
        while d <= max_offset:
            offsets.append(d)
            d *= 2
    out = []
    for d in offsets:
        if d >= n:
            continue
        i = np.arange(n - d)
        out.append(np.stack([i, i + d], axis=1))
    return np.concatenate(out).astype(np.int64) if out else np.zeros((0, 2), np.int64)


def retrieval_pairs(
    similarity: np.ndarray, k: int, exclude_within: int = 0, min_similarity: float = -1.0
) -> np.ndarray:
    """For each image, pairs with its ``k`` most similar images.

    Args:
        similarity: (N, N) similarities (diagonal -inf).
        k: neighbours per image.
        exclude_within: ignore images closer than this in index (already paired sequentially).
        min_similarity: ignore candidates below this similarity.
    """
    S = similarity.copy()
    n = len(S)
    if exclude_within > 0:
        idx = np.arange(n)
        S[np.abs(idx[:, None] - idx[None, :]) <= exclude_within] = -np.inf
    S[S < min_similarity] = -np.inf
    k = min(k, max(0, n - 1))
    if k == 0:
        return np.zeros((0, 2), np.int64)
    top = np.argpartition(-S, kth=k - 1, axis=1)[:, :k]
    rows = np.repeat(np.arange(n), k)
    cols = top.reshape(-1)
    ok = np.isfinite(S[rows, cols])
    pairs = np.stack([np.minimum(rows, cols), np.maximum(rows, cols)], axis=1)[ok]
    return np.unique(pairs, axis=0).astype(np.int64) if len(pairs) else np.zeros((0, 2), np.int64)


def looks_like_sequence(names: Sequence[str]) -> bool:
    """The names are numbered frames of one sequence: the same text around one number that grows
    with the (natural) name order, mostly in equal steps."""
    if len(names) < 3:
        return False
    pattern = re.compile(r"^(.*?)(\d+)(\D*)$")
    parts = [pattern.match(Path(n).stem) for n in names]
    matches = [m for m in parts if m is not None]
    if len(matches) != len(parts):
        return False
    if len({(m.group(1), m.group(3)) for m in matches}) != 1:
        return False
    nums = np.array([int(m.group(2)) for m in matches])
    steps = np.diff(nums)
    if np.any(steps <= 0):
        return False
    return bool(np.mean(steps == np.median(steps)) >= 0.8)


def resolve_pair_mode(mode: PairMode, names: Sequence[str], settings: PairingSettings) -> PairMode:
    """The pairing mode for these images: ``mode`` itself unless it is ``"auto"``.

    The ``auto`` rule: exhaustive up to ``settings.exhaustive_max_images`` images; above that
    sequential when the names are numbered frames of one sequence (:func:`looks_like_sequence`),
    else retrieval.

    Args:
        mode: the requested mode.
        names: the image names, in input (sequence) order.
        settings: the pairing settings (``exhaustive_max_images``).
    """
    if mode != "auto":
        return mode
    if len(names) <= settings.exhaustive_max_images:
        return "exhaustive"
    return "sequential" if looks_like_sequence(names) else "retrieval"


def select_pairs(
    n: int,
    mode: PairMode,
    settings: PairingSettings,
    global_descriptors: Callable[[], np.ndarray] | None = None,
    names: Sequence[str] | None = None,
) -> PairSelection:
    """Pairs to match for ``n`` images.

    Args:
        n: number of images (in sequence order for ``"sequential"``).
        mode: ``"auto"`` (see :func:`resolve_pair_mode`), ``"exhaustive"``, ``"sequential"`` or
            ``"retrieval"``.
        settings: window sizes, neighbours.
        global_descriptors: computes (n, D) unit global descriptors on demand (retrieval and
            loop detection).
        names: the image names, for the ``auto`` rule (without them, ``auto`` never chooses
            sequential).
    """
    if n < 2:
        raise InputError(f"need at least two images to pair, got {n}")
    mode = resolve_pair_mode(mode, names if names is not None else [""] * n, settings)
    if mode == "exhaustive" or (mode == "retrieval" and n <= settings.retrieval_neighbors + 1):
        return PairSelection(exhaustive_pairs(n), "exhaustive")
    if mode == "sequential":
        seq = sequential_pairs(n, settings.window, settings.exponential, settings.max_offset)
        loops = np.zeros((0, 2), np.int64)
        if settings.loop_candidates > 0 and global_descriptors is not None and n > settings.max_offset + 1:
            S = similarity_matrix(global_descriptors())
            loops = retrieval_pairs(
                S, settings.loop_candidates, settings.max_offset, settings.loop_min_similarity
            )
        all_pairs = np.unique(np.concatenate([seq, loops]), axis=0) if len(loops) else seq
        all_pairs = all_pairs[np.lexsort((all_pairs[:, 1], all_pairs[:, 0]))]
        return PairSelection(
            all_pairs,
            "sequential",
            len(all_pairs) - len(seq),
            {"window": settings.window, "max_offset": settings.max_offset},
        )
    if mode == "retrieval":
        if global_descriptors is None:
            raise InputError("retrieval pairing needs global descriptors")
        S = similarity_matrix(global_descriptors())
        pairs = retrieval_pairs(S, settings.retrieval_neighbors)
        return PairSelection(pairs, "retrieval", len(pairs), {"neighbors": settings.retrieval_neighbors})
    raise InputError(f"unknown pairing mode {mode!r}")
