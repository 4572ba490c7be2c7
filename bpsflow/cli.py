"""The ``bpsflow`` command line: a thin typer layer over the package's functions.

Every command takes the YAML config first. Errors in user input print one
paragraph naming the file and key, and exit with status 2; no traceback.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import os
import signal
import sys
import threading
from contextlib import ExitStack
from pathlib import Path

import typer
import yaml
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from bpsflow.errors import BpsflowError

app = typer.Typer(add_completion=False, no_args_is_help=True, rich_markup_mode=None,
                  help="Building performance simulation under uncertainty.")
console = Console()
err_console = Console(stderr=True)

ConfigArg = typer.Argument(..., help="The YAML config.", show_default=False)


def _friendly(func):
    """Turn BpsflowError (and Ctrl-C) into a clear message and a non-zero exit."""
    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            with ExitStack() as stack:
                token = _held.set(stack)
                try:
                    return func(*args, **kwargs)
                finally:
                    _held.reset(token)
        except (typer.Exit, typer.Abort, typer.BadParameter):
            raise
        except BpsflowError as exc:
            # escape: messages quote the user's text and ranges like [low, high], which rich
            # would otherwise read as markup and drop
            err_console.print(f"[bold red]error:[/bold red] {escape(str(exc))}", highlight=False,
                              soft_wrap=True)
            raise typer.Exit(code=2) from None
        except KeyboardInterrupt:
            err_console.print("[yellow]interrupted: finished instances are kept; run the same "
                              "command again to resume[/yellow]")
            raise typer.Exit(code=130) from None
        except OSError as exc:
            # A file the user named (or the run directory) cannot be read or written:
            # say which and why, as for any other bad input.
            where = exc.filename if exc.filename is not None else "a file"
            err_console.print(f"[bold red]error:[/bold red] {escape(f'{where}: {exc.strerror or exc}')}",
                              highlight=False, soft_wrap=True)
            raise typer.Exit(code=2) from None
        except Exception as exc:
            if os.environ.get("BPSFLOW_DEBUG"):
                raise
            # A defect of bpsflow, not of the input: no traceback on the user's screen,
            # but enough to report it, and the way to see the traceback.
            err_console.print(f"[bold red]internal error:[/bold red] "
                              f"{escape(f'{type(exc).__name__}: {exc}')} "
                              f"(a bpsflow defect; set BPSFLOW_DEBUG=1 for the traceback and "
                              f"please report it)", highlight=False, soft_wrap=True)
            raise typer.Exit(code=1) from None
    return wrapper


def _load(config: Path, run_dir: Path | None,
          options: dict[str, tuple[str, object]] | None = None):
    """Load and validate ``config``; ``options`` maps a key path to (option, value given).

    Options that override config keys go through the schema like the file's
    keys (:func:`bpsflow.config.with_overrides`), so a bad value is refused,
    naming the option and the bound, before anything is written or deleted.
    """
    from bpsflow.config import load_config, with_overrides

    overrides = {"execution": {"run_dir": str(run_dir.resolve())}} if run_dir else None
    cfg = load_config(config, overrides)
    if options:
        cfg = with_overrides(cfg, {key: value for key, (_, value) in options.items()},
                             {key: option for key, (option, _) in options.items()})
    return cfg


#: The resources a command holds until it ends (its run directory's lock), released by
#: :func:`_friendly` however the command ends.
_held: contextvars.ContextVar[ExitStack | None] = contextvars.ContextVar("held", default=None)


def _lock_folder(folder: Path) -> None:
    """Lock a folder other than the run directory (created if needed) until the command ends."""
    from bpsflow.simulation.rundir import RunLock, prepare_run_dir

    stack = _held.get()
    if stack is None:
        raise RuntimeError("_lock_folder is for CLI commands wrapped by _friendly")
    stack.enter_context(RunLock(prepare_run_dir(folder, where="--out")))


def _lock(cfg) -> Path:
    """Create the run directory if needed and lock it until the command ends.

    Every command that writes into a run directory calls this before it
    writes anything: a second command on the same directory refuses, naming
    this one's process and command line; the ensemble loop inside takes the
    same lock again (nested). Returns the resolved run directory.
    """
    from bpsflow.simulation.rundir import RunLock, prepare_run_dir

    rd = prepare_run_dir(cfg.run_dir.resolve())
    stack = _held.get()
    if stack is None:  # called outside a command (a library caller): nothing to release into
        raise RuntimeError("_lock is for CLI commands wrapped by _friendly")
    stack.enter_context(RunLock(rd))
    return rd


def _write_resolved(cfg) -> None:
    from bpsflow.files import write_text_atomic
    from bpsflow.simulation.rundir import prepare_run_dir

    run_dir = prepare_run_dir(cfg.run_dir.resolve())
    write_text_atomic(run_dir / "config.resolved.yaml",
                      yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False))


def _run_dir_text(value: str) -> Path:
    """``--run-dir``'s value: a blank one is refused (as a path it would mean the current
    folder, and the command would write its run there)."""
    if not value.strip():
        raise typer.BadParameter(f"expected a folder, got {value!r}")
    return Path(value)


RunDirOption = typer.Option(None, "--run-dir", parser=_run_dir_text,
                            help="Override execution.run_dir.")
BackendOption = typer.Option(None, help="Override model.backend.")
JobsOption = typer.Option(None, "--jobs", "-j", help="Parallel processes for the simulations.")
EngineOption = typer.Option(None, "--engine", help="Override execution.engine: local (processes "
                                                   "on this machine) or dask.")
SchedulerOption = typer.Option(None, "--scheduler", help="Override execution.scheduler: a Dask "
                                                         "scheduler address (selects --engine dask).")

# Every command takes it, so that a script can pass one flag to all of them; those that
# show no progress bar accept it and do nothing more.
NoProgressOption = typer.Option(False, "--no-progress", help="No progress bars.")
AllowImplausibleOption = typer.Option(
    False, "--allow-implausible", help="Accept measured values far outside their plausible "
                                       "range (a note instead of an error).")


def _execution(jobs: int | None, engine: str | None = None,
               scheduler: str | None = None) -> dict[str, tuple[str, object]]:
    """The ``execution`` keys the simulation commands' options override."""
    if scheduler is not None and engine is None:
        engine = "dask"
    return {"execution.jobs": ("--jobs", jobs), "execution.engine": ("--engine", engine),
            "execution.scheduler": ("--scheduler", scheduler)}


