import functools

import pytest

from skyrecon.errors import InputError
from skyrecon.executor import ProcessExecutor, SerialExecutor, get_executor, register_executor


def square_plus(x: int, offset: int = 0) -> int:
    return x * x + offset


def fail_on_three(x: int) -> int:
    if x == 3:
        raise InputError(f"item {x} is bad")
    return x


@pytest.mark.parametrize("executor", [SerialExecutor(), ProcessExecutor(2, max_tasks_in_flight=2)])
def test_results_in_input_order(executor):
    assert executor.map(functools.partial(square_plus, offset=1), range(7)) == [x * x + 1 for x in range(7)]
    assert executor.map(square_plus, []) == []


@pytest.mark.parametrize("executor", [SerialExecutor(), ProcessExecutor(2)])
def test_worker_errors_surface(executor):
    with pytest.raises(InputError, match="item 3 is bad"):
        executor.map(fail_on_three, range(5))


def test_get_executor_and_registry(monkeypatch):
    assert isinstance(get_executor("serial"), SerialExecutor)
    monkeypatch.setenv("SKYRECON_EXECUTOR", "serial")
    assert isinstance(get_executor(), SerialExecutor)
    monkeypatch.setenv("SKYRECON_EXECUTOR", "process")
    monkeypatch.setenv("SKYRECON_WORKERS", "3")
    assert get_executor().workers == 3
    with pytest.raises(InputError, match="unknown executor"):
        get_executor("cluster")
    register_executor("cluster", lambda workers: SerialExecutor())
    assert isinstance(get_executor("cluster"), SerialExecutor)


def _slow_square(x: int) -> int:
    import time

    time.sleep(0.2)
    return x * x


def test_interruption_while_a_worker_starts_leaves_no_worker(monkeypatch):
    """Ctrl-C (or SIGTERM) landing after a worker's fork, before the pool records it: that worker
    is stopped too (else the interpreter's exit joins it for ever: a CI hang on mvs)."""
    import multiprocessing
    import time
    from concurrent.futures import process as cf_process

    spawned = []

    def spawn_then_interrupt(self):
        p = self._mp_context.Process(
            target=cf_process._process_worker,
            args=(
                self._call_queue,
                self._result_queue,
                self._initializer,
                self._initargs,
                self._max_tasks_per_child,
            ),
        )
        p.start()
        spawned.append(p)
        time.sleep(1.5)  # the worker is up and waits on the pool's queue
        if len(spawned) == 1:  # the first worker is started, and the signal arrives
            raise KeyboardInterrupt
        self._processes[p.pid] = p

    monkeypatch.setattr(cf_process.ProcessPoolExecutor, "_spawn_process", spawn_then_interrupt)
    before = set(multiprocessing.active_children())
    with pytest.raises(KeyboardInterrupt):
        ProcessExecutor(workers=2).map(_slow_square, range(8))
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and any(p.is_alive() for p in spawned):
        time.sleep(0.05)
    assert len(spawned) == 1
    assert not any(p.is_alive() for p in spawned)
    assert set(multiprocessing.active_children()) <= before


def test_a_worker_exits_once_orphaned():
    from skyrecon.executor import exit_when_orphaned

    parents = iter([100, 100, 100, 1])
    exits = []
    exit_when_orphaned(
        poll_s=0.0, parent_pid=lambda: next(parents), exit_now=exits.append, sleep=lambda s: None
    )
    assert exits == [1]
