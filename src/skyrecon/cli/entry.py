"""The program's entry point (``skyrecon``, ``python -m skyrecon``): light on purpose.

Loading the command modules takes most of a second (NumPy, Numba, OpenCV); an interruption in that
time must end like any other: one line, exit 130 (Ctrl-C) or 143 (SIGTERM), nothing written.
"""

from __future__ import annotations

import signal
import sys


class _TerminatedWhileStarting(BaseException):
    """SIGTERM before :func:`skyrecon.cli.main.main` installed its own handler."""


def _on_sigterm(signum, frame) -> None:
    raise _TerminatedWhileStarting()


def main() -> int:
    """Run the command line; returns the exit status."""
    try:
        signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:  # not the main thread
        pass
    try:
        from skyrecon.cli.main import main as run

        return run()
    except KeyboardInterrupt:
        print("error: interrupted while starting; nothing was written", file=sys.stderr)
        return 130
    except _TerminatedWhileStarting:
        print("error: terminated (SIGTERM) while starting; nothing was written", file=sys.stderr)
        return 143
