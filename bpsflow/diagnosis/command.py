"""The glue behind ``bpsflow diagnose``: backend, progress bar, files and the console summary."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from bpsflow.config import Config
from bpsflow.diagnosis.report import REPORT_FILES, write_diagnosis
from bpsflow.diagnosis.workflow import Diagnosis, check_settings, choose_output, diagnose, settings_of
from bpsflow.errors import BpsflowError
from bpsflow.progress import LoggedProgress
from bpsflow.simulation.rundir import move_aside


def run_diagnose(config: Config, measured_path: Path, out: Path | None = None, *,
                 backend: str | None = None, jobs: int | None = None,
                 show_progress: bool = True, console: Console | None = None,
                 allow_implausible: bool = False) -> Diagnosis:
    """Diagnose ``config`` against ``measured_path``; write everything under ``out``.

    ``out`` defaults to ``RUN_DIR/diagnosis``. The measured file is read and
    checked (:mod:`bpsflow.measured`) before anything runs or is written;
    ``allow_implausible`` accepts values outside their plausible range.
    Returns the :class:`Diagnosis`.
    """
    from bpsflow.measured import plausibility_reference, read_measured
    from bpsflow.simulation.backend import choose_backend
    from bpsflow.simulation.rundir import prepare_run_dir

    console = console or Console()
    settings = settings_of(config)
    # the config's own contradictions first: they are no fault of the measured file
    check_settings(config, settings)
    if backend is not None:
        config = config.model_copy(deep=True, update={})
        config.model.backend = backend
    out = Path(out) if out is not None else config.run_dir / "diagnosis"
    prepare_run_dir(out, where="--out")
    wanted = settings.output
    reference = plausibility_reference(config.run_dir.resolve())
    chosen = choose_backend(config, console.print).name
    if reference is None:
        reference = nominal_reference(config, chosen)
    data = read_measured(measured_path, config,
                         required=[wanted] if wanted in config.outputs else None,
                         reference=reference, allow_implausible=allow_implausible)
    for note in data.notes:
        console.print(f"[yellow]{note}[/yellow]", highlight=False)
    measured = data.frame
    output = choose_output(config, measured, settings)
    check_span(config, measured, output, measured_path)
    check_varies(config, measured, output, measured_path)
    # base fit, signatures or one fit per candidate extension per round: an estimate the bar extends
    expected = 1 + len(settings.extensions)
    with LoggedProgress(TextColumn("[bold]diagnose[/bold] {task.description}"), BarColumn(),
                        MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn(),
                        console=console, disable=not show_progress, transient=False,
                        name="diagnose") as progress:
        task = progress.add_task("fits", total=expected)

        def step(label: str) -> None:
            done = progress.tasks[task].completed + 1
            progress.update(task, completed=done, description=label,
                            total=max(progress.tasks[task].total or 0, done + 1))

        result = diagnose(config, measured, out, backend=chosen, jobs=jobs, settings=settings,
                          announce=lambda text: console.print(text, highlight=False),
                          step=step)
        progress.update(task, total=progress.tasks[task].completed)
    # after the work, so that a diagnosis that fails leaves the earlier one where it was
    earlier = move_aside(out, REPORT_FILES) if (out / REPORT_FILES[0]).is_file() else None
    if earlier is not None:
        console.print(f"the earlier diagnosis in {out} was moved to {earlier}", highlight=False)
    paths = write_diagnosis(result, out)
    console.print(summary_table(result))
    console.print(f"[bold]verdict: {result.verdict}[/bold] — {result.cause.get('summary', '')}",
                  highlight=False)
    for note in result.notes:
        console.print(f"[yellow]note: {note}[/yellow]", highlight=False)
    figures = sum(1 for path in paths.values() if path.suffix == ".png")
    console.print(f"wrote {paths['json']}, {paths['markdown']} and {figures} figure(s) in "
                  f"{out / 'figures'}", highlight=False)
    return result


def nominal_reference(config: Config, backend: str) -> pd.DataFrame | None:
    """Tidy outputs of one run at the inputs' nominal values: the plausibility reference.

    Without an ensemble in the run directory, the measured file's scale and
    sign are judged against this run (a kW column read as W is 1000 times off
    it); None when the run fails, and the fits then meet the problem.
    """
    from bpsflow.calibration.design import nominal_sample
    from bpsflow.simulation.backend import get_backend
    from bpsflow.simulation.ensemble import simulate_batch

    samples = pd.DataFrame([nominal_sample(config)], index=pd.Index([0], name="instance"))
    # scratch only: a measured file refused after this run leaves nothing behind
    with tempfile.TemporaryDirectory(prefix="bpsflow-reference-") as workdir:
        outcome = simulate_batch(config, samples, Path(workdir), get_backend(backend))
    return None if outcome.failed or not len(outcome.tidy) else outcome.tidy


def check_span(config: Config, measured: pd.DataFrame, output: str, source: Path) -> None:
    """Refuse data that do not reach both ends of every test reporting ``output``.

    Gaps inside a test are allowed (their hours are left out of the fits);
    data that stop early would move the held-out block (the last days) onto
    days that are not the test's last.
    """
    from bpsflow.alignment import evaluation_hours

    present = measured.index[measured[output].notna().to_numpy()]
    for test in config.model.tests:
        if output not in test.outputs:
            continue
        hours = evaluation_hours(test, config.model.year)
        if present.empty or present.min() > hours[0] or present.max() < hours[-1]:
            covered = f"{present.min()} .. {present.max()}" if len(present) else "no hour"
            raise BpsflowError(f"column '{output}': test {test.name} is evaluated over "
                               f"{hours[0]} .. {hours[-1]} (hour-ending) but the measured data "
                               f"cover {covered}; expected values from its first to its last "
                               f"evaluated hour (gaps between are allowed)", source=source)


def check_varies(config: Config, measured: pd.DataFrame, output: str, source: Path) -> None:
    """Refuse a measured output that never changes where evaluated: its residual holds no evidence."""
    from bpsflow.alignment import output_evaluation_hours

    values = measured[output].reindex(output_evaluation_hours(config, output)).to_numpy(
        dtype=float)
    values = values[np.isfinite(values)]
    if values.size and np.ptp(values) == 0:
        raise BpsflowError(f"column '{output}': every value of the evaluated hours is {values[0]:g}; expected a "
                           f"measured output that varies (a diagnosis reads the structure of "
                           f"its residual). Choose another with diagnosis.output",
                           source=source)


def summary_table(result: Diagnosis) -> Table:
    """Held-out scores of the base model and of each candidate extension."""
    table = Table(title=escape(f"diagnosis of {result.output}: held-out block (never fitted)"))
    for column in ("model", "fitted", "CV(RMSE)", "nMCRPS", "NMBE", "accepted"):
        table.add_column(column, justify="left" if column in ("model", "fitted") else "right")
    held = result.scorecard["heldout"]
    table.add_row("base (calibrated)", "", f"{held['cvrmse']:.2%}", f"{held['nmcrps']:.2%}",
                  f"{held['nmbe']:+.2%}", "")
    for e in result.extensions:
        after = e["heldout"]["after"]
        table.add_row(f"+ {e.get('cause', e['name'])} (round {e['round']})",
                      ", ".join(f"{k} = {v:.4g}" for k, v in e["fitted"].items()),
                      f"{after['cvrmse']:.2%}", f"{after['nmcrps']:.2%}",
                      f"{after['nmbe']:+.2%}", "yes" if e.get("accepted") else "no")
    if result.verdict == "parameter" and result.parameter_fit:
        held = result.final_scores["heldout"]
        fit = result.parameter_fit
        table.add_row(f"{fit['name']} refitted", f"{fit['nominal']:.4g} -> {fit['fitted']:.4g}",
                      f"{held['cvrmse']:.2%}", f"{held['nmcrps']:.2%}", f"{held['nmbe']:+.2%}",
                      "yes")
    return table
