"""Entry point of the ``skyrecon`` command.

Exit status: 0 on success, 2 on bad input or a full disk (one ``error: ...`` line on stderr),
1 on an internal error, 130 when interrupted (Ctrl-C, SIGINT), 143 when terminated (SIGTERM).
``--debug`` shows tracebacks. An interrupted command leaves its finished outputs complete and
the rest unwritten (see :mod:`skyrecon.io.atomic`).
"""

from __future__ import annotations

import errno
import importlib
import signal
import sys
import traceback
from collections.abc import Sequence

from skyrecon import __version__
from skyrecon.cli.common import ExampleFormatter, OneLineParser, add_global_options
from skyrecon.errors import EstimationError, InputError, SkyreconError
from skyrecon.jit import install_compile_notice
from skyrecon.progress import set_progress_enabled

# Command modules, in the order --help lists them. Each has add_parser(subparsers) and run(args) -> int.
COMMANDS = [
    "render",
    "stereo",
    "two-view",
    "sfm",
    "align",
    "mvs",
    "map",
    "odometry",
    "survey",
    "plan",
    "eval",
    "view",
    "demo",
    "warmup",
]

EXAMPLES = """Examples:
  skyrecon render stereo --out scene/        # a synthetic stereo pair with ground truth
  skyrecon render sequence --frames 30 --out flight/
  skyrecon <command> --help                  # options and examples of one command
"""


def build_parser() -> OneLineParser:
    parser = OneLineParser(
        prog="skyrecon",
        description="3D understanding of cities from drone cameras.",
        epilog=EXAMPLES,
        formatter_class=ExampleFormatter,
    )
    parser.add_argument("--version", action="version", version=f"skyrecon {__version__}")
    add_global_options(parser)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineParser)
    for name in COMMANDS:
        importlib.import_module(f"skyrecon.cli.{name.replace('-', '_')}").add_parser(sub)
    return parser


class Terminated(BaseException):
    """Raised in the main thread on SIGTERM, so that the same clean-up as Ctrl-C runs."""


def _on_sigterm(signum, frame) -> None:
    raise Terminated()


def install_sigterm() -> object:
    """Turn SIGTERM into :class:`Terminated` (main thread only), so that ``kill PID`` runs the same
    clean-up as Ctrl-C (a process pool's workers stopped, partial outputs removed); returns the
    previous handler. The command line installs it; scripts that run pools (the benchmarks)
    call it first thing."""
    try:
        return signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:  # not the main thread (e.g. called from a worker thread): leave it
        return None


#: warnings filter handed to the processes multiprocessing starts (see :func:`quiet_resource_tracker`)
RESOURCE_TRACKER_FILTER = "ignore:resource_tracker:UserWarning"


def quiet_resource_tracker() -> None:
    """Keep multiprocessing's resource tracker from warning about a worker pool's semaphores.

    The tracker is a separate process that shares our stderr. When an interruption (Ctrl-C,
    SIGTERM) stops a worker pool, the pool's semaphores may still be alive when the program
    exits; the tracker then removes them itself, but first prints a two-line ``UserWarning``
    ("There appear to be N leaked semaphore objects"), after the one-line interruption message.
    The processes multiprocessing starts take their warnings filters from ``sys.warnoptions``
    (``subprocess._args_from_interpreter_flags``), so the filter must be there before the first
    pool; it changes nothing in this process.
    """
    if RESOURCE_TRACKER_FILTER not in sys.warnoptions:
        sys.warnoptions.append(RESOURCE_TRACKER_FILTER)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status (also used by ``python -m skyrecon``)."""
    in_process = argv is not None  # called from Python (tests, scripts), not as the program
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    quiet_resource_tracker()
    previous = install_sigterm()
    try:
        return _main(argv, debug)
    finally:
        if previous is not None:
            # as the program, the work is done: a SIGTERM or Ctrl-C while the interpreter exits
            # (joining the pool's threads, flushing) changes nothing, and must not kill it silently
            # with status -2 after its outputs are complete
            signal.signal(signal.SIGTERM, previous if in_process else signal.SIG_IGN)  # type: ignore[arg-type]
            if not in_process:
                signal.signal(signal.SIGINT, signal.SIG_IGN)


def _main(argv: list[str], debug: bool) -> int:
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if args.command is None:
            parser.print_help()
            return 0
        if args.quiet:
            set_progress_enabled(False)
        install_compile_notice(enabled=not args.quiet)
        module = importlib.import_module(f"skyrecon.cli.{args.command.replace('-', '_')}")
        return int(module.run(args) or 0)
    except (InputError, EstimationError) as exc:
        if debug:
            traceback.print_exc()
        print(f"error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except SkyreconError as exc:
        if debug:
            traceback.print_exc()
        print(f"error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, Terminated) as exc:
        return _interrupted(exc)
    except OSError as exc:
        if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
            return _internal_error(exc, debug)
        if debug:
            traceback.print_exc()
        where = f" while writing {exc.filename}" if exc.filename else ""
        print(
            f"error: the disk is full{where}; free some space or choose another --out, then run the "
            "command again (no partial file was left under an output's name)",
            file=sys.stderr,
        )
        return 2
    except MemoryError:
        if debug:
            traceback.print_exc()
        print("error: out of memory; use smaller images or fewer views at a time", file=sys.stderr)
        return 1
    except Exception as exc:  # an internal bug: say so, in one line unless --debug
        interrupted = _interruption(exc)
        if interrupted is not None:  # e.g. Numba's SystemError around a Ctrl-C that hit a kernel
            return _interrupted(interrupted)
        return _internal_error(exc, debug)


def _interruption(exc: BaseException) -> BaseException | None:
    """The Ctrl-C or SIGTERM behind ``exc`` (its cause or context chain), if any."""
    seen = set()
    cur: BaseException | None = exc
    while cur is not None and id(cur) not in seen:
        if isinstance(cur, (KeyboardInterrupt, Terminated)):
            return cur
        seen.add(id(cur))
        cur = cur.__cause__ or cur.__context__
    return None


def _interrupted(exc: BaseException) -> int:
    """One line, and the exit status of an interruption: 130 (Ctrl-C) or 143 (SIGTERM)."""
    what, code = ("terminated (SIGTERM)", 143) if isinstance(exc, Terminated) else ("interrupted", 130)
    print(f"error: {what}; outputs already written are complete, the rest were not written", file=sys.stderr)
    return code


def _internal_error(exc: BaseException, debug: bool) -> int:
    if debug:
        traceback.print_exc()
    print(
        f"internal error: {type(exc).__name__}: {_one_line(exc)} "
        "(this is a bug in skyrecon; rerun with --debug and report the traceback)",
        file=sys.stderr,
    )
    return 1


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


if __name__ == "__main__":
    sys.exit(main())
