"""Statistics of ``bpsflow diagnose``: drivers, residual-structure tests, held-out comparison.

Known answers only: calendar facts, the EPW's own rows, the isotropic-sky
closed form, statsmodels as the reference implementation, recovery of effects
hidden in autocorrelated noise, and null rejection rates.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import statsmodels.api as sm
from scipy import stats

from bpsflow.config import load_config
from bpsflow.diagnosis import comparison, structure
from bpsflow.diagnosis.drivers import DRIVER_NAMES, FACADES, derive_drivers, driver_group
from bpsflow.weather import epw_rows, read_epw

ROOT = Path(__file__).resolve().parents[1]
PHI = 0.8          # AR(1) coefficient of the synthetic residual noise
N_HOURS = 700      # about four weeks of hourly residuals
WINDOW_START = "2025-11-10 01:00"


@lru_cache(maxsize=1)
def weather_file() -> Path:
    return load_config(ROOT / "configs" / "i600.yaml").model.weather


@lru_cache(maxsize=1)
def window_drivers() -> pd.DataFrame:
    """Drivers of a November–December window of the shipped case's weather."""
    hours = pd.date_range(WINDOW_START, periods=N_HOURS, freq="h")
    return derive_drivers(weather_file(), hours)


def ar1_noise(seed: int, n: int = N_HOURS, phi: float = PHI, sd: float = 1.0) -> np.ndarray:
    """Stationary AR(1) noise with marginal standard deviation ``sd``."""
    rng = np.random.default_rng(seed)
    innovations = rng.standard_normal(n) * sd * np.sqrt(1 - phi ** 2)
    noise = np.empty(n)
    noise[0] = rng.standard_normal() * sd
    for t in range(1, n):
        noise[t] = phi * noise[t - 1] + innovations[t]
    return noise


def epw_field(month: int, day: int, hour: int, field: int) -> float:
    """A field of the EPW data line with that month, day and (1-based, hour-ending) hour."""
    for line in weather_file().read_text().splitlines()[8:]:
        parts = line.split(",")
        if (int(parts[1]), int(parts[2]), int(parts[3])) == (month, day, hour):
            return float(parts[field])
    raise AssertionError("no such EPW line")


# ---------------------------------------------------------------------------
# Drivers


def test_epw_rows_by_month_day_hour_across_years():
    starts = pd.DatetimeIndex(["2025-01-01 00:00", "2025-12-05 09:00", "2024-03-01 00:00",
                               "2024-02-29 05:00", "2023-12-31 23:00"])
    assert epw_rows(starts, 8760).tolist() == [0, 338 * 24 + 9, 59 * 24, 58 * 24 + 5, 8759]
    # a leap-year file keeps 29 February; a non-leap date after it skips that day
    assert epw_rows(starts, 8784).tolist() == [0, 339 * 24 + 9, 60 * 24, 59 * 24 + 5, 8783]


def test_derive_drivers_columns_calendar_and_epw_rows():
    hours = pd.DatetimeIndex(["2025-11-15 00:00", "2025-11-15 01:00", "2025-11-17 00:00",
                              "2025-11-17 01:00", "2025-12-05 10:00", "2025-01-01 00:00",
                              "2024-03-01 01:00"])
    measured = pd.DataFrame({"heating_power_w": np.arange(7.0), "neighbour_temperature_c": 20.0,
                             "outdoor_air_temperature": 9.0, "note": "x"}, index=hours)
    drivers = derive_drivers(weather_file(), hours, measured, exclude=["heating_power_w"])
    assert list(drivers.columns) == [*DRIVER_NAMES, "neighbour_temperature_c",
                                     "measured_outdoor_air_temperature"]
    assert drivers.index.equals(hours)
    # hour-ending stamps: 00:00 on Saturday closes Friday's last hour
    assert drivers["hour_of_day"].tolist() == [23, 0, 23, 0, 9, 23, 0]
    assert drivers["weekend"].tolist() == [0, 1, 1, 0, 0, 0, 0]
    # the weather of an hour is the EPW line of that month, day and hour-ending hour
    for stamp, (month, day, hour) in zip(hours[4:], [(12, 5, 10), (12, 31, 24), (3, 1, 1)]):
        assert drivers.loc[stamp, "outdoor_air_temperature"] == epw_field(month, day, hour, 6)
        assert drivers.loc[stamp, "wind_speed"] == epw_field(month, day, hour, 21)
        assert drivers.loc[stamp, "global_horizontal_radiation"] == epw_field(month, day, hour, 13)
    assert drivers["neighbour_temperature_c"].eq(20.0).all()


