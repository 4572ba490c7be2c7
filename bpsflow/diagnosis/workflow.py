"""``bpsflow diagnose``: what the model gets wrong, why, a fix, and the measured gain.

Four steps (DESIGN.md §8; seed §1.1.1.1, §2.1, §4.3.1):

1. **Scorecard.** Fit the existing calibration parameters to the measured
   output (deterministic, :mod:`bpsflow.diagnosis.fitting`) on all but the
   last ``holdout_days``; score NMBE, CV(RMSE), nMCRPS and Guideline 14 on
   the calibration hours and on the held-out block.
2. **What is wrong.** Residual = measured − fitted prediction on the
   calibration hours; each driver (weather, time axis, extra measured
   columns) is tested with a basis that fits it, HAC errors, a Holm
   correction, an effect size and sign stability across blocked folds
   (:mod:`bpsflow.diagnosis.structure`); Ljung–Box flags missing dynamics.
3. **Name the cause.** With significant structure, first ask whether a
   plausible change of an existing, unfitted parameter removes it
   (characteristic signatures, :mod:`bpsflow.diagnosis.signatures`): if the
   structure is gone after that change, the verdict is ``parameter``.
   Otherwise ``model_form``, and the significant drivers name candidate
   extensions. No significant driver: ``none`` — no cause is invented.
4. **Extend and measure.** Every allowed family is written as candidate
   causes (:func:`candidate_causes`), under the driver whose group calls it
   (:data:`FAMILY_GROUPS`: irradiance and time-of-day structure call the
   scheduled gain and an aperture on every face, since the sun follows the
   clock) or else the strongest one,
   each with its shapes (gain blocks by day type and hours, aperture faces,
   law terms). A linearised screen ranks them all from one run per new
   parameter (:func:`_screen`); the ``cv_candidates`` best causes are fitted
   together with the existing parameters on the calibration hours (a law's
   terms then chosen by BIC, :func:`_choose_terms`; a gain block's edges
   refined). A cause is accepted when, over whole-week folds of the whole
   period (:mod:`bpsflow.diagnosis.crossval`), its out-of-fold errors are
   explained by the cause's change of prediction (a forecast-encompassing
   test, HAC, fixed-b), its BIC is lower and its out-of-fold CV(RMSE) is lower; the
   accepted cause with the lowest BIC becomes the model, and its runner-up
   and their BIC difference are reported. The extended model is diagnosed
   again (a law already in it re-opened with all its terms free), until
   nothing significant is left, nothing passes, or ``max_rounds``;
   structure left that no candidate explains is reported as such.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.config import Config, Parameter, test_dates
from bpsflow.diagnosis import comparison, crossval, structure
from bpsflow.diagnosis.drivers import derive_drivers
from bpsflow.diagnosis.extensions import (
    DAY_TYPES,
    EXTENSIONS,
    SCHEDULED_BLOCKS,
    WEEK_DAYS,
    block_profile,
    building_level_zone,
    diagnosis_zone,
    extend_config,
    facade_irradiance,
    gain_blocks,
    law_text,
    profile_schedule,
    sky_diffuse_irradiance,
)
from bpsflow.diagnosis.fitting import (
    Fit,
    Problem,
    fit_many,
    output_simulator,
    parameter_range,
    predictive_ensemble,
    scores,
)
from bpsflow.diagnosis.settings import DiagnosisSettings
from bpsflow.diagnosis.signatures import (
    candidate_parameters,
    clip_to_physical,
    explain,
    signatures,
)
from bpsflow.errors import BpsflowError
from bpsflow.metrics import cv_rmse, error_concentration, rmse
from bpsflow.simulation.backend import get_backend
from bpsflow.simulation.ensemble import BatchFailure

Announce = Callable[[str], None]

#: Newey–West lags of the out-of-fold tests (encompassing, loss difference): one
#: day. With the fixed-b reference the size holds for any window; a day keeps it (4.8 % at
#: the 5 % level for AR(1) errors with φ = 0.8 over a held-out week, 7.6 % at
#: φ = 0.95; 1000 series each) while the default window (half the week) leaves
#: the t reference 3 degrees of freedom and rejects even a 20-fold gain.
HELDOUT_LAGS = 24

#: A cause is fitted a second time, from the screen's linearised optimum, when
#: the screen promised a BIC lower than its fit from zero reached by more than
#: this (Kass & Raftery 1995: 2 is where evidence starts to count).
SCREEN_START_MARGIN = 2.0

#: Kass & Raftery's (1995) "strong evidence" between two causes' BIC: a smaller
#: difference (counted on independent hours) leaves the choice to out-of-fold error.
STRONG_EVIDENCE_BIC = 6.0

#: A held-out CV(RMSE) is noted as resting on a few hours when its largest 1 % of
#: hours carry more than this share of its squared error.
CONCENTRATED_ERROR_SHARE = 0.5

#: The model holding every candidate at zero is noted as not reproducing the current fit
#: when its BIC is worse by more than this (Kass & Raftery 1995: "very strong").
NESTING_MARGIN_BIC = 10.0

#: Latin-hypercube points screened per candidate with two or more new parameters
#: for a third start of its fit (:func:`_start_screen`).
EXTENSION_START_SCREEN = 8
#: A new parameter nesting at zero is screened on a geometric scale over this many
#: decades below its upper bound: a missing effect's size is unknown to orders of
#: magnitude (an internal mass of 1 m² against a bound of 100 m²).
START_SCREEN_DECADES = 3.0


@dataclass
class Model:
    """A model under diagnosis: its config, fitted parameters and their fit."""

    config: Config
    fitted: list[Parameter]
    fit: Fit
    label: str


@dataclass
class Diagnosis:
    """Everything ``diagnose`` found; :mod:`bpsflow.diagnosis.report` writes it."""

    output: str
    timestamps: pd.DatetimeIndex
    measured: np.ndarray
    calibration: np.ndarray                  # bool mask of the calibration hours
    drivers: pd.DataFrame
    base: Model
    final: Model
    scorecard: dict                          # {"calibration": .., "heldout": ..} of the base fit
    rounds: list[dict] = field(default_factory=list)
    verdict: str = "none"
    cause: dict = field(default_factory=dict)
    extensions: list[dict] = field(default_factory=list)
    parameter_check: list[dict] = field(default_factory=list)
    gain: dict = field(default_factory=dict)
    parameter_fit: dict | None = None
    unexplained: list[str] = field(default_factory=list)   # drivers no candidate explains
    #: the rounds ran out (diagnosis.max_rounds) with structure left: ``unexplained`` then
    #: lists drivers no round got to, not drivers no candidate explains
    round_limit_reached: bool = False
    final_scores: dict = field(default_factory=dict)
    seconds: float = 0.0
    backend: str = "surrogate"
    timings: dict[str, float] = field(default_factory=dict)   # s per batch of fits, by label
    #: what could not be done as asked (clipped perturbations, runs left out, a failed step)
    notes: list[str] = field(default_factory=list)


def settings_of(config: Config) -> DiagnosisSettings:
    return getattr(config, "diagnosis", None) or DiagnosisSettings()


def check_settings(config: Config, settings: DiagnosisSettings) -> list[Parameter]:
    """Refuse ``diagnosis`` settings that contradict the config; return the fitted parameters.

    Checked before the measured file is read or anything runs.
    """
    wanted = [o for t in config.model.tests for o in t.outputs]
    if settings.output is not None and settings.output not in wanted:
        raise BpsflowError(f"diagnosis.output: '{settings.output}' is not an output of the "
                           f"config's tests (expected one of {sorted(set(wanted))})",
                           source=config.source)
    fitted = fitted_parameters(config, settings)
    _check_zones(config, settings)
    names = {p.name for p in fitted}
    for i, name in enumerate(settings.suspects or []):
        if name in names:
            raise BpsflowError(f"diagnosis.suspects[{i}]: '{name}' is also fitted (in "
                               f"diagnosis.parameters, or calibration.parameters by default); "
                               f"expected an input that the fit leaves at its nominal value",
                               source=config.source)
    return fitted


def _check_zones(config: Config, settings: DiagnosisSettings) -> None:
    """``diagnosis.zone`` and ``diagnosis.extension_zones`` must name zones of the model."""
    if not settings.zone and not settings.extension_zones:
        return
    from bpsflow.diagnosis.extensions import diagnosis_zone
    from bpsflow.simulation.idf import model_objects

    model = model_objects(config.model)
    for extension in [None, *settings.extension_zones]:
        diagnosis_zone(config, settings.output, None if extension is None else str(extension),
                       model=model)


def choose_output(config: Config, measured: pd.DataFrame, settings: DiagnosisSettings) -> str:
    """The output to diagnose: ``diagnosis.output``, else the first measured output of the tests."""
    wanted = [o for t in config.model.tests for o in t.outputs]
    if settings.output is not None:
        if settings.output not in wanted:
            raise BpsflowError(f"diagnosis.output: '{settings.output}' is not an output of the "
                               f"config's tests (expected one of {sorted(set(wanted))})",
                               source=config.source)
        if settings.output not in measured.columns:
            raise BpsflowError(f"diagnosis.output: the measured data has no column "
                               f"'{settings.output}'", source=config.source)
        return settings.output
    for output in wanted:
        if output in measured.columns:
            return output
    raise BpsflowError(f"the measured data has none of the config's outputs "
                       f"(expected a column among {sorted(set(wanted))})", source=config.source)


def fitted_parameters(config: Config, settings: DiagnosisSettings) -> list[Parameter]:
    """The existing parameters calibrated before the residuals are read."""
    from bpsflow.calibration.design import calibration_parameters
    from bpsflow.calibration.settings import CalibrationSettings

    known = {p.name for p in config.parameters}
    for i, name in enumerate(settings.parameters or []):
        if name not in known:
            raise BpsflowError(f"diagnosis.parameters[{i}]: '{name}' is not a parameter of the "
                               f"config", source=config.source)
    for i, name in enumerate(settings.suspects or []):
        if name not in known:
            raise BpsflowError(f"diagnosis.suspects[{i}]: '{name}' is not a parameter of the "
                               f"config", source=config.source)
    names = settings.parameters
    if names == []:
        raise BpsflowError("diagnosis.parameters: the list is empty; expected the existing "
                           "parameters to calibrate before the residuals are read (or leave the "
                           "key out for the config's uncertain parameters)", source=config.source)
    if names is None and config.calibration is not None:
        names = config.calibration.parameters
    if names is None:
        from bpsflow.distributions import Constant, Discrete, Empirical, Sampler

        # by default only what a fit can move: a drawn boundary sequence or a discrete choice
        # stays at its nominal, as a constant does
        names = [p.name for p in config.parameters
                 if not isinstance(p.distribution, (Sampler, Discrete, Empirical, Constant))]
        if not names:
            raise BpsflowError("diagnosis.parameters: the config has no uncertain parameter "
                               "with a continuous distribution to fit; name the existing "
                               "parameters to calibrate", source=config.source)
    key = ("diagnosis.parameters" if settings.parameters is not None or config.calibration is None
           or config.calibration.parameters is None else "calibration.parameters")
    return calibration_parameters(config, CalibrationSettings(parameters=names), key)


def indoor_temperature(config: Config, measured: pd.DataFrame,
                       timestamps: pd.DatetimeIndex) -> np.ndarray:
    """Indoor air temperature (°C) for the wind × ΔT basis: measured if present, else the setpoint."""
    for column in measured.columns:
        unit = config.outputs[column].unit if column in config.outputs else ""
        if unit.strip().upper() in ("C", "°C", "DEGC") and "zone" in column.lower():
            return measured.loc[timestamps, column].to_numpy(dtype=float)
    from bpsflow.calibration.design import hourly_setpoints

    heating, _ = hourly_setpoints(config, timestamps)
    return heating


#: A candidate whose calibration RMSE is below this share of the current model's, yet whose
#: linearised out-of-fold error is larger, has its folds refitted by simulation.
LINEARISED_DOUBT = 0.9
#: When the current model's linearised out-of-fold RMSE exceeds its calibration RMSE by this
#: factor, every model's folds are refitted by simulation: leaving out one week of several
#: does not triple an honest model's error, while a difference step across an EnergyPlus
#: control threshold (a Jacobian column hundreds of times the physical response in one
#: week) does more (the 3-zone office's third round: 4 % in the calibration, 64 % out of fold).
LINEARISED_BLOWUP = 3.0

#: Smallest |correlation| of the prediction with the outdoor temperature that tells its sign.
SIGN_CORRELATION = 0.2


def output_sign(config: Config, output: str, prediction: np.ndarray | None = None,
                outdoor_temperature_c: np.ndarray | None = None) -> float:
    """The output's response to an added heat gain: −1 for a heating energy or power, +1 otherwise.

    Read from the model first: an output that falls as the outdoor air warms
    (a heating load, whatever its meter or fuel is called: a gas meter, a
    district-heating meter, a boiler's energy) also falls when heat is added
    indoors; one that rises (an air temperature, a cooling load) rises.
    When the model's ``prediction`` hardly follows ``outdoor_temperature_c``
    (|r| below :data:`SIGN_CORRELATION`), the names decide: the output's
    variable or meter, or its own name, containing ``heating``.
    """
    if prediction is not None and outdoor_temperature_c is not None:
        prediction = np.asarray(prediction, dtype=float)
        outdoor = np.asarray(outdoor_temperature_c, dtype=float)
        if np.std(prediction) > 0 and np.std(outdoor) > 0:
            correlation = float(np.corrcoef(prediction, outdoor)[0, 1])
            if abs(correlation) >= SIGN_CORRELATION:
                return float(np.sign(correlation))
    spec = config.outputs.get(output)
    names = [output] + ([spec.variable or "", spec.meter or ""] if spec is not None else [])
    return -1.0 if any("heating" in name.lower() for name in names) else 1.0


@dataclass
class Data:
    """The measured output prepared for diagnosis (one dataset)."""

    output: str
    timestamps: pd.DatetimeIndex
    y: np.ndarray                 # measured output at every hour
    calibration: np.ndarray       # bool: fitted hours (the rest is the held-out block)
    drivers: pd.DataFrame
    indoor: np.ndarray            # °C, for the wind × ΔT basis
    unmeasured: int = 0           # evaluated hours without a measured value, left out


def prepare(config: Config, measured: pd.DataFrame, settings: DiagnosisSettings) -> Data:
    """Select the output, split calibration / held-out days, derive the drivers."""
    output = choose_output(config, measured, settings)
    unmeasured = _unmeasured_hours(config, measured, output)
    series = measured[output].dropna()
    # warm-up days are simulated, not evaluated (as in validate and calibrate): the model's
    # start from its initial state is no evidence of what it lacks
    stamps = pd.DatetimeIndex(series.index)
    evaluated = np.zeros(len(stamps), bool)
    for test in config.model.tests:
        if output in test.outputs:
            _, first, last = test_dates(test, config.model.year)
            evaluated |= ((stamps > pd.Timestamp(first))
                          & (stamps <= pd.Timestamp(last) + pd.Timedelta(days=1)))
    series = series[evaluated]
    timestamps = pd.DatetimeIndex(series.index)
    days = (timestamps - pd.Timedelta(hours=1)).normalize()
    last_days = np.sort(days.unique())[-settings.holdout_days:]
    calibration = ~np.isin(days, last_days)
    if calibration.sum() < 48 or (~calibration).sum() < 24:
        raise BpsflowError(f"diagnosis.holdout_days: {settings.holdout_days} leaves "
                           f"{int(calibration.sum())} calibration and {int((~calibration).sum())} "
                           f"held-out hours of {output}; expected at least 48 and 24",
                           source=config.source)
    drivers = derive_drivers(config.model.weather, timestamps, measured.loc[timestamps],
                             exclude=list(config.outputs))
    return Data(output, timestamps, series.to_numpy(dtype=float), calibration, drivers,
                indoor_temperature(config, measured, timestamps), unmeasured)


def _unmeasured_hours(config: Config, measured: pd.DataFrame, output: str) -> int:
    """Evaluated hours of the tests reporting ``output`` that have no measured value."""
    from bpsflow.alignment import output_evaluation_hours

    hours = output_evaluation_hours(config, output)
    return int(measured[output].reindex(hours).isna().sum())


def diagnose(config: Config, measured: pd.DataFrame, out_dir: Path, *,
             backend: str, jobs: int | None = None, settings: DiagnosisSettings | None = None,
             announce: Announce = print, step: Callable[[str], None] | None = None) -> Diagnosis:
    """Run the four steps on ``measured`` (timestamp index, one column per output).

    Parameters
    ----------
    backend : {"surrogate", "energyplus"}
        Where every fit runs (the same model the user runs).
    step : callable, optional
        Called with a label after each batch of fits (drives a progress bar).
    """
    return diagnose_many(config, [measured], [out_dir], backend=backend, jobs=jobs,
                         settings=settings, announce=announce, step=step)[0]


def diagnose_many(config: Config, measured: list[pd.DataFrame], out_dirs: list[Path], *,
                  backend: str, jobs: int | None = None,
                  settings: DiagnosisSettings | None = None, announce: Announce = print,
                  step: Callable[[str], None] | None = None) -> list[Diagnosis]:
    """:func:`diagnose` for several datasets of the same hours, base fits in one batch.

    Repeated datasets (e.g. the false-alarm check over noise seeds) share
    every simulation batch of the base fit; the rest runs dataset by dataset.
    """
    settings = settings or settings_of(config)
    data = [prepare(config, m, settings) for m in measured]
    if any(not d.timestamps.equals(data[0].timestamps) for d in data[1:]):
        raise ValueError("diagnose_many needs datasets of the same hours")
    context = _Context(config, data[0], settings, backend, jobs, Path(out_dirs[0]),
                       step or (lambda label: None))
    fitted = fitted_parameters(config, settings)
    # the extensions' zones are read before any simulation: a model whose zone cannot be
    # told fails now, not after the base fit
    zones = {family: diagnosis_zone(config, data[0].output, family)
             for family in settings.extensions}
    if data[0].unmeasured:
        context.notes.append(f"{data[0].unmeasured} evaluated hour(s) of {data[0].output} have "
                             f"no measured value and are left out of every fit and test "
                             f"({len(data[0].timestamps)} hours used)")
        announce(context.notes[-1])
    left_out = data[0].drivers.attrs.get("left_out", [])
    if left_out:
        context.notes.append(f"measured column(s) {', '.join(left_out)} left out of the "
                             "drivers: no data over the analysed hours")
        announce(context.notes[-1])
    if zones and building_level_zone(config, data[0].output):
        zone = next(iter(zones.values()))
        context.notes.append(
            f"'{data[0].output}' is a building-level output (no zone key): it cannot tell "
            f"which zone a cause sits in, so candidate extensions are written for the "
            f"conditioned zone with the most floor area, '{zone}' (diagnosis.zone picks "
            f"another)")
        announce(context.notes[-1])
    announce(f"fitting {len(fitted)} existing parameter(s) to {data[0].output} "
             f"({int(data[0].calibration.sum())} calibration hours, "
             f"{int((~data[0].calibration).sum())} held out)"
             + (f", {len(data)} datasets" if len(data) > 1 else ""))
    started = time.perf_counter()
    try:
        fits = _base_fits(context, config, fitted, data)
    except Exception as exc:
        if (isinstance(exc, BpsflowError) and not isinstance(exc, BatchFailure)) \
                or os.environ.get("BPSFLOW_DEBUG"):
            raise
        message = exc.message if isinstance(exc, BpsflowError) else f"{type(exc).__name__}: {exc}"
        raise BpsflowError(f"diagnose: the fit of the existing parameters failed, so there is "
                           f"nothing to diagnose: {_excerpt(message)}",
                           source=config.source) from exc
    shared = time.perf_counter() - started
    if any(fit.failed for fit in fits):
        # nothing to diagnose without a fitted model: the one case that writes nothing
        raise BpsflowError(f"diagnose: the fit of the existing parameters failed, so there is "
                           f"nothing to diagnose: "
                           f"{_excerpt(next(f for f in fits if f.failed).failure)}",
                           source=config.source)
    shared_notes = list(context.notes)
    results = []
    for d, fit, out_dir in zip(data, fits, out_dirs):
        started = time.perf_counter()
        context.data, context.out_dir = d, Path(out_dir)
        context.notes = list(shared_notes)
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        # an input far from its nominal value may stand in for physics the model lacks (a
        # leak that follows ΔT fits as a conductance): the user sees where the fit went
        announce(f"  fitted: {_fitted_text(fit.named)}")
        results.append(_diagnose_one(context, Model(config, fitted, fit, "base"), announce))
        results[-1].seconds = time.perf_counter() - started + shared
        results[-1].timings = {k: round(v, 2) for k, v in context.timings.items()}
        context.timings = {}
    return results


class _Context:
    """What every step of one diagnosis needs: data, settings, simulators."""

    def __init__(self, config: Config, data: Data, settings: DiagnosisSettings, backend: str,
                 jobs: int | None, out_dir: Path, step: Callable[[str], None]):
        self.config, self.data, self.settings = config, data, settings
        self.backend, self.jobs, self.out_dir, self.step = backend, jobs, out_dir, step
        #: a vectorised backend (the surrogate) pays per call, another (EnergyPlus) per run
        self.vectorised = get_backend(backend).vectorised
        self.round_number = 0
        #: wall time of each batch of fits (s), by label, for the report
        self.timings: dict[str, float] = {}
        #: out-of-fold predictions of a model, by (label, round): shared by its candidates
        self.oof_cache: dict[tuple[str, int, str], np.ndarray] = {}
        self.notes: list[str] = []       # Diagnosis.notes of the dataset under diagnosis
        self.stage = "base"              # the last batch started (named in a failure note)

    def simulator(self, config: Config, label: str):
        # a failed run is a NaN row, never an exception (fit_many, signatures handle it)
        self.stage = label
        return output_simulator(config, self.data.output, self.data.timestamps,
                                backend=self.backend, work_dir=self.out_dir / "runs" / label,
                                jobs=self.jobs, sequences_dir=self.out_dir / "runs",
                                on_failure="record")

    @staticmethod
    def sample_of(config: Config, fit: Fit | None = None) -> dict[str, float]:
        """Every parameter's value: nominal, extensions at zero, fitted values over them."""
        sample = {p.name: float(p.distribution.nominal) for p in config.parameters}
        for p in config.parameters:
            if p.provenance and "nested_at" in p.provenance:
                sample[p.name] = float(p.provenance["nested_at"])
        if fit is not None:
            sample.update(fit.named)
        return sample

    def fit(self, config: Config, label: str, problems: list[Problem],
            max_iterations: int | None = None) -> list[Fit]:
        started = time.perf_counter()
        fits = fit_many(self.simulator(config, label), problems,
                        max_iterations=max_iterations or self.settings.max_fit_iterations,
                        jacobian_on_acceptance=not self.vectorised)
        self.timings[label] = self.timings.get(label, 0.0) + time.perf_counter() - started
        for number, fit in enumerate(fits, start=1):
            if fit.failed_trials:
                self.notes.append(f"fits '{label}', problem {number}: {len(fit.failed_trials)} "
                                  f"trial point(s) did not run and were rejected steps; the "
                                  f"first: {_excerpt(fit.failed_trials[0])}")
        self.step(label)
        return fits

    def run_rows(self, config: Config, label: str, rows: list[dict[str, float]],
                 timing_label: str | None = None) -> np.ndarray:
        """The output of each row of parameter values, ``(len(rows), n)``, from one batch.

        The batch runs under ``label``; its wall time is added to
        :attr:`timings` under ``timing_label`` (default ``label``).
        """
        started = time.perf_counter()
        predicted = np.asarray(self.simulator(config, label)(
            pd.DataFrame(rows, index=pd.RangeIndex(len(rows), name="instance"))), dtype=float)
        key = timing_label or label
        self.timings[key] = self.timings.get(key, 0.0) + time.perf_counter() - started
        return predicted

    def block_scores(self, fit: Fit) -> dict:
        d, s = self.data, self.settings
        ensemble = predictive_ensemble(fit, s.ensemble_size, s.seed)
        cal = d.calibration
        return {"calibration": scores(d.y[cal], fit.prediction[cal], ensemble[cal]),
                "heldout": scores(d.y[~cal], fit.prediction[~cal], ensemble[~cal])}

    def test(self, residual: np.ndarray):
        d, s = self.data, self.settings
        cal = d.calibration
        min_amplitude = s.min_amplitude * abs(float(np.mean(d.y[cal])))
        return structure.test_drivers(
            pd.Series(residual, index=d.timestamps[cal]), d.drivers[cal],
            indoor_temperature_c=d.indoor[cal], alpha=s.alpha, min_share=s.min_share,
            min_amplitude=min_amplitude, folds=s.folds)


#: Latin-hypercube points screened for the base fit's starts when ``start_screen`` is not set.
DEFAULT_START_SCREEN = {"energyplus": 16, "surrogate": 0}


def starting_points(simulate, base_sample: dict[str, float], fitted: list[Parameter],
                    data: list[Data], screen: int, keep: int, seed: int
                    ) -> list[list[dict[str, float] | None]]:
    """Per dataset, the starts of the base fit: nominal (``None``) and the best screened points.

    ``screen`` Latin-hypercube points over the fitted parameters' ranges run
    in one batch of ``simulate`` (shared by every dataset); per dataset the
    ``keep`` with the smallest mean squared error on the calibration hours
    are kept. Points that did not run are never kept.
    """
    from bpsflow.sampling import latin_hypercube_unit

    if screen <= 0 or keep <= 0 or not fitted:
        return [[None] for _ in data]
    unit = latin_hypercube_unit(screen, len(fitted), seed)
    bounds = np.array([parameter_range(p) for p in fitted]).reshape(-1, 2)
    values = bounds[:, 0] + unit * (bounds[:, 1] - bounds[:, 0])
    points = [{p.name: float(v) for p, v in zip(fitted, row)} for row in values]
    predicted = simulate(pd.DataFrame([{**base_sample, **point} for point in points],
                                      index=pd.RangeIndex(len(points), name="instance")))
    starts: list[list[dict[str, float] | None]] = []
    for d in data:
        errors = np.mean((d.y[d.calibration] - predicted[:, d.calibration]) ** 2, axis=1)
        errors = np.where(np.isfinite(errors), errors, np.inf)
        best = [int(i) for i in np.argsort(errors)[:keep] if np.isfinite(errors[i])]
        starts.append([None, *(points[i] for i in best)])
    return starts


def _base_fits(context: _Context, config: Config, fitted: list[Parameter],
               data: list[Data]) -> list[Fit]:
    """The base fit of every dataset: a local search from each start, the lowest objective kept."""
    settings = context.settings
    sample = context.sample_of(config)
    screen = settings.start_screen if settings.start_screen is not None else \
        DEFAULT_START_SCREEN.get(context.backend, 0)
    starts = starting_points(context.simulator(config, "base_starts"), sample, fitted, data,
                             screen, settings.fit_starts, settings.seed)
    problems = [Problem(sample, fitted, d.y, d.calibration, start)
                for d, mine in zip(data, starts) for start in mine]
    fits = context.fit(config, "base", problems)
    chosen, first = [], 0
    for mine in starts:
        group = fits[first:first + len(mine)]
        first += len(mine)
        ran = [f for f in group if not f.failed]
        chosen.append(min(ran, key=lambda f: f.objective) if ran else group[0])
    return chosen


def _diagnose_one(context: _Context, base: Model, announce: Announce) -> Diagnosis:
    """Every round on one dataset; a step that fails ends it with a note, never a crash.

    A :class:`~bpsflow.errors.BpsflowError` that is not a failed batch is
    the user's input (a zone, a snippet) and is raised; anything else (a
    failed batch, an internal error) keeps the verdict reached so far.
    """
    d = context.data
    result = Diagnosis(output=d.output, timestamps=d.timestamps, measured=d.y,
                       calibration=d.calibration, drivers=d.drivers, base=base, final=base,
                       scorecard=context.block_scores(base.fit), backend=context.backend,
                       notes=context.notes)
    try:
        return _diagnose_rounds(context, result, base, announce)
    except Exception as exc:
        if (isinstance(exc, BpsflowError) and not isinstance(exc, BatchFailure)) \
                or os.environ.get("BPSFLOW_DEBUG"):
            raise
        message = exc.message if isinstance(exc, BpsflowError) else \
            f"{type(exc).__name__}: {exc}"
        result.notes.append(f"the diagnosis stopped at step '{context.stage}' (round "
                            f"{max(len(result.rounds), 1)}); the verdict is the one reached "
                            f"before it: {_excerpt(message)}")
        announce(f"step '{context.stage}' failed ({_excerpt(message, 160)}); "
                 f"the diagnosis keeps what it found before")
    for entry in result.extensions:
        entry.setdefault("accepted", False)
    try:
        _finish(context, result)
    except Exception as exc:  # the scores of the final model: keep the rest of the record
        result.final_scores = result.final_scores or result.scorecard
        result.gain = result.gain or {}
        result.notes.append(f"the final scores could not be computed: "
                            f"{_excerpt(f'{type(exc).__name__}: {exc}')}")
    found = result.rounds[-1]["significant"] if result.rounds else []
    if result.verdict == "none" and found:
        result.cause["summary"] = (f"Significant driver(s) {', '.join(found)} were found, but "
                                   f"the diagnosis stopped at step '{context.stage}' before "
                                   f"naming a cause (see the notes).")
    else:
        result.cause["summary"] = (result.cause.get("summary", "") + f" The diagnosis stopped "
                                   f"early, at step '{context.stage}' (see the notes).").strip()
    return result


def _excerpt(text: str, size: int = 300) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= size else text[:size] + " ..."


def _diagnose_rounds(context: _Context, result: Diagnosis, base: Model,
                     announce: Announce) -> Diagnosis:
    d, settings = context.data, context.settings
    current = base
    accepted_causes: set[str] = set()
    for round_number in range(1, settings.max_rounds + 1):
        context.round_number = round_number
        residual = d.y - current.fit.prediction
        tests = context.test(residual[d.calibration])
        white = structure.whiteness(residual[d.calibration])
        significant = [t for t in tests if t.significant]
        suggestive = _suggestive(context, tests)
        result.rounds.append({"round": round_number, "model": current.label,
                              "drivers": [_driver_record(t) for t in tests], "whiteness": white,
                              "significant": [t.name for t in significant],
                              "suggestive": [t.name for t in suggestive]})
        announce(f"round {round_number}: " + (
            f"significant driver(s): {', '.join(t.name for t in significant)}" if significant
            else "no significant structure in the residuals")
            + (f"; suggestive: {', '.join(t.name for t in suggestive)}" if suggestive else ""))
        called: list[Candidate] | None = None
        acceptance_alpha = settings.gain_alpha
        if not significant and not suggestive:
            if not settings.shape_screen:
                break
            # No weather or calendar driver passes its gates, but an effect that acts
            # with a delay (stored heat released at the next morning's reheat) is not
            # synchronous with any driver: test each candidate's own simulated shape.
            called = _shape_screen(context, result, current, tests, residual,
                                   accepted_causes, round_number, announce)
            if not called:
                break
            if accepted_causes:
                # what is left beside an accepted cause holds its small misfit (a block's
                # edges, a law's curvature), and the screen tried every candidate's shape on
                # it: a further cause must pass at the family-wise level of the driver
                # tests, not a single test's
                acceptance_alpha = min(settings.alpha, settings.gain_alpha)
        explained = None
        if round_number == 1 and significant:
            explained = _parameter_check(context, result, current, residual, significant)
            if explained is None:
                result.verdict = "model_form"
                result.cause = {"driver": significant[0].name, "parameter": None,
                                "extension": None, "summary": ""}
        candidates = called if called is not None else candidate_causes(
            context, current, significant + suggestive, accepted_causes)
        if explained is not None and not candidates:
            _accept_parameter(result, *explained, significant[0].name, announce)
            break
        if not candidates:
            announce("no candidate extension left for these drivers")
            result.unexplained = [t.name for t in significant]
            break
        entries = _try_extensions(context, result, current, candidates, residual, round_number,
                                  announce, acceptance_alpha)
        passed = [(e, m) for e, m in entries if e["passed"] and m is not None]
        result.extensions += [e for e, _ in entries]
        if explained is not None:
            # a mis-valued input and a missing piece of physics can leave the same residual
            # shape (ground reflectance and a roof aperture): they compete on BIC, and the
            # existing input, the smaller change to the model, wins a tie
            if not _extension_beats_parameter(context, explained[0], passed, announce):
                _accept_parameter(result, *explained, significant[0].name, announce)
                break
            result.verdict = "model_form"
            result.cause = {"driver": significant[0].name, "parameter": None,
                            "extension": None, "summary": ""}
        if not passed:
            continued = _continue_fit(context, result, current, entries, round_number,
                                      announce)
            if continued is not None:
                current = continued
                continue
            announce("no candidate extension improved the cross-validated accuracy "
                     "significantly")
            result.unexplained = [t.name for t in significant]
            break
        best, model = choose_cause(passed)
        best["accepted"] = True
        result.verdict = "model_form"
        accepted_causes.add(best["cause"])
        current = result.final = model
        if not result.cause.get("extension"):
            _name_cause(result, best)
        announce(f"accepted {best['cause']} ({_fitted_text(best['fitted'])}): out-of-fold "
                 f"CV(RMSE) {best['cross_validation']['cvrmse_before']:.3%} -> "
                 f"{best['cross_validation']['cvrmse_after']:.3%}"
                 + (f"; runner-up {best['runner_up']['cause']} (ΔBIC "
                    f"{best['runner_up']['delta_bic']:.1f}, "
                    f"{best['runner_up']['delta_bic_effective']:.1f} on independent hours, "
                    f"{best['runner_up']['evidence']})" if best.get("runner_up") else "")
                 + (f"; chosen by {best['chosen_by']}" if best.get("chosen_by") else ""))
    else:
        residual = d.y - current.fit.prediction
        left = [t.name for t in context.test(residual[d.calibration]) if t.significant]
        if left and result.verdict == "model_form":
            result.unexplained = left
            result.round_limit_reached = True
            result.notes.append(
                f"the diagnosis stopped at its round limit (diagnosis.max_rounds: "
                f"{settings.max_rounds}) with structure left ({', '.join(left)}); each round "
                f"accepts one cause, so another may remain: raise diagnosis.max_rounds to look "
                f"for it")
            announce(result.notes[-1])
    _prune(context, result, announce)
    for entry in result.extensions:
        entry.setdefault("accepted", False)
    _finish(context, result)
    return result


def _prune(context: _Context, result: Diagnosis, announce: Announce) -> None:
    """Backward step: every accepted extension must still pass acceptance beside the others.

    Forward selection accepts the best cause of each round given those
    before it; an early one can stand in for effects found later (a gain
    block that mimics stored heat before ``thermal_mass`` is fitted). With
    two or more accepted, each is removed in turn (its size parameters at
    their nested value, the rest refitted, one batch) and the full model is
    tested against that reduced one by the same blocked cross-validation
    as a forward step. The weakest that no longer passes is dropped and
    the test repeats on the rest.
    """
    d, settings = context.data, context.settings
    for sweep in range(1, 10):
        accepted = [e for e in result.extensions if e.get("accepted")]
        if len(accepted) < 2:
            return
        final = result.final
        full_sample = context.sample_of(final.config, final.fit)
        reduced: list[tuple[dict, list[Parameter], dict]] = []
        for entry in accepted:
            names = set(entry.get("parameter_names", {}).values())
            own = [p for p in final.fitted if p.name in names]
            if not own:
                continue
            sample = dict(full_sample)
            for p in own:
                sample[p.name] = float((p.provenance or {}).get("nested_at", 0.0))
            reduced.append((entry, _without(final.fitted, own), sample))
        if not reduced:
            return
        fits = context.fit(final.config, f"prune{sweep}", [
            Problem(sample, fitted, d.y, d.calibration,
                    {p.name: final.fit.named[p.name] for p in fitted})
            for _, fitted, sample in reduced])
        weakest = None
        for (entry, fitted, sample), fit in zip(reduced, fits):
            if fit.failed:
                context.notes.append(f"pruning: the model without {entry['cause']} could not "
                                     f"be refitted and the extension is kept: "
                                     f"{_excerpt(fit.failure)}")
                continue
            without = Model(final.config, fitted, fit, f"prune{sweep}_{entry['cause']}")
            cv = _cross_validate(context, final.config, sample, without,
                                 [(final.fitted, final.fit)], 1000 + sweep).get(0)
            if cv is None:
                continue
            p_value = float(cv["test"]["p_value"])
            keeps = p_value < settings.gain_alpha and cv["cvrmse_after"] < cv["cvrmse_before"]
            entry["pruning"] = {"p_value": p_value, "cvrmse_without": cv["cvrmse_before"],
                                "cvrmse_with": cv["cvrmse_after"], "kept": bool(keeps)}
            if not keeps and (weakest is None or p_value > weakest[0]):
                weakest = (p_value, entry, without)
        if weakest is None:
            return
        _, entry, without = weakest
        entry["accepted"] = False
        entry["pruned"] = True
        result.final = without
        _refitted_sizes(result, without.fit)
        context.notes.append(f"{entry['cause']} was accepted in round {entry['round']} but no "
                             f"longer improves the cross-validated fit beside the causes found "
                             f"after it (p = {entry['pruning']['p_value']:.3g}): it is dropped")
        announce(f"pruned {entry['cause']}: beside the other accepted causes it no longer "
                 f"improves the out-of-fold fit (p = {entry['pruning']['p_value']:.3g})")
        if result.cause.get("extension") == entry["name"]:
            _name_cause(result, next(e for e in result.extensions if e.get("accepted")))


def _name_cause(result: Diagnosis, entry: dict) -> None:
    """The verdict's cause is the accepted extension ``entry`` (the first one accepted)."""
    result.cause.update(extension=entry["name"], driver=entry["driver"],
                        confidence=entry.get("confidence"), runner_up=entry.get("runner_up"))


def _continue_fit(context: _Context, result: Diagnosis, current: Model,
                  entries: list[tuple[dict, Model | None]], round_number: int,
                  announce: Announce) -> Model | None:
    """The current model refitted from a candidate that beat it without being a cause, if any.

    A candidate fitted at zero (:func:`null_sized`), or one whose own effect
    is below the smallest that matters while the fit improved significantly,
    owes its gain to the existing parameters it moved: the current model's
    own fit had stopped short of their better values (a nonlinear output, a
    thermal mass, a start far off). The current model's fit, continued from
    there, is the better model, and the residuals are tested again. ``None``
    when no such candidate improved the fit significantly or the continued fit
    is no better.
    """
    d = context.data
    better = [(e, m) for e, m in entries if m is not None and e.get("improves_fit")]
    if not better:
        return None
    _, start = min(better, key=lambda pair: pair[0]["bic"]["after"])
    label = f"round{round_number}_continued"
    fit = context.fit(current.config, label, [Problem(
        context.sample_of(current.config, current.fit), list(current.fitted), d.y,
        d.calibration, {p.name: start.fit.named[p.name] for p in current.fitted})])[0]
    if fit.failed:
        context.notes.append(f"round {round_number}: the current model's continued fit "
                             f"failed: {_excerpt(fit.failure)}")
        return None
    cal = d.calibration
    before = comparison.bic(d.y[cal] - current.fit.prediction[cal], len(current.fitted))
    after = comparison.bic(d.y[cal] - fit.prediction[cal], len(current.fitted))
    if not after < before:
        return None
    model = Model(current.config, list(current.fitted), fit, label)
    if result.final is not result.base:
        result.final = model
    _refitted_sizes(result, fit)
    context.notes.append(f"round {round_number}: a candidate that is not a cause (fitted at "
                         f"zero, or with an effect too small to matter) improved the fit (BIC "
                         f"{before:.1f} -> {after:.1f}): the current model's fit had not "
                         f"converged and was continued from there")
    announce(f"the current model's fit is continued from a candidate that is not a cause: BIC "
             f"{before:.1f} -> {after:.1f}")
    return model


def _refitted_sizes(result: Diagnosis, fit: Fit) -> None:
    """Accepted extensions' sizes from a later fit of the final model (continued or pruned)."""
    for entry in result.extensions:
        if entry.get("accepted"):
            entry.setdefault("fitted_when_accepted", dict(entry["fitted"]))
            entry["fitted"] = {reported: float(fit.named[name]) for reported, name
                               in entry.get("parameter_names", {}).items()
                               if name in fit.named}


def _suggestive(context: _Context, tests: list) -> list:
    """Drivers short of significance that still call candidates (``candidate_alpha``).

    Slow drivers (wind, outdoor temperature) hold few independent events in a
    few weeks, so a large, stable effect can miss the family-wise level
    ``alpha``; its candidates are then fitted anyway, and only the
    cross-validated acceptance test (whose size is measured, see
    :mod:`bpsflow.diagnosis.crossval`) can turn them into a verdict. The
    other gates (share, amplitude, stable sign) still apply.
    """
    settings, d = context.settings, context.data
    min_amplitude = settings.min_amplitude * abs(float(np.mean(d.y[d.calibration])))
    return [t for t in tests if not t.significant and t.p_adjusted < settings.candidate_alpha
            and t.share >= settings.min_share and t.amplitude >= min_amplitude
            and t.sign_consistent]


def _shape_screen(context: _Context, result: Diagnosis, current: Model, tests: list,
                  residual: np.ndarray, accepted: set[str], round_number: int,
                  announce: Announce) -> list[Candidate]:
    """The candidates whose simulated effect shape the residuals carry, tested like drivers.

    Every candidate family is written (all faces, gain blocks, law terms) and
    each new parameter is stepped once (the runs of :func:`_screen`); the
    change of the prediction, with the current fit's parameter directions
    partialled out (Frisch–Waugh), is that variant's regressor. The residuals
    are tested against it exactly as against a driver
    (:func:`bpsflow.diagnosis.structure.test_drivers`: Newey–West Wald test,
    fixed-b reference, share, amplitude and stable sign), Holm-adjusted over
    all variants at ``alpha``; steps into the parameters' allowed range must
    also fit most of it (:func:`_forward`: an extension cannot remove heat it
    never added). When one passes, structure is found, and every candidate
    goes on, as after a significant driver (:func:`candidate_causes`), to the
    screen's ranking and the fitted, cross-validated acceptance of
    :func:`_try_extensions`, which alone can make a verdict.
    """
    from bpsflow.diagnosis.structure import DriverTest, _test_one, holm

    d, settings = context.data, context.settings
    cal = d.calibration
    candidates = candidate_causes(context, current, tests, accepted)
    if not candidates:
        return []
    union = current.config
    for candidate in candidates:
        for extended, _, _ in candidate.variants:
            union = _merge(union, extended)
    flat = [(c, v) for c in candidates for v in c.variants]
    union_sample = context.sample_of(union, current.fit)
    columns = _screen_columns(context, union, union_sample, current, [v for _, v in flat],
                              round_number, "shape")
    controls = current.fit.jacobian[cal]
    y = residual[cal]
    tested: list[tuple[int, DriverTest, bool]] = []     # (flat index, test, step forward)
    for position, ((candidate, variant), design) in enumerate(zip(flat, columns)):
        if design is None:
            continue
        if controls.size:
            design = design - controls @ np.linalg.lstsq(controls, design, rcond=None)[0]
        frame = pd.DataFrame(design, columns=[p.name for p in variant[1]])
        test = _test_one(candidate.cause, y, frame, design[:, 0], folds=settings.folds,
                         hac_lags=None, reference="fixed-b", consistency="component")
        if test is not None:
            tested.append((position, test, _forward(design, y)))
    adjusted = holm([test.p_value for _, test, _ in tested]) if tested else np.zeros(0)
    min_amplitude = settings.min_amplitude * abs(float(np.mean(d.y[cal])))
    passed: dict[int, tuple[float, int]] = {}      # candidate id -> (p_adjusted, flat index)
    record = []
    for (i, test, forward), p_adjusted in zip(tested, adjusted):
        ok = bool(p_adjusted < settings.alpha and test.share >= settings.min_share
                  and test.amplitude >= min_amplitude and test.sign_consistent and forward)
        record.append({"cause": flat[i][0].cause, "parameters": [p.name for p in flat[i][1][1]],
                       "p_adjusted": float(p_adjusted), "share": float(test.share),
                       "amplitude": float(test.amplitude),
                       "sign_consistent": bool(test.sign_consistent),
                       "forward": forward, "passed": ok})
        key = id(flat[i][0])
        if ok and (key not in passed or p_adjusted < passed[key][0]):
            passed[key] = (float(p_adjusted), i)
    result.rounds[-1]["shape_screen"] = record
    for candidate in candidates:
        candidate.screen_columns = [design for (c, _), design in zip(flat, columns)
                                    if c is candidate]
    called = [c for c in candidates if id(c) in passed]
    announce("  shape screen: " + (", ".join(
        f"{c.cause} (p {passed[id(c)][0]:.2g})" for c in called) if called
        else "no candidate's simulated shape is in the residuals"))
    # a shape found is structure found: every candidate then competes, as when a driver
    # is significant (a west aperture half absorbed by the fitted glazing leaves an
    # afternoon shape that a gain block matches better in the screen's test)
    return candidates if called else []


def _forward(design: np.ndarray, residual: np.ndarray) -> bool:
    """Whether steps into the allowed range (every new parameter up from zero) fit the residual.

    True when non-negative least squares on the shape's columns explains at
    least half of what unconstrained least squares does (Lawson & Hanson
    1974): a law whose terms are correlated may fit with one negative
    coefficient, and still mostly with positive ones.
    """
    from scipy.optimize import nnls

    free = np.linalg.lstsq(design, residual, rcond=None)[0]
    explained_free = float(residual @ residual - np.sum((residual - design @ free) ** 2))
    if explained_free <= 0:
        return False
    allowed = nnls(design, residual)[0]
    explained_allowed = float(residual @ residual - np.sum((residual - design @ allowed) ** 2))
    return explained_allowed >= 0.5 * explained_free


def _driver_record(test) -> dict:
    return {"name": test.name, "group": test.group, "effect": float(test.amplitude),
            "share": float(test.share), "direction": int(test.direction),
            "p_value": float(test.p_value), "p_adjusted": float(test.p_adjusted),
            "sign_consistent": bool(test.sign_consistent), "significant": bool(test.significant)}


def where_text(entry: dict) -> str:
    """`` in zone Z on weekdays 17–22 h``: where and when an extension acts ("" if unknown)."""
    text = f" in zone {entry['zone']}" if entry.get("zone") else ""
    block = entry.get("schedule")
    if isinstance(block, dict) and "day_type" in block:
        text += f" on {block['day_type']} {block['start_hour']}–{block['end_hour']} h"
    return text


def _final_sizes(result: Diagnosis) -> None:
    """Give each accepted extension the sizes of the final model, not of its round.

    Later rounds refit every accepted extension beside the new one (a second
    gain block takes over part of the first's hours), so the sizes an
    extension had when it was accepted are not the model the verdict's gain
    is measured with. Those stay as ``fitted_when_accepted``.
    """
    final = result.final.fit.named
    for entry in result.extensions:
        if not entry.get("accepted") or "fitted_when_accepted" in entry:
            continue
        names = entry.get("parameter_names", {})
        if not names or not all(names.get(r) in final for r in entry.get("fitted", {})):
            continue
        entry["fitted_when_accepted"] = dict(entry["fitted"])
        entry["fitted"] = {reported: float(final[names[reported]])
                           for reported in entry["fitted"]}
        if entry.get("law") and entry.get("terms"):
            entry["law"] = law_text({t: entry["fitted"][t] for t in entry["terms"]
                                     if t in entry["fitted"]})


def _fitted_input_bound_notes(fit) -> list[str]:
    """A note per fitted model input (not an extension) that ended at an end of its range.

    An input pressed against its bound is standing in for something else (what
    the model lacks, or a bound set too tight), so the causes and sizes fitted
    beside it may be biased; calibrate warns the same way.
    """
    notes = []
    for parameter, value in zip(fit.parameters, fit.values):
        if parameter.group == "extension":
            continue
        low, high = parameter_range(parameter)
        if not (np.isfinite(low) and np.isfinite(high) and high > low):
            continue
        side = ("lower" if value <= low + 0.01 * (high - low) else
                "upper" if value >= high - 0.01 * (high - low) else None)
        if side is not None:
            notes.append(f"the fitted input {parameter.name} = {float(value):.4g} sits at the "
                         f"{side} end of its range ({low:.4g}..{high:.4g}): it may stand in for "
                         f"what the model lacks, so the causes and sizes fitted beside it may "
                         f"be biased (widen its range if the bound is not physical)")
    return notes


def _bound_notes(result: Diagnosis) -> list[str]:
    """A note per accepted extension size fitted at the top of its range.

    A size pressed against its bound says the extension cannot express the
    effect as it is: larger than the catalogue allows, or acting elsewhere
    (another zone, another shape), and its fit stands in for it.
    """
    parameters = {p.name: p for p in result.final.config.parameters}
    notes = []
    for entry in result.extensions:
        if not entry.get("accepted"):
            continue
        for reported, name in entry.get("parameter_names", {}).items():
            if name not in parameters or reported not in entry.get("fitted", {}):
                continue
            low, high = parameter_range(parameters[name])
            value = entry["fitted"][reported]
            if np.isfinite(high) and high > low and value >= high - 0.01 * (high - low):
                notes.append(f"{entry.get('cause', entry['name'])}{where_text(entry)}: "
                             f"{reported} = {value:.4g} sits at the top of its range "
                             f"({high:.4g}); the extension may not express this effect (larger "
                             f"than allowed, or acting in another zone or shape): treat its size "
                             f"as a bound, and check diagnosis.zone")
    return notes


def _fitted_text(fitted: dict[str, float]) -> str:
    return ", ".join(f"{k} = {v:.4g}" for k, v in fitted.items())


def _parameter_check(context: _Context, result: Diagnosis, current: Model,
                     residual: np.ndarray, significant: list) -> tuple[Model, dict] | None:
    """Does a plausible change of one existing, unfitted parameter remove the structure?

    Screen: project the residual on every candidate's characteristic
    signature (one batch of perturbation runs). The ``parameter_candidates``
    that explain the largest shares are then refitted, each freed within its
    plausible range together with the fitted parameters (one batch). If a
    refit leaves no significant driver, halves each driver's share and
    predicts the held-out days better than the current model, the best such
    one is the cause.
    """
    from bpsflow.distributions import Uniform

    d, settings = context.data, context.settings
    candidates = candidate_parameters(current.config.parameters,
                                      [p.name for p in current.fitted], settings.plausible_change)
    if settings.suspects is not None:
        candidates = [c for c in candidates if c.parameter.name in settings.suspects]
    # perturbations and refit ranges stay within what EnergyPlus accepts (IDD, glazing T + R)
    candidates = clip_to_physical(current.config, context.sample_of(current.config, current.fit),
                                  candidates, context.notes)
    if not candidates:
        return None
    found = signatures(context.simulator(current.config, "signatures"),
                       context.sample_of(current.config, current.fit), candidates,
                       current.fit.prediction, notes=context.notes)
    context.step("signatures")
    bounds = np.array([parameter_range(p) for p in current.fitted]).reshape(-1, 2)
    width = bounds[:, 1] - bounds[:, 0]
    movable = (current.fit.values > bounds[:, 0] + 1e-6 * width) & \
        (current.fit.values < bounds[:, 1] - 1e-6 * width)
    explanations = explain(residual[d.calibration], current.fit.jacobian, found, d.calibration,
                           movable)
    shortlist = [e for e in explanations if e.share >= settings.min_share]
    shortlist = shortlist[:settings.parameter_candidates]
    for e in explanations[:max(5, len(shortlist))]:
        result.parameter_check.append({"name": e.name, "change": e.change, "value": e.value,
                                       "plausible": e.plausible, "share": e.share})
    if not shortlist:
        return None
    by_name = {c.parameter.name: c for c in candidates}
    config = current.config.model_copy(deep=True)
    config.source = current.config.source
    freed = {}
    for e in shortlist:
        c = by_name[e.name]
        parameter = c.parameter.model_copy(deep=True)
        parameter.distribution = Uniform(type="uniform", lower=c.lower, upper=c.upper)
        freed[e.name] = parameter
    config.parameters = [freed.get(p.name, p) for p in config.parameters]
    sample = context.sample_of(config, current.fit)
    for e in shortlist:
        sample[e.name] = by_name[e.name].nominal
    problems = [Problem(sample, [*current.fitted, freed[e.name]], d.y, d.calibration,
                        {**current.fit.named,
                         e.name: float(np.clip(e.value, by_name[e.name].lower,
                                               by_name[e.name].upper))})
                for e in shortlist]
    fits = context.fit(config, "parameters", problems)
    before = {t.name: t.share for t in significant}
    held_out = ~d.calibration           # never empty (prepare requires 24 hours)
    rmse_before = rmse(d.y[held_out], current.fit.prediction[held_out])
    best = None
    for e, fit in zip(shortlist, fits):
        if fit.failed:
            context.notes.append(f"parameter {e.name}: its refit failed and is left out: "
                                 f"{_excerpt(fit.failure)}")
            continue
        after = context.test((d.y - fit.prediction)[d.calibration])
        left = [t.name for t in after if t.significant]
        # explained: nothing significant left AND each driver lost at least half its share
        # (a weak refit can push p over alpha without explaining the structure)
        shares = {t.name: t.share for t in after}
        halved = all(shares.get(name, 0.0) <= 0.5 * share for name, share in before.items())
        # a refit that removes the calibration structure but predicts the held-out days
        # worse has compensated, not explained (a fitted input bent to mimic missing physics)
        generalises = rmse(d.y[held_out], fit.prediction[held_out]) < rmse_before
        explains = bool(not left and halved and generalises)
        record = next(r for r in result.parameter_check if r["name"] == e.name)
        record.update(refitted=float(fit.named[e.name]), structure_left=left,
                      driver_shares_after={name: shares.get(name, 0.0) for name in before},
                      objective=fit.objective, held_out_improves=generalises,
                      explains=explains)
        if explains and (best is None or fit.objective < best[1].objective):
            best = (e, fit)
    if best is None:
        return None
    e, fit = best
    c = by_name[e.name]
    fitted = [*current.fitted, freed[e.name]]
    return (Model(config, fitted, fit, f"parameter {e.name}"),
            {"name": e.name, "nominal": c.nominal, "fitted": float(fit.named[e.name]),
             "plausible_range": [c.lower, c.upper]})


def _extension_beats_parameter(context: _Context, parameter_model: Model,
                               passed: list[tuple[dict, Model]],
                               announce: Announce) -> bool:
    """Whether the best accepted extension's BIC beats the refitted parameter's decisively.

    Both are the base model plus free parameters fitted on the same
    calibration hours, so their BIC (seed eq. 12's penalty on the parameter
    count) compares them; the extension must be lower by
    ``parameter_margin_bic`` (Kass & Raftery 1995: 6 is strong evidence).
    """
    d, cal = context.data, context.data.calibration
    if not passed:
        return False
    bic_parameter = comparison.bic(d.y[cal] - parameter_model.fit.prediction[cal],
                                   len(parameter_model.fitted))
    best = min(passed, key=lambda pair: pair[0]["bic"]["after"])[0]
    margin = bic_parameter - best["bic"]["after"]
    best["versus_parameter"] = {"parameter_bic": float(bic_parameter),
                                "delta_bic": float(margin)}
    wins = margin > context.settings.parameter_margin_bic
    announce(f"  {best['cause']} against the refitted {parameter_model.label}: BIC "
             f"{best['bic']['after']:.1f} vs {bic_parameter:.1f}: "
             + ("the extension explains more" if wins else "the existing input is kept"))
    return wins


def _accept_parameter(result: Diagnosis, model: Model, parameter_fit: dict, driver: str,
                      announce: Announce) -> None:
    """Verdict ``parameter``: the refitted model is the final one."""
    result.verdict = "parameter"
    result.final = model
    result.cause = {"driver": driver, "parameter": parameter_fit["name"], "extension": None,
                    "summary": ""}
    result.parameter_fit = parameter_fit
    announce(f"a plausible change of {parameter_fit['name']} ({parameter_fit['nominal']:.4g} -> "
             f"{parameter_fit['fitted']:.4g}) explains the structure")


@dataclass
class Candidate:
    """One candidate cause: an extension written (or re-opened) in the model, and its variants.

    ``cause`` names what would be concluded (``solar_aperture (west)``,
    ``infiltration``); ``variants`` are its alternative shapes (gain blocks),
    fitted together, the best by objective kept. ``free`` lists, per variant,
    the extension parameters fitted; ``law_terms`` marks a law whose terms are
    chosen by BIC after the fit (:func:`_choose_terms`).
    """

    cause: str
    family: str
    driver: str
    variants: list[tuple[Config, list[Parameter], dict]]
    law_terms: bool = False
    #: per variant, its screening columns if the shape screen already ran them
    screen_columns: list[np.ndarray | None] | None = None


#: Driver groups that call each extension family. Irradiance and time-of-day
#: structure are confounded (the sun follows the clock), so both call every
#: aperture and the scheduled gain, and fit decides (issue: "candidates are
#: chosen by fit, not only by the strongest driver").
FAMILY_GROUPS: dict[str, tuple[str, ...]] = {
    "internal_gain_schedule": ("hour", "weekend", "day", "irradiance"),
    "scheduled_air_exchange": ("hour", "weekend", "day", "temperature"),
    "solar_aperture": ("hour", "irradiance"),
    "infiltration": ("temperature", "wind"),
    "infiltration_wind": ("wind",),
    "envelope_ua": ("temperature",),
    "thermal_mass": ("temperature", "irradiance", "hour"),
}

#: Planes an unmodelled aperture may face: the four walls, the roof, and the sky's
#: diffuse part alone (a shaded or north-light opening).
APERTURE_FACES = ("south", "east", "west", "north", "roof", "sky_diffuse")


def candidate_causes(context: _Context, current: Model, significant: list,
                     accepted: set[str]) -> list[Candidate]:
    """The causes worth fitting for the significant drivers, every shape of each.

    A family is called by the group of any significant driver
    (:data:`FAMILY_GROUPS`), not only by the strongest one. A family no driver
    calls is still a candidate, under the strongest driver: the existing
    parameters' fit can absorb most of an effect's own signature (a constant
    leak looks like a larger wall conductance), so what is left may carry
    only a by-product of it (the morning reheat after a leaky night follows
    the clock, not the outdoor temperature). Every candidate competes on the
    linearised BIC screen of :func:`_try_extensions`, and only the best are
    fitted and cross-validated. An aperture is
    tried on every face (:data:`APERTURE_FACES`); a face already accepted is
    not tried again. A law already in the model (infiltration) is re-opened
    with all its terms free, so a later round can correct a law chosen wrongly
    earlier; a scheduled gain may be found again (another block).
    """
    from bpsflow.diagnosis.drivers import driver_group

    settings = context.settings
    groups: dict[str, str] = {}
    for test in significant:
        groups.setdefault(test.group, test.name)
    allowed = [name for name in settings.extensions if name in EXTENSIONS]
    out: list[Candidate] = []
    for family in allowed:
        called_by = FAMILY_GROUPS.get(family) or tuple(
            driver_group(name) for name in EXTENSIONS[family].drivers)
        calling = [groups[g] for g in called_by if g in groups]
        if not calling and not significant:
            continue
        driver = calling[0] if calling else significant[0].name
        if family == "solar_aperture":
            out += _aperture_candidates(context, current, driver, accepted,
                                        {t.name for t in significant})
        elif family in SCHEDULED_BLOCKS:
            out += _block_candidates(context, current, family, driver)
        elif family in accepted and not _is_law(family):
            continue
        else:
            out.append(_plain_candidate(context, current, family, driver))
    return out


def _is_law(family: str) -> bool:
    return len(EXTENSIONS[family].parameters) > 1 and family.startswith("infiltration")


def _directory(context: _Context, family: str) -> Path:
    return context.out_dir / "extensions" / f"round{context.round_number}_{family}"


def _extension_parameters(config: Config, family: str) -> list[Parameter]:
    return [p for p in config.parameters
            if (p.provenance or {}).get("extension") == family]


def _plain_candidate(context: _Context, current: Model, family: str,
                     driver: str) -> Candidate:
    """One extension with all its parameters free; a law already in the model is re-opened."""
    config = current.config
    present = _extension_parameters(config, family)
    if present:
        return Candidate(family, family, driver, [(config, present, {"reopened": True})],
                         law_terms=_is_law(family))
    zone = diagnosis_zone(config, context.data.output, family)
    extended = extend_config(config, EXTENSIONS[family], _directory(context, family), zone=zone)
    known = {p.name for p in config.parameters}
    new = [p for p in extended.parameters if p.name not in known]
    return Candidate(family, family, driver, [(extended, new, {"zone": zone})],
                     law_terms=_is_law(family))


def _block_candidates(context: _Context, current: Model, family: str,
                      driver: str) -> list[Candidate]:
    """The shortlisted on/off blocks of a scheduled extension (:data:`SCHEDULED_BLOCKS`).

    A gain's blocks are where the residuals ask for heat; an air exchange's
    where they ask for a loss (the gain's screen with the sign turned).
    """
    d, config = context.data, current.config
    as_gain = SCHEDULED_BLOCKS[family][1]
    zone = diagnosis_zone(config, d.output, family)
    residual = d.y - current.fit.prediction
    cal = d.calibration
    # an output that is zero in the model and the data (a heating power while the zone
    # floats) cannot respond to a gain at that hour
    still = 1e-6 * max(float(np.max(np.abs(d.y[cal]))), 1e-12)
    responsive = (np.abs(current.fit.prediction[cal]) > still) | (np.abs(d.y[cal]) > still)
    blocks = gain_blocks(pd.Series(residual[cal], index=d.timestamps[cal]),
                         as_gain * output_sign(
                             config, d.output, current.fit.prediction[cal],
                             d.drivers["outdoor_air_temperature"].to_numpy()[cal]
                             if "outdoor_air_temperature" in d.drivers else None),
                         fitted_jacobian=current.fit.jacobian[cal],
                         count=context.settings.gain_blocks, responsive=responsive)
    known = {p.name for p in config.parameters}
    variants = []
    for number, (profile, block) in enumerate(blocks, start=1):
        extended = extend_config(config, EXTENSIONS[family], _directory(context, family),
                                 profile_schedule(profile, config.model.year),
                                 _fresh_variant(config, family, number), zone=zone)
        variants.append((extended, [p for p in extended.parameters if p.name not in known],
                         {"schedule": block, "zone": zone}))
    return [Candidate(family, family, driver, variants)] if variants else []


def _fresh_variant(config: Config, family: str, number: int) -> int:
    """A variant number whose parameter names are not in ``config`` yet (a second gain...)."""
    taken = {p.name for p in config.parameters}
    base = [p.name for p in EXTENSIONS[family].parameters]
    offset = 0
    while any(f"{name}_v{number + offset}" in taken for name in base):
        offset += 100
    return number + offset


def _aperture_candidates(context: _Context, current: Model, driver: str,
                         accepted: set[str], significant_names: set[str]) -> list[Candidate]:
    d, config = context.data, current.config
    family = "solar_aperture"
    zone = diagnosis_zone(config, d.output, family)
    known = {p.name for p in config.parameters}
    out = []
    for number, face in enumerate(APERTURE_FACES, start=1):
        cause = f"{family} ({face})"
        if cause in accepted:
            continue
        if face == "sky_diffuse":
            irradiance, geometry = sky_diffuse_irradiance(config), {"facade": face, "zone": zone}
        else:
            irradiance, geometry = facade_irradiance(config, zone, face)
        extended = extend_config(config, EXTENSIONS[family], _directory(context, family),
                                 irradiance, _fresh_variant(config, family, number), zone=zone)
        own = f"incident_solar_{face}"
        out.append(Candidate(cause, family, own if own in significant_names else driver,
                             [(extended, [p for p in extended.parameters if p.name not in known],
                               geometry)]))
    return out


def _try_extensions(context: _Context, result: Diagnosis, current: Model,
                    candidates: list[Candidate], residual: np.ndarray, round_number: int,
                    announce: Announce, acceptance_alpha: float
                    ) -> list[tuple[dict, Model | None]]:
    """Fit every candidate's variants, choose each one's shape, cross-validate the best causes.

    ``acceptance_alpha`` is the level of the out-of-fold encompassing test a
    cause must pass (``gain_alpha``, or ``alpha`` in a shape-screen round after
    an accepted cause: :func:`_diagnose_rounds`).

    All variants are fitted in one batch on the union of their IDF objects:
    every extension is nested at zero, so with the other candidates' new
    parameters at zero the union *is* ``current`` plus that one variant. Per
    cause the variant with the lowest objective is kept (a law's terms are
    then chosen by BIC, :func:`_choose_terms`). The causes are ranked by BIC on
    the calibration hours; the ``cv_candidates`` best, and the best of every
    other family that improves on ``current`` (:func:`_nominated`), are
    cross-validated over the whole period (:mod:`bpsflow.diagnosis.crossval`), and a cause
    passes when its change of the out-of-fold prediction explains the
    current model's out-of-fold errors (:func:`comparison.encompassing_test`,
    fixed-b, at ``gain_alpha``), its BIC is lower and its out-of-fold CV(RMSE)
    is lower than ``current``'s.
    """
    d, settings = context.data, context.settings
    union = current.config
    for candidate in candidates:
        for extended, _, _ in candidate.variants:
            union = _merge(union, extended)
    flat = [(c, v) for c in candidates for v in c.variants]
    announce(f"fitting {len(candidates)} candidate cause(s) ({len(flat)} variant(s)): "
             + ", ".join(f"{c.cause} ({c.driver})" for c in candidates))
    union_sample = context.sample_of(union, current.fit)
    # the fits start from this very row, so on a slow backend its run is reused from the
    # run cache: the check costs one run on the surrogate and none on EnergyPlus
    at_zero = context.simulator(union, f"round{round_number}_nesting")(
        pd.DataFrame([union_sample], index=pd.RangeIndex(1, name="instance")))[0]
    note = nesting_note(d.y, at_zero, current.fit.prediction, d.calibration, d.timestamps,
                        d.output, len(current.fitted), round_number)
    if note:
        context.notes.append(note)
        announce("  " + note)
    designs: list[np.ndarray | None] | None = None
    if all(c.screen_columns is not None for c in candidates):
        designs = [d for c in candidates for d in (c.screen_columns or [])]
    screen_starts: list[dict[str, float]] = []
    screened, per_trial = _screen(context, union, union_sample, current,
                                  [v for _, v in flat], round_number, designs, screen_starts)

    def best_causes(values: list[float]) -> list[int]:
        """Per cause its best variant by ``values``, the causes ranked."""
        best_variant: dict[int, int] = {}
        for position, (candidate, _) in enumerate(flat):
            key = id(candidate)
            if key not in best_variant or values[position] < values[best_variant[key]]:
                best_variant[key] = position
        return sorted(best_variant.values(), key=lambda position: values[position])

    ranked = best_causes(screened)
    # each trial size's ranking nominates its best causes, and all are fitted for real: a
    # linearisation can be far off for one cause at one size (hundreds of BIC units), and
    # a leak whose night setback makes it nonlinear can screen no better than the current
    # model and still fit 180 BIC units better, so every family's best cause is fitted
    selected: list[int] = []
    for values in per_trial:
        selected += [i for i in _nominated(best_causes(values), values,
                                           [c.family for c, _ in flat],
                                           settings.cv_candidates, np.inf)
                     if i not in selected]
    for position, (_, variant) in enumerate(flat):
        variant[2]["screen_bic"] = float(screened[position])
    announce("  screened (linearised BIC): " + ", ".join(
        f"{flat[i][0].cause} {screened[i]:.1f}" for i in ranked))
    # Each cause is fitted from its nesting zero (the fit can only improve on
    # the current model), and again from the screen's linearised optimum when
    # the screen promised a BIC lower by SCREEN_START_MARGIN than the first fit
    # reached (on EnergyPlus only when one run of that point keeps the
    # promise), and from the best point of a small lattice over its new
    # parameters when that point alone beats the first fit (_start_screen): an
    # internal mass's area and thickness trade along a long valley that a fit
    # from zero can stall in, and at zero area the linearised screen cannot see
    # the thickness. The best fit is kept; a cause whose first fit reached both
    # promises costs no further fit.
    cal = d.calibration
    problems, flat_fitted = [], []
    for i in selected:
        free = flat[i][1][1]
        fitted = [*_without(current.fitted, free), *free]
        from_zero = {**current.fit.named,
                     # a new parameter starts where it nests the model (a thickness
                     # at its template value, not its bound)
                     **{p.name: current.fit.named.get(p.name, union_sample.get(p.name, 0.0))
                      for p in free}}
        problems.append(Problem(union_sample, fitted, d.y, d.calibration, from_zero))
        flat_fitted.append(flat[i])
    fits = context.fit(union, f"round{round_number}", problems)
    # a law's terms are chosen by BIC after its fit (_choose_terms): a random point of
    # every term at once is no start for it
    counts = [len(problem.parameters) for problem in problems]
    lattice = _start_screen(context, current, union, union_sample,
                            [[] if _is_law(flat[i][0].family) else flat[i][1][1]
                             for i in selected], counts, round_number)
    reached = [np.inf if fit.failed else
               comparison.bic(d.y[cal] - fit.prediction[cal], len(problem.parameters))
               for problem, fit in zip(problems, fits)]
    promised: list[dict[str, float] | None] = []
    for i, problem, bic_reached in zip(selected, problems, reached):
        linearised_optimum = {**(problem.start or {}), **screen_starts[i]}
        promised.append(linearised_optimum if linearised_optimum != problem.start
                        and screened[i] < bic_reached - SCREEN_START_MARGIN else None)
    if not context.vectorised:
        # where every run costs (EnergyPlus), a linearised promise is first checked by
        # one run of its point, as a lattice point is: a second fit of twenty
        # iterations from a start that is in fact worse than the first fit's end
        # costs more runs than the rest of the round
        promised = _run_checked(context, union, union_sample, promised, counts, reached,
                                round_number)
    again = []
    for i, problem, bic_reached, from_screen, (point, point_bic) in zip(
            selected, problems, reached, promised, lattice):
        if from_screen is not None:
            again.append(Problem(union_sample, problem.parameters, d.y, d.calibration,
                                 from_screen))
            flat_fitted.append(flat[i])
        if point and point_bic < bic_reached - SCREEN_START_MARGIN:
            again.append(Problem(union_sample, problem.parameters, d.y, d.calibration,
                                 {**(problem.start or {}), **point}))
            flat_fitted.append(flat[i])
    if again:
        fits = [*fits, *context.fit(union, f"round{round_number}_screen_start", again)]
        problems.extend(again)
    chosen = []         # (candidate, config, fitted parameters, detail, fit)
    for candidate in candidates:
        mine = [(v, f, problem) for (c, v), f, problem in zip(flat_fitted, fits, problems)
                if c is candidate]
        if not mine:
            continue
        (extended, free, detail), fit, problem = min(mine, key=lambda t: t[1].objective)
        if fit.failed:
            context.notes.append(f"candidate {candidate.cause} ({candidate.driver}) left out: "
                                 f"its fit failed: {_excerpt(fit.failure)}")
            continue
        variants = [v for c, v in flat if c is candidate]
        if len(variants) > 1:
            detail = {**detail, "variants": [{**v[2]} for v in variants]}
        fitted = list(problem.parameters)
        if candidate.law_terms:
            fitted, fit, detail = _choose_terms(context, union, union_sample, current, free,
                                                fit, detail, round_number)
        chosen.append((candidate, extended, fitted, detail, fit))
    bic_before = comparison.bic(d.y[cal] - current.fit.prediction[cal], len(current.fitted))

    def ranking() -> tuple[list[float], list[int]]:
        values = [comparison.bic(d.y[cal] - fit.prediction[cal], len(fitted))
                  for _, _, fitted, _, fit in chosen]
        return values, [int(i) for i in np.argsort(values)]

    bics, order = ranking()
    # a gain block's edges are refined only when it may be chosen (ranked among
    # the causes that are cross-validated): each edge step is a batch of fits
    for index in order[:settings.cv_candidates]:
        candidate, extended, fitted, detail, fit = chosen[index]
        if candidate.family in SCHEDULED_BLOCKS and "schedule" in detail:
            new = [p for p in fitted if p.name not in {q.name for q in current.fitted}]
            extended, new, detail, fit = _refine_block(context, current, extended, new, detail,
                                                       fit, round_number, candidate.family)
            chosen[index] = (candidate, extended, [*_without(current.fitted, new), *new],
                             detail, fit)
    bics, order = ranking()
    # a refined block is a new object: the cross-validation runs on a union holding it
    for _, extended, _, _, _ in chosen:
        union = _merge(union, extended)
    union_sample = context.sample_of(union, current.fit)
    validated = _nominated(order, bics, [c.family for c, *_ in chosen],
                           settings.cv_candidates, bic_before)
    before = context.block_scores(current.fit)
    oof = {validated[k]: v for k, v in _cross_validate(
        context, union, union_sample, current,
        [(chosen[i][2], chosen[i][4]) for i in validated], round_number).items()}
    out: list[tuple[dict, Model | None]] = []
    for rank, index in enumerate(order):
        candidate, extended, fitted, detail, fit = chosen[index]
        after = context.block_scores(fit)
        current_names = {q.name for q in current.fitted}
        new = [p for p in fitted if p.name not in current_names
               or (detail.get("reopened")
                   and (p.provenance or {}).get("extension") == candidate.family)]
        cv = oof.get(index)
        test: dict = cv["test"] if cv else {}
        improves = bool(cv is not None and test["p_value"] < acceptance_alpha
                        and bics[index] < bic_before
                        and cv["cvrmse_after"] < cv["cvrmse_before"])
        at_zero = null_sized(fit, new)
        # an effect that matters: the extension's own contribution is as large as a
        # driver's must be (``min_amplitude`` of the mean), so a sliver fitted on top
        # of an accepted cause is not named a second cause
        cal = d.calibration
        effect_rms = float(np.sqrt(np.mean(extension_effect(fit, new)[cal] ** 2)))
        matters = effect_rms >= settings.min_amplitude * abs(float(np.mean(d.y[cal])))
        passed, improves_fit = standing(improves, at_zero, matters)
        names = [p.name for p in fitted]
        screened_out = [(v[2]["screen_bic"], c.cause) for c, v in flat
                        if not any(c is other for other, *_ in chosen)]
        entry = {"name": candidate.family, "cause": candidate.cause, "driver": candidate.driver,
                 "round": round_number, "rank": rank + 1,
                 "fitted": {_reported(p): float(fit.named[p.name]) for p in new},
                 "parameter_names": {_reported(p): p.name for p in new},
                 "fitted_std": {_reported(p): float(np.sqrt(max(
                     fit.covariance[names.index(p.name)][names.index(p.name)], 0.0)))
                     for p in new},
                 "heldout": {"before": _short(before["heldout"]),
                             "after": _short(after["heldout"])},
                 "calibration": {"before": _short(before["calibration"]),
                                 "after": _short(after["calibration"])},
                 "cross_validation": ({k: v for k, v in cv.items()
                                       if k not in ("test", "loss_difference")} if cv
                                      else None),
                 "encompassing": test or None,
                 "loss_difference": cv["loss_difference"] if cv else None,
                 "bic": {"before": bic_before, "after": bics[index]},
                 "passed": passed, "iterations": fit.iterations,
                 "effect_rms": effect_rms,
                 **({"below_min_amplitude": True} if improves and not matters else {}),
                 **({"at_zero": True} if at_zero else {}),
                 # not a cause, but a better fit: the existing parameters moved (see
                 # _continue_fit)
                 **({"improves_fit": True} if improves_fit else {}),
                 "files": str(extended.model.idf_objects[-1].parent), **detail}
        # the runner-up: the next cause fitted, or a screened-out one if its screen is lower
        others = [(float(bics[j]), chosen[j][0].cause, "fitted") for j in order if j != index]
        # a screen is a trial-size fit on other terms: one scoring below this cause's full fit
        # is no like-for-like rival (it read as 'very strong' evidence the wrong way round)
        others += [(value, cause, "screened") for value, cause in screened_out
                   if value >= float(bics[index])]
        # hourly residuals are autocorrelated: a BIC difference counted as if every hour
        # were independent overstates the evidence between two causes
        fraction = comparison.effective_fraction(d.y[cal] - fit.prediction[cal])
        entry["bic"]["effective_fraction"] = fraction
        if others:
            runner_bic, runner_cause, how = min(others)
            entry.update(_runner_up(runner_cause, runner_bic, how, float(bics[index]),
                                    fraction))
        announce(f"  {candidate.cause}: {_fitted_text(entry['fitted'])}; BIC {bic_before:.1f} "
                 f"-> {bics[index]:.1f}" + (
                     f"; out-of-fold CV(RMSE) {cv['cvrmse_before']:.3%} -> "
                     f"{cv['cvrmse_after']:.3%}, encompassing p = {test['p_value']:.3g}" if cv else
                     " (not cross-validated: ranked below the best "
                     f"{settings.cv_candidates})")
                 + (": passes the gates (only the round's best passing cause is accepted)"
                    if passed else ": rejected")
                 + (" (fitted at zero: not a cause)" if at_zero else "")
                 + (f" (its own effect, {effect_rms:.3g} rms, is below the smallest that "
                    f"matters: the existing parameters made the gain)"
                    if improves and not matters and not at_zero else ""))
        out.append((entry, Model(extended, fitted, fit, f"round{round_number}_{candidate.cause}")))
    for candidate, variant in flat:
        if not any(c is candidate for c, *_ in chosen) and variant is \
                min((v for c, v in flat if c is candidate), key=lambda v: v[2]["screen_bic"]):
            out.append(({"name": candidate.family, "cause": candidate.cause,
                         "driver": candidate.driver, "round": round_number, "rank": None,
                         "fitted": {}, "heldout": _unchanged(before),
                         "calibration": None, "cross_validation": None,
                         "encompassing": None, "loss_difference": None,
                         "bic": {"before": bic_before, "after": None},
                         "passed": False, "screened_out": True, **variant[2]}, None))
    return out


def _runner_up(cause: str, runner_bic: float, how: str, bic: float,
               fraction: float) -> dict:
    """The ``runner_up`` record of a cause and its ``confidence`` (BIC weight).

    The evidence words and the weight read the BIC difference scaled by the
    residuals' effective share of independent hours
    (:func:`comparison.effective_fraction`); ``delta_bic`` stays as computed.
    """
    delta = float(runner_bic - bic)
    effective = delta * fraction
    return {"runner_up": {"cause": cause, "bic": runner_bic, "bic_from": how,
                          "delta_bic": delta, "delta_bic_effective": effective,
                          "evidence": crossval.evidence_words(abs(effective))},
            "confidence": crossval.bic_weight(0.0, effective)}


def choose_cause(passed: list[tuple[dict, Model]]) -> tuple[dict, Model]:
    """The cause a round accepts among those that passed its gates.

    The lowest BIC wins, unless a rival is behind it by less than strong
    evidence (Kass & Raftery 1995: ΔBIC < :data:`STRONG_EVIDENCE_BIC`) once
    the difference is scaled to the residuals' independent hours
    (:func:`comparison.effective_fraction`): among such near-ties the lower
    out-of-fold CV(RMSE) wins, the direct measure of prediction on data
    the fit did not see (two faces of a building whose irradiance differs
    by an hour's shift in its daily peak can be that close). The chosen
    entry then records ``chosen_by`` and its runner-up is the BIC-best rival.

    Parameters
    ----------
    passed : list of (entry, Model)
        :func:`_try_extensions`' entries that passed, each with
        ``bic.after``, ``bic.effective_fraction`` and ``cross_validation``.
    """
    by_bic = min(passed, key=lambda pair: pair[0]["bic"]["after"])
    best_bic = by_bic[0]["bic"]["after"]
    fraction = by_bic[0]["bic"].get("effective_fraction", 1.0)
    close = [pair for pair in passed
             if (pair[0]["bic"]["after"] - best_bic) * fraction < STRONG_EVIDENCE_BIC
             and pair[0].get("cross_validation")]
    if len(close) < 2:
        return by_bic
    chosen = min(close, key=lambda pair: pair[0]["cross_validation"]["cvrmse_after"])
    if chosen is by_bic:
        return by_bic
    entry, rival = chosen[0], by_bic[0]
    entry.update(_runner_up(rival["cause"], best_bic, "fitted", entry["bic"]["after"],
                            fraction))
    entry["chosen_by"] = (
        f"out-of-fold CV(RMSE) {entry['cross_validation']['cvrmse_after']:.3%} against "
        f"{rival['cross_validation']['cvrmse_after']:.3%} for {rival['cause']}, whose BIC is "
        f"lower by {entry['bic']['after'] - best_bic:.1f} "
        f"({(entry['bic']['after'] - best_bic) * fraction:.1f} counting the residuals' "
        f"independent hours): not strong evidence")
    return chosen


def _nominated(ranked: list[int], bics: list[float], families: list[str], count: int,
               ceiling: float) -> list[int]:
    """The ``count`` best of ``ranked``, and the best of every other family below ``ceiling``.

    The faces of an aperture are causes of one family and can fill every
    place of a ranking by BIC, while another family (a thermal mass one BIC
    unit behind the second face) is never fitted. Each family whose BIC is
    below ``ceiling`` is represented by its best cause; the faces still
    compete with each other within the ``count``. Every family is fitted
    (``ceiling`` infinite: the screen's BIC is linearised); a fitted one is
    cross-validated when it improves on the current model (``ceiling``: the
    current BIC, which an accepted cause must beat anyway).
    """
    chosen = [int(i) for i in ranked[:count]]
    present = {families[i] for i in chosen}
    for i in ranked[count:]:
        if families[i] not in present and bics[i] < ceiling:
            chosen.append(int(i))
            present.add(families[i])
    return chosen


def extension_effect(fit: Fit, new: list[Parameter]) -> np.ndarray:
    """The extension's own contribution to the fitted output at every hour (output units).

    The fit's linearisation from each size-setting parameter of ``new`` at its
    nested value to its fitted value: the change the extension makes with the
    existing parameters held where they were fitted (exact for a design level,
    which the output is linear in; a first-order size for the others).
    """
    names = [p.name for p in fit.parameters]
    effect = np.zeros(len(fit.prediction))
    for p in new:
        if not (p.provenance or {}).get("sets_size", False) or p.name not in names:
            continue
        nested = float((p.provenance or {}).get("nested_at", 0.0))
        column = names.index(p.name)
        effect += fit.jacobian[:, column] * (float(fit.values[column]) - nested)
    return effect


def standing(improves: bool, at_zero: bool, matters: bool) -> tuple[bool, bool]:
    """Whether a fitted candidate is a cause, and whether it is only a better fit.

    A candidate passes when it improves on the current model (out-of-fold
    encompassing test, BIC, CV(RMSE)), is not fitted at its nested value
    (:func:`null_sized`) and its own effect matters (``min_amplitude``). One
    that improves without being a cause owes the gain to the existing
    parameters it moved: the second flag sends it to :func:`_continue_fit`.

    Returns
    -------
    passed : bool
    improves_fit : bool
    """
    passed = improves and not at_zero and matters
    return passed, improves and not passed


def null_sized(fit: Fit, new: list[Parameter]) -> bool:
    """True when every size-setting parameter of ``new`` is fitted at its nested value.

    An extension nested at zero changes nothing there, so a fit that improves
    on the current model with the extension at zero has only moved the
    existing parameters: the current fit had not converged, and the extension
    is not a cause.
    """
    sizes = [p for p in new if (p.provenance or {}).get("sets_size", False)]
    if not sizes:
        return False
    for p in sizes:
        lower, upper = parameter_range(p)
        nested = float((p.provenance or {}).get("nested_at", 0.0))
        if abs(float(fit.named[p.name]) - nested) > 1e-6 * (upper - lower):
            return False
    return True


#: How far (standard errors of the calibration fit) a linearised fold refit may move a parameter.
FOLD_STEP_SIGMAS = 3.0


def _gauss_newton_refit(measured: np.ndarray, fit: Fit, fitted: list[Parameter],
                        train: np.ndarray) -> np.ndarray:
    """The prediction after one bounded Gauss–Newton step of ``fit`` towards the ``train`` hours.

    The fold's refit linearised at the fit on the calibration hours (its
    Jacobian): exact for a model linear in its parameters, and close when the
    fold moves the parameters little (one week of several). The step stays
    within ``FOLD_STEP_SIGMAS`` standard errors of the fit: leaving out one
    fold of several moves a well-posed estimate by less than one, and a
    finite-difference Jacobian measured over a step of 0.1 % of the range is
    no guide far beyond it (on EnergyPlus a setpoint switch can make one
    column hundreds of times the physical response, and an unbounded step
    then predicts the left-out week wildly).
    """
    from scipy.optimize import lsq_linear

    if not len(fitted):
        return fit.prediction
    ranges = np.array([parameter_range(p) for p in fitted]).reshape(-1, 2)
    lower = ranges[:, 0] - fit.values
    upper = ranges[:, 1] - fit.values
    with np.errstate(invalid="ignore"):
        trust = FOLD_STEP_SIGMAS * np.sqrt(np.diag(fit.covariance))
    usable = np.isfinite(trust) & (trust > 0)
    lower = np.where(usable, np.maximum(lower, -trust), lower)
    upper = np.where(usable, np.minimum(upper, trust), upper)
    upper = np.maximum(upper, lower + 1e-12)
    jacobian = fit.jacobian[train]
    scale = np.maximum(np.abs(jacobian).max(axis=0), 1e-300)
    step = lsq_linear(jacobian / scale, (measured - fit.prediction)[train],
                      bounds=(lower * scale, upper * scale)).x / scale
    return fit.prediction + fit.jacobian @ step


def _unchanged(scores_now: dict) -> dict:
    return {"before": _short(scores_now["heldout"]), "after": _short(scores_now["heldout"])}


#: The screen's trial sizes of each new parameter, as shares of its range: a large
#: one, and a small one near the nesting zero. A law whose effect saturates (a leak
#: at a quarter of its range cools the zone to its setback every night) is linear
#: only near zero; a shape whose size trades with another (a mass's area and
#: thickness) shows only at a larger size. The screen keeps, per variant, the one
#: whose trial size is nearest the size its own linearised fit asks for: a secant is
#: right near the point it passes through.
SCREEN_STEPS = (0.25, 0.05)


def _screen(context: _Context, union: Config, union_sample: dict, current: Model,
            variants: list[tuple[Config, list[Parameter], dict]], round_number: int,
            designs: list[np.ndarray | None] | None = None,
            starts: list[dict[str, float]] | None = None
            ) -> tuple[list[float], list[list[float]]]:
    """Linearised BIC of every variant, from two batches of one run per new parameter.

    Returns the BIC kept per variant, and per trial size every variant's BIC.

    ``starts``, when given, receives per variant the linearised fit's values
    of the existing and new parameters (a second starting point of the fit).

    Each variant's new parameters are set, one at a time, a share of their
    range above their current value (a parameter that acts only through the
    variant's first one, e.g. a gain's radiant fraction, with the first one
    set too); the change of the prediction per unit is its column. With the
    existing parameters' Jacobian of the current fit, bounded linear least
    squares on the calibration hours gives the variant's residual, hence its
    BIC (:func:`bpsflow.diagnosis.comparison.bic`). This is done at each of
    :data:`SCREEN_STEPS` (two batches; ``designs`` are the first one's
    columns when the shape screen already ran them), and the trial whose
    size is nearest (by ratio) the first new parameter's linearised change
    is kept, with its optimum. A law (infiltration) is screened with its best
    subset of terms, as its fit will be (:func:`_choose_terms`): with every
    term free it pays BIC for terms the data do not need, and a two-term leak
    would rank below causes that merely share its hours. The screen ranks;
    the best causes are then fitted by simulation.
    """
    d = context.data
    cal = d.calibration
    if designs is None:         # not already run by the shape screen
        designs = _screen_columns(context, union, union_sample, current, variants,
                                  round_number, "screen", SCREEN_STEPS[0])
    small = _screen_columns(context, union, union_sample, current, variants, round_number,
                            "screen_small", SCREEN_STEPS[1])
    existing_ranges = np.array([parameter_range(p) for p in current.fitted]).reshape(-1, 2)
    residual = d.y[cal] - current.fit.prediction[cal]
    out = []
    per_trial: list[list[float]] = [[] for _ in SCREEN_STEPS]
    for (_, free, _), *trials in zip(variants, designs, small):
        best: tuple[float, float, dict[str, float]] = (np.inf, np.inf, {})
        for trial, (share, new_columns) in enumerate(zip(SCREEN_STEPS, trials)):
            if new_columns is None:
                per_trial[trial].append(np.inf)
                continue
            bic, values, lead = _linearised_terms(current, union_sample, free, new_columns,
                                                  residual, existing_ranges, cal)
            now = float(union_sample.get(lead.name, 0.0))
            step = abs(_trial_step(lead, now, share))
            change = abs(values[lead.name] - now)
            mismatch = abs(np.log(max(change, 1e-6 * step) / step))
            best = min(best, (mismatch, bic, values), key=lambda t: (t[0], t[1]))
            per_trial[trial].append(bic)
        out.append(best[1])
        if starts is not None:
            starts.append(best[2])
    return out, per_trial


def _stepped_back(design: np.ndarray, residual: np.ndarray, values: np.ndarray,
                  ranges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The residual left after the best bounded linear step of the fitted parameters, and
    that step (in the parameters' units).

    ``design`` holds each parameter's change of the output per unit (a fit's
    Jacobian on the same hours as ``residual``); the step keeps every value
    within ``ranges`` (``(k, 2)``) from ``values``.
    """
    from scipy.optimize import lsq_linear

    scale = np.maximum(np.abs(design).max(axis=0), 1e-300)
    lower = (ranges[:, 0] - values) * scale
    upper = np.maximum((ranges[:, 1] - values) * scale, lower + 1e-12)
    step = lsq_linear(design / scale, residual, bounds=(lower, upper)).x
    return residual - (design / scale) @ step, step / scale


def _start_screen(context: _Context, current: Model, union: Config, union_sample: dict,
                  free_sets: list[list[Parameter]], counts: list[int], round_number: int
                  ) -> list[tuple[dict[str, float], float]]:
    """Per candidate, the best point of a Latin hypercube over its new parameters, and its BIC.

    A candidate with two or more new parameters gets
    :data:`EXTENSION_START_SCREEN` points (the existing parameters at the
    current fit), all candidates' points in one batch. A new parameter that
    nests at zero is spread geometrically over :data:`START_SCREEN_DECADES`
    decades below its upper bound, the others uniformly over their range.
    The point's BIC counts ``counts`` parameters (the candidate's fit), so
    it is comparable with the BIC its fit from zero reached. A candidate
    with fewer new parameters, or whose points did not run, gets
    ``({}, inf)``.
    """
    from bpsflow.sampling import latin_hypercube_unit

    d = context.data
    cal = d.calibration
    rows, owners = [], []
    for number, free in enumerate(free_sets):
        if len(free) < 2:
            continue
        unit = latin_hypercube_unit(EXTENSION_START_SCREEN, len(free),
                                    context.settings.seed + 7919 * round_number + number)
        for row in unit:
            point = {}
            for p, u in zip(free, row):
                low, high = parameter_range(p)
                point[p.name] = float(high * 10.0 ** (START_SCREEN_DECADES * (u - 1.0))
                                      if low == 0.0 and high > 0.0 else low + u * (high - low))
            rows.append({**union_sample, **point})
            owners.append((number, point))
    best: list[tuple[dict[str, float], float]] = [({}, np.inf) for _ in free_sets]
    if not rows:
        return best
    predicted = context.run_rows(union, f"round{round_number}_start_screen", rows)
    jacobian = current.fit.jacobian[cal]
    ranges = np.array([parameter_range(p) for p in current.fitted]).reshape(-1, 2)
    for (number, point), prediction in zip(owners, predicted):
        if not np.isfinite(prediction[cal]).all():
            continue
        residual = d.y[cal] - prediction[cal]
        if jacobian.size:
            # the existing parameters were bent towards the missing effect: a point is
            # judged after their best bounded linear step back (the fit's Jacobian)
            residual, _ = _stepped_back(jacobian, residual, current.fit.values, ranges)
        bic = comparison.bic(residual, counts[number])
        if bic < best[number][1]:
            best[number] = (point, bic)
    return best


def _run_checked(context: _Context, union: Config, union_sample: dict,
                 starts: list[dict[str, float] | None], counts: list[int],
                 reached: list[float], round_number: int) -> list[dict[str, float] | None]:
    """The ``starts`` whose simulated point beats the BIC its fit ``reached``, others None.

    All points run in one batch; a point's BIC counts ``counts`` parameters
    (its fit's), so it compares with ``reached`` as :func:`_start_screen`'s
    points do. A point that does not run is dropped.
    """
    wanted = [number for number, start in enumerate(starts) if start is not None]
    if not wanted:
        return starts
    d = context.data
    cal = d.calibration
    predicted = context.run_rows(union, f"round{round_number}_screen_check",
                                 [{**union_sample, **(starts[number] or {})}
                                  for number in wanted])
    kept: list[dict[str, float] | None] = [None] * len(starts)
    for number, prediction in zip(wanted, predicted):
        if np.isfinite(prediction[cal]).all() and comparison.bic(
                d.y[cal] - prediction[cal], counts[number]) \
                < reached[number] - SCREEN_START_MARGIN:
            kept[number] = starts[number]
    return kept


def nesting_note(measured: np.ndarray, at_zero: np.ndarray, current: np.ndarray,
                 calibration: np.ndarray, timestamps: pd.DatetimeIndex, output: str,
                 fitted_count: int, round_number: int) -> str | None:
    """A note when the candidates' objects at zero make the fitted model fit worse.

    Every candidate is fitted in one model holding all of them at zero, which
    must reproduce the current fit (each extension nests at zero). A model
    whose output jumps under a negligible change (an HVAC threshold at a
    morning recovery: one hour of hundreds of W on EnergyPlus) breaks that, and
    every candidate's fit then starts from the jump. ``None`` unless the model
    at zero is worse than the current fit by more than
    :data:`NESTING_MARGIN_BIC` on the calibration hours (all arrays over every
    hour; ``fitted_count`` parameters in both).
    """
    cal = np.asarray(calibration, dtype=bool)
    if not np.isfinite(at_zero[cal]).all():
        return (f"round {round_number}: the model holding every candidate at zero did not "
                f"run, so it was not checked against the current fit")
    now = comparison.bic(measured[cal] - current[cal], fitted_count)
    zero = comparison.bic(measured[cal] - at_zero[cal], fitted_count)
    if zero <= now + NESTING_MARGIN_BIC:
        return None
    change = np.abs(at_zero - current)
    hours = np.flatnonzero(cal & (change > 0.01 * max(float(np.max(np.abs(current[cal]))), 1e-12)))
    worst = int(np.argmax(np.where(cal, change, -np.inf)))
    return (f"round {round_number}: adding the candidates at zero (which changes nothing "
            f"physically) changes {output} by up to {change[worst]:.4g} at {timestamps[worst]} "
            f"({len(hours)} calibration hour(s) by more than 1 % of its peak) and worsens the "
            f"fit by {zero - now:.1f} BIC: the model's output jumps under a negligible change "
            f"(e.g. an HVAC control threshold), and this round's candidates are fitted from "
            f"that jump, so their comparison with the current model is less reliable")


def _trial_step(parameter: Parameter, now: float, share: float) -> float:
    """The screen's trial change of ``parameter`` from ``now``: ``share`` of its range,
    upwards when there is room."""
    low, high = parameter_range(parameter)
    return share * (high - now) if high - now > 1e-12 else share * (low - now)


def _linearised_terms(current: Model, union_sample: dict, free: list[Parameter],
                      new_columns: np.ndarray, residual: np.ndarray,
                      existing_ranges: np.ndarray, cal: np.ndarray
                      ) -> tuple[float, dict[str, float], Parameter]:
    """:func:`_linearised` of a variant; a law's best subset of terms by BIC.

    Returns the BIC, the parameter values (a term left out at its current
    value) and the new parameter whose change measures the trial's size
    (the first one fitted).
    """
    from itertools import combinations

    family = (free[0].provenance or {}).get("extension", "") if free else ""
    if not (family in EXTENSIONS and _is_law(family)):
        bic, values = _linearised(current, union_sample, free, new_columns, residual,
                                  existing_ranges, cal)
        return bic, values, free[0]
    best: tuple[float, dict[str, float], Parameter] | None = None
    for size in range(1, len(free) + 1):
        for subset in combinations(range(len(free)), size):
            chosen = [free[i] for i in subset]
            bic, values = _linearised(current, union_sample, chosen,
                                      new_columns[:, list(subset)], residual,
                                      existing_ranges, cal)
            if best is None or bic < best[0]:
                left_out = {p.name: float(union_sample.get(p.name, 0.0))
                            for p in free if p not in chosen}
                best = (bic, {**values, **left_out}, chosen[0])
    assert best is not None
    return best


def _linearised(current: Model, union_sample: dict, free: list[Parameter],
                new_columns: np.ndarray, residual: np.ndarray, existing_ranges: np.ndarray,
                cal: np.ndarray) -> tuple[float, dict[str, float]]:
    """(BIC, parameter values) of the bounded linear fit of ``residual`` on the current
    fit's Jacobian and a variant's ``new_columns``."""
    from scipy.optimize import lsq_linear

    kept = [p for p in current.fitted if p.name not in {q.name for q in free}]
    keep_index = [i for i, p in enumerate(current.fitted) if p in kept]
    lower = list(existing_ranges[keep_index, 0] - current.fit.values[keep_index])
    upper = list(existing_ranges[keep_index, 1] - current.fit.values[keep_index])
    for parameter in free:
        low, high = parameter_range(parameter)
        now = float(union_sample.get(parameter.name, 0.0))
        lower.append(low - now)
        upper.append(high - now)
    design = np.column_stack([current.fit.jacobian[cal][:, keep_index], new_columns])
    low_bounds, high_bounds = np.array(lower), np.maximum(np.array(upper),
                                                            np.array(lower) + 1e-12)
    scale = np.maximum(np.abs(design).max(axis=0), 1e-300)
    solution = lsq_linear(design / scale, residual, bounds=(low_bounds * scale,
                                                             high_bounds * scale))
    left = residual - (design / scale) @ solution.x
    moved = solution.x / scale
    origin = [float(current.fit.values[i]) for i in keep_index] + \
        [float(union_sample.get(p.name, 0.0)) for p in free]
    return (comparison.bic(left, len(kept) + len(free)),
            {p.name: value + step for p, value, step in zip([*kept, *free], origin, moved)})


def _screen_columns(context: _Context, union: Config, union_sample: dict, current: Model,
                    variants: list[tuple[Config, list[Parameter], dict]], round_number: int,
                    label: str, share: float = SCREEN_STEPS[0]) -> list[np.ndarray | None]:
    """Per variant, the change of the prediction per unit of each new parameter (cal. hours).

    One batch, one run per new parameter: each is set ``share`` of its range
    above its current value (a parameter that acts only through the
    variant's first one, e.g. a gain's radiant fraction, with the first one
    set too). ``None`` for a variant with a failed run (noted).
    """
    d = context.data
    cal = d.calibration
    rows: list[dict[str, float]] = []
    plan = []           # per variant: [(parameter, step, row of its point, row of its base)]
    for _, free, _ in variants:
        steps: list[tuple[Parameter, float, int, int | None]] = []
        first_row = None
        for position, parameter in enumerate(free):
            now = float(union_sample.get(parameter.name, 0.0))
            step = _trial_step(parameter, now, share)
            point = dict(union_sample)
            base_row = None
            if position > 0 and first_row is not None:
                point[free[0].name] = rows[first_row][free[0].name]
                base_row = first_row
            point[parameter.name] = now + step
            rows.append(point)
            if position == 0:
                first_row = len(rows) - 1
            steps.append((parameter, step, len(rows) - 1, base_row))
        plan.append(steps)
    samples = pd.DataFrame(rows, index=pd.RangeIndex(len(rows), name="instance"))
    started = time.perf_counter()
    tag = f"round{round_number}_{label}"
    predicted = context.simulator(union, tag)(samples) if rows else np.zeros((0, len(d.y)))
    context.timings[tag] = time.perf_counter() - started
    context.step(tag)
    out: list[np.ndarray | None] = []
    for (_, free, _), steps in zip(variants, plan):
        columns = []
        for _parameter, step, row, base_row in steps:
            reference = current.fit.prediction if base_row is None else predicted[base_row]
            columns.append((predicted[row] - reference)[cal] / step)
        design = np.column_stack(columns) if columns else np.zeros((int(cal.sum()), 0))
        if not np.isfinite(design).all():       # a screening run failed
            context.notes.append(f"{label} of round {round_number}: a run of a candidate with "
                                 f"{', '.join(p.name for p in free)} failed; it is left out")
            out.append(None)
            continue
        out.append(design)
    return out


def _merge(union: Config, extended: Config) -> Config:
    """``union`` plus the IDF snippets and parameters of ``extended`` it lacks."""
    files = [f for f in extended.model.idf_objects if f not in union.model.idf_objects]
    names = {p.name for p in union.parameters}
    params = [p for p in extended.parameters if p.name not in names]
    if not files and not params:
        return union
    merged = union.model_copy(deep=True)
    merged.source = union.source
    merged.model.idf_objects = [*union.model.idf_objects, *files]
    merged.parameters = [*union.parameters, *params]
    return merged


def _without(parameters: list[Parameter], drop: list[Parameter]) -> list[Parameter]:
    names = {p.name for p in drop}
    return [p for p in parameters if p.name not in names]


def _choose_terms(context: _Context, union: Config, union_sample: dict, current: Model,
                  terms: list[Parameter], fit: Fit, detail: dict,
                  round_number: int) -> tuple[list[Parameter], Fit, dict]:
    """The law's terms by BIC: every non-empty subset, linearised at the all-terms fit.

    Each subset's least squares is solved on the fit's Jacobian (existing
    parameters free within their ranges, the subset's coefficients ≥ 0, the
    other terms at 0); its BIC (:func:`bpsflow.diagnosis.comparison.bic`)
    ranks it. The best subset, if not all terms, is then refitted by
    simulation (one more batch), so the reported coefficients are exact.
    """
    from itertools import combinations

    from scipy.optimize import lsq_linear

    d = context.data
    cal = d.calibration
    others = _without(fit.parameters, terms)
    names = [p.name for p in fit.parameters]
    ranges = np.array([parameter_range(p) for p in fit.parameters]).reshape(-1, 2)
    jacobian = fit.jacobian[cal]
    residual = d.y[cal] - fit.prediction[cal]
    table: list[dict] = []
    for size in range(1, len(terms) + 1):
        for subset in combinations(terms, size):
            keep = {p.name for p in others} | {p.name for p in subset}
            lower = ranges[:, 0] - fit.values
            upper = ranges[:, 1] - fit.values
            for j, name in enumerate(names):
                if name not in keep:           # pinned at the law's zero
                    lower[j] = -fit.values[j] - 1e-12
                    upper[j] = -fit.values[j] + 1e-12
            upper = np.maximum(upper, lower + 1e-12)
            step = lsq_linear(jacobian, residual, bounds=(lower, upper)).x
            rss_residual = residual - jacobian @ step
            table.append({"terms": [_reported(p) for p in subset],
                          "bic": comparison.bic(rss_residual, len(others) + size),
                          "subset": subset})
    table.sort(key=lambda row: row["bic"])
    best = table[0]
    detail = {**detail, "term_selection": [{"terms": r["terms"], "bic": r["bic"]}
                                           for r in table[:8]]}
    chosen_terms: list[Parameter] = list(best["subset"])
    if len(chosen_terms) < len(terms):
        start = {**fit.named, **{p.name: 0.0 for p in terms if p not in chosen_terms}}
        (fit,) = context.fit(union, f"round{round_number}_law",
                             [Problem(union_sample, [*others, *chosen_terms], d.y, cal, start)])
    detail["law"] = law_text({_reported(p): float(fit.named[p.name]) for p in chosen_terms})
    detail["terms"] = [_reported(p) for p in chosen_terms]
    return [*others, *chosen_terms], fit, detail


def _cross_validate(context: _Context, union: Config, union_sample: dict, current: Model,
                    models: list[tuple[list[Parameter], Fit]], round_number: int) -> dict:
    """Out-of-fold errors of ``current`` and each model; the test of each against ``current``.

    Folds are whole weeks over the whole period (:func:`crossval.day_blocks`);
    the held-out block is the last fold, whose fit is the calibration fit.
    Each other fold is refitted from the calibration fit's values
    (``cv_iterations`` Levenberg–Marquardt steps at most), every model and
    fold in one batch.

    Returns
    -------
    dict
        Index in ``models`` -> ``folds``, ``cvrmse_before``, ``cvrmse_after``
        (out-of-fold, all hours), ``test`` (the forecast-encompassing test
        of the out-of-fold errors, which decides) and ``loss_difference``
        (Diebold–Mariano on the absolute out-of-fold errors, HAC over one
        day: whether the model predicts better on average, reported).
    """
    d, settings = context.data, context.settings
    if not models:
        return {}
    folds = crossval.day_blocks(d.timestamps, ~d.calibration, settings.days_per_fold)
    last = int(folds.max())
    if last < 2:
        # one calibration block beside the held-out days: the acceptance has little to go on
        days = len(np.unique(np.asarray((d.timestamps[d.calibration]
                                         - pd.Timedelta(hours=1)).normalize())))
        note = (f"diagnosis.days_per_fold: {settings.days_per_fold} days per fold over {days} "
                f"calibration days make {last} calibration fold(s) beside the held-out days; "
                f"the cross-validated acceptance rests on {last + 1} folds (shorter folds give "
                f"it more)")
        if note not in context.notes:
            context.notes.append(note)
    refit = settings.cv_refit or ("simulated" if context.vectorised
                                  else "linearised")

    def out_of_fold(fits: list[tuple[list[Parameter], Fit]], how: str) -> list[np.ndarray]:
        predictions = []
        if how == "simulated":
            problems = [Problem(union_sample, fitted, d.y, folds != number, dict(fit.named))
                        for fitted, fit in fits for number in range(last)]
            refitted = context.fit(union, f"round{round_number}_folds", problems,
                                   max_iterations=settings.cv_iterations) if problems else []
            for position, (_, fit) in enumerate(fits):
                mine = refitted[position * last:(position + 1) * last]
                per_fold = {number: f.prediction for number, f in enumerate(mine)}
                per_fold[last] = fit.prediction
                predictions.append(crossval.out_of_fold(folds, per_fold))
        else:
            for fitted, fit in fits:
                per_fold = {number: _gauss_newton_refit(d.y, fit, fitted, folds != number)
                            for number in range(last)}
                per_fold[last] = fit.prediction
                predictions.append(crossval.out_of_fold(folds, per_fold))
        return predictions

    def with_base(fits: list[tuple[list[Parameter], Fit]], how: str
                  ) -> tuple[np.ndarray, list[np.ndarray]]:
        """The current model's out-of-fold prediction (cached per round) and each of ``fits``'."""
        key = (current.label, round_number, how)
        cached = key in context.oof_cache
        # one batch: the current model's folds beside the candidates'
        found = out_of_fold(([] if cached else [(current.fitted, current.fit)]) + fits, how)
        if not cached:
            context.oof_cache[key] = found.pop(0)
        return context.oof_cache[key], found

    base, predictions = with_base(models, refit)
    bases = [base] * len(models)
    ways = [refit] * len(models)
    if refit == "linearised" and settings.cv_refit is None:
        # A linearised fold refit rests on a finite-difference Jacobian; where a model fits
        # the calibration hours clearly better yet predicts its folds worse than the current
        # model, the linearisation, not the model, is the suspect: those models (and the
        # current one) are refitted per fold by simulation instead
        cal = d.calibration
        rmse_current = rmse(d.y[cal], current.fit.prediction[cal])
        blown = rmse(d.y, base) / rmse_current
        if blown > LINEARISED_BLOWUP:
            # the current model's own folds: every candidate is judged against them, so
            # all are refitted by simulation, the same way
            doubtful = list(range(len(models)))
            why = (f"the current model's linearised out-of-fold CV(RMSE) was {blown:.1f} "
                   f"times its calibration error")
        else:
            doubtful = [i for i, (_, fit) in enumerate(models)
                        if rmse(d.y[cal], fit.prediction[cal]) < LINEARISED_DOUBT * rmse_current
                        and rmse(d.y, predictions[i]) > rmse(d.y, bases[i])]
            why = (f"{len(doubtful)} candidate(s) fitted the calibration hours clearly better "
                   f"but predicted their folds worse under the linearised refit")
        if doubtful:
            simulated_base, simulated = with_base([models[i] for i in doubtful], "simulated")
            for i, prediction in zip(doubtful, simulated):
                predictions[i], bases[i], ways[i] = prediction, simulated_base, "simulated"
            context.notes.append(f"round {round_number}: {why}; their folds (and the current "
                                 f"model's) were refitted by simulation")
    mean = float(np.mean(d.y))
    out = {}
    for index, prediction in enumerate(predictions):
        base = bases[index]
        test = comparison.encompassing_test(d.y - base, d.y - prediction, lags=HELDOUT_LAGS)
        loss_difference = comparison.loss_difference_test(d.y - base, d.y - prediction,
                                                          loss="absolute", lags=HELDOUT_LAGS)
        out[index] = {"folds": last + 1, "days_per_fold": settings.days_per_fold,
                      "refit": ways[index],
                      "cvrmse_before": float(np.sqrt(np.mean((d.y - base) ** 2)) / abs(mean)),
                      "cvrmse_after": float(np.sqrt(np.mean((d.y - prediction) ** 2))
                                            / abs(mean)),
                      "test": test, "loss_difference": loss_difference}
    return out


def _refine_block(context: _Context, current: Model, extended: Config, new: list[Parameter],
                  detail: dict, fit: Fit, round_number: int,
                  family: str, steps: int = 8):
    """Move the best block's edges while the fit improves; one real refit at the end.

    ``family`` is the scheduled extension (:data:`SCHEDULED_BLOCKS`): a gain, or
    an air exchange whose block is refined the same way.

    The screen that shortlisted the blocks is linear on the residual, and the
    calibration bent the existing parameters towards the missing gain, so the
    edges it finds can be off by hours. Each step simulates the block's
    neighbours (start ± 1 h or ± 2 h, end ± 1 h or ± 2 h) at the fitted
    level, one run each in one batch, and scores each by the residual sum of
    squares left after a linear correction of every fitted parameter (the
    fit's Jacobian): the best neighbour is taken if it improves, up to
    ``steps`` times. The block reached is then fitted by simulation (from the
    values reached) and kept if its objective beats the block it started from.

    Before the edges move, the block may jump (:func:`_pulse_jumps`): a gain
    at hours when the output is already clipped (no heating on a sunny
    afternoon) shows up in the residuals only hours later, when the stored
    heat offsets the evening's heating, so the residual-shaped shortlist can
    sit wholly after the true hours, further than edge steps reach. The
    block's own simulated response, composed from one-hour pulses, finds the
    hours whose *effect* fits; the best such blocks are the first step's
    candidates, scored like the edge moves.
    """

    d, config = context.data, current.config
    cal = d.calibration
    extension = EXTENSIONS[family]
    directory = context.out_dir / "extensions" / f"round{round_number}_{family}"
    fitted = [*_without(current.fitted, new), *new]
    names = [p.name for p in fitted]
    ranges = np.array([parameter_range(p) for p in fitted]).reshape(-1, 2)
    jacobian = fit.jacobian[cal].copy()
    # the block's own columns (its level, its radiant fraction): a block that jumps to
    # other hours takes its simulated effect per watt as the level's column
    level_column = next(i for i, p in enumerate(fitted)
                        if p in new and _reported(p) == SCHEDULED_BLOCKS[family][0])
    block_columns = [i for i, p in enumerate(fitted) if p in new]

    def corrected(prediction: np.ndarray, values: np.ndarray,
                  design: np.ndarray | None = None) -> tuple[float, np.ndarray]:
        """RSS after the best bounded linear step of every fitted parameter, and that step."""
        left, step = _stepped_back(jacobian if design is None else design,
                                   (d.y - prediction)[cal], values, ranges)
        return float(left @ left), step

    def own_design(effect: np.ndarray, level: float) -> np.ndarray:
        """The Jacobian with the block's columns replaced by its own effect per watt."""
        design = jacobian.copy()
        design[:, block_columns] = 0.0
        design[:, level_column] = effect[cal] / level
        return design

    block = dict(detail["schedule"])
    state_values = fit.values.copy()
    state_rss = float(np.sum((d.y - fit.prediction)[cal] ** 2))
    tried = {(block["day_type"], block["start_hour"], block["end_hour"])}
    moves: list[dict] = []
    reached: tuple[Config, list[Parameter]] | None = None
    jumps, without = _pulse_jumps(context, current, config, detail, fitted, new, state_values,
                                  level_column, corrected, own_design, directory, round_number,
                                  family)
    tried.update(jumps)
    for step_number in range(steps):
        kind, first, last = block["day_type"], block["start_hour"], block["end_hour"]
        jumping = step_number == 0 and bool(jumps)
        neighbours = jumps if jumping else [
            (kind, a, b) for a, b in ((first - 2, last), (first - 1, last),
                                      (first + 1, last), (first + 2, last),
                                      (first, last - 2), (first, last - 1),
                                      (first, last + 1), (first, last + 2))
            if 0 <= a < b <= 24 and (kind, a, b) not in tried]
        if not neighbours:
            break
        tried.update(neighbours)
        union, variants = config, []
        for number, (day_type, a, b) in enumerate(neighbours, start=1):
            schedule = profile_schedule(block_profile(day_type, a, b), config.model.year)
            number = _fresh_variant(config, family, 1000 + 10 * step_number + number)
            variant = extend_config(config, extension, directory / f"edge{step_number}",
                                    schedule, number, zone=detail.get("zone"), output=d.output)
            union = _merge(union, variant)
            added = [p for p in variant.parameters
                     if p.name not in {q.name for q in config.parameters}]
            variants.append((variant, added, {"day_type": day_type, "start_hour": a,
                                              "end_hour": b}))
        base_row = context.sample_of(union, current.fit)
        base_row.update(dict(zip(names, state_values)))
        level = {_reported(p): float(v) for p, v in zip(fitted, state_values) if p in new}
        rows = []
        for _, added, _ in variants:
            row = dict(base_row)
            row.update({p.name: 0.0 for p in new})          # the block being replaced
            row.update({p.name: level.get(_reported(p), 0.0) for p in added})
            rows.append(row)
        predicted = context.run_rows(union, f"round{round_number}_edges{step_number}", rows,
                                     timing_label=f"round{round_number}_edges")
        scored = []
        level_w = float(state_values[level_column])
        for (variant, added, shape), prediction in zip(variants, predicted):
            if not np.isfinite(prediction).all():
                continue
            design = (own_design(prediction - without, level_w)
                      if jumping and without is not None else None)
            rss, step = corrected(prediction, state_values, design)
            scored.append((rss, variant, added, shape, step, design))
        if not scored:
            break
        rss, variant, added, shape, step, design = min(scored, key=lambda item: item[0])
        moves.append({"schedule": shape, "rss": rss, "from_rss": state_rss,
                      **({"jump": True} if jumping else {})})
        if rss >= state_rss * (1 - 1e-4):
            if jumping:
                continue
            break
        if design is not None:
            jacobian = design
        block = {**block, **shape}
        state_values = np.clip(state_values + step, ranges[:, 0], ranges[:, 1])
        state_rss = rss
        reached = (variant, added)
        # the moved block's parameters take the fitted ones' places
        fitted = [*_without(fitted, new), *added]
        new = added
        names = [p.name for p in fitted]
    detail = {**detail, "edge_moves": moves}
    if reached is None:
        return extended, new, detail, fit
    variant, added = reached
    start = dict(zip(names, state_values))
    (refit,) = context.fit(variant, f"round{round_number}_edges_fit",
                           [Problem(context.sample_of(variant, current.fit), fitted, d.y, cal,
                                    start)],
                           max_iterations=context.settings.cv_iterations)
    if refit.failed or refit.objective >= fit.objective:
        return extended, _original_new(extended, current), detail, fit
    return variant, added, {**detail, "schedule": {**detail["schedule"], **block}}, refit


#: Blocks a gain block may jump to before its edges move (:func:`_pulse_jumps`): each
#: runs once, in one batch.
PULSE_JUMPS = 6
#: ... none sharing more than this share of its hours (Jaccard) with one listed before it.
PULSE_JUMP_OVERLAP = 0.3


def _pulse_days(kind: str) -> list[str]:
    """The day types whose hours a block of ``kind`` may jump to: its own, and for a
    single day the day before (a gain on a Tuesday evening while the heating is off
    shows in the residuals only on Wednesday morning, when the stored heat offsets
    the heating; no block of Wednesday's hours reproduces that)."""
    if kind in WEEK_DAYS:
        return [WEEK_DAYS[WEEK_DAYS.index(kind) - 1], kind]
    return [kind]


def _pulse_jumps(context: _Context, current: Model, config: Config, detail: dict,
                 fitted: list[Parameter], new: list[Parameter], values: np.ndarray,
                 level_column: int, corrected, own_design, directory: Path,
                 round_number: int, family: str
                 ) -> tuple[list[tuple[str, int, int]], np.ndarray | None]:
    """The blocks whose simulated response fits the data best, on the gain's day type
    and, for a single day, the day before (:func:`_pulse_days`).

    One batch of runs: the current fit without the block, and one one-hour
    pulse for each hour of each of those day types, at the block's fitted
    level and radiant fraction. A block's response is the sum of its hours'
    pulse effects (superposition: exact for a linear model, a first
    approximation where the output clips at zero). Every block ``[a, b)`` of
    those day types is scored by the residual sum of squares left after the
    same bounded linear correction as an edge move, with the block's own
    effect per watt as its level's column.

    Returns
    -------
    jumps : list of (day type, start hour, end hour)
        At most :data:`PULSE_JUMPS` blocks that score better than the
        current block scored the same way; empty when none does.
    without : ndarray or None
        The prediction without the block (``None`` when no pulse ran).
    """
    d = context.data
    block = detail["schedule"]
    kind = block["day_type"]
    level = float(values[level_column])
    if level <= 0:
        return [], None
    extension = EXTENSIONS[family]
    known = {q.name for q in config.parameters}
    days = _pulse_days(kind)
    union, pulses = config, []
    for day_number, day_type in enumerate(days):
        for hour in range(24):
            schedule = profile_schedule(block_profile(day_type, hour, hour + 1),
                                        config.model.year)
            number = _fresh_variant(config, family, 2000 + 100 * day_number + hour)
            variant = extend_config(config, extension, directory / "pulses", schedule, number,
                                    zone=detail.get("zone"), output=d.output)
            union = _merge(union, variant)
            pulses.append([q for q in variant.parameters if q.name not in known])
    base_row = context.sample_of(union, current.fit)
    base_row.update(dict(zip([q.name for q in fitted], values)))
    base_row.update({q.name: 0.0 for q in new})
    own = {_reported(q): float(v) for q, v in zip(fitted, values) if q in new}
    rows = [dict(base_row)]
    for added in pulses:
        rows.append({**base_row, **{q.name: own.get(_reported(q), 0.0) for q in added}})
    runs = context.run_rows(union, f"round{round_number}_pulses", rows)
    if not np.isfinite(runs).all():
        return [], None
    without = runs[0]
    scores = {}
    for day_number, day_type in enumerate(days):
        effects = runs[1 + 24 * day_number: 25 + 24 * day_number] - without
        # cumulative[h]: the summed effect of the day's pulses before hour h
        cumulative = np.vstack([np.zeros_like(without), np.cumsum(effects, axis=0)])
        for first in range(24):
            for last in range(first + 1, 25):
                effect = cumulative[last] - cumulative[first]
                scores[(day_type, first, last)] = corrected(without + effect, values,
                                                            own_design(effect, level))[0]
    here = (kind, block["start_hour"], block["end_hour"])
    bar = scores[here]
    better = sorted((rss, key) for key, rss in scores.items() if key != here and rss < bar)
    # superposition errs where the output clips (a long block drives the heating to zero,
    # its pulses one by one do not), so the shortlist that runs for real is spread out:
    # a block mostly the same hours as one already listed adds nothing
    jumps: list[tuple[str, int, int]] = []
    for _, key in better:
        if len(jumps) == PULSE_JUMPS:
            break
        if not any(_overlap(key, other) > PULSE_JUMP_OVERLAP for other in jumps):
            jumps.append(key)
    return jumps, without


def _overlap(one: tuple[str, int, int], other: tuple[str, int, int]) -> float:
    """Jaccard overlap of two blocks' hours of the week (day type, start, end)."""
    first = _week_hours(*one)
    second = _week_hours(*other)
    union = len(first | second)
    return len(first & second) / union if union else 0.0


def _week_hours(day_type: str, start_hour: int, end_hour: int) -> set[tuple[int, int]]:
    return {(day, hour) for day, on in enumerate(DAY_TYPES[day_type]) if on
            for hour in range(start_hour, end_hour)}


def _original_new(extended: Config, current: Model) -> list[Parameter]:
    known = {p.name for p in current.config.parameters}
    return [p for p in extended.parameters if p.name not in known]


def _reported(parameter: Parameter) -> str:
    """An extension parameter's name without its variant suffix."""
    return (parameter.provenance or {}).get("reports_as", parameter.name)


def _short(block: dict) -> dict:
    return {"cvrmse": block["cvrmse"], "nmbe": block["nmbe"], "nmcrps": block["nmcrps"],
            "guideline14": block["guideline14"]}


def _tested_driver(result: Diagnosis, cause: dict, accepted: list[dict]) -> None:
    """The cause's driver as the residual tests found it, not as the candidate was called.

    Once structure is found every candidate competes (a gain block may win on
    residuals whose significant drivers are all irradiance), and a candidate
    carries the driver it is usually called by. When that driver was not
    significant (or suggestive) in the round the cause was accepted, the
    strongest driver that was is named instead; the candidate's own stays in
    its entry.
    """
    if not accepted:
        return
    number = accepted[0].get("round")
    tested = next((r for r in result.rounds if r.get("round") == number), None)
    if tested is None:
        return
    found = list(tested.get("significant", [])) + list(tested.get("suggestive", []))
    if found and cause.get("driver") not in found:
        cause["driver"] = found[0]


def concentration_note(measured: np.ndarray, prediction: np.ndarray,
                       timestamps: pd.DatetimeIndex, output: str) -> str | None:
    """A note when a held-out CV(RMSE) rests on a few hours (:func:`error_concentration`).

    ``None`` unless the largest 1 % of the hours' errors carry more than
    :data:`CONCENTRATED_ERROR_SHARE` of the squared error; the note names
    them and gives the CV(RMSE) of the other hours.
    """
    positions, share = error_concentration(measured, prediction)
    if share <= CONCENTRATED_ERROR_SHARE or len(positions) >= len(measured):
        return None
    rest = np.ones(len(measured), dtype=bool)
    rest[positions] = False
    hours = ", ".join(f"{timestamps[i]:%Y-%m-%d %H:%M}" for i in positions[:3])
    return (f"the final model's held-out CV(RMSE) of {output} rests on {len(positions)} of "
            f"{len(measured)} hours ({hours}{', ...' if len(positions) > 3 else ''}), "
            f"{share:.0%} of its squared error; over the other hours it is "
            f"{float(cv_rmse(measured[rest], prediction[rest])):.2%}. A peak that the "
            f"simulation's time step places differently (a reheat after a setback) can "
            f"outweigh the rest of the record")


def _finish(context: _Context, result: Diagnosis) -> None:
    """Verdict summary sentence and the overall held-out gain."""
    before = result.scorecard["heldout"]
    result.final_scores = context.block_scores(result.final.fit) \
        if result.final is not result.base else result.scorecard
    after = result.final_scores["heldout"]
    result.gain = {"metric": "cvrmse", "before": before["cvrmse"], "after": after["cvrmse"],
                   "nmcrps_before": before["nmcrps"], "nmcrps_after": after["nmcrps"]}
    held = ~result.calibration
    note = concentration_note(result.measured[held], result.final.fit.prediction[held],
                              result.timestamps[held], result.output)
    if note and note not in result.notes:
        result.notes.append(note)
    _final_sizes(result)
    for note in _fitted_input_bound_notes(result.final.fit):
        if note not in result.notes:
            result.notes.append(note)
    cause = {"driver": None, "parameter": None, "extension": None, **(result.cause or {})}
    result.cause = cause
    if result.verdict == "none":
        first = result.rounds[0] if result.rounds else {}
        white = first.get("whiteness", {}).get("white", True)
        cause["summary"] = ("No driver explains a share of the residuals that matters; "
                            "the model is kept as it is"
                            + ("." if white else " (the residuals are autocorrelated, which "
                               "alone names no cause)."))
    elif result.verdict == "parameter":
        fit = result.parameter_fit
        cause["summary"] = (f"The residual structure ({cause['driver']}) is explained by "
                            f"{fit['name']} = {fit['fitted']:.4g} instead of {fit['nominal']:.4g}; "
                            f"held-out CV(RMSE) {before['cvrmse']:.2%} -> {after['cvrmse']:.2%}.")
    elif cause.get("extension"):
        accepted = [e for e in result.extensions if e.get("accepted")]
        _tested_driver(result, cause, accepted)
        cause["summary"] = (f"The residuals follow {cause['driver']}, which the model lacks: "
                            + ", ".join(f"{e.get('cause', e['name'])}{where_text(e)} "
                                        f"({e.get('law') or _fitted_text(e['fitted'])})"
                                        for e in accepted)
                            + f" improves held-out CV(RMSE) {before['cvrmse']:.2%} -> "
                            f"{after['cvrmse']:.2%}.")
        for note in _bound_notes(result):
            if note not in result.notes:
                result.notes.append(note)
        rival = next((e["versus_parameter"] for e in accepted if "versus_parameter" in e), None)
        explaining = [r["name"] for r in result.parameter_check if r.get("explains")]
        if rival and explaining:
            cause["summary"] += (f" A plausible change of {explaining[0]} also removes the "
                                 f"structure, but fits worse (BIC higher by "
                                 f"{rival['delta_bic']:.1f}).")
    else:
        cause["summary"] = (f"The residuals follow {cause['driver']}, but no candidate extension "
                            f"improved the cross-validated accuracy significantly: the model "
                            f"lacks something the extension catalogue cannot express (see the "
                            f"drivers, the residual heatmap and the lag plot).")
    if result.unexplained and result.verdict == "model_form":
        cause["unexplained"] = list(result.unexplained)
        if cause.get("extension") and result.round_limit_reached:
            cause["summary"] += (f" Structure remains ({', '.join(result.unexplained)}) after "
                                 f"the last round allowed (diagnosis.max_rounds): another cause "
                                 f"may remain.")
        elif cause.get("extension"):
            cause["summary"] += (" Structure remains that no candidate explains: "
                                 + ", ".join(result.unexplained) + ".")
