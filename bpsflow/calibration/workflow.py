"""The calibration workflow of one data scenario: design, emulator, calibration, held-out test.

1. **Design** (:mod:`~bpsflow.calibration.design`): an LHD over θ, run over the
   calibration period on the config's backend (resumable), paired with the
   measurements at the scenario's resolution; calibration rows subsampled.
2. **Emulator** (:mod:`~bpsflow.calibration.emulator`): MLE hyperparameters,
   the conditional on every simulated value, hold-out test on 10 % of runs.
3. **Deterministic baseline** (:mod:`~bpsflow.calibration.deterministic`) —
   always: it is cheap and starts the sampler.
4. **Bayesian calibration** (:mod:`~bpsflow.calibration.bayes`): NUTS,
   convergence diagnostics, the posterior predictive on the held-out rows.
5. **Physical check**: posterior draws (and the deterministic optimum) re-run
   on the physical model; every prediction scored on the held-out days at
   daily and hourly resolution (:mod:`~bpsflow.calibration.heldout`).
6. **Report** (:mod:`~bpsflow.calibration.report`).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from rich.console import Console
from scipy import special

from bpsflow.alignment import check_coverage
from bpsflow.calibration import design as design_module
from bpsflow.calibration import known_error
from bpsflow.calibration.design import Paired
from bpsflow.calibration.emulator import (
    Emulator,
    fit_emulator,
    parameter_effects,
    unit_inputs,
    value_inputs,
)
from bpsflow.calibration.settings import CalibrationSettings, Scenario
from bpsflow.config import Config, Parameter, window_config
from bpsflow.errors import BpsflowError
from bpsflow.files import read_parquet, read_user_text, write_text_atomic

if TYPE_CHECKING:   # bayes imports JAX, which a run without a posterior never needs
    from bpsflow.calibration.bayes import Convergence, Posterior

console = Console(stderr=True)

POSTERIOR_RUNS_DIR = "posterior_runs"
#: Beside the design runs: the screened-out inputs' ensemble (calibration.screened_error).
SCREENED_DIR = "screened_error"
REFINEMENT_DIR = "refinement"
#: Beside the physical check's runs: the model section (days, tests) they simulated.
RUNS_WINDOW_FILE = "window.json"
PREDICTIVE_DRAWS = 200
# Below this hold-out R² the emulator's error is a sizeable part of what it predicts, and
# the user is told so (the calibration still runs: its hold-out error enters the likelihood).
EMULATOR_R2_WARN = 0.9


@dataclass
class Design:
    """The design runs shared by every scenario."""

    parameters: list[Parameter]
    unit: np.ndarray              # (runs, k) prior-CDF values, row = instance
    results: pd.DataFrame         # tidy results of every run
    backend: str
    seconds: float
    #: the screened-out inputs' ensemble (instance 0 all nominal), when asked for
    screened: pd.DataFrame | None = None
    screened_names: list[str] = field(default_factory=list)
    #: runs added at posterior draws (calibration.refinement), after the hypercube's
    refined_runs: int = 0

    @property
    def space_filling_runs(self) -> int:
        """Instances below this number are the Latin hypercube's."""
        return len(self.unit) - self.refined_runs


@dataclass
class CalibrationRun:
    """Everything one scenario's calibration produced (what the report writes)."""

    scenario: Scenario
    method: str
    backend: str
    parameters: list[Parameter]
    paired: Paired                 # selected calibration rows + held-out rows
    x: pd.DataFrame
    emulator: Emulator
    obs_rows: np.ndarray
    heldout_rows: np.ndarray
    deterministic: object
    effects: np.ndarray
    active: np.ndarray
    posterior: Posterior | None = None
    convergence: Convergence | None = None
    koh: object | None = None
    unit_draws: np.ndarray | None = None
    predictive: dict | None = None        # held-out GP predictive (output units)
    physical: dict = field(default_factory=dict)   # resolution -> Paired of re-runs
    prior: dict = field(default_factory=dict)      # resolution -> Paired of design runs
    heldout: pd.DataFrame | None = None
    truth: dict[str, float] | None = None
    units: dict[str, str] = field(default_factory=dict)
    labels: dict[str, list[str]] = field(default_factory=dict)   # names of vector sites
    extra_variance: np.ndarray | None = None   # per row: known error variance (standardised)
    #: per row: the screened-out inputs' ensemble, column 0 the nominal run (output units)
    screened_simulated: np.ndarray | None = None
    screened_names: list[str] = field(default_factory=list)
    screened_error: dict | None = None     # what the screened-out inputs' spread added
    refinement: dict | None = None         # the refinement rounds (calibration.refinement)
    timings: dict[str, float] = field(default_factory=dict)


def settings_of(config: Config) -> CalibrationSettings:
    """The config's ``calibration:`` section (defaults when absent)."""
    return config.calibration or CalibrationSettings()


def default_outputs(config: Config) -> list[str]:
    """Every output some test reports, in config order."""
    seen: list[str] = []
    for test in config.model.tests:
        seen += [o for o in test.outputs if o not in seen]
    return seen