def test_derive_drivers_units_over_a_window():
    drivers = window_drivers()
    assert drivers["outdoor_air_temperature"].between(-10, 35).all()   # °C, San Francisco
    assert drivers["wind_speed"].between(0, 30).all()                  # m/s
    for name in DRIVER_NAMES:
        if driver_group(name) == "irradiance":
            assert drivers[name].between(0, 1400).all(), name           # W/m²
    night = drivers["global_horizontal_radiation"] == 0
    assert (drivers.loc[night, [f"incident_solar_{f}" for f in FACADES]] == 0).all().all()
    assert drivers["incident_solar_south"].max() > 600                   # low winter sun


def test_incident_solar_equals_isotropic_closed_form():
    import pvlib

    drivers = window_drivers()
    epw = read_epw(weather_file())
    header = epw.header[0].split(",")
    latitude, longitude, zone, elevation = map(float, header[6:10])
    middles = (drivers.index - pd.Timedelta(minutes=30) - pd.Timedelta(hours=zone)).tz_localize("UTC")
    sun = pvlib.solarposition.get_solarposition(middles, latitude, longitude, altitude=elevation)
    zenith = np.radians(sun["apparent_zenith"].to_numpy())
    azimuth = np.radians(sun["azimuth"].to_numpy())
    dni = drivers["direct_normal_radiation"].to_numpy()
    dhi = drivers["diffuse_horizontal_radiation"].to_numpy()
    ghi = drivers["global_horizontal_radiation"].to_numpy()
    up = zenith < np.pi / 2
    albedo = 0.2
    for facade, (tilt_deg, azimuth_deg) in FACADES.items():
        tilt, facing = np.radians(tilt_deg), np.radians(azimuth_deg)
        cos_incidence = (np.cos(zenith) * np.cos(tilt)
                         + np.sin(zenith) * np.sin(tilt) * np.cos(azimuth - facing))
        expected = (np.where(up, dni, 0.0) * np.clip(cos_incidence, 0, None)
                    + dhi * (1 + np.cos(tilt)) / 2 + ghi * albedo * (1 - np.cos(tilt)) / 2)
        np.testing.assert_allclose(drivers[f"incident_solar_{facade}"], expected, atol=1e-6,
                                   err_msg=facade)
    # a clear hour: the beam dominates the south facade
    clear = int(np.argmax(dni))
    assert drivers["incident_solar_south"].iloc[clear] > dni[clear] * 0.5 + dhi[clear] / 2
    # the sun in the south: the north facade sees sky and ground only
    south_sun = up & (np.abs(np.degrees(azimuth) - 180) < 60) & (dni > 100)
    assert south_sun.sum() > 50
    np.testing.assert_allclose(drivers["incident_solar_north"].to_numpy()[south_sun],
                               (dhi / 2 + albedo * ghi / 2)[south_sun], atol=1e-6)


def test_driver_groups():
    assert driver_group("outdoor_air_temperature") == "temperature"
    assert driver_group("neighbour_temperature_c") == "temperature"
    assert driver_group("hour_of_day") == "hour"
    assert driver_group("weekend") == "weekend"
    assert {driver_group(f"incident_solar_{f}") for f in FACADES} == {"irradiance"}
    assert driver_group("diffuse_horizontal_radiation") == "irradiance"
    assert driver_group("wind_speed") == "wind"
    assert driver_group("cooling_power_w") == "other"
    assert driver_group("wind_direction") == "other"


# ---------------------------------------------------------------------------
# Bases and single-driver tests


