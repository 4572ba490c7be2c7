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
4. **Extend and measure.** Each candidate (:mod:`bpsflow.diagnosis.extensions`)
   is fitted together with the existing parameters on the calibration hours
   and scored on the held-out block; it is accepted only if the held-out
   loss difference is significant (Diebold–Mariano with HAC variance), its
   BIC is lower and its held-out CV(RMSE) is lower. The best accepted one
   becomes the model, which is diagnosed again, until nothing significant
   is left or ``max_rounds``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.config import Config, Parameter
from bpsflow.diagnosis import comparison, structure
from bpsflow.diagnosis.drivers import derive_drivers
from bpsflow.diagnosis.extensions import (
    EXTENSIONS,
    block_profile,
    candidates_for,
    diagnosis_zone,
    extend_config,
    facade_irradiance,
    facade_of,
    gain_blocks,
    profile_schedule,
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
from bpsflow.diagnosis.signatures import candidate_parameters, explain, signatures
from bpsflow.errors import BpsflowError

Announce = Callable[[str], None]

#: Newey–West lags of the held-out loss-difference test: one day. With the
#: fixed-b reference the size holds for any window; a day keeps it (4.8 % at
#: the 5 % level for AR(1) errors with φ = 0.8 over a held-out week, 7.6 % at
#: φ = 0.95; 1000 series each) while the default window (half the week) leaves
#: the t reference 3 degrees of freedom and rejects even a 20-fold gain.
HELDOUT_LAGS = 24


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
    final_scores: dict = field(default_factory=dict)
    seconds: float = 0.0
    backend: str = "surrogate"


def settings_of(config: Config) -> DiagnosisSettings:
    return getattr(config, "diagnosis", None) or DiagnosisSettings()


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
    if names is None and config.calibration is not None:
        names = config.calibration.parameters
    return calibration_parameters(config, CalibrationSettings(parameters=names))


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


def output_sign(config: Config, output: str) -> float:
    """The output's response to an added heat gain: −1 for heating power, +1 otherwise."""
    variable = config.outputs[output].variable.lower() if output in config.outputs else output
    return -1.0 if "heating" in variable or "heating" in output.lower() else 1.0


@dataclass
class Data:
    """The measured output prepared for diagnosis (one dataset)."""

    output: str
    timestamps: pd.DatetimeIndex
    y: np.ndarray                 # measured output at every hour
    calibration: np.ndarray       # bool: fitted hours (the rest is the held-out block)
    drivers: pd.DataFrame
    indoor: np.ndarray            # °C, for the wind × ΔT basis


def prepare(config: Config, measured: pd.DataFrame, settings: DiagnosisSettings) -> Data:
    """Select the output, split calibration / held-out days, derive the drivers."""
    output = choose_output(config, measured, settings)
    series = measured[output].dropna()
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
                indoor_temperature(config, measured, timestamps))


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
    announce(f"fitting {len(fitted)} existing parameter(s) to {data[0].output} "
             f"({int(data[0].calibration.sum())} calibration hours, "
             f"{int((~data[0].calibration).sum())} held out)"
             + (f", {len(data)} datasets" if len(data) > 1 else ""))
    started = time.perf_counter()
    fits = context.fit(config, "base", [Problem(context.sample_of(config), fitted, d.y,
                                                d.calibration) for d in data])
    shared = time.perf_counter() - started
    results = []
    for d, fit, out_dir in zip(data, fits, out_dirs):
        started = time.perf_counter()
        context.data, context.out_dir = d, Path(out_dir)
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        results.append(_diagnose_one(context, Model(config, fitted, fit, "base"), announce))
        results[-1].seconds = time.perf_counter() - started + shared
    return results


class _Context:
    """What every step of one diagnosis needs: data, settings, simulators."""

    def __init__(self, config: Config, data: Data, settings: DiagnosisSettings, backend: str,
                 jobs: int | None, out_dir: Path, step: Callable[[str], None]):
        self.config, self.data, self.settings = config, data, settings
        self.backend, self.jobs, self.out_dir, self.step = backend, jobs, out_dir, step

    def simulator(self, config: Config, label: str):
        return output_simulator(config, self.data.output, self.data.timestamps,
                                backend=self.backend, work_dir=self.out_dir / "runs" / label,
                                jobs=self.jobs, sequences_dir=self.out_dir / "runs")

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

    def fit(self, config: Config, label: str, problems: list[Problem]) -> list[Fit]:
        fits = fit_many(self.simulator(config, label), problems,
                        max_iterations=self.settings.max_fit_iterations)
        self.step(label)
        return fits

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