def check_scenario(config: Config, scenario: Scenario, where: str,
                   measured: pd.DataFrame | None = None,
                   measured_source: Path | None = None) -> None:
    """Refuse, before any run, a scenario output the config, its tests or the data lack."""
    reported = default_outputs(config)
    for i, output in enumerate(scenario.outputs):
        if output not in config.outputs:
            raise BpsflowError(f"{where}.outputs[{i}]: unknown output '{output}', expected one "
                               f"of {sorted(config.outputs)}", source=config.source)
        if output not in reported:
            raise BpsflowError(f"{where}.outputs[{i}]: '{output}' is not an output of any test "
                               f"in model.tests (they report {reported})", source=config.source)
        if measured is not None and output not in measured.columns:
            raise BpsflowError(f"no column {output}, which {where} calibrates on",
                               source=measured_source)
    if measured is not None:
        # every evaluated hour measured: alignment's own error, before the design runs
        check_coverage(config, measured, measured_source, outputs=list(scenario.outputs))


def check_holdout(config: Config, settings: CalibrationSettings, scenario: Scenario) -> None:
    """Refuse, before any run, a hold-out that leaves an output under 2 calibration values.

    The held-out days are the last evaluated days over every calibrated output's tests
    (as :func:`bpsflow.calibration.design.pair` splits them).
    """
    from bpsflow.alignment import evaluation_hours

    days: dict[str, set] = {}
    for test in config.model.tests:
        for output in test.outputs:
            if output in scenario.outputs:
                hours = evaluation_hours(test, config.model.year) - pd.Timedelta(hours=1)
                days.setdefault(output, set()).update(hours.normalize())
    if not days:
        return
    last = max(max(d) for d in days.values())
    first_heldout = last - pd.Timedelta(days=settings.holdout_days - 1)
    for output, own in days.items():
        kept = sorted(d for d in own if d < first_heldout)
        values = len(kept) if scenario.resolution == "daily" else 24 * len(kept)
        if values < 2:
            raise BpsflowError(
                f"calibration.holdout_days: holding out {settings.holdout_days} day(s) (from "
                f"{first_heldout:%m-%d}) leaves {output} {values} {scenario.resolution} "
                f"calibration value(s) of its tests' evaluated days; expected at least 2 (hold "
                f"out fewer days, or lengthen its tests)", source=config.source)


def prepare_design(config: Config, settings: CalibrationSettings, design_dir: Path,
                   backend: str, jobs: int | None = None, show_progress: bool = True) -> Design:
    """Draw the LHD over θ and run it (finished runs of the same design are reused)."""
    started = time.perf_counter()
    parameters = design_module.calibration_parameters(config, settings)
    unit = design_module.design_unit(settings, len(parameters))
    samples = design_module.samples_frame(config, parameters, unit)
    console.print(f"design: {len(samples)} runs over {len(parameters)} calibration parameters "
                  f"({', '.join(p.name for p in parameters)}) on {backend}")
    results = design_module.run_samples(config, samples, design_dir, backend=backend, jobs=jobs,
                                        show_progress=show_progress)
    design = Design(parameters=parameters, unit=unit, results=results, backend=backend,
                    seconds=0.0)
    if settings.screened_error.runs:
        _screened_ensemble(config, settings, design, design_dir.parent / SCREENED_DIR, jobs,
                           show_progress)
    design.seconds = time.perf_counter() - started
    return design


def _screened_ensemble(config: Config, settings: CalibrationSettings, design: Design,
                       run_dir: Path, jobs: int | None, show_progress: bool) -> None:
    """Run the screened-out inputs' ensemble into ``design`` (see :mod:`known_error`)."""
    screened = known_error.screened_parameters(config)
    calibrated = {p.name for p in design.parameters}
    screened = [p for p in screened if p.name not in calibrated]
    if not screened:
        console.print("note: calibration.screened_error.runs is set, but no constant parameter "
                      "carries provenance.original_distribution (what `bpsflow sensitivity "
                      "--screen` writes): there is no screened-out input to spread; no "
                      "screened-input error is added", highlight=False)
        return
    runs = settings.screened_error.runs
    console.print(f"screened-out inputs: {runs} runs + 1 nominal over the {len(screened)} "
                  "inputs screening fixed, drawn from their original distributions, θ at its "
                  "prior median", highlight=False)
    samples = known_error.screened_samples(config, screened, runs, settings.screened_error.seed)
    try:
        results = design_module.run_samples(config, samples, run_dir, backend=design.backend,
                                            jobs=jobs, show_progress=show_progress)
    except BpsflowError as exc:
        # the ensemble widens the likelihood; the runs that finished still measure the spread
        from bpsflow.simulation.rundir import read_results

        console.print(f"[yellow]note: screened-out inputs' ensemble: {exc}; the spread is "
                      "measured on the runs that finished[/yellow]", highlight=False)
        try:
            results = read_results(run_dir)
        except BpsflowError:
            results = pd.DataFrame({"instance": []})
    finished = set(results["instance"].unique()) if len(results) else set()
    if 0 not in finished or len(finished) < 6:
        console.print("[yellow]note: the screened-out inputs' nominal run or most of the "
                      "ensemble failed; no screened-input error is added[/yellow]",
                      highlight=False)
        return
    design.screened = results
    design.screened_names = [p.name for p in screened]


