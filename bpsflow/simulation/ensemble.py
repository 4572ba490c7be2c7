"""The one ensemble loop: every command that runs instances goes through it.

:func:`run_ensemble` runs the unfinished instances of a design in a run
directory on any :class:`~bpsflow.simulation.backend.Backend`:

- **resume** — an instance with a readable ``outputs.parquet`` is finished and
  skipped; a failed one runs again only with ``retry_failed``;
- **failure isolation** — a failed instance is recorded in the manifest with
  its error excerpt and never stops the others;
- **lock** — one process at a time per run directory;
- **progress** — a rich bar counting finished instances and failures;
- **executor** — tasks go to the engine ``execution.engine`` names (local
  processes or a Dask cluster, :mod:`bpsflow.simulation.executor`), a chunk of
  instances per task for a vectorised backend, one otherwise. The backend and
  the config go to each worker once; a worker that cannot see this machine's
  files gets the input files once (:mod:`bpsflow.simulation.staging`) and
  sends the outputs back, and this process writes them.

:func:`simulate_samples` is the in-memory form for callers that need outputs
of a batch now (fits, calibration designs): a vectorised backend simulates the
batch in this process; others run it through :func:`run_ensemble` in a fresh
directory.
"""

from __future__ import annotations

import contextlib
import math
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from bpsflow.design_record import (
    require_same_simulation,
    simulation_inputs,
    write_simulation_record,
)
from bpsflow.errors import BpsflowError
from bpsflow.progress import LoggedProgress
from bpsflow.simulation import rundir
from bpsflow.simulation.backend import Backend, Batch
from bpsflow.simulation.executor import Executor, executor_for
from bpsflow.simulation.rundir import InstanceRecord
from bpsflow.simulation.staging import StagedInputs, localised_config, stage_inputs

if TYPE_CHECKING:
    from bpsflow.config import Config

console = Console(stderr=True)


@dataclass
class RunSummary:
    """What :func:`run_ensemble` did."""

    backend: str
    total: int
    ran: int
    skipped: int
    ok: int
    failed: int
    seconds: float
    first_error: str = ""


def _chunks(labels: list[int], backend: Backend, jobs: int) -> list[list[int]]:
    if not backend.vectorised:
        return [[label] for label in labels]
    per_chunk = int(min(500, max(50, math.ceil(len(labels) / (2 * jobs)))))
    return [labels[i:i + per_chunk] for i in range(0, len(labels), per_chunk)]


def _warm_worker(backend: Backend, config: Config) -> None:
    """In a fresh worker: let the backend load what every instance reads (``warm``, optional)."""
    warm = getattr(backend, "warm", None)
    if warm is not None:
        try:
            warm(config)
        except Exception:  # noqa: S110 - a problem here shows again, reported, in the real task
            pass


def _failed_chunk(chunk: pd.DataFrame, backend_name: str, message: str,
                  seconds: float = 0.0) -> tuple[list[InstanceRecord], dict[int, pd.DataFrame]]:
    records = [InstanceRecord(instance=int(i), status="failed", seconds=seconds,
                              error=message, backend=backend_name) for i in chunk.index]
    return records, {}