def test_basis_per_group():
    drivers = window_drivers()
    temperature = structure.basis("outdoor_air_temperature", drivers)
    knots = np.quantile(drivers["outdoor_air_temperature"], [1 / 3, 2 / 3])
    assert temperature.shape[1] == 3
    np.testing.assert_allclose(temperature.iloc[:, 2],
                               np.maximum(drivers["outdoor_air_temperature"] - knots[1], 0))
    hour = structure.basis("hour_of_day", drivers)
    assert hour.shape[1] == 6
    np.testing.assert_allclose(hour["hour_of_day_cos3"],
                               np.cos(2 * np.pi * 3 * drivers["hour_of_day"] / 24))
    wind = structure.basis("wind_speed", drivers, indoor_temperature_c=21.0)
    np.testing.assert_allclose(wind["wind_speed_x_delta_t"], drivers["wind_speed"]
                               * (21.0 - drivers["outdoor_air_temperature"]))
    assert list(structure.basis("wind_speed", drivers).columns) == ["wind_speed"]
    weekdays = drivers[drivers["weekend"] == 0].iloc[:96]
    assert structure.basis("weekend", weekdays).shape[1] == 0


def test_one_driver_matches_statsmodels():
    drivers = window_drivers()
    residual = pd.Series(0.004 * drivers["incident_solar_west"] + ar1_noise(3), index=drivers.index)
    for name, lags in [("incident_solar_west", 30), ("hour_of_day", 40)]:
        design = sm.add_constant(structure.basis(name, drivers).to_numpy())
        reference = sm.OLS(residual.to_numpy(), design).fit(
            cov_type="HAC", cov_kwds={"maxlags": lags, "use_correction": True})
        q = design.shape[1] - 1
        wald = reference.wald_test(np.column_stack([np.zeros(q), np.eye(q)]), use_f=False,
                                   scalar=True)
        [chi2] = structure.test_drivers(residual, drivers[[name]], hac_lags=lags, reference="chi2")
        assert chi2.p_value == pytest.approx(float(wald.pvalue), rel=1e-9)
        assert chi2.p_adjusted == pytest.approx(chi2.p_value)  # one test: Holm changes nothing
        assert chi2.share == pytest.approx(reference.rsquared)
        assert chi2.amplitude == pytest.approx(np.std(design[:, 1:] @ reference.params[1:]))
        if q == 1:  # the t-test of the slope
            assert chi2.p_value == pytest.approx(reference.pvalues[1], rel=1e-9)
            # fixed-b with q = 1: |t| / sqrt(exp(b)) against Student's t with ⌈3/(2b)⌉ dof
            [fixed] = structure.test_drivers(residual, drivers[[name]], hac_lags=lags)
            b = (lags + 1) / len(residual)
            expected = 2 * stats.t.sf(abs(reference.tvalues[1]) / np.sqrt(np.exp(b)),
                                      np.ceil(1.5 / b))
            assert fixed.p_value == pytest.approx(expected, rel=1e-9)
            assert fixed.direction == 1 and fixed.coefficients["incident_solar_west"] > 0


def test_a_driver_in_huge_units_gives_the_same_test():
    """A sensor logged in odd units (×1e298) is the same driver: no overflow, same p and share."""
    drivers = window_drivers()
    residual = pd.Series(0.004 * drivers["incident_solar_west"] + ar1_noise(3), index=drivers.index)
    huge = drivers[["incident_solar_west"]] * 1e298
    [plain] = structure.test_drivers(residual, drivers[["incident_solar_west"]], hac_lags=30)
    [scaled] = structure.test_drivers(residual, huge, hac_lags=30)
    assert scaled.p_value == pytest.approx(plain.p_value, rel=1e-6)
    assert scaled.share == pytest.approx(plain.share, rel=1e-9)
    assert scaled.direction == plain.direction == 1
    assert scaled.coefficients["incident_solar_west"] == pytest.approx(
        plain.coefficients["incident_solar_west"] * 1e-298, rel=1e-9)


def test_fixed_b_reference_tends_to_chi2():
    # b → 0: the fixed-b F approximation is the χ²(q) test
    assert structure.fixed_b_pvalue(12.6, 6, 0, 10 ** 7) == pytest.approx(
        stats.chi2.sf(12.6, 6), rel=1e-4)
    # a wide window costs: the same statistic is less significant
    assert structure.fixed_b_pvalue(12.6, 6, 70, 700) > 2 * stats.chi2.sf(12.6, 6)


def test_holm_matches_statsmodels():
    from statsmodels.stats.multitest import multipletests

    p_values = np.array([0.01, 0.04, 0.001, 0.3, 0.02, 0.5])
    np.testing.assert_allclose(structure.holm(p_values),
                               multipletests(p_values, method="holm")[1])