def _diagnose_one(context: _Context, base: Model, announce: Announce) -> Diagnosis:
    d, settings = context.data, context.settings
    result = Diagnosis(output=d.output, timestamps=d.timestamps, measured=d.y,
                       calibration=d.calibration, drivers=d.drivers, base=base, final=base,
                       scorecard=context.block_scores(base.fit), backend=context.backend)
    current = base
    tried: set[str] = set()
    for round_number in range(1, settings.max_rounds + 1):
        residual = d.y - current.fit.prediction
        tests = context.test(residual[d.calibration])
        white = structure.whiteness(residual[d.calibration])
        significant = [t for t in tests if t.significant]
        result.rounds.append({"round": round_number, "model": current.label,
                              "drivers": [_driver_record(t) for t in tests], "whiteness": white,
                              "significant": [t.name for t in significant]})
        announce(f"round {round_number}: " + (
            f"significant driver(s): {', '.join(t.name for t in significant)}" if significant
            else "no significant structure in the residuals"))
        if not significant:
            break
        if round_number == 1:
            explained = _parameter_check(context, result, current, residual, significant)
            if explained is not None:
                _accept_parameter(result, *explained, significant[0].name, announce)
                break
            result.verdict = "model_form"
            result.cause = {"driver": significant[0].name, "parameter": None,
                            "extension": None, "summary": ""}
        candidates = [(name, driver) for name, driver in
                      candidates_for([t.name for t in significant], list(settings.extensions))
                      if name not in tried]
        if not candidates:
            announce("no candidate extension left for these drivers")
            break
        tried.update(name for name, _ in candidates)
        entries = _try_extensions(context, result, current, candidates, residual, round_number,
                                  announce)
        passed = [(e, m) for e, m in entries if e["passed"]]
        result.extensions += [e for e, _ in entries]
        if not passed:
            announce("no candidate extension improved the held-out accuracy significantly")
            break
        best, model = min(passed, key=lambda pair: pair[0]["heldout"]["after"]["cvrmse"])
        best["accepted"] = True
        current = result.final = model
        if not result.cause.get("extension"):
            result.cause["extension"], result.cause["driver"] = best["name"], best["driver"]
        announce(f"accepted {best['name']} ({_fitted_text(best['fitted'])}): held-out "
                 f"CV(RMSE) {best['heldout']['before']['cvrmse']:.3%} -> "
                 f"{best['heldout']['after']['cvrmse']:.3%}")
    for entry in result.extensions:
        entry.setdefault("accepted", False)
    _finish(context, result)
    return result


def _driver_record(test) -> dict:
    return {"name": test.name, "group": test.group, "effect": float(test.amplitude),
            "share": float(test.share), "direction": int(test.direction),
            "p_value": float(test.p_value), "p_adjusted": float(test.p_adjusted),
            "sign_consistent": bool(test.sign_consistent), "significant": bool(test.significant)}


def _fitted_text(fitted: dict[str, float]) -> str:
    return ", ".join(f"{k} = {v:.4g}" for k, v in fitted.items())


def _parameter_check(context: _Context, result: Diagnosis, current: Model,
                     residual: np.ndarray, significant: list) -> tuple[Model, dict] | None:
    """Does a plausible change of one existing, unfitted parameter remove the structure?

    Screen: project the residual on every candidate's characteristic
    signature (one batch of perturbation runs). The ``parameter_candidates``
    that explain the largest shares are then refitted, each freed within its
    plausible range together with the fitted parameters (one batch). If a
    refit leaves no significant driver, the best such one is the cause.
    """
    from bpsflow.distributions import Uniform

    d, settings = context.data, context.settings
    candidates = candidate_parameters(current.config.parameters,
                                      [p.name for p in current.fitted], settings.plausible_change)
    if settings.suspects is not None:
        candidates = [c for c in candidates if c.parameter.name in settings.suspects]
    if not candidates:
        return None
    found = signatures(context.simulator(current.config, "signatures"),
                       context.sample_of(current.config, current.fit), candidates,
                       current.fit.prediction)
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
    best = None
    for e, fit in zip(shortlist, fits):
        after = context.test((d.y - fit.prediction)[d.calibration])
        left = [t.name for t in after if t.significant]
        # explained: nothing significant left AND each driver lost at least half its share
        # (a weak refit can push p over alpha without explaining the structure)
        shares = {t.name: t.share for t in after}
        halved = all(shares.get(name, 0.0) <= 0.5 * share for name, share in before.items())
        record = next(r for r in result.parameter_check if r["name"] == e.name)
        record.update(refitted=float(fit.named[e.name]), structure_left=left,
                      driver_shares_after={name: shares.get(name, 0.0) for name in before},
                      objective=fit.objective, explains=bool(not left and halved))
        if not left and halved and (best is None or fit.objective < best[1].objective):
            best = (e, fit)
    if best is None:
        return None
    e, fit = best
    c = by_name[e.name]
    fitted = [*current.fitted, freed[e.name]]
    return (Model(config, fitted, fit, f"parameter {e.name}"),
            {"name": e.name, "nominal": c.nominal, "fitted": float(fit.named[e.name]),
             "plausible_range": [c.lower, c.upper]})


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