def _read_measured(path: Path, cfg, *, required=None, reference=None,
                   allow_implausible: bool = False):
    """The measured file read and checked (bpsflow.measured), its notes printed."""
    from bpsflow.measured import read_measured

    data = read_measured(path, cfg, required=required, reference=reference,
                         allow_implausible=allow_implausible)
    for note in data.notes:
        console.print(f"[yellow]{escape(note)}[/yellow]", highlight=False, soft_wrap=True)
    return data


def _test_outputs(cfg) -> list[str]:
    """Every output some test reports, in the config's order."""
    return list(dict.fromkeys(o for t in cfg.model.tests for o in t.outputs))


#: What a run directory holds for one design: moved aside together by ``sample --force``.
_DESIGN_FILES = ("instances", "manifest.parquet", "results.parquet", "samples.parquet",
                 "design_unit.parquet", "boundary_sequences.npz", "design.json", "simulation.json",
                 "config.resolved.yaml", "figures", "validation.json", "validation.csv")
#: Files that mean instances of the design have run.
_RUN_FILES = ("instances", "manifest.parquet", "results.parquet")


@app.command()
@_friendly
def sample(config: Path = ConfigArg, run_dir: Path | None = RunDirOption,
           samples: int | None = typer.Option(None, help="Override design.samples."),
           seed: int | None = typer.Option(None, help="Override design.seed."),
           force: bool = typer.Option(False, help="Draw a new design in a run directory that "
                                                  "holds results of another one; the old "
                                                  "results are moved to RUN_DIR/previous/."),
           no_progress: bool = NoProgressOption) -> None:
    """Draw the design (LHS or Morris) and write samples.parquet."""
    cfg = _load(config, run_dir, {"design.samples": ("--samples", samples),
                                  "design.seed": ("--seed", seed)})
    from bpsflow.design_record import design_changes
    from bpsflow.simulation.model_inputs import check_model_inputs
    from bpsflow.simulation.rundir import move_aside

    check_model_inputs(cfg)  # refuse bad model inputs before anything is moved
    drawn = _draw(cfg)  # every option is checked and the design drawn before anything moves
    rd = _lock(cfg)
    overrides = {key: value for key, value in (("design.samples", samples),
                                               ("design.seed", seed)) if value is not None}
    changes = design_changes(cfg, rd, frozenset(overrides))
    ran = [name for name in _RUN_FILES if (rd / name).exists()]
    if changes == [] and not force:
        from bpsflow.design_record import recorded_overrides

        earlier = {k: v for k, v in recorded_overrides(rd).items() if k not in overrides}
        console.print(f"the design in {rd} is the config's already: kept samples.parquet"
                      + (" and the instances run from it" if ran else "")
                      + (" (drawn with " + ", ".join(f"{k} {v}" for k, v in earlier.items())
                         + " from the command line; --force draws the config's own)"
                         if earlier else ""))
        return
    if ran and not force:
        what = "; ".join(changes[:3]) if changes else "a design with no record"
        raise BpsflowError(f"{rd} already holds results of another design ({what}); a new "
                           f"design would mix with them. Use another --run-dir, or --force "
                           f"to move them to {rd / 'previous'}/<timestamp> and draw the "
                           f"new design")
    moved = move_aside(rd, _DESIGN_FILES) if ran else None
    path = _write_drawn(cfg, drawn, overrides)
    console.print(f"wrote {path} ({cfg.design.method}, {len(cfg.parameters)} parameters)")
    if moved is not None:
        console.print(f"the previous design and its results are in {moved}")


def _draw(cfg):
    """The design and the boundary sequences (or None) of ``cfg``, in memory."""
    from bpsflow.boundary import draw_sequences, period_hours
    from bpsflow.sampling import sample as draw
    from bpsflow.simulation.target_bounds import check_sample_values

    design = draw(cfg)
    check_sample_values(cfg, design.values, "the drawn design")
    sequences = (draw_sequences(cfg.model.boundary, period_hours(cfg))
                 if cfg.model.boundary is not None else None)
    return design, sequences


def _write_drawn(cfg, drawn, overrides: dict | None = None) -> Path:
    """Write a drawn design, its boundary sequences, its record and the resolved config.

    ``overrides``: the design keys the command line set (recorded in ``design.json``)."""
    from bpsflow.boundary import SEQUENCES_FILE, write_sequences
    from bpsflow.design_record import write_design_record
    from bpsflow.sampling import write_design

    design, sequences = drawn
    run_dir = cfg.run_dir.resolve()
    path = write_design(design, run_dir)
    if sequences is not None:
        write_sequences(sequences, run_dir)
    else:
        (run_dir / SEQUENCES_FILE).unlink(missing_ok=True)
    write_design_record(cfg, run_dir, overrides)
    _write_resolved(cfg)
    return path


def _sample(cfg) -> Path:
    """Draw and write the design of ``cfg`` (its model inputs already checked by the caller)."""
    return _write_drawn(cfg, _draw(cfg))


@app.command()
@_friendly
def keys(section: str = typer.Argument("", help="only the keys under this one, e.g. diagnosis")
         ) -> None:
    """Every config key with its type and default, read from the schema configs are checked against."""
    from bpsflow.config import Config
    from bpsflow.schema import config_keys

    every = config_keys(Config)
    rows = [row for row in every if not section or row[0] == section
            or row[0].startswith((f"{section}.", f"{section}[", f"{section}("))]
    if not rows:
        sections = sorted({key.split(".")[0].split("[")[0] for key, _, _ in every})
        raise BpsflowError(f"keys: no config key '{section}'; expected a key such as "
                           f"{', '.join(sections)} (or diagnosis.holdout_days, ...)")
    table = Table(title=escape(f"config keys{f' under {section}' if section else ''} (list "
                               f"items key[], named entries key.<name>)"))
    table.add_column("key", no_wrap=True)
    for column in ("type", "default"):
        table.add_column(column, overflow="fold")
    for key, kind, default in rows:
        table.add_row(escape(key), escape(kind), escape(default))
    console.print(table)


