"""Where the ensemble loop's tasks run: the one place that starts worker processes.

An executor maps a function over tasks and yields results as they complete,
in any order. Two engines implement it (``execution.engine``):

- :class:`LocalExecutor` (``local``) — joblib's process pool on this machine;
- :class:`DaskExecutor` (``dask``) — a Dask distributed cluster: a scheduler
  at ``execution.scheduler``, or a cluster bpsflow starts from
  ``execution.cluster`` (a ``LocalCluster``, or SLURM/PBS jobs through
  dask-jobqueue).

Objects every task needs (the backend, the config, staged input files) are
passed as ``shared``: the Dask engine sends them to each worker once, not
once per task. A task that dies with its worker is rescheduled by Dask; one
that still fails is handed to ``on_error``, so it is recorded like any other
failed instance and never stops the others. Leaving the iteration early
(Ctrl-C) cancels what has not run.

:func:`executor_for` picks the engine a config asks for; nothing else in
bpsflow spawns workers.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import os
from collections.abc import Callable, Iterable, Iterator
from typing import TYPE_CHECKING, Any, Protocol

from rich.console import Console

from bpsflow.errors import BpsflowError
from bpsflow.simulation.parentdeath import run_in_worker

if TYPE_CHECKING:
    from bpsflow.config import Config, DaskCluster, Execution

console = Console(stderr=True)

#: ``on_error(task, exception) -> result``: what a task that could not complete yields.
ErrorHandler = Callable[[tuple[Any, ...], BaseException], Any]


class Executor(Protocol):
    #: Tasks that run at once (the chunk size of a vectorised backend follows it).
    jobs: int
    #: Whether workers see this machine's files (else inputs are staged, outputs returned).
    shared_filesystem: bool

    def map_unordered(self, function: Callable[..., Any], tasks: Iterable[tuple[Any, ...]], *,
                      shared: tuple[Any, ...] = (), on_error: ErrorHandler | None = None
                      ) -> Iterator[Any]:
        """``function(*shared, *task)`` for every task, yielded as each completes."""
        ...


class LocalExecutor:
    """joblib worker processes on this machine (one process: run in this one).

    Workers die with this process on Linux (``PR_SET_PDEATHSIG``).

    Parameters
    ----------
    jobs : int, optional
        Worker processes (default: the CPU count).
    """

    shared_filesystem = True

    def __init__(self, jobs: int | None = None):
        self.jobs = max(1, int(jobs or os.cpu_count() or 1))

    def map_unordered(self, function: Callable[..., Any], tasks: Iterable[tuple[Any, ...]], *,
                      shared: tuple[Any, ...] = (), on_error: ErrorHandler | None = None
                      ) -> Iterator[Any]:
        tasks = list(tasks)
        if self.jobs == 1 or len(tasks) <= 1:
            for task in tasks:
                yield function(*shared, *task)
            return
        from joblib import Parallel, delayed

        parent = os.getpid()
        # Each worker dies with this process (Linux): a killed run leaves no orphan writing
        # into its run directory (see bpsflow.simulation.parentdeath).
        yield from Parallel(n_jobs=min(self.jobs, len(tasks)), batch_size=1,
                            return_as="generator_unordered")(
            delayed(run_in_worker)(parent, function, *shared, *task) for task in tasks)


class DaskExecutor:
    """Tasks on a Dask distributed cluster, through one ``distributed.Client``.

    Parameters
    ----------
    client : distributed.Client
        Connected to the scheduler.
    jobs : int
        Tasks that run at once (the cluster's worker threads, or what was asked for).
    shared_filesystem : bool
        ``execution.shared_filesystem``.
    """

    def __init__(self, client: Any, jobs: int, shared_filesystem: bool = True):
        self.client = client
        self.jobs = max(1, int(jobs))
        self.shared_filesystem = shared_filesystem

    def map_unordered(self, function: Callable[..., Any], tasks: Iterable[tuple[Any, ...]], *,
                      shared: tuple[Any, ...] = (), on_error: ErrorHandler | None = None
                      ) -> Iterator[Any]:
        from distributed import as_completed

        tasks = list(tasks)
        if not tasks:
            return
        # One copy of the shared objects on every worker, referenced by each task.
        shared_futures = self.client.scatter(list(shared), broadcast=True, hash=False) \
            if shared else []
        futures = {self.client.submit(function, *shared_futures, *task, pure=False): task
                   for task in tasks}
        try:
            for future in as_completed(list(futures), loop=self.client.loop):
                task = futures.pop(future)
                if future.status == "finished":
                    yield future.result()
                    continue
                try:
                    future.result()
                except Exception as exc:  # KilledWorker, or an error raised on the worker
                    if on_error is None:
                        raise
                    yield on_error(task, exc)
        finally:
            if futures:  # left early (Ctrl-C, an error): nothing more runs for this call
                with contextlib.suppress(Exception):
                    self.client.cancel(list(futures), force=True)
            with contextlib.suppress(Exception):
                self.client.cancel(shared_futures)


def local_executor(jobs: int | None = None) -> LocalExecutor:
    """The default executor: ``jobs`` local processes."""
    return LocalExecutor(jobs)


_DASK: dict[str, DaskExecutor] = {}


def _cluster_key(execution: Execution, jobs: int | None) -> str:
    return execution.scheduler or f"{execution.cluster.model_dump_json()}/{jobs}"


def batch_cluster(spec: DaskCluster) -> Any:
    """The dask-jobqueue cluster (SLURM or PBS) of ``spec``, before any job is submitted."""
    import dask_jobqueue

    kind = dask_jobqueue.SLURMCluster if spec.jobqueue == "slurm" else dask_jobqueue.PBSCluster
    return kind(cores=spec.cores, processes=spec.cores, memory=spec.memory,
                walltime=spec.walltime, queue=spec.queue,
                job_extra_directives=list(spec.job_directives))


def _start_cluster(execution: Execution, jobs: int | None) -> Any:
    spec = execution.cluster
    if spec.jobqueue is None:
        from distributed import LocalCluster

        workers = spec.workers or jobs or execution.jobs or os.cpu_count() or 1
        # One single-threaded process per worker: an EnergyPlus run or a surrogate chunk
        # fills one core, and a process keeps the workers' Python work apart.
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                            dashboard_address=":0", silence_logs=logging.ERROR)
    cluster = batch_cluster(spec)
    cluster.scale(jobs=spec.workers or 1)
    return cluster


def dask_executor(config: Config, jobs: int | None = None) -> DaskExecutor:
    """The Dask executor of ``config.execution`` (one client per process, reused by every batch).

    Connects to ``execution.scheduler`` within ``execution.connect_timeout_s``,
    or starts the cluster ``execution.cluster`` describes and prints its
    dashboard address.

    Raises
    ------
    BpsflowError
        When the scheduler cannot be reached, or the cluster cannot start.
    """
    execution = config.execution
    key = _cluster_key(execution, jobs)
    if key in _DASK:
        cached = _DASK[key]
        cached.shared_filesystem = execution.shared_filesystem
        return cached
    from distributed import Client

    timeout = f"{execution.connect_timeout_s}s"
    if execution.scheduler is not None:
        try:
            client = Client(execution.scheduler, timeout=timeout, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise BpsflowError(
                f"execution.scheduler: cannot reach a Dask scheduler at {execution.scheduler} "
                f"within {execution.connect_timeout_s:g} s ({type(exc).__name__}: {exc}); check "
                f"the address and that the scheduler runs, or use engine 'local'",
                source=config.source) from None
        threads = sum(client.nthreads().values())
        if not threads:
            client.close()
            raise BpsflowError(f"execution.scheduler: the Dask scheduler at "
                               f"{execution.scheduler} has no workers", source=config.source)
        console.print(f"dask: connected to {execution.scheduler} ({threads} worker thread(s)); "
                      f"dashboard {client.dashboard_link}", highlight=False)
        atexit.register(_close, client, None)
        executor = DaskExecutor(client, threads, execution.shared_filesystem)
    else:
        try:
            cluster = _start_cluster(execution, jobs)
            client = Client(cluster, timeout=timeout, set_as_default=False)
        except (OSError, TimeoutError, ValueError, RuntimeError) as exc:
            raise BpsflowError(f"execution.cluster: could not start the Dask {execution.cluster.kind} "
                               f"cluster ({type(exc).__name__}: {exc})",
                               source=config.source) from None
        spec = execution.cluster
        if spec.jobqueue is not None:
            try:
                client.wait_for_workers(1, timeout=spec.start_timeout_s)
            except (OSError, TimeoutError) as exc:
                _close(client, cluster)
                raise BpsflowError(
                    f"execution.cluster: no {spec.kind} worker joined within "
                    f"{spec.start_timeout_s:g} s ({type(exc).__name__}); are the batch jobs "
                    f"queued or refused? (execution.cluster.start_timeout_s waits longer)",
                    source=config.source) from None
        planned = (spec.workers or jobs or execution.jobs or os.cpu_count() or 1) * \
            (spec.cores if spec.jobqueue is not None else 1)
        console.print(f"dask: started a {spec.kind} cluster ({planned} worker thread(s)); "
                      f"dashboard {client.dashboard_link}", highlight=False)
        atexit.register(_close, client, cluster)
        executor = DaskExecutor(client, planned, execution.shared_filesystem)
    _DASK[key] = executor
    return executor


def _close(client: Any, cluster: Any) -> None:
    with contextlib.suppress(Exception):
        client.close(timeout=5)
    if cluster is not None:
        with contextlib.suppress(Exception):
            cluster.close(timeout=5)


def close_dask() -> None:
    """Close every Dask client (and cluster) this process opened."""
    for executor in list(_DASK.values()):
        cluster = getattr(executor.client, "cluster", None)
        _close(executor.client, cluster)
    _DASK.clear()


def executor_for(config: Config, jobs: int | None = None) -> Executor:
    """The executor ``config.execution.engine`` names (``jobs`` overrides ``execution.jobs``)."""
    if config.execution.engine == "dask":
        return dask_executor(config, jobs)
    return local_executor(jobs or config.execution.jobs)