def measured_outputs(config: Config, measured: pd.DataFrame) -> list[str]:
    """Outputs of the tests that the measured file has (scored on the held-out days)."""
    return [o for o in default_outputs(config) if o in measured.columns]


#: An emulator length-scale (emulator-input units) at or above this sits at its MLE bound (1e3).
LENGTHSCALE_AT_BOUND = 999.0


def ignored_inputs(emulator: Emulator, unit: np.ndarray, parameters: list[Parameter],
                   space_filling: np.ndarray | None = None) -> dict[str, list[str]]:
    """Per emulator block: parameters whose length-scale sits at its bound though they act.

    A parameter acts on a block when the runs' mean standardised output over
    the block's rows differs between the quintiles of its prior-CDF value
    ``unit`` (runs × k): one-way ANOVA, p < 0.001, which sees effects that are
    not monotone too. An output that truly ignores a parameter (electricity
    and a glazing U-value) is not reported. ``space_filling`` (mask over the
    runs) keeps the test to the Latin hypercube's runs: runs clustered at
    posterior draws (refinement) move every parameter's quintiles together.
    """

    keep = np.ones(len(unit), dtype=bool) if space_filling is None else space_filling
    out: dict[str, list[str]] = {}
    for name, block in zip(emulator.grid.names, emulator.grid.blocks):
        response = block.y.mean(axis=1)[keep]
        flat = [p.name for j, p in enumerate(parameters)
                if block.hyper.t_lengthscales[j] >= LENGTHSCALE_AT_BOUND
                and _acts(unit[keep, j], response)]
        if flat:
            out[name] = flat
    return out


def _acts(unit: np.ndarray, response: np.ndarray, bins: int = 5) -> bool:
    """Whether ``response`` differs between the quantile bins of ``unit`` (ANOVA p < 0.001)."""
    from scipy import stats

    if len(unit) < 4 * bins:
        return False
    edges = np.quantile(unit, np.linspace(0, 1, bins + 1)[1:-1])
    groups = [response[(np.searchsorted(edges, unit) == b)] for b in range(bins)]
    if np.ptp(response) == 0 or any(len(g) < 2 for g in groups):
        return False
    return bool(stats.f_oneway(*groups).pvalue < 1e-3)


def calibrate_scenario(config: Config, settings: CalibrationSettings, scenario: Scenario,
                       design: Design, measured: pd.DataFrame, measured_source: Path | None,
                       method: str, out_dir: Path, jobs: int | None = None,
                       truth: dict[str, float] | None = None,
                       show_progress: bool = True, physical_check: bool = True) -> CalibrationRun:
    """Calibrate to one scenario's data and test the result on the held-out days.

    ``physical_check=False`` stops after the posterior (no re-runs of the
    physical model, no held-out scores): for timing the sampler alone.
    With ``calibration.refinement.runs`` a Bayesian posterior is refined
    (:func:`refine_posterior`) before the check.
    """
    run = _calibrate_on(config, settings, scenario, design, measured, measured_source, method,
                        truth, show_progress)
    if method == "bayes" and settings.refinement.runs:
        run = refine_posterior(run, config, settings, design, measured, measured_source,
                               out_dir / REFINEMENT_DIR, jobs, show_progress)
    if not physical_check:
        return run
    _physical_check(run, config, settings, design, measured, measured_source, out_dir, jobs,
                    show_progress)
    return run


def refine_posterior(run: CalibrationRun, config: Config, settings: CalibrationSettings,
                     design: Design, measured: pd.DataFrame, measured_source: Path | None,
                     folder: Path, jobs: int | None = None,
                     show_progress: bool = True) -> CalibrationRun:
    """Add design runs at posterior draws, refit the emulator and sample again.

    Each round runs ``calibration.refinement.runs`` posterior draws of θ
    (spread over the shuffled draws) over the design's period in
    ``folder/round<N>``, adds them to the design runs and calibrates again.
    The emulator's error, which biases θ, is largest where design runs are
    sparse; the new runs put them where the posterior is (sequential
    design, Santner et al. 2018, ch. 6). The earlier emulator's error on
    the new runs is recorded: it is the error the earlier posterior rested on.
    """
    refinement = settings.refinement
    rounds = []
    first_timings = run.timings
    for round_number in range(1, refinement.rounds + 1):
        assert run.unit_draws is not None       # a Bayesian run's posterior draws
        rng = np.random.default_rng([refinement.seed, round_number])
        draws = run.unit_draws[rng.permutation(len(run.unit_draws))]
        picked = draws[np.linspace(0, len(draws) - 1, refinement.runs).astype(int)]
        picked = np.clip(picked, 1e-6, 1 - 1e-6)
        samples = design_module.samples_frame(config, design.parameters, picked,
                                              first_instance=len(design.unit))
        console.print(f"[{run.scenario.name}] refinement round {round_number}: "
                      f"{len(samples)} runs at posterior draws")
        results = design_module.run_samples(config, samples, folder / f"round{round_number}",
                                            backend=design.backend, jobs=jobs,
                                            show_progress=show_progress)
        error = _emulator_error_at(run, config, settings, results, picked, measured,
                                   measured_source)
        console.print(f"[{run.scenario.name}] refinement round {round_number}: the emulator's "
                      "error at the posterior draws (RMS, standardised) "
                      + ", ".join(f"{o} {v:.3g}" for o, v in error.items()))
        design = replace(design, unit=np.vstack([design.unit, picked]),
                         results=pd.concat([design.results, results], ignore_index=True),
                         refined_runs=design.refined_runs + len(picked))
        run = _calibrate_on(config, settings, run.scenario, design, measured, measured_source,
                            "bayes", run.truth, show_progress)
        rounds.append({"round": round_number, "runs": int(len(picked)),
                       "design_runs": int(len(design.unit)),
                       "emulator_error_at_posterior": error})
    run.timings = {**run.timings, **{f"first_{k}": v for k, v in first_timings.items()}}
    run.refinement = {"runs": refinement.runs, "rounds": rounds}
    return run


