"""Accuracy metrics (seed §2.4 eq. 1–2, 5–7) and validation risks (seed §3.6.2)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from bpsflow import metrics
from bpsflow.metrics import (
    GUIDELINE14_HOURLY,
    GUIDELINE14_MONTHLY,
    MetricResult,
    crps_ensemble,
    cv_rmse,
    guideline14_check,
    instance_nmae,
    mae,
    mbe,
    mcrps,
    nmae,
    nmbe,
    nmcrps,
    reduced_risk,
    rmse,
    type_ii_risk,
    validation_threshold,
)

# ---------------------------------------------------------------------------
# Brute-force references


def crps_pairwise(y: float, members: np.ndarray, estimator: str) -> float:
    """CRPS of one ensemble by the O(m²) definition E|X−y| − ½E|X−X′| (eq. 5)."""
    members = members[~np.isnan(members)]
    m = members.size
    if np.isnan(y) or m == 0:
        return float("nan")
    abs_error = np.mean(np.abs(members - y))
    pair_sum = np.abs(members[:, None] - members[None, :]).sum()
    pairs = m * m if estimator == "standard" else m * (m - 1)
    spread = pair_sum / pairs if pairs else 0.0
    return float(abs_error - 0.5 * spread)


def pairwise_scores(observations: np.ndarray, ensemble: np.ndarray, estimator: str) -> list:
    return [crps_pairwise(y, row, estimator)
            for y, row in zip(observations, ensemble, strict=True)]


def crps_normal(y: float, mu: float, sigma: float) -> float:
    """Closed-form CRPS of N(mu, sigma²) at y."""
    z = (y - mu) / sigma
    return sigma * (z * (2 * stats.norm.cdf(z) - 1) + 2 * stats.norm.pdf(z)
                    - 1 / math.sqrt(math.pi))


# ---------------------------------------------------------------------------
# CRPS


@pytest.mark.parametrize("estimator", ["standard", "fair"])
@pytest.mark.parametrize("y", [-3.0, 0.0, 1.3, 6.5])
def test_crps_of_normal_sample_converges_to_closed_form(y, estimator):
    mu, sigma, m = 2.0, 1.5, 20_000
    rng = np.random.default_rng(20240611)
    members = rng.normal(mu, sigma, size=m)
    score = crps_ensemble(np.array([y]), members[None, :], estimator)[0]
    # Monte Carlo standard error from the first-order projection of the
    # estimator: |x − y| − E_{X′}|x − X′|, with the latter in closed form.
    z = (members - mu) / sigma
    mean_distance = sigma * (z * (2 * stats.norm.cdf(z) - 1) + 2 * stats.norm.pdf(z))
    standard_error = np.std(np.abs(members - y) - mean_distance) / math.sqrt(m)
    bias_bound = sigma / (math.sqrt(math.pi) * m)  # standard estimator's O(1/m) bias
    assert abs(score - crps_normal(y, mu, sigma)) < 5 * standard_error + bias_bound
    assert standard_error < 0.02 * sigma  # the tolerance is tight enough to mean something


@pytest.mark.parametrize("estimator", ["standard", "fair"])
@pytest.mark.parametrize("m", [1, 2, 3, 7, 50])
def test_crps_equals_pairwise_computation(m, estimator):
    rng = np.random.default_rng(m)
    n = 40
    observations = rng.normal(0, 3, size=n)
    continuous = rng.normal(0, 3, size=(n, m))
    with_ties = rng.integers(-3, 4, size=(n, m)).astype(float)  # many equal members
    observations[:5] = with_ties[:5, 0]  # observation equal to a member
    for ensemble in (continuous, with_ties):
        expected = pairwise_scores(observations, ensemble, estimator)
        np.testing.assert_allclose(crps_ensemble(observations, ensemble, estimator), expected,
                                   rtol=1e-12, atol=1e-12)


def test_standard_and_fair_differ_by_the_spread_correction():
    observations = np.array([0.0])
    ensemble = np.array([[0.0, 1.0, 3.0]])
    # E|X−y| = 4/3; pair sum = 2·(1 + 3 + 2) = 12.
    assert crps_ensemble(observations, ensemble, "standard")[0] == pytest.approx(4 / 3 - 6 / 9)
    assert crps_ensemble(observations, ensemble, "fair")[0] == pytest.approx(4 / 3 - 6 / 6)


def test_crps_across_blocks_with_missing_members():
    rng = np.random.default_rng(7)
    n, m = metrics._ROWS_PER_BLOCK * 2 + 37, 9
    observations = rng.normal(size=n)
    ensemble = rng.normal(size=(n, m))
    ensemble[rng.random((n, m)) < 0.05] = np.nan
    ensemble[5] = np.nan  # a row with no member left
    observations[11] = np.nan
    for estimator in ("standard", "fair"):
        expected = pairwise_scores(observations, ensemble, estimator)
        np.testing.assert_allclose(crps_ensemble(observations, ensemble, estimator), expected,
                                   rtol=1e-12, atol=1e-12)


def test_crps_missing_values():
    observations = np.array([np.nan, 1.0, 1.0, 1.0])
    ensemble = np.array([[0.0, 2.0, 4.0],
                         [0.0, np.nan, 4.0],
                         [np.nan, np.nan, np.nan],
                         [3.0, np.nan, np.nan]])
    scores = crps_ensemble(observations, ensemble)
    assert np.isnan(scores[0])  # NaN observation
    assert scores[1] == pytest.approx(crps_ensemble(np.array([1.0]), np.array([[0.0, 4.0]]))[0])
    assert np.isnan(scores[2])  # no member left
    assert scores[3] == pytest.approx(2.0)  # one member left: the absolute error


def test_crps_of_point_forecast_is_absolute_error():
    rng = np.random.default_rng(3)
    observations, predicted = rng.normal(size=100), rng.normal(size=100)
    for estimator in ("standard", "fair"):
        np.testing.assert_allclose(crps_ensemble(observations, predicted[:, None], estimator),
                                   np.abs(observations - predicted), rtol=0, atol=1e-15)


def test_nmcrps_of_point_forecast_equals_nmae():
    rng = np.random.default_rng(4)
    observations = rng.uniform(200, 800, size=240)  # e.g. hourly heating power, W
    predicted = observations * rng.normal(1.0, 0.1, size=240)
    for estimator in ("standard", "fair"):
        result = nmcrps(observations, predicted[:, None], estimator)
        assert result.value == pytest.approx(nmae(observations, predicted).value, rel=1e-12)
        assert result.estimator == estimator
        assert result.normaliser == pytest.approx(observations.mean())
    assert mcrps(observations, predicted[:, None]).value == pytest.approx(
        mae(observations, predicted), rel=1e-12)


def test_mcrps_records_estimator_and_is_mean_crps():
    rng = np.random.default_rng(5)
    observations, ensemble = rng.normal(size=30), rng.normal(size=(30, 4))
    for estimator in ("standard", "fair"):
        result = mcrps(observations, ensemble, estimator)
        assert isinstance(result, MetricResult)
        assert (result.name, result.estimator, result.normaliser, result.note) == \
            ("MCRPS", estimator, None, "")
        assert float(result) == pytest.approx(crps_ensemble(observations, ensemble,
                                                            estimator).mean())
    assert mcrps(observations, ensemble, "fair").value < mcrps(observations, ensemble).value


def test_bad_estimator_and_shapes_are_rejected():
    with pytest.raises(ValueError, match="estimator"):
        crps_ensemble(np.zeros(2), np.zeros((2, 3)), "nrg")
    with pytest.raises(ValueError, match=r"\(n, m\)"):
        crps_ensemble(np.zeros(2), np.zeros(2))
    with pytest.raises(ValueError, match="no members"):
        crps_ensemble(np.zeros(2), np.zeros((2, 0)))


# ---------------------------------------------------------------------------
# Point metrics, eq. 1–2

OBSERVED = np.array([10.0, 20.0, 30.0])   # ȳ = 20
PREDICTED = np.array([12.0, 18.0, 27.0])  # y − ŷ = [−2, 2, 3]: Σ = 3, Σ² = 17, Σ|·| = 7


def test_nmbe_hand_computed():
    assert nmbe(OBSERVED, PREDICTED).value == pytest.approx(3 / (2 * 20))  # 0.075
    assert nmbe(OBSERVED, PREDICTED, p=0).value == pytest.approx(3 / (3 * 20))  # 0.05
    assert nmbe(PREDICTED, OBSERVED).value == pytest.approx(-3 / (2 * 19))  # ȳ = 19
    result = nmbe(OBSERVED, PREDICTED)
    assert (result.name, result.normaliser, result.estimator, result.note) == \
        ("NMBE", 20.0, None, "")
    assert mbe(OBSERVED, PREDICTED) == pytest.approx(1.5)


def test_cv_rmse_hand_computed():
    assert cv_rmse(OBSERVED, PREDICTED).value == pytest.approx(math.sqrt(17 / 2) / 20)  # 0.14577
    assert cv_rmse(OBSERVED, PREDICTED, p=0).value == pytest.approx(math.sqrt(17 / 3) / 20)
    assert rmse(OBSERVED, PREDICTED) == pytest.approx(2.9154759474)


def test_nmae_hand_computed():
    assert nmae(OBSERVED, PREDICTED).value == pytest.approx(7 / 3 / 20)  # 0.11667
    assert mae(OBSERVED, PREDICTED) == pytest.approx(7 / 3)


def test_p_must_leave_degrees_of_freedom():
    assert nmbe(OBSERVED, PREDICTED, p=2).value == pytest.approx(3 / (1 * 20))
    with pytest.raises(ValueError, match="n - p"):
        nmbe(OBSERVED, PREDICTED, p=3)
    with pytest.raises(ValueError, match="3 values"):
        cv_rmse(OBSERVED, PREDICTED[:2])


def test_temperature_metrics_are_unnormalised():
    observed_c = np.array([-1.0, 0.5, 1.0, -0.5])  # mean 0 °C
    predicted_c = np.array([-0.5, 0.5, 2.0, -0.5])
    assert mbe(observed_c, predicted_c) == pytest.approx(-1.5 / 3)
    assert rmse(observed_c, predicted_c) == pytest.approx(math.sqrt(1.25 / 3))
    assert mae(observed_c, predicted_c) == pytest.approx(1.5 / 4)


# ---------------------------------------------------------------------------
# Near-zero mean


def test_zero_mean_gives_nan_with_note_not_inf():
    observed = np.array([5.0, -5.0])  # ȳ = 0 exactly
    predicted = np.array([4.0, -4.0])
    with np.errstate(all="raise"):  # no division by zero happens either
        results = [nmbe(observed, predicted), cv_rmse(observed, predicted),
                   nmae(observed, predicted), nmcrps(observed, predicted[:, None])]
    for result in results:
        assert math.isnan(result.value) and not math.isinf(result.value)
        assert "near zero" in result.note
        assert result.normaliser == 0.0
    assert results[-1].estimator == "standard"


def test_heating_test_that_barely_heats_gives_nan():
    observed_w = np.array([0.0, 0.0, 1e-6, 0.0])  # sensor noise, W
    predicted_w = np.array([100.0, 120.0, 90.0, 110.0])
    result = cv_rmse(observed_w, predicted_w)
    assert math.isnan(result.value)
    assert "near zero" in result.note and "un-normalised" in result.note
    assert rmse(observed_w, predicted_w) > 100  # the un-normalised form still works
    ensemble = np.column_stack([predicted_w, predicted_w * 1.1])
    assert np.isnan(instance_nmae(observed_w, ensemble).value).all()
    assert "near zero" in instance_nmae(observed_w, ensemble).note


def test_tolerance_is_relative_to_data_scale():
    observed = np.array([2.0, 0.0])  # ȳ = 1, largest magnitude 1000 below
    predicted = np.array([1000.0, 0.0])
    assert math.isnan(nmbe(observed, predicted).value)  # 1 <= 1e-3 · 1000
    assert not math.isnan(nmbe(observed, predicted, rtol=1e-4).value)
    small = np.array([2e-9, 0.0])  # tiny unit, but ȳ is half the scale: fine
    assert nmbe(small, np.array([1e-9, 0.0])).value == pytest.approx(1e-9 / 1e-9)


def test_missing_observation_gives_nan_with_note():
    result = nmbe(np.array([1.0, np.nan, 3.0]), np.array([1.0, 2.0, 3.0]))
    assert math.isnan(result.value) and "missing" in result.note
    result = nmcrps(np.array([1.0, 2.0]), np.array([[1.0, 2.0], [np.nan, np.nan]]))
    assert math.isnan(result.value) and "missing" in result.note


# ---------------------------------------------------------------------------
# ASHRAE Guideline 14


def test_guideline14_thresholds_are_pinned():
    assert (GUIDELINE14_MONTHLY.max_abs_nmbe,
            GUIDELINE14_MONTHLY.max_cv_rmse) == (0.05, 0.15)
    assert (GUIDELINE14_HOURLY.max_abs_nmbe,
            GUIDELINE14_HOURLY.max_cv_rmse) == (0.10, 0.30)


@pytest.mark.parametrize(("interval", "nmbe_limit", "cv_limit"),
                         [("monthly", 0.05, 0.15), ("hourly", 0.10, 0.30)])
def test_guideline14_limits_are_inclusive(interval, nmbe_limit, cv_limit):
    step = 1e-9
    assert guideline14_check(nmbe_limit, cv_limit, interval).passed  # on the limit: pass
    assert guideline14_check(-nmbe_limit, cv_limit, interval).passed  # |NMBE|
    over_bias = guideline14_check(nmbe_limit + step, cv_limit, interval)
    assert not over_bias.passed and not over_bias.nmbe_passed and over_bias.cv_rmse_passed
    assert not guideline14_check(-nmbe_limit - step, 0.0, interval).passed
    over_spread = guideline14_check(0.0, cv_limit + step, interval)
    assert not over_spread.passed and over_spread.nmbe_passed and not over_spread.cv_rmse_passed
    assert not guideline14_check(float("nan"), 0.0, interval).passed
    assert guideline14_check(0.0, 0.0, interval).criteria.data_interval == interval


def test_guideline14_accepts_metric_results():
    predicted = OBSERVED * 1.02  # y − ŷ = [−0.2, −0.4, −0.6]: Σ = −1.2, Σ² = 0.56
    check = guideline14_check(nmbe(OBSERVED, predicted), cv_rmse(OBSERVED, predicted), "monthly")
    assert check.nmbe == pytest.approx(-1.2 / (2 * 20))  # −3 %
    assert check.cv_rmse == pytest.approx(math.sqrt(0.56 / 2) / 20)  # 2.6 %
    assert check.passed
    with pytest.raises(ValueError, match="data_interval"):
        guideline14_check(0.0, 0.0, "daily")


# ---------------------------------------------------------------------------
# Validation threshold and risks


def offset_ensemble(observations: np.ndarray, offsets) -> np.ndarray:
    """Members = observations shifted by each offset: member nMAE = |offset| / ȳ."""
    return observations[:, None] + np.asarray(offsets, dtype=float)[None, :]


def test_instance_nmae_per_member():
    observations = np.array([5.0, 10.0, 15.0])  # ȳ = 10
    ensemble = offset_ensemble(observations, [0.0, 1.0, -2.0, 4.5])
    result = instance_nmae(observations, ensemble)
    np.testing.assert_allclose(np.asarray(result), [0.0, 0.1, 0.2, 0.45])
    for j in range(ensemble.shape[1]):
        assert result.value[j] == pytest.approx(nmae(observations, ensemble[:, j]).value)


def test_threshold_type_ii_and_reduced_risk_known_answer():
    observations = np.full(4, 10.0)
    refined = offset_ensemble(observations, np.arange(10))  # nMAE 0.0, 0.1, …, 0.9
    baseline = offset_ensemble(observations, np.arange(5, 25))  # nMAE 0.5, 0.6, …, 2.4
    q = 0.9
    threshold = validation_threshold(instance_nmae(observations, refined), q)
    assert threshold == pytest.approx(0.81)  # linear: 0.8 + 0.1 · (0.9·9 − 8)
    assert validation_threshold(instance_nmae(observations, refined), q,
                                method="inverted_cdf") == pytest.approx(0.8)
    type_ii = type_ii_risk(threshold, instance_nmae(observations, baseline))
    assert type_ii == pytest.approx(4 / 20)  # 0.5, 0.6, 0.7, 0.8 are accepted
    assert reduced_risk(q, type_ii) == pytest.approx(0.7)


def test_type_ii_counts_values_on_the_threshold_as_accepted():
    assert type_ii_risk(1.0, [0.5, 1.0, 1.5, 2.0]) == 0.5
    assert math.isnan(type_ii_risk(1.0, [0.5, np.nan]))
    assert math.isnan(type_ii_risk(float("nan"), [0.5]))


def test_baseline_against_its_own_threshold_keeps_q():
    rng = np.random.default_rng(11)
    values = rng.gamma(2.0, 0.2, size=1000)
    q = 0.9
    threshold = validation_threshold(values, q)
    # Accepting at most the threshold admits q of the valid set itself.
    assert type_ii_risk(threshold, values) == pytest.approx(q, abs=1 / values.size)
    assert reduced_risk(q, type_ii_risk(threshold, values)) == pytest.approx(0.0, abs=1e-3)


def test_reduced_risk_matches_seed_table_3_5():
    # I600-C-ST: type II risk 20.85 % at q = 90 % → reduced risk 69.15 %.
    assert reduced_risk(0.9, 0.2085) == pytest.approx(0.6915)


def test_validation_threshold_rejects_bad_q():
    with pytest.raises(ValueError, match="q must be"):
        validation_threshold([1.0, 2.0], 90)