def _run_chunk(backend: Backend, config: Config, staged: StagedInputs | None, prepared: object,
               chunk: pd.DataFrame, run_dir: Path, keep_inputs: bool
               ) -> tuple[list[InstanceRecord], dict[int, pd.DataFrame]]:
    """Simulate one chunk in a worker; write each finished instance's outputs there.

    With ``staged`` inputs (a worker without the shared filesystem) the chunk
    runs in the worker's scratch run directory and writes nothing of the run
    directory: the outputs go back to the caller, which writes them.
    """
    backend_name = backend.name
    started = time.perf_counter()
    try:
        if staged is not None:
            config = localised_config(config, staged)
            run_dir = config.run_dir
        if prepared is not None:
            backend.install(config, prepared)  # type: ignore[attr-defined]  # optional method
        batch = backend.simulate(config, chunk, run_dir, keep_inputs=keep_inputs)
    except Exception as exc:  # a chunk-wide failure is recorded per instance, the run goes on
        seconds = (time.perf_counter() - started) / max(len(chunk), 1)
        message = str(exc) if isinstance(exc, BpsflowError) else f"{type(exc).__name__}: {exc}"
        return _failed_chunk(chunk, backend_name, message, seconds)
    outputs: dict[int, pd.DataFrame] = {}
    by_instance = dict(tuple(batch.tidy.groupby("instance", sort=False))) if len(batch.tidy) \
        else {}
    for record in batch.records:
        record.backend = backend_name
        if record.status != "ok":
            continue
        frame = by_instance.get(record.instance)
        if frame is None or not len(frame):
            record.status, record.error = "failed", "the backend returned no outputs"
            continue
        if not np.isfinite(frame["value"].to_numpy(dtype=float)).all():
            record.status, record.error = "failed", "non-finite outputs"
            continue
        if staged is None:
            rundir.write_instance_outputs(run_dir, record.instance, frame)
        else:  # the worker's copy of a finished instance is of no use to anyone: it goes
            shutil.rmtree(rundir.instance_dir(run_dir, record.instance), ignore_errors=True)
        outputs[record.instance] = frame
    return batch.records, outputs


def run_ensemble(config: Config, samples: pd.DataFrame, backend: Backend, *,
                 jobs: int | None = None, retry_failed: bool = False, keep_inputs: bool = False,
                 show_progress: bool = True, executor: Executor | None = None,
                 label: str | None = None, announce: bool = True) -> RunSummary:
    """Run every unfinished instance of ``samples`` in ``config.run_dir``.

    Parameters
    ----------
    config : Config
    samples : DataFrame
        Indexed by instance (int), one column per parameter.
    backend : Backend
        From :func:`~bpsflow.simulation.backend.choose_backend`.
    jobs : int, optional
        Worker processes (default ``execution.jobs``, else the CPU count).
    retry_failed : bool
        Run instances recorded as failed again (finished ones are always skipped).
    keep_inputs : bool
        Keep each instance's input files (EnergyPlus: IDF, EPW, CSV).
    executor : Executor, optional
        Where tasks run (default: the engine of ``execution.engine``,
        :func:`~bpsflow.simulation.executor.executor_for`).
    label : str, optional
        The progress bar's label (default: the backend's name).
    announce : bool
        Print a line saying how many instances run (off for a command's inner batches).

    Returns
    -------
    RunSummary
    """
    started = time.perf_counter()
    run_dir = rundir.prepare_run_dir(config.run_dir.resolve())
    if "instance" in samples.columns:
        samples = samples.set_index("instance")
    samples.index = samples.index.astype(int)
    executor = executor or executor_for(config, jobs)
    warm = getattr(executor, "warm", None)  # the local pool starts while the model is checked
    if warm is not None and len(samples) > 1:
        warm(_warm_worker, backend, config)
    backend.check(config)
    check_samples = getattr(backend, "check_samples", None)  # optional (see Backend)
    if check_samples is not None:
        check_samples(config, samples)
    wanted = [int(i) for i in samples.index]
    with rundir.RunLock(run_dir):
        records = rundir.manifest_records(run_dir)
        finished = rundir.finished_instances(run_dir, wanted)
        # hashed once per batch: diagnose runs many batches, each file read once here
        inputs = simulation_inputs(config)
        if finished or records:
            require_same_simulation(config, run_dir, "run", backend.name, inputs)
        if any(i not in finished for i in wanted):
            write_simulation_record(config, run_dir, backend.name, inputs)
        failed_before = {i for i, r in records.items() if r.status == "failed"} - finished
        todo = [i for i in wanted if i not in finished
                and (retry_failed or i not in failed_before)]
        for i in finished:
            if i not in records or records[i].status != "ok":
                records[i] = InstanceRecord(instance=i, status="ok", seconds=0.0,
                                            backend=backend.name)
        chunks = _chunks(todo, backend, executor.jobs)
        if todo and announce:
            console.print(f"running {len(todo)} instance(s) on {backend.name} with "
                          f"{min(executor.jobs, len(chunks))} job(s); {len(finished)} finished "
                          f"before, {len(failed_before - set(todo))} failed before (not retried)")
        fresh: dict[int, pd.DataFrame] = {}
        failed = 0
        columns = [TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                   TextColumn("[red]{task.fields[failed]} failed"), TimeElapsedColumn(),
                   TextColumn("ETA"), TimeRemainingColumn()]
        try:
            with LoggedProgress(*columns, console=console,
                                disable=not show_progress or not todo) as progress:
                task = progress.add_task(label or backend.name, total=len(todo), failed=0)
                staged = None if executor.shared_filesystem else stage_inputs(config)
                prepare = getattr(backend, "prepare", None)  # optional (see Backend)
                prepared = prepare(config) if prepare is not None and todo else None
                tasks = ((samples.loc[chunk], run_dir, keep_inputs) for chunk in chunks)

                def lost(task: tuple, exc: BaseException) -> tuple:
                    return _failed_chunk(task[0], backend.name, f"the worker running it was "
                                         f"lost ({type(exc).__name__}: {exc})")

                since_write = 0
                completions = executor.map_unordered(
                    _run_chunk, tasks, shared=(backend, config, staged, prepared), on_error=lost)
                # closed at once when this loop is left (Ctrl-C): the executor stops its workers
                # then, not when the interpreter exits
                with contextlib.closing(completions):
                    for chunk_records, outputs in completions:
                        if staged is not None:
                            for instance, frame in outputs.items():
                                rundir.write_instance_outputs(run_dir, instance, frame)
                        fresh.update(outputs)
                        for record in chunk_records:
                            records[record.instance] = record
                            failed += record.status != "ok"
                        progress.update(task, advance=len(chunk_records), failed=failed)
                        since_write += len(chunk_records)
                        if since_write >= 50:
                            rundir.write_manifest(run_dir, records)
                            since_write = 0
        finally:
            rundir.write_manifest(run_dir, records)
            rundir.collect_results(run_dir, wanted, fresh)
    ok = sum(records[i].status == "ok" for i in wanted if i in records)
    first_error = next((records[i].error for i in wanted
                        if i in records and records[i].status != "ok" and records[i].error), "")
    return RunSummary(backend=backend.name, total=len(wanted), ran=len(todo),
                      skipped=len(wanted) - len(todo), ok=ok, failed=len(wanted) - ok,
                      seconds=time.perf_counter() - started, first_error=first_error)