@app.command()
@_friendly
def check(config: Path = ConfigArg,
          backend: str | None = BackendOption,
          run: bool = typer.Option(True, "--run/--no-run",
                                   help="On EnergyPlus, also run the model once at its nominal "
                                        "values over two days (catches what only the engine "
                                        "sees, e.g. a broken object reference)."),
          no_progress: bool = NoProgressOption) -> None:
    """Validate the config, every IDF target and the thermostats against the model.

    On EnergyPlus the nominal model then runs once over two days of the first test
    (--no-run skips it); nothing is written to the run directory.
    """
    from bpsflow.distributions import truncation_notes
    from bpsflow.simulation.backend import choose_backend
    from bpsflow.simulation.target_bounds import inert_targets

    cfg = _load(config, None)
    _set_backend(cfg, backend)
    chosen = choose_backend(cfg, err_console.print)
    report = chosen.check(cfg)
    if cfg.diagnosis is not None:
        # what diagnose would refuse before reading data: output, parameters, zones
        from bpsflow.diagnosis.workflow import check_settings as check_diagnosis_settings

        check_diagnosis_settings(cfg, cfg.diagnosis)
    if cfg.calibration is not None:
        # what calibrate would refuse before its design runs: outputs, parameters, hold-out
        from bpsflow.calibration import workflow as calibration_workflow
        from bpsflow.calibration.design import calibration_parameters

        settings = cfg.calibration
        calibration_parameters(cfg, settings)
        scenarios = [(settings.scenario(calibration_workflow.default_outputs(cfg)),
                      "calibration")]
        scenarios += [(s, f"calibration.scenarios ({s.name})") for s in settings.scenarios]
        for scenario, where in scenarios:
            calibration_workflow.check_scenario(cfg, scenario, where)
            calibration_workflow.check_holdout(cfg, settings, scenario)
    report.notes.extend(inert_targets(cfg))
    report.notes.extend(truncation_notes(cfg.parameters))
    used = {test.period for test in cfg.model.tests}
    report.notes.extend(f"model.periods: '{p.name}' is the period of no test; every instance "
                        f"simulates it, and nothing reads its results" for p in cfg.model.periods
                        if p.name not in used)
    if report.controlled_zones:
        from bpsflow.simulation.idf import model_objects
        from bpsflow.simulation.setpoints import sizing_note

        sizing = sizing_note(cfg, model_objects(cfg.model))
        if sizing:
            report.notes.append(sizing)
    trial_run = getattr(chosen, "trial_run", None)
    if run and trial_run is not None:
        seconds = trial_run(cfg)
        report.notes.append(f"the nominal model ran in EnergyPlus over two days of the first "
                            f"test ({seconds:.1f} s)")
    zones = (f"; setpoints control zone(s) {', '.join(report.controlled_zones)}"
             if report.controlled_zones else "")
    console.print(f"config is valid for {report.backend}: {len(cfg.parameters)} parameters, "
                  f"{report.idf_fields} IDF fields, {report.weather_targets} weather and "
                  f"{report.boundary_targets} boundary targets; {len(cfg.model.tests)} tests in "
                  f"{len(cfg.model.periods)} run period(s){zones}", highlight=False)
    for note in report.notes:
        err_console.print(f"[yellow]{escape(note)}[/yellow]", highlight=False)


def _set_backend(cfg, backend: str | None) -> None:
    if backend is not None:
        if backend not in ("energyplus", "surrogate", "auto"):
            raise BpsflowError(f"--backend: expected energyplus, surrogate or auto, got '{backend}'")
        cfg.model.backend = backend


@app.command()
@_friendly
def instances(config: Path = ConfigArg, run_dir: Path | None = RunDirOption,
              instance: list[int] = typer.Option([0], "--instance", "-i",
                                                 help="Instance(s) to write."),
              out: Path | None = typer.Option(None, file_okay=False, help="Where to write (default RUN_DIR/inspect)."),
              no_progress: bool = NoProgressOption) -> None:
    """Write instance inputs (IDF per period, weather, boundary data) without running them."""
    from bpsflow.design_record import require_same_design
    from bpsflow.sampling import read_samples
    from bpsflow.simulation.backend import choose_backend
    from bpsflow.simulation.rundir import prepare_run_dir

    cfg = _load(config, run_dir)
    rd = _lock(cfg)
    samples = read_samples(rd)
    require_same_design(cfg, rd, "instances")
    chosen = choose_backend(cfg, err_console.print)
    unknown = [i for i in instance if i not in samples.index]
    if unknown:
        raise BpsflowError(f"--instance {unknown[0]}: not in samples.parquet "
                           f"(0..{len(samples) - 1})")
    out = prepare_run_dir(out or rd / "inspect", where="--out")
    for i in instance:
        files = chosen.write_inputs(cfg, samples.loc[i].to_dict(), out / f"{i:06d}")
        console.print(f"instance {i}: " + ", ".join(str(p) for p in files))


