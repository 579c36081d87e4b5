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