def all_failed_message(summary: RunSummary, run_dir: Path, what: str = "instances") -> str:
    """``all N instances failed`` with the first error excerpt."""
    return (f"all {summary.total} {what} failed on {summary.backend}; the first error: "
            f"{summary.first_error or 'none recorded'} (every error: "
            f"{Path(run_dir) / rundir.MANIFEST_FILE})")


def run_config(config: Config, run_dir: Path, backend: str | None = None) -> Config:
    """A copy of ``config`` that runs in ``run_dir`` (with ``model.backend`` set if given)."""
    copy = config.model_copy(deep=True)
    copy.execution.run_dir = Path(run_dir)
    copy.source = config.source
    if backend is not None:
        copy.model.backend = backend  # type: ignore[assignment]  # a registered name
    return copy


class BatchFailure(BpsflowError):
    """Instances of an in-memory batch failed (:func:`simulate_samples`): a run, not the input."""


@dataclass
class BatchOutcome:
    """What :func:`simulate_batch` gives back: the outputs of the instances that ran, and the rest.

    ``tidy`` holds the rows (``RESULT_COLUMNS``) of the finished instances
    only; ``failed`` maps every other instance (the samples' index label) to
    its error excerpt.
    """

    tidy: pd.DataFrame
    failed: dict[int, str]