def test_default_lags_follow_residual_persistence():
    # AR(1) with ρ = 0.8: ⌈2·0.8/(0.36·0.1)⌉ − 1 = 44 lags (within sampling error of ρ̂)
    noise = ar1_noise(11, n=20000)
    assert 40 <= structure.default_hac_lags(noise[:, None], noise) <= 50
    white = np.random.default_rng(1).standard_normal(700)
    assert structure.default_hac_lags(white[:, None], white) == structure.MIN_HAC_LAGS


def test_sign_flip_between_folds_is_not_consistent():
    drivers = window_drivers()
    solar = drivers["incident_solar_south"].to_numpy()
    half = len(solar) // 2
    effect = 0.01 * solar * np.where(np.arange(len(solar)) < half, 1.0, -3.0)
    residual = pd.Series(effect + ar1_noise(5, sd=0.2), index=drivers.index)
    [test] = structure.test_drivers(residual, drivers[["incident_solar_south"]])
    assert test.direction == -1 and test.share > 0.05
    assert not test.sign_consistent and not test.significant
    steady = pd.Series(-0.01 * solar + ar1_noise(5, sd=0.2), index=drivers.index)
    [test] = structure.test_drivers(steady, drivers[["incident_solar_south"]])
    assert test.direction == -1 and test.sign_consistent and test.significant


# ---------------------------------------------------------------------------
# Detection of hidden effects, and false alarms


SEEDS = range(5)


def _significant(residual: np.ndarray, **kwargs) -> list[str]:
    drivers = window_drivers()
    tests = structure.test_drivers(pd.Series(residual, index=drivers.index), drivers, **kwargs)
    return [t.name for t in tests if t.significant]


def test_detects_an_east_facade_solar_gain():
    drivers = window_drivers()
    aperture_m2 = 1.0   # W of gain per W/m² on the east facade
    for seed in SEEDS:
        residual = aperture_m2 * drivers["incident_solar_east"].to_numpy() + ar1_noise(seed, sd=100)
        found = _significant(residual)
        assert found and found[0] == "incident_solar_east", (seed, found)


def test_detects_a_weekday_office_hours_gain():
    drivers = window_drivers()
    office = ((drivers["weekend"] == 0) & drivers["hour_of_day"].between(9, 16)).to_numpy()
    for seed in SEEDS:
        residual = 400.0 * office + ar1_noise(seed, sd=100)
        found = _significant(residual)
        assert {"hour_of_day", "weekend"} <= set(found), (seed, found)
        assert found[0] == "hour_of_day"


def test_detects_wind_driven_infiltration():
    drivers = window_drivers()
    indoor_c = 20.0
    conductance = 6.0   # W per (m/s · K)
    for seed in SEEDS:
        residual = (conductance * drivers["wind_speed"].to_numpy()
                    * (indoor_c - drivers["outdoor_air_temperature"].to_numpy())
                    + ar1_noise(seed, sd=100))
        found = _significant(residual, indoor_temperature_c=indoor_c)
        assert found and found[0] == "wind_speed", (seed, found)


@pytest.mark.slow
def test_false_alarm_rate_on_autocorrelated_noise():
    drivers = window_drivers()
    alarms, p_values = [], []
    for seed in range(100, 200):
        tests = structure.test_drivers(pd.Series(ar1_noise(seed), index=drivers.index), drivers,
                                       indoor_temperature_c=20.0)
        alarms.append(any(t.significant for t in tests))
        p_values.append([t.p_value for t in tests])
    rate = float(np.mean(alarms))
    single = float(np.mean(np.array(p_values) < 0.05))
    print(f"false-alarm rate over {len(alarms)} AR(1) null series: {rate:.3f}; "
          f"single-driver rejection at 5 %: {single:.3f}")
    assert rate <= 0.10
    # per driver, near the nominal level (white-noise variance: 0.40, 6 lags and χ²: 0.12)
    assert single <= 0.10


# ---------------------------------------------------------------------------
# Whiteness


