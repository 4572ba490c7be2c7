"""Where the ensemble loop's tasks run: the one place that starts worker processes.

An executor maps a function over tasks and yields results as they complete,
in any order. Two engines implement it (``execution.engine``):

- :class:`LocalExecutor` (``local``) — loky's (joblib's) process pool on this machine;
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
import hashlib
import logging
import os
import pickle
import signal
import tempfile
from collections.abc import Callable, Generator, Iterable
from pathlib import Path
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
                      ) -> Generator[Any, None, None]:
        """``function(*shared, *task)`` for every task, yielded as each completes."""
        ...


_SHARED: dict[str, tuple[Any, ...]] = {}


def _with_shared(function: Callable[..., Any], key: str, shared: bytes, stop: str,
                 *task: Any) -> Any:
    """In a local worker: ``function(*shared, *task)``, the shared objects unpickled once per key.

    Nothing runs once the ``stop`` file exists (the caller left early: a task
    already queued to a worker must not start).
    """
    if os.path.exists(stop):
        return None
    if key not in _SHARED:
        _SHARED.clear()
        _SHARED[key] = pickle.loads(shared)
    return function(*_SHARED[key], *task)


class _InterruptSeen:
    """Ctrl-C, remembered: the KeyboardInterrupt a signal raises is lost when it lands in a
    finalizer (a Dask future's ``__del__`` on the main thread prints it and goes on), so the
    outcome loop also checks this flag and raises it again at the next completed task."""

    seen = False

    @classmethod
    def handler(cls, signum: int, frame: Any) -> None:
        cls.seen = True
        raise KeyboardInterrupt

    @classmethod
    @contextlib.contextmanager
    def watching(cls) -> Generator[None, None, None]:
        import threading

        if threading.current_thread() is not threading.main_thread() \
                or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
            yield
            return
        cls.seen = False
        signal.signal(signal.SIGINT, cls.handler)
        try:
            yield
        finally:
            signal.signal(signal.SIGINT, signal.default_int_handler)

    @classmethod
    def raise_if_seen(cls) -> None:
        if cls.seen:
            raise KeyboardInterrupt


def _outcomes(completed: Iterable[Any], futures: dict[Any, tuple[Any, ...]],
              on_error: ErrorHandler | None) -> Generator[Any, None, None]:
    """Each completed future's result, or ``on_error(task, exception)`` for one that failed (a
    worker that died: loky's TerminatedWorkerError, Dask's KilledWorker); the future leaves
    ``futures`` as it completes, so what is left there never ran to the end."""
    with _InterruptSeen.watching():
        for future in completed:
            _InterruptSeen.raise_if_seen()
            task = futures.pop(future)
            try:
                result = future.result()
            except Exception as exc:
                if on_error is None:
                    raise
                result = on_error(task, exc)
            yield result
        _InterruptSeen.raise_if_seen()


def _remove_stale_stops(stop: Path) -> None:
    """Remove ``stop`` (an earlier batch of this process left early) and the stop marks of
    processes that have ended (a mark lives until its process exits)."""
    stop.unlink(missing_ok=True)
    for mark in stop.parent.glob("bpsflow-stop-*-*"):
        try:
            os.kill(int(mark.name.split("-")[2]), 0)
        except ProcessLookupError:
            mark.unlink(missing_ok=True)
        except (ValueError, OSError):
            continue


def _end_workers(pool: Any) -> None:
    """Kill a loky pool's workers (their EnergyPlus runs die with them, PR_SET_PDEATHSIG).

    Loky's own ``shutdown(kill_workers=True)`` races its manager thread when
    futures are pending (KeyError, InvalidStateError on stderr); killed
    workers are a case it handles: the pool is marked broken and the next
    batch gets a new one.
    """
    for process in list(getattr(pool, "_processes", {}).values()):
        with contextlib.suppress(Exception):
            process.kill()


def leave_interrupt_to_parent() -> None:
    """In a worker: ignore SIGINT. A terminal's Ctrl-C reaches the whole process group; the
    command handles it (cancels, keeps the run resumable, ends the workers and, through
    ``PR_SET_PDEATHSIG``, their EnergyPlus runs), a worker would only print a traceback."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _warm(parent_pid: int, warm: Callable[..., Any] | None, args: tuple[Any, ...]) -> int:
    run_in_worker(parent_pid, lambda: None)
    if warm is not None:
        warm(*args)
    return os.getpid()