def _emulator_error_at(run: CalibrationRun, config: Config, settings: CalibrationSettings,
                       results: pd.DataFrame, unit: np.ndarray, measured: pd.DataFrame,
                       measured_source: Path | None) -> dict[str, float]:
    """RMS standardised error of ``run``'s emulator, per output, on new runs at ``unit``
    (rows of ``unit`` are the runs' instances in order), over the calibration rows."""
    paired = design_module.resimulated(run.paired, design_module.pair(
        config, results, measured, run.scenario.outputs, run.scenario.resolution,
        settings.holdout_days, settings.idle_fraction, measured_source))
    emulator = run.emulator
    outputs = run.paired.rows["output"].to_numpy()
    simulated = emulator.scaling.y(paired.simulated[:, np.argsort(paired.instances)], outputs)
    predicted = emulator.grid.predict_mean(emulator.grid.t_of_unit(unit))   # (runs, rows)
    error = predicted - simulated.T
    rows = run.obs_rows
    return {o: float(np.sqrt(np.mean(error[:, rows[outputs[rows] == o]] ** 2)))
            for o in emulator.scaling.outputs}


def _calibrate_on(config: Config, settings: CalibrationSettings, scenario: Scenario,
                  design: Design, measured: pd.DataFrame, measured_source: Path | None,
                  method: str, truth: dict[str, float] | None,
                  show_progress: bool) -> CalibrationRun:
    """Emulator, deterministic optimum and (``bayes``) posterior on ``design``'s runs."""
    from bpsflow.calibration import deterministic as det

    timings: dict[str, float] = {"design_seconds": design.seconds}
    started = time.perf_counter()
    parameters = design.parameters
    paired_all = design_module.pair(config, design.results, measured, scenario.outputs,
                                    scenario.resolution, settings.holdout_days,
                                    settings.idle_fraction, measured_source)
    paired = design_module.select_observations(paired_all, settings.max_observations,
                                               settings.observation_seed)
    names = design_module.variable_input_names(scenario)
    x = design_module.variable_inputs(config, paired.rows, scenario.resolution, names,
                                      scenario.outputs)
    screened_simulated = None
    if design.screened is not None:
        ensemble = design_module.pair(config, design.screened, measured, scenario.outputs,
                                      scenario.resolution, settings.holdout_days,
                                      settings.idle_fraction, measured_source)
        matched = design_module.resimulated(paired, ensemble)
        # nominal run first: the deviations are taken from it
        order = np.argsort(matched.instances != 0, kind="stable")
        screened_simulated = matched.simulated[:, order]
    obs_rows = np.flatnonzero((paired.rows["split"] == "calibration").to_numpy())
    heldout_rows = np.flatnonzero((paired.rows["split"] == "heldout").to_numpy())
    console.print(f"[{scenario.name}] {len(obs_rows)} calibration and {len(heldout_rows)} "
                  f"held-out {scenario.resolution} rows of {', '.join(scenario.outputs)}")

    em = settings.emulator
    inputs = value_inputs(lambda unit: design_module.unit_to_values(unit, parameters),
                          len(parameters)) if em.inputs == "value" else unit_inputs(len(parameters))
    emulator = fit_emulator(x, paired.rows["output"], paired.simulated,
                            design.unit[paired.instances], points=em.points,
                            test_fraction=em.test_fraction, restarts=em.restarts,
                            random_state=em.seed, inputs=inputs,
                            per_output=em.hyperparameters == "per_output",
                            grid_fit=em.fit == "grid")
    timings["emulator_seconds"] = time.perf_counter() - started
    if len(emulator.fit_points) < em.points:
        console.print(f"[{scenario.name}] note: calibration.emulator.points is {em.points}, "
                      f"but the training runs hold only {len(emulator.fit_points)} (run, "
                      f"{scenario.resolution} row) pairs; the emulator is fitted on all of them")
    for name, flat in ignored_inputs(emulator, design.unit[paired.instances], parameters,
                                     paired.instances < design.space_filling_runs).items():
        # the MLE can park a real input's length-scale at its bound: the posterior then
        # rests on an emulator that ignores it
        where = "these observations" if name == "all" else name
        console.print(f"[yellow][{scenario.name}] note: the emulator finds no effect of "
                      f"{', '.join(flat)} on {where} (length-scale at its bound), but the "
                      "design runs show one; more design runs or emulator points "
                      "(calibration.emulator.points) may let it see it[/yellow]",
                      highlight=False)
    if emulator.test is not None:
        console.print(f"[{scenario.name}] emulator: hold-out R² {emulator.test.r2:.4f} "
                      f"({len(emulator.test.test_runs)} runs), MLE fit "
                      f"{sum(h.fit_seconds for h in emulator.hypers):.1f} s")
        if emulator.test.r2 < EMULATOR_R2_WARN:
            console.print(f"[yellow][{scenario.name}] warning: the emulator predicts its "
                          f"held-out runs poorly (R² {emulator.test.r2:.3f} < "
                          f"{EMULATOR_R2_WARN}); the posterior rests on it. More design runs "
                          "(calibration.design.runs), fit points (calibration.emulator.points) "
                          "or restarts (calibration.emulator.restarts) may help.[/yellow]")

    outputs_obs = paired.rows["output"].to_numpy()[obs_rows]
    observed = paired.observed[obs_rows]
    grid = emulator.grid

    if settings.deterministic.model == "simulator":
        predict = _simulator_predictor(config, parameters, paired, obs_rows, measured,
                                       measured_source, scenario, settings, design.backend)
    else:
        def predict(unit: np.ndarray) -> np.ndarray:
            mean = grid.predict_mean(grid.t_of_unit(unit))[:, obs_rows]
            return emulator.scaling.y_back(mean, outputs_obs)
    started = time.perf_counter()
    optimum = det.calibrate(predict, observed, outputs_obs, len(parameters), settings.deterministic)
    timings["deterministic_seconds"] = time.perf_counter() - started
    console.print(f"[{scenario.name}] deterministic optimum: objective {optimum.objective:.4g} "
                  f"({optimum.evaluations} evaluations, {optimum.seconds:.1f} s)")

    effects = parameter_effects(grid, obs_rows, random_state=em.seed)
    active = np.flatnonzero(effects >= settings.bayes.screen_effect)
    run = CalibrationRun(scenario=scenario, method=method, backend=design.backend,
                         parameters=parameters, paired=paired, x=x, emulator=emulator,
                         obs_rows=obs_rows, heldout_rows=heldout_rows, deterministic=optimum,
                         effects=effects, active=active, truth=truth, timings=timings,
                         units={o: config.outputs[o].unit for o in config.outputs},
                         screened_simulated=screened_simulated,
                         screened_names=design.screened_names)
    if method == "bayes":
        _bayes(run, settings, show_progress)
    return run


