"""The body of ``bpsflow calibrate``: options -> workflow -> files -> console tables.

Kept out of :mod:`bpsflow.cli` so the command line stays a thin layer; the
returned :class:`Outcome` tells the CLI whether every run converged.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydantic import ValidationError
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from bpsflow.calibration.settings import CalibrationSettings
from bpsflow.config import Config
from bpsflow.errors import BpsflowError

DEFAULT_OUT = "calibration"
SCENARIOS_DIR = "scenarios"


@dataclass
class Outcome:
    """What ran and whether the Bayesian runs converged."""

    runs: list = field(default_factory=list)
    paths: dict = field(default_factory=dict)
    unconverged: list[str] = field(default_factory=list)


def apply_overrides(settings: CalibrationSettings, *, outputs: list[str] | None = None,
                    resolution: str | None = None, chains: int | None = None,
                    warmup: int | None = None, samples: int | None = None,
                    runs: int | None = None, source: Path | None = None) -> CalibrationSettings:
    """A copy of ``settings`` with command-line overrides applied (validated).

    A bad value is a :class:`BpsflowError` naming the option, the key and the
    bound (``source``: the config file, for the message).
    """
    data = settings.model_dump()
    if outputs:
        data["outputs"] = outputs
    if resolution:
        data["resolution"] = resolution
    for key, value in (("chains", chains), ("warmup", warmup), ("samples", samples)):
        if value is not None:
            data["bayes"][key] = value
    if runs is not None:
        data["design"]["runs"] = runs
    try:
        return CalibrationSettings.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        key = ".".join(str(part) for part in first["loc"])
        option = {"outputs": "--outputs", "resolution": "--resolution", "bayes.chains": "--chains",
                  "bayes.warmup": "--warmup", "bayes.samples": "--samples",
                  "design.runs": "--runs"}.get(key.split(".0")[0], "calibration option")
        raise BpsflowError(f"{option} (calibration.{key}): "
                           f"{first['msg'].removeprefix('Value error, ')}", source=source) from None


def calibrate(config: Config, measured_path: Path, *, method: str = "bayes",
              all_scenarios: bool = False, out: Path | None = None, backend: str | None = None,
              jobs: int | None = None, truth_path: Path | None = None,
              settings: CalibrationSettings | None = None, show_progress: bool = True,
              console: Console | None = None, allow_implausible: bool = False) -> Outcome:
    """Run ``bpsflow calibrate``: one scenario (the section's top level) or all of them.

    The measured file is read and checked (:mod:`bpsflow.measured`) before
    anything runs; once the design's runs exist their values set the
    plausibility ceiling of powers and energies, checked before anything of
    the calibration is written. ``allow_implausible`` accepts values outside
    their plausible range.

    Raises
    ------
    BpsflowError
        Bad options, config keys, measured data or failed simulations.
    """
    from bpsflow.calibration import workflow
    from bpsflow.calibration.report import write
    from bpsflow.calibration.scenarios import write_comparison
    from bpsflow.config import config_fingerprint
    from bpsflow.measured import plausibility_reference, read_measured
    from bpsflow.simulation.backend import choose_backend

    console = console or Console()
    if method not in ("bayes", "deterministic"):
        raise BpsflowError(f"--method: expected bayes or deterministic, got '{method}'")
    settings = settings or workflow.settings_of(config)
    if backend is not None:
        if backend not in ("energyplus", "surrogate", "auto"):
            raise BpsflowError(f"--backend: expected energyplus, surrogate or auto, got "
                               f"'{backend}'")
        config.model.backend = backend
    # an output the config lacks is the config's error (check_scenario names the key)
    required = [o for o in settings.outputs or [] if o in config.outputs] or None
    data = read_measured(measured_path, config, required=required,
                         reference=plausibility_reference(config.run_dir.resolve()),
                         allow_implausible=allow_implausible)
    for note in data.notes:
        console.print(f"[yellow]{escape(note)}[/yellow]", highlight=False)
    measured = data.frame
    if all_scenarios:
        if not settings.scenarios:
            raise BpsflowError("calibration.scenarios: --scenarios needs at least one scenario "
                               "in the config's calibration section", source=config.source)
        scenarios = [(s, f"calibration.scenarios ({s.name})") for s in settings.scenarios]
    else:
        scenarios = [(settings.scenario(workflow.measured_outputs(config, measured)),
                      "calibration")]
    for scenario, where in scenarios:
        workflow.check_scenario(config, scenario, where, measured, Path(measured_path))
        workflow.check_holdout(config, settings, scenario)
    if method == "bayes":
        from bpsflow.calibration.bayes import configure_jax

        configure_jax(settings.bayes.chains)
    if truth_path:
        # a wrong --truth file is refused before the design runs, not after
        workflow.read_truth(truth_path, config.parameters)
    out = Path(out) if out else config.run_dir.resolve() / DEFAULT_OUT
    from bpsflow.simulation.rundir import prepare_run_dir

    prepare_run_dir(out, where="--out")
    chosen_backend = choose_backend(config, console.print).name
    design = workflow.prepare_design(config, settings, out / "design", chosen_backend, jobs,
                                     show_progress)
    # the design's ensemble bounds powers and energies (a x1000 unit mistake)
    read_measured(measured_path, config, required=required, reference=design.results,
                  allow_implausible=allow_implausible)
    truth = workflow.read_truth(truth_path, design.parameters,
                                frozenset(p.name for p in config.parameters)) \
        if truth_path else None
    outcome = Outcome()
    provenance = {"measured": str(Path(measured_path).resolve()),
                  "config": {"source": str(config.source),
                             "fingerprint": config_fingerprint(config)}}
    for scenario, _ in scenarios:
        folder = out / SCENARIOS_DIR / scenario.name if all_scenarios else out
        try:
            run = workflow.calibrate_scenario(config, settings, scenario, design, measured,
                                              measured_path, method, folder, jobs, truth,
                                              show_progress)
        except (Exception, KeyboardInterrupt):
            if all_scenarios and outcome.runs:
                _compare_finished(outcome, [s for s, _ in scenarios], scenario.name, out,
                                  console)
            raise
        paths = write(run, folder, provenance=provenance)
        outcome.runs.append(run)
        outcome.paths[scenario.name] = paths
        print_run(run, console)
        console.print(f"wrote {paths['json']}" + (f", {paths['posterior']}"
                                                  if "posterior" in paths else "")
                      + f", {paths['heldout']} and figures in {paths['figures']}")
        if "earlier" in paths:
            console.print(f"the earlier calibration in {folder} was moved to "
                          f"{paths['earlier']}", highlight=False)
        if run.convergence is not None and not run.convergence.converged:
            outcome.unconverged.append(f"{scenario.name}: {'; '.join(run.convergence.reasons)}")
    if all_scenarios:
        paths = write_comparison(outcome.runs, out)
        outcome.paths["comparison"] = paths
        print_comparison(outcome.runs, console)
        console.print(f"wrote {paths['csv']}, {paths['json']}, {paths['figure']}")
    return outcome


def _compare_finished(outcome: Outcome, scenarios: list, failed: str, out: Path,
                      console: Console) -> None:
    """On a scenario's failure, the comparison holds the scenarios this command finished.

    An earlier comparison would otherwise sit beside scenario folders this command
    has already replaced; the scenarios after the failed one keep whatever an earlier
    run left in their folders, and the message says so.
    """
    from bpsflow.calibration.scenarios import write_comparison

    finished = [run.scenario.name for run in outcome.runs]
    rest = [s.name for s in scenarios if s.name not in finished]
    paths = write_comparison(outcome.runs, out)
    console.print(f"[yellow]scenario {failed} failed: {paths['csv']} compares only the "
                  f"scenarios calibrated now ({', '.join(finished)}); {', '.join(rest)} were "
                  f"not calibrated again (their folders under {out / SCENARIOS_DIR} hold "
                  "an earlier run's results, if any)[/yellow]", highlight=False)


def print_run(run, console: Console) -> None:
    """Parameters (prior vs posterior) and held-out accuracy of one calibration."""
    from bpsflow.calibration.report import parameter_table

    title = f"{run.scenario.name}: {run.method} calibration to {'+'.join(run.scenario.outputs)} " \
            f"({run.scenario.resolution}, {len(run.obs_rows)} observations)"
    table = Table(title=escape(title))
    for column in ("parameter", "prior 90 %", "posterior 90 %", "contraction", "deterministic",
                   "truth"):
        table.add_column(column, justify="left" if column == "parameter" else "right")
    for entry in parameter_table(run):
        prior = entry["prior"]
        post = entry.get("posterior")
        truth = entry.get("truth")
        mark = "" if "truth_in_90" not in entry else (" ✓" if entry["truth_in_90"] else " ✗")
        table.add_row(entry["name"] + ("" if entry["sampled"] else " (not sampled)"),
                      f"{prior['q05']:.3g} .. {prior['q95']:.3g}",
                      "-" if post is None else f"{post['q05']:.3g} .. {post['q95']:.3g}",
                      "-" if post is None else f"{entry['contraction']:.0%}",
                      f"{entry['deterministic']:.3g}",
                      "-" if truth is None else f"{truth:.3g}{mark}")
    console.print(table)
    for note in getattr(run.paired, "notes", []):
        # rows left out or subsampled: the table's counts and metrics rest on what is left
        console.print(f"[yellow]{escape(f'{run.scenario.name}: {note}')}[/yellow]", highlight=False)
    bounded = [f"{e['name']} ({e['deterministic_at_bound']} end)"
               for e in parameter_table(run) if e["deterministic_at_bound"]]
    if bounded:
        console.print(f"[yellow]note: the deterministic optimum sits at its prior's end for "
                      f"{', '.join(bounded)} (within its outer 1 %): the data pull it beyond "
                      "the prior range, or it compensates another input or a model error; "
                      "widen the prior or look for the cause before trusting it[/yellow]",
                      highlight=False)
    held = Table(title=escape(f"{run.scenario.name}: held-out accuracy (last days, never calibrated on)"))
    for column in ("model", "output", "resolution", "CV(RMSE) / RMSE", "NMBE / MBE",
                   "nMCRPS / MCRPS", "G14"):
        held.add_column(column, justify="left" if column in ("model", "output", "resolution")
                        else "right")
    for r in run.heldout.to_dict("records"):
        r = {k: (None if _missing(v) else v) for k, v in r.items()}
        temperature = r["cv_rmse"] is None

        def shown(value, spec: str, unit: str = "") -> str:
            # None: a metric undefined on the held-out rows (one value: no n − 1 form)
            return "-" if value is None else f"{value:{spec}}{unit}"

        unit = f" {r['unit']}"
        held.add_row(r["model"], r["output"], r["resolution"],
                     shown(r["rmse"], ".3g", unit) if temperature else shown(r["cv_rmse"], ".1%"),
                     shown(r["mbe"], ".3g", unit) if temperature else shown(r["nmbe"], "+.1%"),
                     shown(r["mcrps"], ".3g", unit) if temperature or r["nmcrps"] is None
                     else shown(r["nmcrps"], ".1%"),
                     r["guideline14"] or "-")
    console.print(held)
    if run.posterior is not None:
        conv, post = run.convergence, run.posterior
        ess = min(conv.ess_bulk_min, conv.ess_tail_min)
        console.print(
            f"NUTS: {post.num_steps.shape[0]} chains ({post.chain_method}), {post.seconds:.1f} s "
            f"(warm-up {post.warmup_seconds:.1f} s), R-hat max {conv.rhat_max:.4f}, ESS bulk "
            f"{conv.ess_bulk_min:.0f} / tail {conv.ess_tail_min:.0f} "
            f"({ess / post.seconds:.2f} ESS/s), {post.num_steps.mean():.1f} steps per iteration, "
            f"{conv.divergences} divergences: "
            + ("[green]converged[/green]" if conv.converged else
               "[bold red]NOT converged[/bold red]: " + "; ".join(conv.reasons)))
    test = run.emulator.test
    if test is not None:
        console.print(f"emulator hold-out ({len(test.test_runs)} runs): R² {test.r2:.4f}; "
                      + ", ".join(f"{o} R² {v['r2']:.4f} RMSE {v['rmse']:.3g}"
                                  for o, v in test.per_output.items()))
        if len(test.test_runs) < FEW_TEST_RUNS:
            console.print(f"[yellow]the emulator was checked on {len(test.test_runs)} held-out "
                          f"run(s): too few to judge it (raise calibration.design.runs or "
                          f"calibration.emulator.test_fraction for at least "
                          f"{FEW_TEST_RUNS})[/yellow]", highlight=False)


#: Held-out runs below which the emulator's check says little (its R² on one run is noise).
FEW_TEST_RUNS = 5


def _missing(value) -> bool:
    return value is None or (isinstance(value, (float, np.floating)) and not np.isfinite(value))


def print_comparison(runs: list, console: Console) -> None:
    """The scenario comparison: contraction per parameter and held-out accuracy."""
    from bpsflow.calibration.scenarios import comparison_table

    frame = comparison_table(runs)
    table = Table(title="data scenarios: posterior contraction and held-out accuracy "
                        "(seed Table 4.1, Figures 4.8-4.9)")
    table.add_column("column")
    for run in runs:
        table.add_column(run.scenario.name, justify="right")
    for column in frame.columns:
        if column == "scenario":
            continue
        cells = []
        for value in frame[column]:
            if isinstance(value, (float, np.floating)):
                cells.append("-" if not np.isfinite(value) else f"{value:.3g}")
            else:
                cells.append(str(value))
        table.add_row(column.replace("contraction:", "contraction ").replace(":", " "), *cells)
    console.print(table)
