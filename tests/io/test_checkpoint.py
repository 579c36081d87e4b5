"""Checkpoints of sequential runs: written at most every ``every_s`` seconds, atomically, read
back only by the same run."""

from __future__ import annotations

from skyrecon.io.checkpoint import Checkpoint


def test_save_writes_when_due_and_load_takes_only_the_same_run(tmp_path):
    path = tmp_path / "ws" / "run.pkl"
    ckpt = Checkpoint(path, {"source": "a"}, every_s=3600.0)
    assert not ckpt.due() and not ckpt.save(3, {"x": 1}) and not path.exists()
    assert ckpt.save(3, {"x": 1}, force=True) and ckpt.saves == 1
    assert ckpt.load() == (3, {"x": 1})
    assert Checkpoint(path, {"source": "b"}).load() is None  # another run's key
    eager = Checkpoint(path, {"source": "a"}, every_s=0.0)
    assert eager.due() and eager.save(4, {"x": 2}) and eager.load() == (4, {"x": 2})
    eager.clear()
    assert not path.exists() and not path.parent.exists()