def _bayes(run: CalibrationRun, settings: CalibrationSettings, show_progress: bool) -> None:
    from bpsflow.calibration import bayes

    bs = settings.bayes
    if len(run.active) == 0:
        raise BpsflowError("calibration: no calibration parameter has an effect on the "
                           f"emulated outputs above bayes.screen_effect = {bs.screen_effect}; "
                           "the data cannot inform any of them")
    screened = [run.parameters[i].name for i in np.setdiff1d(np.arange(len(run.parameters)),
                                                             run.active)]
    if screened:
        console.print(f"[{run.scenario.name}] not sampled (effect < {bs.screen_effect:g} "
                      f"standardised units; posterior = prior): {', '.join(screened)}")
    emulator = run.emulator
    outputs_obs = run.paired.rows["output"].to_numpy()[run.obs_rows]
    y = emulator.scaling.y(run.paired.observed[run.obs_rows], outputs_obs)
    row_output = emulator.scaling.output_index(run.paired.rows["output"].to_numpy())
    extra, factor = None, None
    if bs.emulator_error == "holdout" and emulator.test is not None:
        # per grid row: the emulator's hold-out squared error of the row's output
        mse = np.array([emulator.test.per_output[o]["mse_standardised"]
                        for o in emulator.scaling.outputs])
        extra = mse[row_output]
    elif bs.emulator_error == "correlated" and emulator.test is not None:
        factor, extra = known_error.holdout_error_factor(emulator, row_output)
    if run.screened_simulated is not None:
        screened_factor, screened_rest = known_error.screened_error_factor(
            run.screened_simulated, emulator.scaling.y_std[row_output])
        factor = screened_factor if factor is None else np.hstack([factor, screened_factor])
        extra = screened_rest if extra is None else extra + screened_rest
        _report_screened_error(run, screened_factor, screened_rest)
    run.extra_variance = extra
    data = bayes.koh_data(emulator.grid, run.obs_rows, y, run.active, bs,
                          None if extra is None else extra[run.obs_rows],
                          obs_outputs=row_output[run.obs_rows],
                          extra_factor=None if factor is None else factor[run.obs_rows])
    z_start = special.ndtri(np.clip(run.deterministic.unit, 1e-6, 1 - 1e-6)) \
        if bs.init == "deterministic" else None
    inverse_mass = None
    if bs.laplace:
        start = {k: v[0] for k, v in bayes.initial_values(data, z_start, 1, bs.seed,
                                                          spread=0.0).items()}
        approx = bayes.laplace(data, start)
        init = bayes.laplace_starts(approx, bs.chains, bs.seed)
        inverse_mass = approx.covariance
        run.timings["laplace_seconds"] = approx.seconds
    else:
        init = bayes.initial_values(data, z_start, bs.chains, bs.seed)
    console.print(f"[{run.scenario.name}] NUTS: {bs.chains} chains x ({bs.warmup} warm-up + "
                  f"{bs.samples}) draws, {len(run.active)} calibration parameters, "
                  f"{len(y)} observations")
    posterior = bayes.sample_posterior(data, bs, init, progress=show_progress,
                                       inverse_mass_matrix=inverse_mass)
    labels = {"z": [run.parameters[i].name for i in run.active],
              "log_discrepancy_lengthscale": (list(emulator.scaling.x_columns) if bs.ard
                                              else ["log_discrepancy_lengthscale"])}
    convergence = bayes.assess(posterior, labels, bs)
    while posterior.extensions < bs.extend and not convergence.converged \
            and convergence.divergence_share <= bs.divergence_max:
        # longer chains cure slow mixing (R-hat, ESS), not divergences
        console.print(f"[{run.scenario.name}] NUTS not converged ("
                      + "; ".join(convergence.reasons) + f"): every chain draws {bs.samples} "
                      f"more (extension {posterior.extensions + 1} of {bs.extend})")
        posterior = bayes.extend_posterior(posterior)
        convergence = bayes.assess(posterior, labels, bs)
    # the sampler's objects hold compiled code and the model's arrays: not kept per scenario
    posterior = replace(posterior, resume=[])
    run.posterior, run.convergence, run.koh, run.labels = posterior, convergence, data, labels
    run.timings["mcmc_seconds"] = posterior.seconds
    run.unit_draws = bayes.unit_draws(data, posterior, random_state=bs.seed)
    flat = bayes.flat_draws(posterior)
    pick = np.linspace(0, len(run.unit_draws) - 1,
                       min(PREDICTIVE_DRAWS, len(run.unit_draws))).astype(int)
    started = time.perf_counter()
    heldout = bayes.predictive(
        emulator.grid, run.obs_rows, run.heldout_rows, y, run.unit_draws[pick],
        flat["log_discrepancy_std"][pick], flat["log_discrepancy_lengthscale"][pick],
        flat["log_noise_std"][pick], bs.ard, x_inducing=data.x_inducing,
        extra_variance=extra, random_state=bs.seed, noise_index=row_output,
        extra_factor=factor)
    at_obs = bayes.predictive(
        emulator.grid, run.obs_rows, run.obs_rows, y, run.unit_draws[pick],
        flat["log_discrepancy_std"][pick], flat["log_discrepancy_lengthscale"][pick],
        flat["log_noise_std"][pick], bs.ard, x_inducing=data.x_inducing,
        extra_variance=extra, random_state=bs.seed, noise_index=row_output,
        extra_factor=factor)
    outputs_h = run.paired.rows["output"].to_numpy()[run.heldout_rows]
    scaling = emulator.scaling
    run.predictive = {
        "mean": scaling.y_back(heldout.mean, outputs_h),
        "samples": scaling.y_back(heldout.sample, outputs_h),
        # δ in output units: standardised δ times the output's scale
        "discrepancy_heldout": heldout.discrepancy * scaling.y_std[scaling.output_index(outputs_h)],
        "discrepancy_calibration": at_obs.discrepancy
        * scaling.y_std[scaling.output_index(outputs_obs)]}
    run.timings["predictive_seconds"] = time.perf_counter() - started
    verdict = "converged" if convergence.converged else \
        "NOT converged: " + "; ".join(convergence.reasons)
    console.print(f"[{run.scenario.name}] NUTS {posterior.seconds:.1f} s "
                  f"({posterior.chain_method} chains): R-hat max {convergence.rhat_max:.4f}, "
                  f"ESS bulk/tail min {convergence.ess_bulk_min:.0f}/"
                  f"{convergence.ess_tail_min:.0f}, {posterior.num_steps.mean():.1f} steps per "
                  f"iteration, {convergence.divergences} divergences: {verdict}")