def refused_instances(config: Config, samples: pd.DataFrame, backend: Backend) -> dict[int, str]:
    """Instances whose values the backend refuses before running (``check_samples``), with why.

    The whole batch is checked at once; only when it is refused is every
    instance checked on its own, to name the ones at fault.
    """
    check_samples = getattr(backend, "check_samples", None)
    if check_samples is None or not len(samples):
        return {}
    try:
        check_samples(config, samples)
        return {}
    except BpsflowError:
        pass
    refused = {}
    for label in samples.index:
        try:
            check_samples(config, samples.loc[[label]])
        except BpsflowError as exc:
            refused[int(label)] = exc.message
    return refused


def simulate_samples(config: Config, samples: pd.DataFrame, workdir: Path, backend: Backend, *,
                     jobs: int | None = None, show_progress: bool = False, what: str = "runs",
                     sequences_dir: Path | None = None) -> pd.DataFrame:
    """Tidy outputs of ``samples`` now, on ``backend``, with scratch files under ``workdir``.

    :func:`simulate_batch` that refuses a partial batch.

    Raises
    ------
    BatchFailure
        When an instance failed (naming it and its error), so a fit never
        works on part of a batch.
    """
    outcome = simulate_batch(config, samples, workdir, backend, jobs=jobs,
                             show_progress=show_progress, sequences_dir=sequences_dir)
    if outcome.failed:
        instance, error = next(iter(outcome.failed.items()))
        raise BatchFailure(f"{len(outcome.failed)} of {len(samples)} {what} failed on "
                           f"{backend.name} in {workdir}: instance {instance}: {error}")
    return outcome.tidy


def simulate_batch(config: Config, samples: pd.DataFrame, workdir: Path, backend: Backend, *,
                   jobs: int | None = None, show_progress: bool = False,
                   sequences_dir: Path | None = None) -> BatchOutcome:
    """Outputs of ``samples`` now, on ``backend``; a failed instance is recorded, never raised.

    A vectorised backend simulates the whole batch in this process; another
    runs it through :func:`run_ensemble` in ``workdir`` (cleared first, in
    parallel, ``jobs``). The instances draw their boundary sequences from
    ``sequences_dir`` (default ``workdir``; drawn there when missing).
    Instances the backend refuses before running (a field value outside the
    IDD's bounds, :func:`refused_instances`) are failed without running, so
    one bad instance never stops the others.

    Returns
    -------
    BatchOutcome
        The finished instances' tidy outputs and ``failed``: instance -> error.
    """
    from bpsflow.boundary import SEQUENCES_FILE, ensure_sequences

    workdir = Path(workdir)
    sequences_dir = Path(sequences_dir or workdir)
    rundir.prepare_run_dir(sequences_dir)
    ensure_sequences(run_config(config, sequences_dir))
    if "instance" in samples.columns:
        samples = samples.set_index("instance")
    failed = refused_instances(run_config(config, sequences_dir), samples, backend)
    runnable = samples[~samples.index.isin(list(failed))]
    if not len(runnable):
        return BatchOutcome(pd.DataFrame(columns=rundir.RESULT_COLUMNS), failed)
    if backend.vectorised:
        batch: Batch = backend.simulate(run_config(config, sequences_dir), runnable,
                                        sequences_dir)
        failed.update({int(r.instance): r.error or "failed" for r in batch.records
                       if r.status != "ok"})
        return BatchOutcome(batch.tidy, failed)
    if workdir.exists() and workdir.resolve() != sequences_dir.resolve():
        shutil.rmtree(workdir)
    rundir.prepare_run_dir(workdir)
    if config.model.boundary is not None and workdir.resolve() != sequences_dir.resolve():
        shutil.copy2(sequences_dir / SEQUENCES_FILE, workdir / SEQUENCES_FILE)
    summary = run_ensemble(run_config(config, workdir), runnable, backend, jobs=jobs,
                           show_progress=show_progress, announce=show_progress)
    if summary.failed:
        records = rundir.manifest_records(workdir)
        failed.update({int(i): (records[int(i)].error if int(i) in records else "") or "failed"
                       for i in runnable.index
                       if int(i) not in records or records[int(i)].status != "ok"})
    tidy = rundir.read_results(workdir) if summary.ok else pd.DataFrame(
        columns=rundir.RESULT_COLUMNS)
    return BatchOutcome(tidy, failed)
