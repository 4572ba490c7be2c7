"""Where the ensemble loop's tasks run: the one place that starts worker processes.

An executor maps a function over tasks and yields results as they complete,
in any order. :class:`LocalExecutor` uses joblib's process pool on this
machine. The ensemble loop takes any object with the same ``map_unordered``
method, so another engine (e.g. a Dask cluster) plugs in here without
touching the loop.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from typing import Any, Protocol

from bpsflow.simulation.parentdeath import run_in_worker


class Executor(Protocol):
    jobs: int

    def map_unordered(self, function: Callable[..., Any],
                      tasks: Iterable[tuple[Any, ...]]) -> Iterator[Any]:
        """``function(*task)`` for every task, yielded as each completes."""
        ...


class LocalExecutor:
    """joblib worker processes on this machine (one process: run in this one).

    Workers die with this process on Linux (``PR_SET_PDEATHSIG``).

    Parameters
    ----------
    jobs : int, optional
        Worker processes (default: the CPU count).
    """

    def __init__(self, jobs: int | None = None):
        self.jobs = max(1, int(jobs or os.cpu_count() or 1))

    def map_unordered(self, function: Callable[..., Any],
                      tasks: Iterable[tuple[Any, ...]]) -> Iterator[Any]:
        tasks = list(tasks)
        if self.jobs == 1 or len(tasks) <= 1:
            for task in tasks:
                yield function(*task)
            return
        from joblib import Parallel, delayed

        parent = os.getpid()
        # Each worker dies with this process (Linux): a killed run leaves no orphan writing
        # into its run directory (see bpsflow.simulation.parentdeath).
        yield from Parallel(n_jobs=min(self.jobs, len(tasks)), batch_size=1,
                            return_as="generator_unordered")(
            delayed(run_in_worker)(parent, function, *task) for task in tasks)


def local_executor(jobs: int | None = None) -> LocalExecutor:
    """The default executor: ``jobs`` local processes."""
    return LocalExecutor(jobs)