@app.command()
@_friendly
def run(config: Path = ConfigArg, run_dir: Path | None = RunDirOption,
        jobs: int | None = typer.Option(None, "--jobs", "-j", help="Parallel processes."),
        engine: str | None = EngineOption,
        scheduler: str | None = SchedulerOption,
        retry_failed: bool = typer.Option(False, help="Run failed instances again."),
        keep_inputs: bool = typer.Option(False, help="Keep instance IDF/EPW/CSV files."),
        backend: str | None = typer.Option(None, help="Override model.backend."),
        measured: Path | None = typer.Option(None, help="Measured data to draw in the figures."),
        allow_implausible: bool = AllowImplausibleOption,
        no_progress: bool = typer.Option(False, "--no-progress", help="No progress bar.")) -> None:
    """Run every instance (sampling first if needed); resume skips finished instances."""
    from bpsflow.design_record import require_same_design, require_same_simulation
    from bpsflow.measured import plausibility_reference
    from bpsflow.plots import band_summary, plot_bands
    from bpsflow.sampling import SAMPLES_FILE, read_samples
    from bpsflow.simulation.backend import choose_backend
    from bpsflow.simulation.ensemble import all_failed_message, run_ensemble
    from bpsflow.simulation.model_inputs import check_model_inputs
    from bpsflow.simulation.rundir import read_results

    cfg = _load(config, run_dir, _execution(jobs, engine, scheduler))
    _set_backend(cfg, backend)
    chosen = choose_backend(cfg, err_console.print)
    check_model_inputs(cfg)  # before config.resolved.yaml or samples are written
    rd = _lock(cfg)
    observed = _read_measured(measured, cfg, reference=plausibility_reference(rd),
                              allow_implausible=allow_implausible).frame if measured else None
    if not (rd / SAMPLES_FILE).is_file():
        console.print(f"no samples in {rd}: sampling first")
        _sample(cfg)
    else:
        require_same_design(cfg, rd, "run")
        require_same_simulation(cfg, rd, "run", chosen.name)
        _write_resolved(cfg)
    summary = run_ensemble(cfg, read_samples(rd), chosen, jobs=jobs, retry_failed=retry_failed,
                           keep_inputs=keep_inputs, show_progress=not no_progress)
    if summary.ok == 0 and summary.total:
        err_console.print(f"[bold red]error:[/bold red] {all_failed_message(summary, rd)}",
                          highlight=False, soft_wrap=True)
        raise typer.Exit(code=1)
    results = read_results(rd)
    figures = plot_bands(cfg, results, rd / "figures", observed) if len(results) else []
    table = Table(title=escape(f"{cfg.name}: {summary.ok}/{summary.total} instances ok "
                        f"({summary.backend}, {summary.seconds:.1f} s)"))
    for column in ("test", "output", "reports", "unit", "instances", "mean", "band_width"):
        table.add_column(column, justify="right" if column in ("instances", "mean", "band_width")
                         else "left", overflow="fold")
    for row in band_summary(cfg, results).itertuples():
        table.add_row(row.test, row.output, cfg.outputs[row.output].label, row.unit,
                      str(row.instances), f"{row.mean:.3g}", f"{row.band_width:.3g}")
    console.print(table)
    console.print(f"ran {summary.ran}, skipped {summary.skipped} finished, {summary.failed} "
                  f"failed; results: {rd / 'results.parquet'}; figures: {len(figures)} in "
                  f"{rd / 'figures'}")
    if summary.failed:
        console.print(f"[yellow]{summary.failed} instance(s) failed: see "
                      f"{rd / 'manifest.parquet'} (status, error); first error: "
                      f"{summary.first_error}[/yellow]", highlight=False)
        raise typer.Exit(code=1)


@app.command()
@_friendly
def synth(config: Path = ConfigArg,
          truth: Path = typer.Option(..., help="YAML with the true parameter values and noise."),
          out: Path | None = typer.Option(None, file_okay=False, help="Output folder (default RUN_DIR/truth)."),
          run_dir: Path | None = RunDirOption,
          backend: str | None = typer.Option(None, help="Override model.backend."),
          jobs: int | None = JobsOption,
          engine: str | None = EngineOption,
          scheduler: str | None = SchedulerOption,
          detailed: bool = typer.Option(False, "--detailed", help="Also write detailed "
                                        "measurements (detailed.csv, sensor_calibration.csv, "
                                        "detailed.json; seed §3.4.3-3.5)."),
          equivalent_for: Path | None = typer.Option(
              None, "--equivalent-for", help="Config of a simpler model (e.g. prototype rooms) "
              "to be calibrated on these data: also write truth_equivalent.json, the true "
              "values that model can recover (room-weighted means of the fields)."),
          no_progress: bool = NoProgressOption) -> None:
    """Run a truth instance and write synthetic measurements (measured.csv)."""
    from bpsflow.simulation.rundir import prepare_run_dir
    from bpsflow.synth import load_truth, synthesize, truth_notes, write_equivalent_truth

    cfg = _load(config, run_dir, _execution(jobs, engine, scheduler))
    if backend is not None:
        cfg.model.backend = backend
    spec = load_truth(truth, cfg)
    for note in truth_notes(cfg, spec):
        err_console.print(f"[yellow]{escape(f'{truth.name}: {note}')}[/yellow]", highlight=False)
    # the other config is read before anything runs: a bad one loses nothing
    simpler = _load(equivalent_for, None) if equivalent_for is not None else None
    rd = _lock(cfg)
    out = out or rd / "truth"
    prepare_run_dir(out, where="--out")
    path = synthesize(cfg, spec, out.resolve(), detailed=detailed)
    console.print(f"wrote {path}")
    if simpler is not None:
        console.print(f"wrote {write_equivalent_truth(cfg, spec, simpler, out.resolve())}")
    if detailed:
        from bpsflow.detailed import CALIBRATION_FILE, DETAILED_FILE, METADATA_FILE

        names = (DETAILED_FILE, CALIBRATION_FILE, METADATA_FILE)
        console.print("wrote " + ", ".join(str(path.parent / name) for name in names))


