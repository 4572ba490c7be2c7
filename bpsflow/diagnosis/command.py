"""The glue behind ``bpsflow diagnose``: backend, progress bar, files and the console summary."""

from __future__ import annotations

from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from bpsflow.config import Config
from bpsflow.diagnosis.report import write_diagnosis
from bpsflow.diagnosis.workflow import Diagnosis, diagnose, settings_of


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

    console = console or Console()
    wanted = settings_of(config).output
    data = read_measured(measured_path, config,
                         required=[wanted] if wanted in config.outputs else None,
                         reference=plausibility_reference(config.run_dir.resolve()),
                         allow_implausible=allow_implausible)
    for note in data.notes:
        console.print(f"[yellow]{note}[/yellow]", highlight=False)
    measured = data.frame
    if backend is not None:
        config = config.model_copy(deep=True, update={})
        config.model.backend = backend
    chosen = choose_backend(config, console.print).name
    out = Path(out) if out is not None else config.run_dir / "diagnosis"
    settings = settings_of(config)
    # base fit, signatures or one fit per candidate extension per round: an estimate the bar extends
    expected = 1 + len(settings.extensions)
    with Progress(TextColumn("[bold]diagnose[/bold] {task.description}"), BarColumn(),
                  MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn(),
                  console=console, disable=not show_progress, transient=False) as progress:
        task = progress.add_task("fits", total=expected)

        def step(label: str) -> None:
            done = progress.tasks[task].completed + 1
            progress.update(task, completed=done, description=label,
                            total=max(progress.tasks[task].total or 0, done + 1))

        result = diagnose(config, measured, out, backend=chosen, jobs=jobs, settings=settings,
                          announce=lambda text: console.print(text, highlight=False),
                          step=step)
        progress.update(task, total=progress.tasks[task].completed)
    paths = write_diagnosis(result, out)
    console.print(summary_table(result))
    console.print(f"[bold]verdict: {result.verdict}[/bold] — {result.cause.get('summary', '')}",
                  highlight=False)
    for note in result.notes:
        console.print(f"[yellow]note: {note}[/yellow]", highlight=False)
    console.print(f"wrote {paths['json']}, {paths['markdown']} and figures in {out / 'figures'}",
                  highlight=False)
    return result


def summary_table(result: Diagnosis) -> Table:
    """Held-out scores of the base model and of each candidate extension."""
    table = Table(title=f"diagnosis of {result.output}: held-out block (never fitted)")
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
