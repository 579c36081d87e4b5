"""Shared command-line plumbing: a parser that reports errors in one line, and small helpers."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from skyrecon.errors import InputError
from skyrecon.io.atomic import sweep_stale_temps

if TYPE_CHECKING:
    from skyrecon.record import Recorder


class UsageError(InputError):
    """A command-line usage mistake (bad option or value)."""


class OneLineParser(argparse.ArgumentParser):
    """argparse parser whose errors raise :class:`UsageError` instead of printing usage and exiting."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise UsageError(f"{message} (see '{self.prog} --help')")


class ExampleFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the examples in the epilog as written."""


def add_global_options(parser: argparse.ArgumentParser, suppress_defaults: bool = False) -> None:
    """``--debug`` and ``--quiet``, accepted before or after the command name."""
    default: Any = argparse.SUPPRESS if suppress_defaults else False
    parser.add_argument(
        "--debug", action="store_true", default=default, help="show full tracebacks on errors"
    )
    parser.add_argument("--quiet", action="store_true", default=default, help="no progress bars or summaries")


def add_command(subparsers, name: str, help: str, description: str, examples: str) -> argparse.ArgumentParser:
    """A subcommand parser with an ``Examples:`` epilog and the global options."""
    parser = subparsers.add_parser(
        name,
        help=help,
        description=description,
        epilog="Examples:\n" + examples,
        formatter_class=ExampleFormatter,
    )
    add_global_options(parser, suppress_defaults=True)
    return parser


def output_dir(path: str | Path) -> Path:
    """Create the ``--out`` directory if missing; refuse a path that is a file. Temporaries that
    an earlier, killed run left in it are removed (:func:`skyrecon.io.atomic.sweep_stale_temps`)."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError("--out must be a directory, but a file of that name exists", p)
    p.mkdir(parents=True, exist_ok=True)
    sweep_stale_temps(p)
    return p


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text}")
    return value


def info(message: str) -> None:
    """A line of progress or summary for the person watching (stderr, so stdout stays clean)."""
    print(message, file=sys.stderr, flush=True)


@contextmanager
def stage(name: str, timings: dict[str, float] | None = None) -> Iterator[None]:
    """Time a stage; record its seconds in ``timings`` under ``name``."""
    t0 = time.perf_counter()
    yield
    if timings is not None:
        timings[name] = time.perf_counter() - t0


def add_cloud_format(parser: argparse.ArgumentParser) -> None:
    """``--format ply|las|laz`` for the point clouds a command writes (see :mod:`skyrecon.io.las`)."""
    parser.add_argument(
        "--format",
        choices=("ply", "las", "laz"),
        default="ply",
        help="point cloud files: PLY (default), LAS or LAZ (metres, 1 mm; LAS/LAZ need the 'geo' extra)",
    )


def add_record_option(parser: argparse.ArgumentParser) -> None:
    """``--record FILE``: log the run on a timeline for a viewer (see :mod:`skyrecon.record`)."""
    parser.add_argument(
        "--record",
        metavar="FILE",
        type=record_path,
        help="log the run on a timeline for a viewer: FILE.rrd for Rerun ('rerun' extra), FILE.mcap "
        "for Foxglove / Lichtblick ('foxglove' extra); chosen by the extension",
    )


def record_path(text: str) -> str:
    """A ``--record`` value: a file name ending in ``.rrd`` or ``.mcap``."""
    from skyrecon.record import check_record_path

    try:
        check_record_path(text)
    except InputError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


@contextmanager
def recording(args: argparse.Namespace) -> Iterator[Recorder]:
    """The recorder of ``args.record`` (a :class:`~skyrecon.record.NullRecorder` without one),
    closed (the file moved into place) when the block ends, removed on an error."""
    from skyrecon.record import open_recorder

    path = getattr(args, "record", None)
    with open_recorder(path) as recorder:
        yield recorder
    if path is not None and not getattr(args, "quiet", False):
        size = Path(path).stat().st_size
        info(f"wrote recording {path} ({size / 1e6:.1f} MB; open with {_viewer(path)})")


def _viewer(path: str | Path) -> str:
    return f"'rerun {path}'" if str(path).lower().endswith(".rrd") else "Foxglove or Lichtblick"