@app.command()
@_friendly
def validate(config: Path = ConfigArg,
             measured: Path = typer.Option(..., help="Measured data (timestamp + output columns)."),
             invalid: Path | None = typer.Option(None, help="Run directory of an ensemble "
                                                    "treated as invalid predictions (e.g. the baseline)."),
             q: float | None = typer.Option(None, help="Override validation.q."),
             allow_implausible: bool = AllowImplausibleOption,
             run_dir: Path | None = RunDirOption,
             no_progress: bool = NoProgressOption) -> None:
    """Probabilistic validation: thresholds, type I/II risk, nMCRPS, NMBE, CV(RMSE)."""
    from bpsflow.design_record import require_same_design, require_same_simulation
    from bpsflow.plots import plot_bands
    from bpsflow.simulation.rundir import ensemble_gap_note, read_results
    from bpsflow.validation import note_measured, write_outputs
    from bpsflow.validation import validate as run_validation

    cfg = _load(config, run_dir, {"validation.q": ("--q", q)})
    rd = _lock(cfg)
    require_same_design(cfg, rd, "validate")
    require_same_simulation(cfg, rd, "validate")
    # Everything is read and checked before anything is written: a bad file leaves the
    # previous validation.csv/.json as they were.
    results = read_results(rd)
    gap = ensemble_gap_note(rd, results)
    if gap:
        console.print(f"[yellow]{escape(gap)}[/yellow]", highlight=False)
    if invalid is not None and invalid.resolve() == rd.resolve():
        raise BpsflowError(f"--invalid: {invalid} is the run being validated; expected the run "
                           f"directory of another ensemble (e.g. the baseline's) whose "
                           f"predictions are treated as invalid")
    invalid_results = read_results(invalid.resolve()) if invalid else None
    invalid_notes: list[str] = []
    if invalid is not None:
        from bpsflow.validation import invalid_ensemble_problems

        problems, invalid_notes = invalid_ensemble_problems(cfg, invalid.resolve())
        if problems:
            raise BpsflowError(f"--invalid: {invalid} cannot serve as the known-invalid "
                               f"ensemble ({'; '.join(problems[:3])}"
                               + (f"; and {len(problems) - 3} more" if len(problems) > 3
                                  else "")
                               + "); expected the run directory of an ensemble run "
                               "with the same tests, days and output definitions (e.g. the "
                               "baseline's, from a config that extends this one)")
        for note in invalid_notes:
            console.print(f"[yellow]--invalid: {escape(note)}[/yellow]", highlight=False)
    if invalid_results is not None:
        # another model's ensemble by design, but it must report this config's tests
        have = set(zip(invalid_results["test"], invalid_results["output"]))
        lacking = [f"{t.name}:{o}" for t in cfg.model.tests for o in t.outputs
                   if (t.name, o) not in have]
        if lacking:
            raise BpsflowError(f"--invalid: {invalid} has no results of {', '.join(lacking[:3])}"
                               + (f" and {len(lacking) - 3} more" if len(lacking) > 3 else "")
                               + "; expected an ensemble run with this config's tests and "
                               "outputs (e.g. the baseline's, from a config that extends this "
                               "one)")
    data = _read_measured(measured, cfg, required=_test_outputs(cfg), reference=results,
                          allow_implausible=allow_implausible)
    observed = data.frame
    validations = run_validation(cfg, results, observed, cfg.validation.q,
                                 cfg.validation.estimator, invalid_results, measured)
    note_measured(validations, data)
    for extra in ([gap] if gap else []) + [f"--invalid: {n}" for n in invalid_notes]:
        # the files say it too: a partial ensemble's thresholds are not the designed ones
        for v in validations:
            v.row["notes"] = "; ".join(n for n in (v.row["notes"], extra) if n)
    paths = write_outputs(validations, rd, cfg.validation.q, measured=data.record())
    plot_bands(cfg, results, rd / "figures", observed)
    table = Table(title=escape(f"{cfg.name}: validation (q = {cfg.validation.q:g}, type I risk "
                        f"{1 - cfg.validation.q:.0%}, CRPS {cfg.validation.estimator})"))
    columns = ["test", "output", "metric", "threshold"] + (
        ["invalid_quantile", "type_ii_risk", "reduced_risk"] if invalid else []) + \
        ["nMCRPS / MCRPS", "CV(RMSE)", "NMBE", "G14"]
    for column in columns:
        table.add_column(column, justify="left" if column in ("test", "output", "metric")
                         else "right", overflow="fold")
    for v in validations:
        row = v.row
        temperature = row["metric"] == "MAE"
        cells = [row["test"], f"{row['output']} ({cfg.outputs[row['output']].label})",
                 escape(f"{row['metric']} [{row['metric_unit']}]"), f"{row['threshold']:.4g}"]
        if invalid:
            cells += [f"{row['invalid_quantile']:.4g}", f"{row['type_ii_risk']:.1%}",
                      f"{row['reduced_risk']:.1%}"]
        cells += [f"{row['mcrps_c']:.3g} C" if temperature else f"{row['nmcrps']:.3g}",
                  f"{row['rmse_c']:.3g} C (RMSE)" if temperature else f"{row['cv_rmse']:.1%}",
                  f"{row['mbe_c']:.3g} C (MBE)" if temperature else f"{row['nmbe']:.1%}",
                  "-" if temperature else row["guideline14_hourly"]]
        table.add_row(*cells)
    console.print(table)
    console.print(f"threshold: the {cfg.validation.q:g}-quantile of the instances' own scores "
                  "(nMAE; MAE for temperatures) against the measurements. A prediction is "
                  "accepted as valid when its score is at most the threshold (a valid one is "
                  f"rejected with probability {1 - cfg.validation.q:.0%})"
                  + (". " if invalid else "; --invalid RUN_DIR scores known-invalid "
                     "predictions against it (type II risk). ")
                  + "nMCRPS scores the ensemble as a whole and is not compared with it.",
                  highlight=False)
    for v in validations:
        if v.row["notes"]:
            console.print(f"[yellow]{v.row['test']}: {v.row['notes']}[/yellow]")
    console.print(f"wrote {paths['json']}, {paths['csv']}, {paths['figure']}")


