"""Recordings of a run for a viewer: ``.rrd`` (Rerun) or ``.mcap`` (Foxglove / Lichtblick).

Open one with :func:`open_recorder` (the extension picks the backend; None gives a
:class:`NullRecorder` that records nothing) and pass it to a stage as an optional observer.
See :mod:`skyrecon.record.recorder` for the names, frames and time conventions.
"""

from skyrecon.record.recorder import (
    INSTALL_LINES,
    RECORD_EXTENSIONS,
    NullRecorder,
    Recorder,
    RecordSettings,
    check_record_path,
    open_recorder,
)

__all__ = [
    "INSTALL_LINES",
    "RECORD_EXTENSIONS",
    "NullRecorder",
    "RecordSettings",
    "Recorder",
    "check_record_path",
    "open_recorder",
]
