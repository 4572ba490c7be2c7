"""Running an ensemble on the surrogate: tidy outputs, results and manifest files."""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
from joblib import Parallel, delayed
from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                           TimeElapsedColumn, TimeRemainingColumn)

from bpsflow.config import Config, WeatherTarget, test_dates
from bpsflow.errors import BpsflowError
from bpsflow.surrogate.cell import build_cell
from bpsflow.surrogate.forcing import period_forcing
from bpsflow.simulation.idf import model_objects
from bpsflow.surrogate.network import build_network, simulate
from bpsflow.surrogate.outputs import (SUPPORTED_OUTPUTS, check_variables, face_probe,
                                       hourly_outputs, resolve_outputs, used_outputs)
from bpsflow.surrogate.params import field_values, sample_columns

#: Weather quantities the surrogate has no physics for.
WEATHER_IGNORED = {"wind_direction": "the exterior convection uses wind speed only"}

__all__ = ["SUPPORTED_OUTPUTS", "WEATHER_IGNORED", "simulate_instances", "simulate_tidy",
           "run_surrogate", "ignored_targets", "announce_ignored"]


class _Extra:
    """Fields read only for reporting (thermostat temperature)."""

    def __init__(self, values, wanted: bool):
        gt = "ROOMAIR:TEMPERATUREPATTERN:CONSTANTGRADIENT"
        patterns = values.idf.of_type(gt)
        if wanted and patterns:
            self.thermostat_offset = values.get(gt, patterns[0].name, "Thermostat Offset")
        else:
            self.thermostat_offset = np.zeros(values.n)


def simulate_instances(config: Config, samples: pd.DataFrame, run_dir: Path | None = None,
                       ) -> tuple[pd.DataFrame, list[str]]:
    """Tidy hourly outputs of ``samples`` (index = instance labels) and the ignored targets.

    Rows: instance, test, output, timestamp (hour-ending), value, for each
    test's whole window like :func:`bpsflow.runner.tidy_outputs`.
    """
    check_variables(config)
    samples = sample_columns(config, samples)
    labels = list(samples.index)
    values = field_values(config, model_objects(config.model), samples)
    cell = build_cell(config, values)
    requests = resolve_outputs(config, cell)
    extra = _Extra(values, _wants_thermostat(config))
    network = build_network(cell)
    tph = config.model.timesteps_per_hour
    integer = all(isinstance(label, (int, np.integer)) for label in labels)
    label_array = np.asarray(labels, dtype=np.int64 if integer else object)
    frames = []
    for period in config.model.periods:
        tests = config.tests_in(period.name)
        if not tests:
            continue
        forcing = period_forcing(config, cell, period, samples, run_dir)
        hours = forcing.days * 24
        wanted = [requests[o] for o in sorted({o for t in tests for o in t.outputs})]
        probe = face_probe(wanted, hours, tph)
        result = simulate(cell, network, forcing, probe=probe)
        hourly = hourly_outputs(wanted, cell, forcing, result, probe, extra.thermostat_offset)
        stamps = pd.Timestamp(forcing.first) + pd.to_timedelta(np.arange(1, hours + 1), unit="h")
        for test in tests:
            first, _, last = test_dates(test, config.model.year)
            begin = (first - forcing.first).days * 24
            end = ((last - forcing.first).days + 1) * 24
            for output in test.outputs:
                data = hourly[output][:, begin:end] * config.outputs[output].scale
                count = end - begin
                frames.append(pd.DataFrame({
                    "instance": np.repeat(label_array, count),
                    "test": test.name, "output": output,
                    "timestamp": np.tile(stamps[begin:end].to_numpy(), len(labels)),
                    "value": data.reshape(-1)}))
    tidy = pd.concat(frames, ignore_index=True)
    return tidy, ignored_targets(config, values)


def _wants_thermostat(config: Config) -> bool:
    return any(config.outputs[o].variable.strip().upper() == "ZONE THERMOSTAT AIR TEMPERATURE"
               for o in used_outputs(config))


def ignored_targets(config: Config, values=None) -> list[str]:
    """Targets of the config the surrogate has no physics for (labels with parameters)."""
    if values is None:
        samples = sample_columns(config, pd.DataFrame(index=pd.Index([0], name="instance")))
        values = field_values(config, model_objects(config.model), samples)
        build_cell(config, values)
        _Extra(values, _wants_thermostat(config))
    out = values.ignored()
    for p in config.parameters:
        for t in p.targets:
            if isinstance(t, WeatherTarget) and t.weather in WEATHER_IGNORED:
                out.append(f"weather {t.weather} ({p.name})")
    return out


