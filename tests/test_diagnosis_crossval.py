"""Blocked cross-validation of a model change: folds, out-of-fold assembly, size and power.

The acceptance test of ``diagnose`` compares out-of-fold errors of two
nested models over whole-week folds (:mod:`bpsflow.diagnosis.crossval`).
Here the models are linear least squares, so every fold fit is exact, and the
test's size under the null (an irrelevant extra regressor, AR(1) errors) and
its power for a weekend-only effect are measured against known truths.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from bpsflow.diagnosis import comparison, crossval
from bpsflow.diagnosis.workflow import HELDOUT_LAGS

HOURS = pd.date_range("2025-11-01 01:00", periods=24 * 35, freq="h")


def _heldout(days: int = 7) -> np.ndarray:
    day = (HOURS - pd.Timedelta(hours=1)).normalize()
    return np.isin(day, np.sort(day.unique())[-days:])


def test_folds_are_whole_weeks_and_the_heldout_block_is_last():
    folds = crossval.day_blocks(HOURS, _heldout())
    assert folds.max() == 4 and set(np.unique(folds)) == {0, 1, 2, 3, 4}
    assert np.all(folds[_heldout()] == 4) and np.all(folds[~_heldout()] < 4)
    start = HOURS - pd.Timedelta(hours=1)
    for number in range(5):
        hours = start[folds == number]
        assert len(hours) == 7 * 24
        # every fold holds each day of the week once: weekend days are held out in every fold
        assert sorted(set(hours.day_of_week)) == list(range(7))
    assert np.all(np.diff(folds) >= 0)          # consecutive blocks, in time order


def test_a_short_remainder_spreads_over_the_folds():
    hours = HOURS[:24 * 24]                      # 17 calibration days + 7 held out
    day = (hours - pd.Timedelta(hours=1)).normalize()
    heldout = np.isin(day, np.sort(day.unique())[-7:])
    folds = crossval.day_blocks(hours, heldout)
    sizes = np.bincount(folds) // 24
    assert list(sizes) == [9, 8, 7]


def test_out_of_fold_takes_each_fold_from_its_own_fit():
    folds = np.array([0, 0, 1, 1, 2])
    predictions = {0: np.full(5, 10.0), 1: np.full(5, 20.0), 2: np.full(5, 30.0)}
    assert list(crossval.out_of_fold(folds, predictions)) == [10, 10, 20, 20, 30]
    with pytest.raises(ValueError, match="fold"):
        crossval.out_of_fold(folds, {0: np.zeros(5)})


def test_bic_weight_closed_form():
    assert crossval.bic_weight(100.0, 100.0) == pytest.approx(0.5)
    assert crossval.bic_weight(100.0, 110.0) == pytest.approx(1 / (1 + np.exp(-5)))
    assert crossval.evidence_words(1.0) == "nearly indistinguishable"
    assert crossval.evidence_words(12.0) == "very strong"


def test_effective_fraction_is_the_variance_of_the_mean_of_ar1_noise():
    """(1 − φ)/(1 + φ): the share of independent hours, checked on the variance of the mean."""
    rng = np.random.default_rng(4)
    phi, n = 0.6, 2000
    assert comparison.effective_fraction(_ar1(rng, 50_000, phi, 1.0)) == pytest.approx(
        (1 - phi) / (1 + phi), abs=0.01)
    assert comparison.effective_fraction(rng.normal(size=50_000)) == pytest.approx(1.0, abs=0.02)
    # the definition itself: n·fraction independent hours give the mean's variance
    means = [np.mean(_ar1(rng, n, phi, 1.0)) for _ in range(600)]
    assert np.var(means) * n * (1 - phi) / (1 + phi) == pytest.approx(1.0, rel=0.15)


def _passed(cause: str, bic: float, cvrmse_after: float, fraction: float) -> tuple:
    entry = {"cause": cause, "bic": {"before": 2441.4, "after": bic,
                                     "effective_fraction": fraction},
             "cross_validation": {"cvrmse_before": 0.128, "cvrmse_after": cvrmse_after}}
    return entry, cause


def test_a_near_tie_in_bic_is_decided_by_out_of_fold_error():
    from bpsflow.diagnosis.workflow import choose_cause

    # ΔBIC 7.9 on residuals with φ = 0.5 is 2.6 on independent hours: not strong evidence
    roof = _passed("solar_aperture (roof)", 1683.1, 0.0571, 1 / 3)
    south = _passed("solar_aperture (south)", 1691.0, 0.0478, 1 / 3)
    entry, model = choose_cause([roof, south])
    assert model == "solar_aperture (south)"
    assert entry["runner_up"]["cause"] == "solar_aperture (roof)"
    assert entry["runner_up"]["delta_bic"] == pytest.approx(-7.9)
    assert entry["runner_up"]["delta_bic_effective"] == pytest.approx(-7.9 / 3)
    assert "out-of-fold" in entry["chosen_by"]
    # the same difference on independent hours is strong evidence: BIC decides
    roof = _passed("solar_aperture (roof)", 1683.1, 0.0571, 1.0)
    south = _passed("solar_aperture (south)", 1691.0, 0.0478, 1.0)
    assert choose_cause([roof, south])[1] == "solar_aperture (roof)"
    assert "chosen_by" not in south[0]
    # a rival far behind is never chosen, however its folds went
    gain = _passed("internal_gain_schedule", 1831.3, 0.0100, 1 / 3)
    assert choose_cause([roof, gain])[1] == "solar_aperture (roof)"


def _ar1(rng, n: int, phi: float, scale: float) -> np.ndarray:
    noise = rng.normal(0, scale * np.sqrt(1 - phi ** 2), n)
    out = np.empty(n)
    out[0] = rng.normal(0, scale)
    for i in range(1, n):
        out[i] = phi * out[i - 1] + noise[i]
    return out


def _oof_linear(y: np.ndarray, design: np.ndarray, folds: np.ndarray) -> np.ndarray:
    predictions = {}
    for number in np.unique(folds):
        train = folds != number
        beta = np.linalg.lstsq(design[train], y[train], rcond=None)[0]
        predictions[int(number)] = design @ beta
    return crossval.out_of_fold(folds, predictions)


def _accepts(y, base, extended, folds, alpha=0.05) -> bool:
    before = _oof_linear(y, base, folds)
    after = _oof_linear(y, extended, folds)
    test = comparison.encompassing_test(y - before, y - after, lags=HELDOUT_LAGS)
    rmse = lambda e: float(np.sqrt(np.mean(e ** 2)))  # noqa: E731
    return bool(test["p_value"] < alpha and rmse(y - after) < rmse(y - before))


def test_cross_validated_acceptance_keeps_its_size_and_finds_a_weekend_effect():
    """Size: an irrelevant weekend regressor, AR(1) φ = 0.9 errors; power: a real one.

    The nominal level is 5 %; the null rejection rate over 300 series must
    stay at or below 7 %, and a weekend-only effect of twice the error's
    standard deviation (48 of every 168 hours) must be accepted in ≥ 90 %.
    """
    rng = np.random.default_rng(7)
    folds = crossval.day_blocks(HOURS, _heldout())
    start = HOURS - pd.Timedelta(hours=1)
    outdoor = 8 + 4 * np.sin(2 * np.pi * np.arange(len(HOURS)) / 24) + rng.normal(0, 2,
                                                                                  len(HOURS))
    weekend = (start.day_of_week >= 5).astype(float)
    base = np.column_stack([np.ones(len(HOURS)), outdoor])
    extended = np.column_stack([base, weekend])
    false_alarms = found = 0
    series = 300
    for _ in range(series):
        noise = _ar1(rng, len(HOURS), 0.9, 1.0)
        null = 100 - 3 * outdoor + noise
        false_alarms += _accepts(null, base, extended, folds)
    for _ in range(50):
        noise = _ar1(rng, len(HOURS), 0.9, 1.0)
        effect = 100 - 3 * outdoor - 2.0 * weekend + noise
        found += _accepts(effect, base, extended, folds)
    print(f"weekend regressor: {false_alarms} of {series} false alarms, found {found} of 50")
    assert false_alarms / series <= 0.07, false_alarms
    assert found / 50 >= 0.9, found


def _linear_fit(design: np.ndarray, measured: np.ndarray, jacobian: np.ndarray):
    """A Fit of a model linear in two parameters (range 0-10), as fit_many reports one."""
    from pathlib import Path

    from bpsflow.config import load_config
    from bpsflow.diagnosis.fitting import Fit
    from bpsflow.distributions import Uniform

    config = load_config(Path(__file__).resolve().parents[1] / "configs" / "diagnosis.yaml")
    parameters = [p.model_copy(update={"distribution": Uniform(type="uniform", lower=0.0,
                                                              upper=10.0)})
                  for p in config.parameters[:2]]
    values = np.linalg.lstsq(design, measured, rcond=None)[0]
    prediction = design @ values
    residual_std = float(np.std(measured - prediction, ddof=2))
    covariance = residual_std ** 2 * np.linalg.pinv(jacobian.T @ jacobian)
    return parameters, Fit(parameters=parameters, values=values, prediction=prediction,
                           jacobian=jacobian, covariance=covariance, residual_std=residual_std,
                           objective=0.0, evaluations=1, seconds=0.0, iterations=1)


def test_linearised_fold_refits_are_exact_for_a_linear_model_and_bounded_for_a_bad_jacobian():
    """The fold refit of the linearised cross-validation (EnergyPlus's).

    For a model linear in its parameters, each fold's refit is the exact least
    squares without that fold. A finite-difference Jacobian with one column
    hundreds of times too large over one week (a setpoint switch inside the
    difference step) must not let that fold's refit predict it wildly: the
    step stays within a few standard errors, so the out-of-fold error stays
    near the fit's own, where an unbounded step multiplies it.
    """
    from scipy.optimize import lsq_linear

    from bpsflow.diagnosis.workflow import _gauss_newton_refit

    rng = np.random.default_rng(5)
    n = len(HOURS)
    design = np.column_stack([1.0 + rng.random(n), np.sin(np.arange(n) * 2 * np.pi / 24) + 1.5])
    measured = design @ np.array([4.0, 6.0]) + rng.normal(0, 0.3, n)
    folds = crossval.day_blocks(HOURS, _heldout())
    parameters, fit = _linear_fit(design, measured, design)
    for number in range(folds.max()):
        train = folds != number
        exact = design @ np.linalg.lstsq(design[train], measured[train], rcond=None)[0]
        np.testing.assert_allclose(_gauss_newton_refit(measured, fit, parameters, train), exact,
                                   rtol=1e-6)
    corrupted = design.copy()
    corrupted[folds == 0, 1] *= 500.0
    parameters, fit = _linear_fit(design, measured, corrupted)
    own = np.sqrt(np.mean((measured - fit.prediction)[folds == 0] ** 2))
    bounded = _gauss_newton_refit(measured, fit, parameters, folds != 0)
    assert np.sqrt(np.mean((measured - bounded)[folds == 0] ** 2)) < 1.5 * own
    jacobian = fit.jacobian[folds != 0]
    step = lsq_linear(jacobian, (measured - fit.prediction)[folds != 0],
                      bounds=(0.0 - fit.values, 10.0 - fit.values)).x
    unbounded = fit.prediction + fit.jacobian @ step
    assert np.sqrt(np.mean((measured - unbounded)[folds == 0] ** 2)) > 3 * own


def test_a_current_model_whose_linearised_folds_blow_up_is_refitted_by_simulation():
    """A Jacobian column 500 times too large in one week (a threshold inside the step).

    The parameter is poorly determined (its standard error spans its range,
    as a radiant fraction's often does), so the refit's trust region does
    not hold the step. The current model's linearised fold refits then predict that week
    wildly, and every candidate would "beat" it; the folds of all models
    are refitted by simulation instead (here exact least squares, as the
    model is linear), so the comparison is with the model's honest
    out-of-fold error. With a sound Jacobian the linearised refit stands.
    """
    from types import SimpleNamespace

    from bpsflow.diagnosis.fitting import Fit
    from bpsflow.diagnosis.settings import DiagnosisSettings
    from bpsflow.diagnosis.workflow import Model, _cross_validate

    rng = np.random.default_rng(8)
    n = len(HOURS)
    heldout = _heldout()
    design = np.column_stack([1.0 + rng.random(n), np.sin(np.arange(n) * 2 * np.pi / 24) + 1.5])
    measured = design @ np.array([4.0, 6.0]) + rng.normal(0, 0.3, n)

    def simulated_fits(config, label, problems, max_iterations=None):
        fits = []
        for problem in problems:
            train = np.asarray(problem.calibration, dtype=bool)
            values = np.linalg.lstsq(design[train], measured[train], rcond=None)[0]
            fits.append(Fit(parameters=problem.parameters, values=values,
                            prediction=design @ values, jacobian=design,
                            covariance=np.eye(2), residual_std=0.3, objective=0.0,
                            evaluations=1, seconds=0.0))
        return fits

    def cross_validate(jacobian: np.ndarray) -> tuple[dict, list[str]]:
        parameters, fit = _linear_fit(design[~heldout], measured[~heldout], jacobian[~heldout])
        fit.prediction, fit.jacobian = design @ fit.values, jacobian
        fit.covariance = np.diag([100.0, 100.0])
        context = SimpleNamespace(
            data=SimpleNamespace(y=measured, calibration=~heldout, timestamps=HOURS),
            settings=DiagnosisSettings(), backend="energyplus", vectorised=False, oof_cache={},
            notes=[], fit=simulated_fits)
        current = Model(None, parameters, fit, "current")  # type: ignore[arg-type]
        out = _cross_validate(context, None, {}, current,  # type: ignore[arg-type]
                              [(parameters, fit)], round_number=3)
        return out[0], context.notes

    sound, notes = cross_validate(design)
    assert sound["refit"] == "linearised" and not notes
    folds = crossval.day_blocks(HOURS, heldout)
    corrupted = design.copy()
    corrupted[folds == 0, 1] *= 500.0
    redone, notes = cross_validate(corrupted)
    assert redone["refit"] == "simulated"
    assert len(notes) == 1 and "times its calibration error" in notes[0]
    # the honest (exact) out-of-fold error of this well-specified model is its noise
    assert redone["cvrmse_before"] == pytest.approx(sound["cvrmse_before"], rel=0.05)
    assert redone["cvrmse_before"] < 0.05


def test_a_heldout_error_resting_on_one_hour_is_noted_with_the_others_cv():
    from bpsflow.diagnosis.workflow import concentration_note
    from bpsflow.metrics import error_concentration

    hours = pd.date_range("2025-03-05 01:00", periods=168, freq="h")
    measured = np.full(168, 100.0)
    prediction = measured + 1.0
    prediction[100] = measured[100] + 20.0       # one reheat peak placed a time step later
    positions, share = error_concentration(measured, prediction)
    assert len(positions) == 2 and positions[0] == 100      # 1 % of 168 hours, rounded
    assert share == pytest.approx(401.0 / (400.0 + 167.0))
    note = concentration_note(measured, prediction, hours, "heating_power_w")
    assert note is not None and f"{hours[100]:%Y-%m-%d %H:%M}" in note
    assert "2 of 168 hours" in note and "1.00%" in note      # the other hours: 1 W on 100 W
    # errors spread over the record: no note
    assert concentration_note(measured, measured + np.linspace(-2, 2, 168), hours, "x") is None
