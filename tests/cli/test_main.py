"""The command line's contract: help, version, one-line errors with exit status 2."""

import subprocess
import sys

import pytest

from skyrecon import __version__
from skyrecon.cli.main import COMMANDS, main


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "skyrecon", *args], capture_output=True, text=True, timeout=300
    )


def test_help_and_version(capsys):
    assert main([]) == 0
    assert "Examples:" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert __version__ in capsys.readouterr().out


def test_every_command_has_help_with_an_example(capsys):
    for name in COMMANDS:
        with pytest.raises(SystemExit) as exc:
            main([name, "--help"])
        assert exc.value.code == 0
        out = capsys.readouterr().out
        assert "Examples:" in out and f"skyrecon {name} " in out.split("Examples:")[1]


def test_usage_errors_are_one_line_exit_2():
    result = run_cli("render", "stereo", "--out", "x", "--width", "abc")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and "--width" in lines[0]
    result = run_cli("no-such-command")
    assert result.returncode == 2 and result.stderr.strip().startswith("error:")


def test_out_is_a_file(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["render", "stereo", "--out", str(f)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(f) in err[0] and "directory" in err[0]


@pytest.mark.parametrize(
    "raised, code, says",
    [
        (KeyboardInterrupt(), 130, "interrupted"),
        ("numba", 130, "interrupted"),  # Ctrl-C inside a compiled kernel surfaces as a SystemError
        ("sigterm", 143, "terminated"),
    ],
)
def test_interruptions_are_one_line_with_their_exit_status(monkeypatch, capsys, raised, code, says):
    from skyrecon.cli import main as main_module
    from skyrecon.cli import warmup

    def run(args):
        if raised == "numba":
            try:
                raise KeyboardInterrupt()
            except KeyboardInterrupt as e:
                raise SystemError("<numba function> returned a result with an exception set") from e
        if raised == "sigterm":
            raise main_module.Terminated()
        raise raised

    monkeypatch.setattr(warmup, "run", run)
    assert main(["warmup"]) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and says in err[0]


def test_sigterm_stops_a_command_with_143(tmp_path):
    import signal
    import time

    proc = subprocess.Popen(
        [sys.executable, "-c", "import time, sys; from skyrecon.cli import main as m; "
         "m.importlib.import_module('skyrecon.cli.warmup').run = "
         "lambda a: (print('ready', file=sys.stderr, flush=True), time.sleep(30)); sys.exit(m.main(['warmup']))"],
        stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    # wait until the command runs (its handlers are installed), however slow the start on a busy machine
    assert proc.stderr is not None and proc.stderr.readline().strip() == "ready"
    time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 143 and "terminated" in err


def test_the_resource_tracker_stays_quiet_after_an_interrupted_pool():
    """An interruption that stops a worker pool can leave its semaphores to multiprocessing's
    resource tracker, which shares stderr: with the command line's filter it cleans them up
    without the two-line warning that would follow the one-line interruption message."""
    leak = (
        "import os, multiprocessing as mp\n"
        "from skyrecon.cli.main import quiet_resource_tracker\n"
        "{setup}"
        "q = mp.get_context('forkserver').Queue()\n"
        "from multiprocessing import resource_tracker\n"
        "resource_tracker.register('/skyrecon_test_leak', 'semaphore')\n"
        "os._exit(0)\n"  # exit with the semaphores alive, as a stopped pool can
    )
    loud = subprocess.run(
        [sys.executable, "-c", leak.format(setup="")], capture_output=True, text=True, timeout=60
    )
    assert "leaked semaphore" in loud.stderr  # what users saw now and then
    quiet = subprocess.run(
        [sys.executable, "-c", leak.format(setup="quiet_resource_tracker()\n")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert quiet.stderr.strip() == ""