def _try_extensions(context: _Context, result: Diagnosis, current: Model,
                    candidates: list[tuple[str, str]], residual: np.ndarray, round_number: int,
                    announce: Announce) -> list[tuple[dict, Model]]:
    """Fit each candidate extension with the existing parameters; score it against ``current``.

    All candidates are fitted in one batch on the union of their IDF objects:
    every extension is nested at zero, so with the other candidates' new
    parameters at zero the union *is* ``current`` plus that one extension.
    """
    d, config = context.data, current.config
    union = config
    variants = []     # (candidate index, extended config, new parameters, detail)
    for index, (name, driver) in enumerate(candidates):
        extension = EXTENSIONS[name]
        directory = context.out_dir / "extensions" / f"round{round_number}_{name}"
        zone = diagnosis_zone(config, d.output, name)
        options: list[tuple[pd.Series | None, dict, int | None]] = [(None, {"zone": zone},
                                                                     None)]
        if name == "internal_gain_schedule":
            blocks = gain_blocks(
                pd.Series(residual[d.calibration], index=d.timestamps[d.calibration]),
                output_sign(config, d.output),
                fitted_jacobian=current.fit.jacobian[d.calibration],
                count=context.settings.gain_blocks)
            options = [(profile_schedule(profile, config.model.year),
                        {"schedule": block, "zone": zone},
                        number if len(blocks) > 1 else None)
                       for number, (profile, block) in enumerate(blocks, start=1)]
        elif name == "solar_aperture":
            # the irradiance on the zone's own facade (model geometry), not a fixed plane
            irradiance, geometry = facade_irradiance(config, zone, facade_of(driver))
            options = [(irradiance, geometry, None)]
        for schedule, detail, variant in options:
            extended = extend_config(config, extension, directory, schedule, variant, zone=zone)
            union = extend_config(union, extension, directory, schedule, variant, zone=zone)
            known = {p.name for p in config.parameters}
            new = [p for p in extended.parameters if p.name not in known]
            variants.append((index, extended, new, detail))
    announce(f"fitting {len(candidates)} candidate extension(s) ({len(variants)} variant(s)): "
             + ", ".join(f"{n} ({drv})" for n, drv in candidates))
    union_sample = context.sample_of(union, current.fit)
    problems = [Problem(union_sample, [*current.fitted, *new], d.y, d.calibration,
                        {**current.fit.named, **{p.name: 0.0 for p in new}})
                for _, _, new, _ in variants]
    fits = context.fit(union, f"round{round_number}", problems)
    per_candidate = []
    for index, (name, driver) in enumerate(candidates):
        mine = [(v, f) for v, f in zip(variants, fits) if v[0] == index]
        (_, extended, new, detail), fit = min(mine, key=lambda pair: pair[1].objective)
        if len(mine) > 1:
            detail = {**detail, "variants": [
                {**v[3], "objective": f.objective,
                 "fitted": {_reported(p): float(f.named[p.name]) for p in v[2]}}
                for v, f in mine]}
        if name == "internal_gain_schedule" and "schedule" in detail:
            extended, new, detail, fit = _refine_block(context, current, extended, new, detail,
                                                       fit, round_number)
        per_candidate.append((name, driver, extended, new, detail, fit))
    before = context.block_scores(current.fit)
    held, cal = ~d.calibration, d.calibration
    out = []
    for name, driver, extended, new, detail, fit in per_candidate:
        fitted = [*current.fitted, *new]
        after = context.block_scores(fit)
        test = comparison.loss_difference_test(d.y[held] - current.fit.prediction[held],
                                               d.y[held] - fit.prediction[held],
                                               loss="absolute", lags=HELDOUT_LAGS)
        bic_before = comparison.bic(d.y[cal] - current.fit.prediction[cal], len(current.fitted))
        bic_after = comparison.bic(d.y[cal] - fit.prediction[cal], len(fitted))
        passed = bool(test["p_value"] < context.settings.gain_alpha and bic_after < bic_before
                      and after["heldout"]["cvrmse"] < before["heldout"]["cvrmse"])
        names = [p.name for p in fitted]
        entry = {"name": name, "driver": driver, "round": round_number,
                 "fitted": {_reported(p): float(fit.named[p.name]) for p in new},
                 "fitted_std": {_reported(p): float(np.sqrt(fit.covariance[names.index(p.name)]
                                                            [names.index(p.name)]))
                                for p in new},
                 "heldout": {"before": _short(before["heldout"]),
                             "after": _short(after["heldout"])},
                 "calibration": {"before": _short(before["calibration"]),
                                 "after": _short(after["calibration"])},
                 "loss_difference": test, "bic": {"before": bic_before, "after": bic_after},
                 "passed": passed, "iterations": fit.iterations,
                 "files": str(extended.model.idf_objects[-1].parent), **detail}
        announce(f"  {name}: {_fitted_text(entry['fitted'])}; held-out CV(RMSE) "
                 f"{before['heldout']['cvrmse']:.3%} -> {after['heldout']['cvrmse']:.3%}, "
                 f"loss-difference p = {test['p_value']:.3g}, BIC {bic_before:.1f} -> "
                 f"{bic_after:.1f}: {'passes' if passed else 'rejected'}")
        out.append((entry, Model(extended, fitted, fit, f"round{round_number}_{name}")))
    return out