def _simulator_predictor(config, parameters, paired: Paired, obs_rows, measured, source,
                         scenario, settings, backend):
    """Calibration-row predictions from surrogate runs (deterministic ``model: simulator``)."""
    from bpsflow.simulation.backend import get_backend
    from bpsflow.simulation.ensemble import simulate_samples

    simulator = get_backend(backend)
    if not simulator.vectorised:
        raise BpsflowError("calibration.deterministic.model: 'simulator' needs a vectorised "
                           f"backend such as the surrogate (each objective evaluation is a "
                           f"simulation), not {backend}; use model: emulator",
                           source=config.source)
    keys = paired.rows.iloc[obs_rows][["time", "output"]]

    def predict(unit: np.ndarray) -> np.ndarray:
        samples = design_module.samples_frame(config, parameters, unit)
        tidy = simulate_samples(config, samples, config.run_dir, simulator)
        sim = design_module.pair(config, tidy, measured, scenario.outputs, scenario.resolution,
                                 settings.holdout_days, settings.idle_fraction, source)
        index = pd.MultiIndex.from_frame(sim.rows[["time", "output"]])
        rows = index.get_indexer(pd.MultiIndex.from_frame(keys))
        return sim.simulated[rows].T

    return predict


def _physical_check(run: CalibrationRun, config: Config, settings: CalibrationSettings,
                    design: Design, measured: pd.DataFrame, source, out_dir: Path,
                    jobs: int | None, show_progress: bool) -> None:
    """Re-run posterior draws and the deterministic optimum; score everything held out."""
    from bpsflow.calibration import heldout

    started = time.perf_counter()
    units = {o: config.outputs[o].unit for o in config.outputs}
    outputs = measured_outputs(config, measured)
    unit_runs = []
    if run.unit_draws is not None:
        pick = np.linspace(0, len(run.unit_draws) - 1,
                           min(settings.posterior_runs, len(run.unit_draws))).astype(int)
        unit_runs.append(run.unit_draws[pick])
    unit_runs.append(run.deterministic.unit[None, :])
    unit = np.vstack(unit_runs)
    samples = design_module.samples_frame(config, run.parameters, unit)
    console.print(f"[{run.scenario.name}] physical check: {len(samples)} run(s) "
                  f"({len(samples) - 1} posterior draws + the deterministic optimum)")
    # every output on the days this calibration held out (an output of other tests, e.g. a
    # free float after the heated days, is scored where its days meet them, else not at all)
    held_days = design_module.row_days(run.paired.rows.iloc[run.heldout_rows],
                                       run.paired.resolution)
    priors = {resolution: design_module.pair(
        config, design.results, measured, outputs, resolution, settings.holdout_days,
        settings.idle_fraction, source, heldout_window=(held_days.min(), held_days.max())
    ).split("heldout") for resolution in ("daily", "hourly")}
    # only the held-out days are scored: the re-runs simulate them after their tests'
    # warm-up days, not the whole period
    days = design_module.row_days(priors["daily"].rows, "daily")
    window = window_config(config, days.min().date(), days.max().date())
    # the held-out days are the data's last: an output whose tests end earlier (a winter
    # test beside a summer one) has none, and the window does not simulate it
    held = [o for o in outputs if any((priors[r].rows["output"] == o).any() for r in priors)]
    if len(held) < len(outputs):
        console.print(f"[yellow][{run.scenario.name}] no held-out days of "
                      f"{', '.join(o for o in outputs if o not in held)} (the held-out days "
                      f"{days.min():%m-%d}..{days.max():%m-%d} lie in no test that reports "
                      f"them): the physical check scores {', '.join(held)}[/yellow]",
                      highlight=False)
    outputs = held
    results = design_module.run_samples(window, samples, out_dir / POSTERIOR_RUNS_DIR,
                                        backend=design.backend, jobs=jobs, fresh=True,
                                        show_progress=show_progress)
    write_text_atomic(out_dir / POSTERIOR_RUNS_DIR / RUNS_WINDOW_FILE, _window_record(window))
    records = []
    for resolution, prior in priors.items():
        rerun = design_module.resimulated(prior, design_module.pair(
            window, results, measured, outputs, resolution, holdout_days=0, measured_source=source))
        run.physical[resolution], run.prior[resolution] = rerun, prior
        out = rerun.rows["output"].to_numpy()
        records += heldout.score("prior", resolution, prior.rows["output"].to_numpy(),
                                 prior.observed, prior.simulated, units)
        if run.unit_draws is not None:
            records += heldout.score("bayes_physical", resolution, out, rerun.observed,
                                     rerun.simulated[:, :-1], units)
        records += heldout.score("deterministic_physical", resolution, out, rerun.observed,
                                 rerun.simulated[:, -1:], units)
        if run.predictive is not None and resolution == run.scenario.resolution:
            rows = run.paired.rows.iloc[run.heldout_rows]
            records += heldout.score("bayes_gp", resolution, rows["output"].to_numpy(),
                                     run.paired.observed[run.heldout_rows],
                                     run.predictive["samples"].T, units)
    order = {"prior": 0, "bayes_gp": 1, "bayes_physical": 2, "deterministic_physical": 3}
    frame = heldout.table(records)
    frame["_order"] = frame["model"].map(order)
    run.heldout = (frame.sort_values(["resolution", "output", "_order"])
                   .drop(columns="_order").reset_index(drop=True))
    run.timings["physical_check_seconds"] = time.perf_counter() - started


