"""The worker plugin of :mod:`skyrecon.executor_dask`'s local clusters (imports Dask: import it only
once Dask is known to be installed)."""

from __future__ import annotations

import logging
import signal
from typing import Any

from distributed import WorkerPlugin

__all__ = ["QuietWorker"]


class QuietWorker(WorkerPlugin):
    """Set up on every worker of a local cluster, restarted ones included (on the worker's main
    thread). Ctrl-C reaches the whole process group, but only the command handles it (it cancels
    the tasks and closes the cluster), so the workers print no tracebacks of their own; nor do they
    log what the client reports anyway (a task's exception, a lost worker, the scheduler gone at
    the end)."""

    name = "skyrecon-quiet-worker"

    def setup(self, worker: Any) -> None:
        logging.getLogger("distributed").setLevel(logging.CRITICAL)
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        except ValueError:  # not the main thread: leave it
            pass