def _refine_block(context: _Context, current: Model, extended: Config, new: list[Parameter],
                  detail: dict, fit: Fit, round_number: int, steps: int = 3):
    """Move the best gain block's edges an hour at a time while the refit improves.

    The screen that shortlisted the blocks is linear; the winner's edges are
    checked by refitting its neighbours (start ± 1 h, end ± 1 h) in one batch,
    up to ``steps`` times.
    """
    d, config = context.data, current.config
    extension = EXTENSIONS["internal_gain_schedule"]
    tried = {(v["schedule"]["day_type"], v["schedule"]["start_hour"], v["schedule"]["end_hour"])
             for v in detail.get("variants", [detail])}
    best = (extended, new, detail, fit)
    for step in range(steps):
        block = best[2]["schedule"]
        day_type, first, last = block["day_type"], block["start_hour"], block["end_hour"]
        neighbours = [(day_type, a, b) for a, b in ((first - 1, last), (first + 1, last),
                                                    (first, last - 1), (first, last + 1))
                      if 0 <= a < b <= 24 and (day_type, a, b) not in tried]
        if not neighbours:
            break
        tried.update(neighbours)
        union, variants = config, []
        for number, (kind, a, b) in enumerate(neighbours, start=1):
            schedule = profile_schedule(block_profile(kind, a, b), config.model.year)
            directory = (context.out_dir / "extensions"
                         / f"round{round_number}_internal_gain_schedule" / f"edge{step}")
            variant = extend_config(config, extension, directory, schedule, number,
                                    zone=detail.get("zone"), output=d.output)
            union = extend_config(union, extension, directory, schedule, number,
                                  zone=detail.get("zone"), output=d.output)
            added = [p for p in variant.parameters if p.name not in
                     {q.name for q in config.parameters}]
            variants.append((variant, added, {"day_type": kind, "start_hour": a, "end_hour": b}))
        level = float(next(iter(best[3].named[p.name] for p in best[1])))
        problems = [Problem(context.sample_of(union, current.fit), [*current.fitted, *added],
                            d.y, d.calibration,
                            {**best[3].named, **{p.name: level for p in added}})
                    for _, added, _ in variants]
        fits = context.fit(union, f"round{round_number}_edges{step}", problems)
        (variant, added, block), refit = min(zip(variants, fits),
                                             key=lambda pair: pair[1].objective)
        best[2].setdefault("variants", []).extend(
            {"schedule": b, "objective": f.objective,
             "fitted": {_reported(p): float(f.named[p.name]) for p in a}}
            for (_, a, b), f in zip(variants, fits))
        if refit.objective >= best[3].objective:
            break
        best = (variant, added, {**best[2], "schedule": block}, refit)
    return best


def _reported(parameter: Parameter) -> str:
    """An extension parameter's name without its variant suffix."""
    return (parameter.provenance or {}).get("reports_as", parameter.name)


def _short(block: dict) -> dict:
    return {"cvrmse": block["cvrmse"], "nmbe": block["nmbe"], "nmcrps": block["nmcrps"],
            "guideline14": block["guideline14"]}


def _finish(context: _Context, result: Diagnosis) -> None:
    """Verdict summary sentence and the overall held-out gain."""
    before = result.scorecard["heldout"]
    result.final_scores = context.block_scores(result.final.fit) \
        if result.final is not result.base else result.scorecard
    after = result.final_scores["heldout"]
    result.gain = {"metric": "cvrmse", "before": before["cvrmse"], "after": after["cvrmse"],
                   "nmcrps_before": before["nmcrps"], "nmcrps_after": after["nmcrps"]}
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
        cause["summary"] = (f"The residuals follow {cause['driver']}, which the model lacks: "
                            + ", ".join(f"{e['name']} ({_fitted_text(e['fitted'])})"
                                        for e in accepted)
                            + f" improves held-out CV(RMSE) {before['cvrmse']:.2%} -> "
                            f"{after['cvrmse']:.2%}.")
    else:
        cause["summary"] = (f"The residuals follow {cause['driver']}, but no candidate extension "
                            f"improved the held-out accuracy significantly.")