def _window_record(window: Config) -> str:
    return json.dumps(window.model.model_dump(mode="json"), sort_keys=True)


def checked_runs(folder: Path, window: Config, samples: pd.DataFrame) -> pd.DataFrame | None:
    """The physical check's results of ``samples`` over ``window``, if it ran exactly those.

    ``folder`` is a calibration's folder. The check re-runs the first
    posterior draws over the held-out days; a later command that needs the
    same draws over the same days (``decide`` on the held-out week) takes its
    results instead of simulating them again. None when the days, the draws
    or the parameter values differ in any way.
    """
    from bpsflow.sampling import SAMPLES_FILE
    from bpsflow.simulation.rundir import read_results

    runs = Path(folder) / POSTERIOR_RUNS_DIR
    try:
        if (runs / RUNS_WINDOW_FILE).read_text() != _window_record(window):
            return None
        done = read_parquet(runs / SAMPLES_FILE).set_index("instance")
        results = read_results(runs)
    except (OSError, ValueError, BpsflowError):
        return None
    wanted = samples.reset_index(drop=True)
    done = done.iloc[:len(wanted)].reset_index(drop=True)
    if len(done) < len(wanted) or sorted(done.columns) != sorted(wanted.columns) or not \
            np.array_equal(done[wanted.columns].to_numpy(float), wanted.to_numpy(float)):
        return None
    results = results[results["instance"] < len(wanted)]
    if results["instance"].nunique() != len(wanted):
        return None
    return results