@app.command()
@_friendly
def sensitivity(
        config: Path = ConfigArg,
        measured: Path | None = typer.Option(
            None, help="Measured data (timestamp + output columns); needed by --response "
                       "difference|absolute."),
        response: str | None = typer.Option(
            None, help="difference (prediction - measurement, the source's response; default "
                       "with --measured), absolute (|prediction - measurement|) or raw (the "
                       "prediction; default without --measured), each averaged over a test's "
                       "evaluated days."),
        top: int = typer.Option(20, help="Inputs shown per response (ranked by mu*)."),
        trajectories: int | None = typer.Option(None, help="Override design.trajectories."),
        levels: int | None = typer.Option(None, help="Override design.levels (even)."),
        jobs: int | None = typer.Option(None, "--jobs", "-j", help="Parallel processes."),
        engine: str | None = EngineOption,
        scheduler: str | None = SchedulerOption,
        backend: str | None = typer.Option(None, help="Override model.backend."),
        groups: bool = typer.Option(False, "--groups", help="Also print mu* summed per "
                                                           "parameter group."),
        screen: int | None = typer.Option(None, help="Write a reduced config keeping the top "
                                             "N inputs of each response, the others fixed."),
        screen_out: Path | None = typer.Option(None, dir_okay=False, help="Where --screen writes (default "
                                                  "<config stem>_screened.yaml beside CONFIG)."),
        screen_ties: bool = typer.Option(False, "--screen-ties", help="With --screen N, also "
                                         "keep each input whose mu* confidence interval "
                                         "reaches the N-th input's (not told apart from it)."),
        allow_implausible: bool = AllowImplausibleOption,
        run_dir: Path | None = RunDirOption,
        no_progress: bool = typer.Option(False, "--no-progress", help="No progress bar.")) -> None:
    """Morris screening (mu*, sigma) of the uncertain inputs, in RUN_DIR/morris (seed §3.4.8)."""
    from bpsflow import sensitivity as morris
    from bpsflow.alignment import check_coverage
    from bpsflow.config import with_overrides
    from bpsflow.measured import plausibility_reference
    from bpsflow.simulation.backend import choose_backend
    from bpsflow.simulation.ensemble import all_failed_message, run_ensemble
    from bpsflow.simulation.rundir import read_results

    cfg = _load(config, run_dir, _execution(jobs, engine, scheduler))
    # The Morris design the options ask for passes the schema (and its run cap) like a file's.
    with_overrides(cfg, {"design.method": "morris", "design.trajectories": trajectories,
                         "design.levels": levels},
                   {"design.trajectories": "--trajectories", "design.levels": "--levels"})
    kind = response or ("difference" if measured else "raw")
    if kind not in morris.RESPONSE_KINDS:
        raise BpsflowError(f"--response: expected one of {', '.join(morris.RESPONSE_KINDS)}, "
                           f"got '{kind}'")
    if kind != "raw" and measured is None:
        raise BpsflowError(f"--response {kind} compares predictions with measurements: give "
                           f"--measured FILE (or use --response raw)")
    if top < 1:
        raise BpsflowError(f"--top: expected a number of inputs ≥ 1, got {top}")
    if screen is not None and screen < 1:
        raise BpsflowError(f"--screen: expected a number of inputs to keep per response ≥ 1, "
                           f"got {screen}")
    if screen_ties and screen is None:
        raise BpsflowError("--screen-ties needs --screen N (how many inputs to keep per response)")
    if screen_out is not None and screen is None:
        raise BpsflowError("--screen-out needs --screen N (how many inputs to keep per response)")
    if kind == "raw" and measured is not None:
        raise BpsflowError(f"--measured: {measured} is not used by --response raw (the "
                           f"predictions alone); drop it, or use --response difference or "
                           f"absolute to compare with it")
    _set_backend(cfg, backend)
    mcfg = morris.morris_config(cfg, trajectories, levels)
    if screen is not None:
        morris.check_screen_target(cfg, screen_out)
    observed = None
    if measured is not None:
        reference = plausibility_reference(cfg.run_dir.resolve())
        if reference is None:
            reference = plausibility_reference(mcfg.run_dir.resolve())
        observed = _read_measured(measured, mcfg, required=_test_outputs(mcfg),
                                  reference=reference,
                                  allow_implausible=allow_implausible).frame
        check_coverage(mcfg, observed, measured)
    chosen = choose_backend(mcfg, announce=err_console.print)
    _lock(cfg)
    samples = morris.prepare_morris(mcfg, chosen.name, announce=err_console.print)
    md = mcfg.run_dir.resolve()
    varied = morris.varied_parameters(mcfg)
    k = len(varied)
    fixed = len(mcfg.parameters) - k
    err_console.print(f"Morris design: {mcfg.design.trajectories} trajectories × ({k} + 1) = "
                      f"{len(samples)} runs, {mcfg.design.levels} levels"
                      + (f"; {fixed} constant parameter(s) not stepped" if fixed else ""))
    # a discrete input whose rare value no level reaches is never stepped: its mu* of 0
    # says nothing of its effect
    unmoved = [p.name for p in varied if p.name in samples
               and samples[p.name].nunique(dropna=False) < 2]
    if unmoved:
        err_console.print(f"[yellow]the Morris design never changes {', '.join(unmoved)} (its "
                          f"distribution puts the design's levels on one value): its mu* of 0 "
                          f"does not measure its effect[/yellow]", highlight=False)
    summary = run_ensemble(mcfg, samples, chosen, jobs=jobs, show_progress=not no_progress)
    if summary.ok == 0:
        raise BpsflowError(all_failed_message(summary, md, "Morris runs"))
    results = read_results(md)
    responses = morris.window_responses(mcfg, results, observed, kind, measured)
    unit = morris.read_unit_design(md)
    indices = morris.morris_indices(varied, unit[[p.name for p in varied]].to_numpy(),
                                    responses.reindex(unit.index), mcfg.design.levels,
                                    seed=mcfg.design.seed)
    group_table = morris.group_summary(indices)
    paths = morris.write_tables(indices, group_table, md)
    figures = morris.plot_all(mcfg, indices, md / "figures", label_top=min(top, 10))
    for name, frame in indices.groupby("response", sort=False):
        output_unit = mcfg.outputs[name.split(":", 1)[1]].unit
        used = int(frame["trajectories"].iloc[0])
        table = Table(title=escape(f"{name}: Morris, {kind} response [{output_unit}], top {top} by mu* "
                            f"({used} trajectories)"))
        for column in ("rank", "parameter", "group", "mu*", "mu*_conf", "mu", "sigma"):
            table.add_column(column, justify="left" if column in ("parameter", "group")
                             else "right", overflow="fold")
        for row in frame.nsmallest(top, "rank").itertuples():
            table.add_row(str(row.rank), row.parameter, row.group, f"{row.mu_star:.3g}",
                          f"{row.mu_star_conf:.2g}", f"{row.mu:.3g}", f"{row.sigma:.3g}")
        console.print(table)
    if groups:
        table = Table(title="mu* per parameter group")
        for column in ("response", "group", "sum mu*", "max mu*", "top parameter", "count"):
            table.add_column(column, justify="right" if "mu*" in column or column == "count"
                             else "left", overflow="fold")
        for row in group_table.itertuples():
            table.add_row(row.response, row.group, f"{row.mu_star_sum:.3g}",
                          f"{row.mu_star_max:.3g}", row.top_parameter, str(row.count))
        console.print(table)
    console.print(f"{summary.ok}/{summary.total} runs ok ({summary.backend}); wrote "
                  f"{paths['indices']}, {paths['groups']}, {len(figures)} figure(s) in "
                  f"{md / 'figures'}")
    if summary.failed:
        console.print(f"[yellow]{summary.failed} run(s) failed: their trajectories are left out "
                      f"(see {md / 'manifest.parquet'})[/yellow]")
    if screen is not None:
        path, kept, fixed_names = morris.write_screened_config(cfg, indices, screen, screen_out,
                                                               paths["indices"], screen_ties)
        console.print(f"wrote {path}: keeps {len(kept)} input(s) "
                      f"({morris.screen_rule(screen, screen_ties)}), fixes {len(fixed_names)} "
                      "at their nominal value")