class LocalExecutor:
    """Worker processes on this machine (loky's reusable pool; one job: run in this process).

    Workers die with this process on Linux (``PR_SET_PDEATHSIG``). The pool
    outlives one batch (a command that runs many batches starts its workers
    once). :meth:`warm` starts them ahead of the first batch, so that their
    start-up overlaps the caller's own (checking the model).

    Parameters
    ----------
    jobs : int, optional
        Worker processes (default: the CPU count).
    """

    shared_filesystem = True

    def __init__(self, jobs: int | None = None):
        self.jobs = max(1, int(jobs or os.cpu_count() or 1))

    def _pool(self) -> Any:
        from joblib.externals.loky import get_reusable_executor

        return get_reusable_executor(max_workers=self.jobs, timeout=300,
                                     initializer=leave_interrupt_to_parent)

    def warm(self, function: Callable[..., Any] | None = None, *args: Any) -> None:
        """Start the workers now; each runs ``function(*args)`` (e.g. loading inputs) once."""
        if self.jobs == 1:
            return
        pool = self._pool()
        for _ in range(self.jobs):
            pool.submit(_warm, os.getpid(), function, args)

    def map_unordered(self, function: Callable[..., Any], tasks: Iterable[tuple[Any, ...]], *,
                      shared: tuple[Any, ...] = (), on_error: ErrorHandler | None = None
                      ) -> Generator[Any, None, None]:
        from concurrent.futures import as_completed

        tasks = list(tasks)
        if self.jobs == 1 or len(tasks) <= 1:
            for task in tasks:
                yield function(*shared, *task)
            return
        # The shared objects are pickled once here, and unpickled once per worker.
        payload = pickle.dumps(shared, protocol=pickle.HIGHEST_PROTOCOL)
        key = hashlib.sha256(payload).hexdigest()
        parent = os.getpid()
        pool = self._pool()
        stop = Path(tempfile.gettempdir()) / f"bpsflow-stop-{parent}-{key[:16]}"
        _remove_stale_stops(stop)
        futures = {pool.submit(run_in_worker, parent, _with_shared, function, key, payload,
                               str(stop), *task): task for task in tasks}
        try:
            yield from _outcomes(as_completed(futures), futures, on_error)
        finally:
            if futures:  # left early (Ctrl-C, an error): the workers end, nothing more runs
                for future in futures:
                    future.cancel()
                with contextlib.suppress(OSError):
                    stop.touch()  # what loky had queued to a worker returns at once
                _end_workers(pool)


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
        self._warming: list[Any] = []

    def warm(self, function: Callable[..., Any] | None = None, *args: Any) -> None:
        """Have every worker run ``function(*args)`` (e.g. loading inputs) now, without waiting."""
        if function is None:
            return
        with contextlib.suppress(Exception):
            self._warming = [self.client.submit(function, *args, workers=[address], pure=False,
                                                allow_other_workers=False)
                             for address in self.client.scheduler_info()["workers"]]

    def map_unordered(self, function: Callable[..., Any], tasks: Iterable[tuple[Any, ...]], *,
                      shared: tuple[Any, ...] = (), on_error: ErrorHandler | None = None
                      ) -> Generator[Any, None, None]:
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
            yield from _outcomes(as_completed(list(futures), loop=self.client.loop), futures,
                                 on_error)
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

#: Dask settings of a LocalCluster bpsflow starts (its workers are given them too):
#: no statistical profiler, no work stealing (tasks are queued on the scheduler and
#: handed out as workers free up), slower event-loop and system-monitor ticks.
LOCAL_CLUSTER_SETTINGS = {
    "distributed.worker.profile.enabled": False,
    "distributed.scheduler.work-stealing": False,
    "distributed.admin.tick.interval": "500ms",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.admin.system-monitor.gil.enabled": False,
}


def _cluster_key(execution: Execution) -> str:
    """One client per scheduler or cluster spec: every batch of a command shares the cluster
    its first batch started (a later ``jobs`` does not start another)."""
    return execution.scheduler or execution.cluster.model_dump_json()


def _planned_workers(execution: Execution, jobs: int | None) -> int:
    """Workers (local processes or batch jobs) of a cluster bpsflow starts."""
    return execution.cluster.workers or jobs or execution.jobs or os.cpu_count() or 1


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
        import dask
        from distributed import LocalCluster

        workers = _planned_workers(execution, jobs)
        # One single-threaded process per worker: an EnergyPlus run or a surrogate chunk
        # fills one core, and a process keeps the workers' Python work apart. The cluster
        # shares this machine's cores with the simulations, so its housekeeping runs less
        # often: idle, it took 6 % of a core at Dask's defaults, half that with these.
        with dask.config.set(LOCAL_CLUSTER_SETTINGS):
            return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                dashboard_address=":0", silence_logs=logging.ERROR,
                                preload=["bpsflow.simulation.dask_worker"])
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
    key = _cluster_key(execution)
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
        planned = _planned_workers(execution, jobs) * \
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