def test_whiteness_matches_ljung_box_closed_form():
    white = np.random.default_rng(2).standard_normal(2000)
    red = ar1_noise(2, n=2000)
    for series, expected_white in [(white, True), (red, False)]:
        result = structure.whiteness(series, lags=24)
        centred = series - series.mean()
        rho = np.array([centred[k:] @ centred[:-k] for k in range(1, 25)]) / (centred @ centred)
        n = len(series)
        q = n * (n + 2) * np.sum(rho ** 2 / (n - np.arange(1, 25)))
        assert result["statistic"] == pytest.approx(q, rel=1e-9)
        assert result["p_value"] == pytest.approx(stats.chi2.sf(q, 24), rel=1e-6)
        assert result["white"] is expected_white
    acf = structure.autocorrelation(red, 3)
    centred = red - red.mean()
    np.testing.assert_allclose(acf, [1.0] + [centred[k:] @ centred[:-k] / (centred @ centred)
                                             for k in (1, 2, 3)], atol=1e-10)
    assert acf[1] == pytest.approx(PHI, abs=0.05)


# ---------------------------------------------------------------------------
# Held-out comparison


def test_loss_difference_test_matches_ols_on_a_constant():
    rng = np.random.default_rng(4)
    before = ar1_noise(4, n=168) + 0.3
    after = 0.5 * before + 0.2 * rng.standard_normal(168)
    for loss, lags in [("squared", 20), ("absolute", 5)]:
        difference = before ** 2 - after ** 2 if loss == "squared" else np.abs(before) - np.abs(after)
        reference = sm.OLS(difference, np.ones(168)).fit(
            cov_type="HAC", cov_kwds={"maxlags": lags, "use_correction": True})
        normal = comparison.loss_difference_test(before, after, loss=loss, lags=lags,
                                                 reference="normal")
        assert normal["mean_difference"] == pytest.approx(difference.mean())
        assert normal["statistic"] == pytest.approx(reference.tvalues[0], rel=1e-10)
        assert normal["p_value"] == pytest.approx(reference.pvalues[0] / 2, rel=1e-8)
        fixed = comparison.loss_difference_test(before, after, loss=loss, lags=lags)
        b = (lags + 1) / 168
        assert fixed["p_value"] == pytest.approx(
            stats.t.sf(reference.tvalues[0] / np.sqrt(np.exp(b)), np.ceil(1.5 / b)), rel=1e-9)
    # the better model is found, the worse one is not (a week of errors with
    # lag-1 autocorrelation 0.84 in d: 84 lags, fixed-b t with 3 dof)
    better = comparison.loss_difference_test(before, after)
    assert better["mean_difference"] > 0 and better["p_value"] < 0.05
    assert comparison.loss_difference_test(after, before)["p_value"] > 0.95


def test_loss_difference_null_rejection_rate():
    n, seeds = 168, 200   # a held-out week, hourly
    bound = stats.binom.ppf(0.99, seeds, 0.05) / seeds

    def rejection_rate(**kwargs) -> float:
        rejected = 0
        for seed in range(seeds):
            difference = ar1_noise(1000 + seed, n=n)       # AR(1) loss differences, mean 0
            offset = 10.0 + np.abs(difference).max()        # squared loss: d = e_b² − e_a²
            result = comparison.loss_difference_test(
                np.sqrt(difference + offset), np.full(n, np.sqrt(offset)), **kwargs)
            rejected += result["p_value"] < 0.05
        return rejected / seeds

    rate = rejection_rate()
    print(f"loss-difference test, null rejection at 5 %: {rate:.3f} (bound {bound:.3f})")
    assert rate <= bound
    # the test can fail: white-noise variance with normal quantiles rejects far too often
    assert rejection_rate(lags=0, reference="normal") > bound