@app.command()
@_friendly
def refine(config: Path = ConfigArg,
           detailed: Path = typer.Option(..., help="detailed.csv (or its folder), with "
                                         "sensor_calibration.csv and detailed.json beside it."),
           out: Path | None = typer.Option(None, file_okay=False, help="Output folder (default RUN_DIR/refine)."),
           refined_config: Path | None = typer.Option(
               None, "--refined-config", help="Where to write the refined config (default "
                                              "OUT/refined.yaml); its data files go beside it."),
           run_dir: Path | None = RunDirOption,
           no_progress: bool = NoProgressOption) -> None:
    """Refine input distributions from detailed measurements (seed §3.4.3-3.5)."""
    from bpsflow.config import refuse_config_chain
    from bpsflow.files import check_writable_file
    from bpsflow.refine import interval_table, write_refinement
    from bpsflow.refine import refine as run_refine
    from bpsflow.simulation.rundir import prepare_run_dir

    cfg = _load(config, run_dir)
    rd = _lock(cfg)
    out = prepare_run_dir((out or rd / "refine").resolve(), where="--out")
    if refined_config is not None:
        from bpsflow.files import refuse_foreign_file
        from bpsflow.refine.report import REFINED_HEADER

        refuse_config_chain(cfg, refined_config, "--refined-config")
        refuse_foreign_file(refined_config, REFINED_HEADER, "--refined-config",
                            "a refined config")
        check_writable_file(refined_config, "--refined-config")
    refinement = run_refine(cfg, detailed)
    paths = write_refinement(refinement, out, refined_config)
    table = Table(title=escape(f"{cfg.name}: refined inputs, 90 % intervals (seed §3.5)"))
    for column in ("parameter", "mode", "baseline", "refined", "width ratio"):
        table.add_column(column, justify="right" if column == "width ratio" else "left",
                         overflow="fold")
    for row in interval_table(refinement).itertuples():
        table.add_row(row.parameter, row.mode, f"[{row.before_low:.4g}, {row.before_high:.4g}]",
                      f"[{row.after_low:.4g}, {row.after_high:.4g}]", f"{row.width_ratio:.3f}")
    console.print(table)
    for surface in refinement.boundary:
        console.print(f"boundary {surface.surface}: {len(surface.rows)} hours replaced, "
                      f"sensor_std_c {surface.sensor_std_c:.4g} C (eq. 13)")
    glazing = refinement.glazing
    if glazing.get("single_pane_estimate") is not None and "bias_single_pane" in glazing:
        console.print(f"glazing (not refined, seed §3.5.5): single-pane estimate "
                      f"{glazing['single_pane_estimate']:.4f} vs normal-incidence "
                      f"{glazing['normal_incidence_single_pane_nominal']:.4f} "
                      f"({glazing['relative_bias_single_pane']:+.1%}; off-normal and diffuse "
                      f"light transmit less)")
    for message in refinement.skipped + refinement.notes:
        console.print(f"[yellow]{escape(message)}[/yellow]", highlight=False)
    console.print(f"wrote {paths['config']}, {paths['json']}, {paths['convection_csv']} and "
                  f"figures in {out / 'figures'}")


