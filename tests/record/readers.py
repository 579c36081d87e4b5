"""Read recordings back with their own libraries: rows per Rerun entity, messages per MCAP topic."""

from __future__ import annotations

from collections import Counter
from pathlib import Path


def rrd_rows(path: Path) -> Counter[tuple[str, str]]:
    """Rows per (entity path, archetype) of the first recording in a ``.rrd`` file (``rerun-sdk``);
    static rows count under the archetype name suffixed with ``:static``."""
    from rerun.chunk import RrdReader

    rows: Counter[tuple[str, str]] = Counter()
    for chunk in RrdReader(path).stream():
        if chunk.entity_path.startswith("/__"):
            continue
        names = chunk.to_record_batch().schema.names
        archetypes = {n.split(":", 1)[0] for n in names if ":" in n}
        for a in archetypes:
            rows[(chunk.entity_path, a + (":static" if chunk.is_static else ""))] += chunk.num_rows
    return rows


def rrd_frames(path: Path, entity: str) -> list[int]:
    """The ``frame`` values of an entity's non-static rows, sorted."""
    from rerun.chunk import RrdReader

    frames: list[int] = []
    for chunk in RrdReader(path).stream():
        if chunk.entity_path == entity and not chunk.is_static:
            batch = chunk.to_record_batch()
            if "frame" in batch.schema.names:
                frames += [v for v in batch.column("frame").to_pylist() if v is not None]
    return sorted(frames)


def mcap_topics(path: Path) -> dict[str, tuple[str, int]]:
    """{topic: (schema name, message count)} of an ``.mcap`` file, counted by reading every message
    (``mcap``)."""
    from mcap.reader import make_reader

    counts: Counter[str] = Counter()
    schemas: dict[str, str] = {}
    with open(path, "rb") as f:
        for schema, channel, _ in make_reader(f).iter_messages():
            counts[channel.topic] += 1
            schemas[channel.topic] = schema.name if schema is not None else ""
    return {t: (schemas[t], n) for t, n in counts.items()}