def _evening_change(n: int, size: float = 1.0) -> np.ndarray:
    """A change acting 15 of every 168 hours: 17–20 h on weekdays, like an evening gain."""
    hours = np.arange(n)
    return size * (((hours % 24) >= 17) & ((hours % 24) < 20) & ((hours // 24) % 7 < 5))


def test_encompassing_test_matches_ols_on_the_change():
    n, lags = 840, 30
    noise = ar1_noise(11, n=n, phi=0.8)
    change = _evening_change(n, 2.0) + 0.3 * ar1_noise(12, n=n, phi=0.5)
    before = 0.8 * change + noise
    after = before - change
    reference = sm.OLS(before, sm.add_constant(change)).fit(
        cov_type="HAC", cov_kwds={"maxlags": lags, "use_correction": True})
    t_against_zero = comparison.encompassing_test(before, after, weight=0.0, lags=lags,
                                                   reference="normal")
    assert t_against_zero["slope"] == pytest.approx(reference.params[1], rel=1e-10)
    assert t_against_zero["statistic"] == pytest.approx(reference.tvalues[1], rel=1e-10)
    assert t_against_zero["p_value"] == pytest.approx(reference.pvalues[1] / 2, rel=1e-8)
    fixed = comparison.encompassing_test(before, after, lags=lags)
    t_half = (reference.params[1] - 0.5) / reference.bse[1]
    b = (lags + 1) / n
    assert fixed["p_value"] == pytest.approx(
        stats.t.sf(t_half / np.sqrt(np.exp(b)), np.ceil(1.5 / b)), rel=1e-9)
    # a weight of 1/2 is where the squared loss stops improving (means apart)
    half = 0.5 * change + noise
    gain = np.mean(half ** 2) - np.mean((half - change) ** 2)
    slope = comparison.encompassing_test(half, half - change)["slope"]
    assert gain == pytest.approx((2 * slope - 1) * np.var(change)
                                 + 2 * half.mean() * change.mean() - change.mean() ** 2,
                                 rel=1e-9)
    # a change that is zero everywhere carries nothing
    assert comparison.encompassing_test(before, before)["p_value"] == 1.0


def test_encompassing_test_keeps_its_size_and_finds_a_sparse_effect():
    n, seeds = 840, 200   # five weeks of out-of-fold hours
    bound = stats.binom.ppf(0.99, seeds, 0.05) / seeds
    change = _evening_change(n) + 0.5 * ar1_noise(7, n=n, phi=0.9)

    def rejection_rate(**kwargs) -> float:
        rejected = 0
        for seed in range(seeds):
            # on the null's edge: the change removes half of what it touches (λ = 1/2)
            before = 0.5 * change + ar1_noise(2000 + seed, n=n, phi=0.9)
            rejected += comparison.encompassing_test(before, before - change, **kwargs)[
                "p_value"] < 0.05
        return rejected / seeds

    for lags in (None, 24):   # the default window, and the diagnosis's one day
        rate = rejection_rate(lags=lags)
        print(f"encompassing test, {lags} lags, null rejection at 5 %: {rate:.3f} "
              f"(bound {bound:.3f})")
        assert rate <= bound
    # the test can fail: white-noise variance with normal quantiles rejects far too often
    assert rejection_rate(lags=0, reference="normal") > bound
    # an evening effect of 1.5 noise standard deviations, 15 hours a week, fully removed
    found = {"encompassing": 0, "loss difference": 0}
    for seed in range(40):
        noise = ar1_noise(3000 + seed, n=n, phi=0.9)
        before, after = noise + _evening_change(n, 1.5), noise
        found["encompassing"] += comparison.encompassing_test(before, after)["p_value"] < 0.05
        found["loss difference"] += comparison.loss_difference_test(
            before, after, loss="absolute", lags=24)["p_value"] < 0.05
    print(f"sparse effect found in 40 series: {found}")
    assert found["encompassing"] >= 38 and found["encompassing"] >= found["loss difference"]


def test_bic_closed_form_and_statsmodels():
    residuals = np.array([1.0, -1.0, 2.0, -2.0])
    assert comparison.bic(residuals, 2) == pytest.approx(4 * np.log(10 / 4) + 2 * np.log(4))
    rng = np.random.default_rng(6)
    x = rng.standard_normal((50, 3))
    y = x @ [1.0, 0.5, 0.0] + rng.standard_normal(50)
    fit = sm.OLS(y, sm.add_constant(x)).fit()
    # statsmodels' Gaussian BIC = ours + n (1 + ln 2π)
    assert comparison.bic(fit.resid, 4) == pytest.approx(fit.bic - 50 * (1 + np.log(2 * np.pi)))
    # a useless extra parameter costs ln n
    assert comparison.bic(fit.resid, 5) - comparison.bic(fit.resid, 4) == pytest.approx(np.log(50))