def announce_ignored(ignored: list[str], announce) -> None:
    if ignored:
        announce(f"[yellow]surrogate: no physics for {len(ignored)} targeted field(s); these "
                 f"parameters do not change its outputs: {'; '.join(ignored)}[/yellow]")


def simulate_tidy(config: Config, samples_frame: pd.DataFrame) -> pd.DataFrame:
    """Tidy outputs of a few instances on the surrogate (e.g. the synthetic 'truth')."""
    from bpsflow.runner import console

    tidy, ignored = simulate_instances(config, samples_frame, config.run_dir)
    announce_ignored(ignored, console.print)
    return tidy


def _run_chunk(config: Config, chunk: pd.DataFrame, run_dir: Path, number: int):
    started = time.perf_counter()
    try:
        tidy, _ = simulate_instances(config, chunk, run_dir)
        error = ""
    except BpsflowError:
        raise
    except Exception as exc:  # recorded per instance, the run goes on
        tidy, error = None, f"{type(exc).__name__}: {exc}"
    return number, list(chunk.index), tidy, error, time.perf_counter() - started


def run_surrogate(config: Config, samples: pd.DataFrame, run_dir: Path,
                  show_progress: bool = True, jobs: int | None = None):
    """Run every instance of ``samples`` on the surrogate; write results and manifest.

    Instances are simulated in chunks (vectorised within a chunk) spread over
    ``jobs`` processes (default ``execution.jobs``, else the CPU count).
    """
    from bpsflow.runner import (MANIFEST_FILE, RESULT_COLUMNS, RESULTS_FILE, InstanceRecord,
                                RunSummary, console)

    started = time.perf_counter()
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    if "instance" in samples.columns:
        samples = samples.set_index("instance")
    announce_ignored(ignored_targets(config), console.print)
    jobs = jobs or config.execution.jobs or os.cpu_count() or 1
    total = len(samples)
    per_chunk = int(min(500, max(50, math.ceil(total / (2 * jobs)))))
    chunks = [samples.iloc[i:i + per_chunk] for i in range(0, total, per_chunk)]
    jobs = max(1, min(jobs, len(chunks)))
    console.print(f"running {total} instance(s) on the surrogate model with {jobs} job(s) "
                  f"({len(chunks)} chunk(s))")
    records: dict = {}
    frames: dict[int, pd.DataFrame] = {}
    failed = 0
    columns = [TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
               TextColumn("[red]{task.fields[failed]} failed"), TimeElapsedColumn(),
               TextColumn("ETA"), TimeRemainingColumn()]
    with Progress(*columns, console=console, disable=not show_progress or not total) as progress:
        task = progress.add_task("surrogate", total=total, failed=0)
        tasks = (delayed(_run_chunk)(config, chunk, run_dir, k) for k, chunk in enumerate(chunks))
        for k, labels, tidy, error, seconds in Parallel(n_jobs=jobs, batch_size=1,
                                                        return_as="generator_unordered")(tasks):
            per = seconds / max(len(labels), 1)
            bad = set()
            if tidy is not None:
                bad = set(tidy.loc[~np.isfinite(tidy["value"].to_numpy()), "instance"])
                frames[k] = tidy[~tidy["instance"].isin(bad)] if bad else tidy
            for label in labels:
                status_error = error or ("non-finite outputs" if label in bad else "")
                records[label] = InstanceRecord(
                    instance=int(label), status="failed" if status_error else "ok", seconds=per,
                    simulate_seconds=per, error=status_error, backend="surrogate")
                failed += bool(status_error)
            progress.update(task, advance=len(labels), failed=failed)
    results = pd.concat([frames[k] for k in sorted(frames)], ignore_index=True) if frames \
        else pd.DataFrame(columns=RESULT_COLUMNS)
    results = results[RESULT_COLUMNS]
    temporary = run_dir / (RESULTS_FILE + ".tmp")
    results.to_parquet(temporary, index=False)
    temporary.replace(run_dir / RESULTS_FILE)
    manifest = pd.DataFrame([r.__dict__ for r in records.values()],
                            columns=list(InstanceRecord.__dataclass_fields__))
    manifest = manifest.sort_values("instance").reset_index(drop=True)
    temporary = run_dir / (MANIFEST_FILE + ".tmp")
    manifest.to_parquet(temporary, index=False)
    temporary.replace(run_dir / MANIFEST_FILE)
    ok = total - failed
    return RunSummary(backend="surrogate", total=total, ran=total, skipped=0, ok=ok,
                      failed=failed, seconds=time.perf_counter() - started)
