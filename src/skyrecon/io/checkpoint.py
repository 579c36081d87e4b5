"""Checkpoints of long sequential runs, so that a killed run resumes where it stopped.

A checkpoint is one pickle file in the run's workspace, written atomically (so a kill leaves the
previous checkpoint or none): ``{"format", "version", "key", "done", "state"}``. ``key`` is a
JSON-able description of everything the result depends on (the input, the settings, the
package version); a checkpoint whose key differs from the rerun's is ignored, so changing an
argument starts over instead of mixing two runs. ``done`` counts the items (frames) already in
``state``. Checkpoints are the run's own files: load only those your own runs wrote.

Example:
    >>> ckpt = Checkpoint(workspace / "map.ckpt", key={"source": "...", "voxel": 0.5})
    >>> done, state = ckpt.load() or (0, None)
    >>> ...  # after each frame: ckpt.save(done, state)      (at most every ``every_s`` seconds)
    >>> ckpt.clear()                                          # after the outputs are written
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import pickle
import time
from pathlib import Path
from typing import Any

from skyrecon import __version__
from skyrecon.io.atomic import write_bytes_atomic

__all__ = ["Checkpoint", "key_digest"]

DEFAULT_EVERY_S = 5.0
FORMAT = "skyrecon.checkpoint"
VERSION = 1


def key_digest(key: Any) -> str:
    """A short stable hash of a JSON-able key (sorted keys; numbers as JSON writes them)."""
    text = json.dumps(key, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class Checkpoint:
    """The resumable state of one run (see the module).

    Args:
        path: the checkpoint file (its folder is created when first saved).
        key: what the run's result depends on (JSON-able); the package version is added.
        every_s: :meth:`save` writes at most this often (seconds), unless forced; default 5, or
            the environment's ``SKYRECON_CHECKPOINT_S`` (0: after every item, as the kill tests use).
    """

    def __init__(self, path: str | Path, key: Any, every_s: float | None = None):
        self.path = Path(path)
        self.key = key_digest({"key": key, "skyrecon": __version__})
        if every_s is None:
            every_s = float(os.environ.get("SKYRECON_CHECKPOINT_S", DEFAULT_EVERY_S))
        self.every_s = float(every_s)
        self._last_save = time.monotonic()
        self.saves = 0

    def load(self) -> tuple[int, Any] | None:
        """``(done, state)`` of a checkpoint of this same run, or None (no file, another run's
        key, or an unreadable file, which is then ignored)."""
        if not self.path.is_file():
            return None
        try:
            with open(self.path, "rb") as f:
                doc = pickle.load(f)
        except Exception:  # noqa: BLE001 - a damaged checkpoint only means starting over
            return None
        if not isinstance(doc, dict) or doc.get("format") != FORMAT or doc.get("version") != VERSION:
            return None
        if doc.get("key") != self.key:
            return None
        return int(doc["done"]), doc["state"]

    def due(self) -> bool:
        """Whether :meth:`save` would write now (``every_s`` has passed since the last save):
        for a state that costs something to get (e.g. one that waits for work in flight)."""
        return time.monotonic() - self._last_save >= self.every_s

    def save(self, done: int, state: Any, force: bool = False) -> bool:
        """Write ``state`` after ``done`` items if ``every_s`` has passed since the last save (or
        ``force``); returns whether it wrote."""
        if not force and not self.due():
            return False
        doc = {"format": FORMAT, "version": VERSION, "key": self.key, "done": int(done), "state": state}
        write_bytes_atomic(self.path, pickle.dumps(doc, protocol=pickle.HIGHEST_PROTOCOL))
        self._last_save = time.monotonic()
        self.saves += 1
        return True

    def clear(self) -> None:
        """Remove the checkpoint file (and its folder when that is left empty)."""
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
        with contextlib.suppress(OSError):
            self.path.parent.rmdir()
