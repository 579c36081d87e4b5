"""Shared command-line plumbing: a parser that reports errors in one line, and small helpers."""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from skyrecon.errors import InputError
from skyrecon.io.atomic import sweep_stale_temps

if TYPE_CHECKING:
    from skyrecon.executor import Executor
    from skyrecon.record import Recorder

#: ``--executor`` choices (see :mod:`skyrecon.executor`).
EXECUTORS = ("serial", "process", "dask")


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


def add_camera_noise_option(parser: argparse.ArgumentParser, writes: str = "") -> None:
    """``--camera-noise SIGMA``: steady sensor noise of the simulated cameras
    (``MissionConfig.camera_noise``), for ``skyrecon demo`` and the mission benchmarks
    (``writes``: what a benchmark then writes, added to the help)."""
    parser.add_argument(
        "--camera-noise",
        type=float,
        default=0.0,
        metavar="SIGMA",
        help="steady sensor noise of both cameras, grey levels (standard deviation; default 0: the "
        "renderer's noise-free images; real cameras have about 1-2)" + (f"; {writes}" if writes else ""),
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


def add_executor_options(parser: argparse.ArgumentParser, workers_help: str) -> None:
    """``--workers N``, ``--executor serial|process|dask`` and ``--scheduler ADDRESS`` for a
    command that fans work out (see :func:`open_executor`)."""
    parser.add_argument("--workers", type=positive_int, default=None, help=workers_help)
    parser.add_argument(
        "--executor",
        choices=EXECUTORS,
        default=None,
        help="where the fanned-out work runs: serial (this process), process (local worker processes; "
        "the default, or $SKYRECON_EXECUTOR), dask (a Dask cluster: --scheduler, else a local one "
        "of --workers processes; needs the 'dask' extra). Same inputs and seed: the same outputs",
    )
    parser.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        default=None,
        help="with --executor dask: join the running Dask scheduler at ADDRESS (tcp://host:8786; "
        "default $SKYRECON_SCHEDULER, else start a local cluster); the workspace must be on a "
        "filesystem the workers share",
    )


@contextmanager
def open_executor(args: argparse.Namespace) -> Iterator[Executor]:
    """The executor of ``--executor``/``--workers``/``--scheduler``, closed when the block ends
    (also on errors and Ctrl-C: a local Dask cluster is shut down).

    ``--scheduler`` without ``--executor`` means dask. A local process executor with one worker
    is the serial one (same results, no process to start).

    Raises:
        InputError: ``--scheduler`` with another executor, Dask not installed, or an
            unreachable scheduler (one line naming the address).
    """
    from skyrecon.executor import get_executor

    kind = getattr(args, "executor", None)
    scheduler = getattr(args, "scheduler", None)
    workers = getattr(args, "workers", None)
    if scheduler and kind not in (None, "dask"):
        raise UsageError(f"--scheduler needs --executor dask (got --executor {kind})")
    if scheduler:
        kind = "dask"
    kind = kind or os.environ.get("SKYRECON_EXECUTOR") or "process"
    if kind == "dask":
        from skyrecon.executor_dask import DaskExecutor

        executor: Executor = DaskExecutor(workers, scheduler)
    elif kind == "process" and workers == 1:
        executor = get_executor("serial")
    else:
        executor = get_executor(kind, workers)
    try:
        yield executor
    finally:
        close = getattr(executor, "close", None)
        if close is not None:
            close()


def describe_executor(executor: Executor) -> str:
    """``2 workers``, ``dask, 4 workers at tcp://...`` or ``dask, 2 local workers`` for a summary line."""
    n = int(getattr(executor, "workers", 1) or 1)
    count = f"{n} worker{'s' if n != 1 else ''}"
    if type(executor).__name__ != "DaskExecutor":
        return count
    where = getattr(executor, "scheduler", None)
    return f"dask, {count} at {where}" if where else f"dask, {n} local worker{'s' if n != 1 else ''}"