def _report_screened_error(run: CalibrationRun, factor: np.ndarray, rest: np.ndarray) -> None:
    """Say how large the screened-out inputs' spread is, per output, against the noise."""
    outputs = run.paired.rows["output"].to_numpy()
    variance = np.sum(factor * factor, axis=1) + rest
    spread = {o: float(np.sqrt(np.mean(variance[outputs == o])))
              for o in run.emulator.scaling.outputs}
    run.screened_error = {"inputs": run.screened_names,
                          "runs": int(run.screened_simulated.shape[1] - 1)
                          if run.screened_simulated is not None else 0,
                          "components": int(factor.shape[1]),
                          "rms_standardised": spread}
    console.print(f"[{run.scenario.name}] screened-out inputs' spread (RMS, standardised): "
                  + ", ".join(f"{o} {v:.3f}" for o, v in spread.items())
                  + f"; {factor.shape[1]} correlated components in the likelihood",
                  highlight=False)


def read_truth(path: Path, parameters: list[Parameter],
               not_fitted: frozenset[str] = frozenset()) -> dict[str, float]:
    """True θ values from ``bpsflow synth``'s ``truth.json`` or a truth YAML (``values:``).

    ``parameters`` are the ones compared; ``not_fitted`` names the config's
    other parameters (constants, inputs left out of the calibration), which
    a truth may hold and are said as such rather than as unknown.
    """
    import yaml

    path = Path(path)
    if not path.is_file():
        raise BpsflowError(f"truth file not found: {path}")
    try:
        text = read_user_text(path, "a truth file (JSON or YAML)")
        raw = json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
    except (ValueError, yaml.YAMLError) as exc:
        raise BpsflowError(f"cannot read the truth file: {exc}", source=path) from None
    values = raw.get("values") if isinstance(raw, dict) else None
    if not isinstance(values, dict):
        raise BpsflowError("expected a mapping 'values: {parameter: value}'", source=path)
    known = {p.name for p in parameters}
    skipped = sorted(str(name) for name in values if name in not_fitted and name not in known)
    unknown = sorted(str(name) for name in values if name not in known and name not in not_fitted)
    if skipped:
        console.print(f"{path.name}: values of {len(skipped)} parameter(s) the calibration does "
                      f"not fit (constants, or left out of calibration.parameters) are not "
                      f"compared: {', '.join(skipped[:8])}{' ...' if len(skipped) > 8 else ''}",
                      highlight=False)
    if unknown and len(unknown) == len(values):
        raise BpsflowError(f"values: none of {', '.join(unknown)} is a parameter of the config "
                           f"(expected some of {sorted(known)})", source=path)
    if unknown:
        # a truth of a more detailed model may hold inputs this one has not: said, not refused
        console.print(f"[yellow]{path.name}: values {', '.join(unknown)} are no parameters of "
                      f"the config and are not compared[/yellow]", highlight=False)
    truth = {}
    for parameter in parameters:
        if parameter.name not in values:
            continue
        try:
            truth[parameter.name] = float(values[parameter.name])
        except (TypeError, ValueError):
            raise BpsflowError(f"values.{parameter.name}: expected a number, got "
                               f"{values[parameter.name]!r}", source=path) from None
    missing = [p.name for p in parameters if p.name not in truth]
    if missing:
        # a truth of another run: its coverage count would silently leave these out
        console.print(f"[yellow]{path.name}: no true value of calibration parameter(s) "
                      f"{', '.join(missing)}; their coverage is not judged[/yellow]",
                      highlight=False)
    return truth