@app.command()
@_friendly
def calibrate(config: Path = ConfigArg,
              measured: Path = typer.Option(..., help="Measured data (timestamp + output columns)."),
              method: str = typer.Option("bayes", help="bayes (Kennedy-O'Hagan, NUTS; the "
                                         "deterministic baseline runs too) or deterministic."),
              scenarios: bool = typer.Option(False, "--scenarios", help="Run every scenario of "
                                             "calibration.scenarios and compare them."),
              outputs: str | None = typer.Option(None, help="Override calibration.outputs "
                                                    "(comma-separated)."),
              resolution: str | None = typer.Option(None, help="Override calibration."
                                                       "resolution: daily or hourly."),
              chains: int | None = typer.Option(None, help="Override calibration.bayes.chains."),
              warmup: int | None = typer.Option(None, help="Override calibration.bayes.warmup."),
              samples: int | None = typer.Option(None, help="Override calibration.bayes.samples."),
              runs: int | None = typer.Option(None, help="Override calibration.design.runs."),
              truth: Path | None = typer.Option(None, help="True parameter values (synth's "
                                                   "truth.json): report whether 90 % intervals "
                                                   "cover them."),
              allow_unconverged: bool = typer.Option(False, help="Exit 0 even when NUTS has not "
                                                     "converged (R-hat, ESS, divergences)."),
              allow_implausible: bool = AllowImplausibleOption,
              out: Path | None = typer.Option(None, file_okay=False, help="Output folder (default "
                                                 "RUN_DIR/calibration)."),
              backend: str | None = BackendOption,
              jobs: int | None = JobsOption,
              engine: str | None = EngineOption,
              scheduler: str | None = SchedulerOption,
              run_dir: Path | None = RunDirOption,
              no_progress: bool = NoProgressOption) -> None:
    """Calibrate to measured data (Kennedy-O'Hagan or deterministic); test on held-out days."""
    from bpsflow.calibration.command import apply_overrides
    from bpsflow.calibration.command import calibrate as run_calibration
    from bpsflow.calibration.workflow import settings_of

    if scenarios and (outputs is not None or resolution):
        # each scenario names its own outputs and resolution: an override would be ignored
        raise BpsflowError(f"{'--outputs' if outputs is not None else '--resolution'}: --scenarios "
                           "calibrates each scenario of calibration.scenarios with its own "
                           "outputs and resolution; drop the option, or drop --scenarios")
    if method == "deterministic" and any(v is not None for v in (chains, warmup, samples)):
        raise BpsflowError("--chains/--warmup/--samples set the Bayesian sampler; --method "
                           "deterministic does not sample")
    cfg = _load(config, run_dir, _execution(jobs, engine, scheduler))
    output_names = [o.strip() for o in outputs.split(",")] if outputs is not None else None
    if output_names is not None and not all(output_names):
        raise BpsflowError(f"--outputs '{outputs}': expected comma-separated output names, "
                           f"some of {', '.join(sorted(cfg.outputs))}", source=cfg.source)
    for name in output_names or []:
        if name not in cfg.outputs:
            raise BpsflowError(f"--outputs: '{name}' is not an output of the config (expected "
                               f"some of {', '.join(sorted(cfg.outputs))})", source=cfg.source)
    settings = apply_overrides(settings_of(cfg),
                               outputs=output_names,
                               resolution=resolution, chains=chains, warmup=warmup,
                               samples=samples, runs=runs, source=cfg.source)
    _lock(cfg)
    from bpsflow.calibration.command import DEFAULT_OUT

    # decide locks the calibration folder it reads: the same lock keeps it from reading a
    # calibration this command is writing
    folder = out.resolve() if out else cfg.run_dir.resolve() / DEFAULT_OUT
    if folder.is_dir():
        # (a folder not there yet is created after the checks: a refusal leaves none behind)
        _lock_folder(folder)
    outcome = run_calibration(cfg, measured, method=method, all_scenarios=scenarios,
                              out=out.resolve() if out else None, backend=backend, jobs=jobs,
                              truth_path=truth, settings=settings, show_progress=not no_progress,
                              console=console, allow_implausible=allow_implausible)
    if outcome.unconverged:
        err_console.print("[bold red]not converged:[/bold red] " + " | ".join(outcome.unconverged)
                          + ("" if allow_unconverged else
                             " (more warm-up/samples, or --allow-unconverged to accept)"),
                          highlight=False, soft_wrap=True)
        if not allow_unconverged:
            raise typer.Exit(code=1)


@app.command()
@_friendly
def diagnose(config: Path = ConfigArg,
             measured: Path = typer.Option(..., help="Measured data (timestamp + output columns)."),
             out: Path | None = typer.Option(None, file_okay=False, help="Output folder (default "
                                                "RUN_DIR/diagnosis)."),
             backend: str | None = BackendOption,
             jobs: int | None = JobsOption,
             engine: str | None = EngineOption,
             scheduler: str | None = SchedulerOption,
             allow_implausible: bool = AllowImplausibleOption,
             run_dir: Path | None = RunDirOption,
             no_progress: bool = NoProgressOption) -> None:
    """What the model gets wrong, why, a fix, and its held-out gain (writes diagnosis.json)."""
    from bpsflow.diagnosis.command import run_diagnose

    cfg = _load(config, run_dir, _execution(jobs, engine, scheduler))
    _lock(cfg)
    run_diagnose(cfg, measured, out.resolve() if out else None, backend=backend, jobs=jobs,
                 show_progress=not no_progress, console=console,
                 allow_implausible=allow_implausible)


@app.command()
@_friendly
def decide(config: Path = ConfigArg,
           calibration: Path = typer.Option(..., help="A calibration folder (RUN_DIR/calibration)."),
           intervention: Path = typer.Option(..., help="The intervention file (YAML): change, "
                                             "test week, outcomes, decision rules."),
           scenarios: bool = typer.Option(False, "--scenarios", help="Decide with every "
                                          "scenario's calibration and correlate accuracy with risk."),
           measured: Path | None = typer.Option(None, help="Measured data (default: the file the "
                                                "calibration used)."),
           jobs: int | None = JobsOption,
           engine: str | None = EngineOption,
           scheduler: str | None = SchedulerOption,
           run_dir: Path | None = RunDirOption,
           no_progress: bool = NoProgressOption) -> None:
    """Underperformance probability and decision risk of an intervention (seed §4.4.2, eq. 23)."""
    from bpsflow.decision.workflow import decide as run_decide

    cfg = _load(config, run_dir, _execution(jobs, engine, scheduler))
    _lock(cfg)
    if calibration.is_dir():
        # a calibrate writing there (from another run directory, or with --out) holds it too
        _lock_folder(calibration.resolve())
    run_decide(cfg, calibration.resolve(), intervention, scenarios=scenarios,
               measured_path=measured, jobs=jobs, show_progress=not no_progress, console=console)


def main() -> None:  # pragma: no cover
    """The ``bpsflow`` executable: the typer app, then a quiet end on a late Ctrl-C."""
    try:
        app(prog_name="bpsflow")
    finally:
        # The command's work is over (finished, or interrupted with its files written). A
        # Ctrl-C now lands in the interpreter's shutdown, where a worker pool joins its
        # threads: it printed tracebacks there and could leave the process hanging. It ends
        # the process at once instead.
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, _exit_at_once)


def _exit_at_once(signum: int, frame: object) -> None:  # pragma: no cover
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(130)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
