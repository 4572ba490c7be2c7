"""Structure in the residuals: which driver explains them, and are they white.

The residual ``r_t`` (measured − calibrated prediction) of a model that
explains the physics is noise: no pattern against any variable (seed §1.1.1.1,
residual analysis after Palomo et al. 1991), and no autocorrelation beyond
what the measurement noise has. Each candidate driver
(:mod:`bpsflow.diagnosis.drivers`) is tested with a basis that fits its
physics (:func:`basis`), by OLS ``r ~ 1 + basis`` with a Wald test whose
covariance holds under autocorrelated residuals (Newey–West HAC, fixed-b
reference distribution), Holm's correction across drivers, an effect size
that matters (share of residual variance, amplitude) and the same direction in
every blocked fold (DESIGN.md §8: not p < 0.05 at n = 8760).
:func:`whiteness` (Ljung–Box) flags missing dynamics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats

from bpsflow.diagnosis.drivers import driver_group

#: Harmonics of the daily cycle in the ``hour_of_day`` basis (sin and cos of 2πkh/24).
HOUR_HARMONICS = (1, 2, 3)
#: Quantiles of a temperature driver where its hinges sit (the tertiles).
HINGE_QUANTILES = (1 / 3, 2 / 3)
#: Bartlett kernel constants ∫k(x)dx and ∫k(x)²dx of the fixed-b approximation.
_BARTLETT_C1, _BARTLETT_C2 = 1.0, 2.0 / 3.0
#: Relative bias of the Newey–West variance tolerated by the default lag length.
HAC_BIAS_TOLERANCE = 0.1
#: Shortest default lag window (h): a day, so the day-to-day correlation of a
#: daily pattern the model misses enters the variance.
MIN_HAC_LAGS = 24


# ---------------------------------------------------------------------------
# Bases


def basis(name: str, drivers: pd.DataFrame,
          indoor_temperature_c: np.ndarray | float | None = None) -> pd.DataFrame:
    """The regressors a driver is tested with, chosen by its group.

    * temperature (°C): the driver and hinges ``max(x − q, 0)`` at its
      tertiles ``q`` (a change of slope: a balance point, a setpoint);
    * ``hour_of_day``: ``sin`` and ``cos`` of ``2πkh/24``, k = 1..3 (a daily
      profile of width down to ~4 h);
    * ``weekend``: the 0/1 dummy;
    * ``day_of_week``: a 0/1 dummy per day but the first (an effect on one day);
    * irradiance (W/m²) and other measured columns: the driver (linear);
    * wind (m/s): the wind speed and, when the indoor temperature is given,
      ``wind × (T_in − T_out)`` (m/s·K): infiltration driven by wind carries
      heat in proportion to both.

    Parameters
    ----------
    name : str
        A column of ``drivers``.
    drivers : DataFrame
        :func:`bpsflow.diagnosis.drivers.derive_drivers`' output (the wind ×
        ΔT term reads ``outdoor_air_temperature``).
    indoor_temperature_c : array or float, optional
        Zone air temperature of each row (°C).

    Returns
    -------
    DataFrame
        One column per regressor, index of ``drivers``; columns that do not
        vary (no weekend in the window, a hinge above every value) are left
        out, so the frame may be empty.
    """
    x = drivers[name].to_numpy(dtype=float)
    group = driver_group(name)
    columns: dict[str, np.ndarray] = {}
    if group == "temperature":
        columns[name] = x
        for knot in np.unique(np.nanquantile(x, HINGE_QUANTILES)):
            columns[f"{name}_above_{knot:.3g}"] = np.maximum(x - knot, 0.0)
    elif group == "hour":
        for k in HOUR_HARMONICS:
            angle = 2 * np.pi * k * x / 24.0
            columns[f"{name}_sin{k}"] = np.sin(angle)
            columns[f"{name}_cos{k}"] = np.cos(angle)
    elif group == "day":
        # one dummy per day of the week but the first present (the reference)
        for day in np.unique(x[np.isfinite(x)])[1:]:
            columns[f"{name}_is_{int(day)}"] = (x == day).astype(float)
    elif group == "wind":
        columns[name] = x
        if indoor_temperature_c is not None:
            if "outdoor_air_temperature" not in drivers:
                raise ValueError("the wind x delta-T term needs drivers['outdoor_air_temperature']")
            delta_t = (np.asarray(indoor_temperature_c, dtype=float)
                       - drivers["outdoor_air_temperature"].to_numpy(dtype=float))
            columns[f"{name}_x_delta_t"] = x * delta_t
    else:  # weekend dummy, irradiance, other measured columns
        columns[name] = x
    varies = {column: values for column, values in columns.items() if _varies(values)}
    return pd.DataFrame(varies, index=drivers.index)


def _varies(values: np.ndarray) -> bool:
    finite = values[np.isfinite(values)]
    return finite.size > 1 and float(np.ptp(finite)) > 1e-9 * (1.0 + float(np.abs(finite).max()))


# ---------------------------------------------------------------------------
# HAC inference


def default_hac_lags(scores: np.ndarray, residual: np.ndarray | None = None,
                     tolerance: float = HAC_BIAS_TOLERANCE, min_lags: int = MIN_HAC_LAGS) -> int:
    """Newey–West lag length for hourly regression scores ``x_t·u_t``.

    The Bartlett estimator of the long-run variance of an AR(1) series with
    coefficient ρ, truncated at bandwidth ``M = L + 1``, is biased by about
    ``−2ρ / (M (1 − ρ²))`` (the sum of ``|j| ρ^|j|`` over the long-run
    variance). Hourly residuals of a building model are strongly
    autocorrelated (ρ ≈ 0.8–0.95: a slow process the model misses, a lagged
    response), and at ρ = 0.8 the textbook ``4 (n/100)^(2/9)`` lags (6 at
    n = 700) underestimate the variance by ~60 %. The lag length here keeps
    that bias under ``tolerance``: ``L + 1 = ⌈2ρ / ((1 − ρ²) tolerance)⌉`` — the
    AR(1) plug-in of Andrews (1991) aimed at the test's bias rather than the
    variance's mean squared error — at least ``min_lags`` (a day), at most
    ``n/2``; 44 lags at ρ = 0.8. ρ is the largest lag-1 autocorrelation of
    the score columns and of the residual: a regressor with hour-to-hour
    noise (wind) lowers its score's lag-1 autocorrelation although its slow
    part carries the residual's whole persistence. So wide a window leaves
    the variance estimate with few degrees of freedom; the test pays for it
    in its reference distribution (:func:`fixed_b_pvalue`), not in size.

    Parameters
    ----------
    scores : ndarray, (n,) or (n, k)
        Score series: centred regressors (without the constant) times residual.
    residual : ndarray, (n,), optional
        The regression residual.
    tolerance : float
        Relative bias of the variance tolerated (-).
    min_lags : int
        Floor of the lag length (h).

    Returns
    -------
    int
    """
    scores = np.asarray(scores, dtype=float).reshape(len(scores), -1)
    if residual is not None:
        scores = np.column_stack([scores, np.asarray(residual, dtype=float)])
    n = scores.shape[0]
    centred = scores - scores.mean(axis=0)
    numerator = (centred[1:] * centred[:-1]).sum(axis=0)
    denominator = (centred ** 2).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.where(denominator > 0, numerator / denominator, 0.0)
    rho = float(np.clip(np.max(rho, initial=0.0), 0.0, 0.98))
    lags = math.ceil(2 * rho / ((1 - rho ** 2) * tolerance)) - 1
    return int(min(max(lags, min_lags), max(n // 2, 1)))


def fixed_b_pvalue(wald: float, q: int, lags: int, n: int) -> float:
    """p-value of a Newey–West Wald statistic under fixed-b asymptotics.

    With the bandwidth a fixed share ``b = (L + 1)/n`` of the sample
    (Kiefer & Vogelsang, 2005), the Wald statistic is not χ²(q): the HAC
    variance is itself random with few effective degrees of freedom. Sun
    (2014, J. Econometrics 178: 659–677) approximates its limit by a scaled
    F: ``W / q ~ κ F(q, K)`` with ``κ = exp(b (c₁ + (q − 1) c₂))`` and
    ``K = max(⌈1 / (b c₂)⌉ − q + 1, 1)``, ``c₁ = ∫k``, ``c₂ = ∫k²`` of the
    kernel (Bartlett: 1 and 2/3). As ``b → 0`` this is the χ²(q) test.

    Parameters
    ----------
    wald : float
        Wald statistic (χ² form, not divided by q).
    q : int
        Number of restrictions.
    lags : int
        Newey–West lag length L (statsmodels' ``maxlags``).
    n : int
        Observations.
    """
    b = (lags + 1) / n
    kappa = math.exp(b * (_BARTLETT_C1 + (q - 1) * _BARTLETT_C2))
    dof = max(math.ceil(1.0 / (b * _BARTLETT_C2)) - q + 1, 1)
    return float(stats.f.sf(wald / (q * kappa), q, dof))


@dataclass
class DriverTest:
    """The test of one driver against the residuals.

    Attributes
    ----------
    name, group : str
        Driver and its group (:func:`bpsflow.diagnosis.drivers.driver_group`).
    p_value : float
        HAC Wald test that every basis coefficient is zero.
    p_adjusted : float
        ``p_value`` after Holm's correction across the drivers tested.
    share : float
        Fraction of the residual variance the basis explains (R², -).
    amplitude : float
        Standard deviation of the fitted component (residual units).
    direction : int
        Sign of the covariance of the fitted component with the driver
        (+1: the residual grows with the driver; 0 when undefined).
    sign_consistent : bool
        The component fitted on each blocked fold alone correlates positively
        with the full fit there, in every fold where the driver varies.
    significant : bool
        ``p_adjusted < alpha``, ``share ≥ min_share``, ``amplitude ≥
        min_amplitude`` and ``sign_consistent``.
    coefficients : dict
        OLS coefficient of each basis column (residual units per column unit).
    lags : int
        Newey–West lag length used.
    """

    name: str
    group: str
    p_value: float
    p_adjusted: float
    share: float
    amplitude: float
    direction: int
    sign_consistent: bool
    significant: bool
    coefficients: dict[str, float] = field(default_factory=dict)
    lags: int = 0


def _block_consistent(y: np.ndarray, regressors: np.ndarray, full_component: np.ndarray,
                      folds: int) -> bool:
    """Same direction in every contiguous fold: the fold's own fit vs the full fit there."""
    agree = []
    for block in np.array_split(np.arange(len(y)), folds):
        design = np.column_stack([np.ones(len(block)), regressors[block]])
        target = full_component[block]
        if len(block) <= design.shape[1] or np.std(target) <= 1e-12 * (1 + np.abs(target).max()):
            continue  # the driver does not vary in this fold: it has nothing to say
        coefficients = np.linalg.lstsq(design, y[block], rcond=None)[0]
        own = design[:, 1:] @ coefficients[1:]
        if np.std(own) <= 1e-12 * (1 + np.abs(own).max()):
            agree.append(False)
            continue
        agree.append(bool(np.corrcoef(own, target)[0, 1] > 0))
    return len(agree) >= min(2, folds) and all(agree)


#: A fold whose given shape varies less than this share of the folds' mean variance is
#: not asked for its sign (:func:`_component_consistent`).
QUIET_FOLD_SHARE = 0.1


def _component_consistent(y: np.ndarray, full_component: np.ndarray, folds: int) -> bool:
    """Same direction in every contiguous fold: the residual's slope on the full fit there.

    One degree of freedom per fold, for a regressor whose shape is given (a
    simulated effect), not fitted from a flexible basis: refitting several
    nearly collinear columns of one physical effect on a week of noisy data
    can turn the fold's own combination around while the shape itself still
    explains that week. A fold where the shape moves less than
    ``QUIET_FOLD_SHARE`` of the folds' mean variance is skipped: the effect
    barely acts there (a week whose heating is off at the effect's hours), so
    its sign is the noise's.
    """
    blocks = np.array_split(np.arange(len(y)), folds)
    variances = np.array([np.var(full_component[block]) for block in blocks])
    agree = []
    for block, variance in zip(blocks, variances):
        target = full_component[block]
        if len(block) <= 2 or variance <= QUIET_FOLD_SHARE * variances.mean():
            continue
        centred = target - target.mean()
        agree.append(bool(centred @ (y[block] - y[block].mean()) > 0))
    return len(agree) >= min(2, folds) and all(agree)


def _test_one(name: str, y: np.ndarray, regressors: pd.DataFrame, driver: np.ndarray, *,
              folds: int, hac_lags: int | None, reference: str,
              consistency: str = "refit") -> DriverTest | None:
    """The unadjusted test of one driver; None when its basis does not vary here.

    ``consistency``: ``"refit"`` refits the basis on each fold
    (:func:`_block_consistent`, for a driver's flexible basis); ``"component"``
    checks the full fit's own shape on each fold (:func:`_component_consistent`,
    for a given physical shape).
    """
    import statsmodels.api as sm

    group = driver_group(name)
    values = regressors.to_numpy(dtype=float)
    # each column over its largest magnitude: the tests are invariant to a column's scale,
    # and a sensor logged in odd units (1e300) would overflow the squares otherwise
    scale = np.abs(values).max(axis=0, initial=0.0)
    scale = np.where(np.isfinite(scale) & (scale > 0), scale, 1.0)
    values = values / scale
    varies = values.std(axis=0) > 1e-12 * (1.0 + np.abs(values).max(axis=0, initial=0.0))
    values, columns, scale = values[:, varies], regressors.columns[varies], scale[varies]
    driver_peak = float(np.max(np.abs(driver), initial=0.0))
    driver = driver / driver_peak if np.isfinite(driver_peak) and driver_peak > 0 else driver
    q = values.shape[1]
    if q == 0 or len(y) <= 2 * (q + 1):
        return None
    design = np.column_stack([np.ones(len(y)), values])
    ols_residual = y - design @ np.linalg.lstsq(design, y, rcond=None)[0]
    scores = (values - values.mean(axis=0)) * ols_residual[:, None]
    lags = default_hac_lags(scores, ols_residual) if hac_lags is None else int(hac_lags)
    ols = sm.OLS(y, design).fit(cov_type="HAC", cov_kwds={"maxlags": lags, "use_correction": True})
    restriction = np.column_stack([np.zeros(q), np.eye(q)])
    wald = ols.wald_test(restriction, use_f=False, scalar=True)
    statistic = float(wald.statistic)
    if reference == "fixed-b":
        p_value = fixed_b_pvalue(statistic, q, lags, len(y))
    elif reference == "chi2":
        p_value = float(wald.pvalue)
    else:
        raise ValueError(f"reference must be 'fixed-b' or 'chi2', got {reference!r}")
    component = values @ ols.params[1:]
    share = float(max(ols.rsquared, 0.0))
    amplitude = float(np.std(component))
    covariance = float(np.cov(component, driver)[0, 1]) if np.std(driver) > 0 else 0.0
    direction = int(np.sign(covariance)) if amplitude > 0 else 0
    consistent = (_component_consistent(y, component, folds) if consistency == "component"
                  else _block_consistent(y, values, component, folds))
    return DriverTest(name=name, group=group, p_value=p_value, p_adjusted=p_value, share=share,
                      amplitude=amplitude, direction=direction, sign_consistent=consistent,
                      significant=False,
                      coefficients=dict(zip(columns, map(float, ols.params[1:] / scale))),
                      lags=lags)


def test_drivers(residual: pd.Series, drivers: pd.DataFrame, *,
                 indoor_temperature_c: np.ndarray | float | None = None, alpha: float = 0.01,
                 min_share: float = 0.05, min_amplitude: float = 0.0, folds: int = 4,
                 hac_lags: int | None = None, reference: str = "fixed-b") -> list[DriverTest]:
    """Test every driver against the residuals; the ones that explain them come first.

    Per driver, OLS ``r ~ 1 + basis(driver)`` (:func:`basis`) and a Wald test
    that the basis coefficients are all zero, with Newey–West (HAC)
    covariance (statsmodels ``cov_type="HAC"``, Bartlett kernel, small-sample
    factor n/(n − k)). Hourly residuals are strongly autocorrelated (an
    unmodelled slow process, a lagged response): the default lag length is
    :func:`default_hac_lags` of the driver's scores (≥ 24 h; ~44 h for AR(1)
    residuals with φ = 0.8), and the p-value is read from the fixed-b F
    approximation (:func:`fixed_b_pvalue`) rather than χ², since such a
    window leaves the variance with few degrees of freedom.

    Measured null rejection rates (two sets of 400 series of AR(1) noise,
    φ = 0.8, 700 h of November–December drivers of the shipped San Francisco
    weather), nominal 5 % / 1 %: irradiance drivers 4–7 % / 0.7–2.2 %,
    ``hour_of_day`` 2–5.5 % / 0.5–0.7 %, ``weekend`` 8–10 % / 1.8–2.8 %,
    ``wind_speed`` 8.5–12 % / 2.8–3.3 %, ``outdoor_air_temperature``
    11–15 % / 3.5–5.5 % (its hinge columns rest on a few warm spells, which
    no lag window repairs); mean over drivers 6.7–7.2 % / 1.5–2 %. With the
    textbook 6 lags and χ²: mean 9.6 % / 2.9 %, temperature 22 % / 11 %.
    Some driver significant (every condition below, defaults): 0.5–5 % of
    the series (the project tests assert ≤ 10 % over 100 series).

    Holm's step-down correction (:func:`holm`) controls the
    family-wise error over the drivers tested. A driver is significant when
    ``p_adjusted < alpha``, it explains at least ``min_share`` of the residual
    variance, its fitted component's standard deviation is at least
    ``min_amplitude`` (residual units) and its direction holds in each of
    ``folds`` contiguous blocks (:class:`DriverTest`).

    Parameters
    ----------
    residual : Series
        Measured − predicted, hourly, in time order (output units). Rows
        where the residual or a driver is missing are dropped (the series is
        then treated as contiguous: keep gaps rare).
    drivers : DataFrame
        :func:`bpsflow.diagnosis.drivers.derive_drivers` output, same index
        as ``residual`` (or a superset).
    indoor_temperature_c : array or float, optional
        Zone air temperature (°C), aligned with ``residual``; adds the wind ×
        ΔT term to wind drivers.
    alpha : float
        Family-wise level (Holm).
    min_share : float
        Smallest share of residual variance (R², -) that matters.
    min_amplitude : float
        Smallest standard deviation of the fitted component that matters
        (residual units).
    folds : int
        Contiguous blocks of the sign-consistency check.
    hac_lags : int, optional
        Newey–West lag length for every driver; default per driver
        (:func:`default_hac_lags`).
    reference : {"fixed-b", "chi2"}
        Reference distribution of the Wald statistic; ``"chi2"`` is
        statsmodels' own p-value.

    Returns
    -------
    list of DriverTest
        Sorted by ``share``, largest first. A driver whose basis does not
        vary over the residual's hours (no weekend in a five-day window) is
        listed untested: p-values 1, share 0, not significant.
    """
    residual = pd.Series(residual, dtype=float)
    if not residual.index.equals(drivers.index):
        drivers = drivers.reindex(residual.index)
    indoor = None if indoor_temperature_c is None else \
        np.broadcast_to(np.asarray(indoor_temperature_c, dtype=float), (len(residual),))
    y = residual.to_numpy()
    results: list[DriverTest] = []
    tested: list[bool] = []
    for name in drivers.columns:
        regressors = basis(name, drivers, indoor)
        keep = np.isfinite(y) & np.isfinite(regressors.to_numpy()).all(axis=1)
        result = _test_one(name, y[keep], regressors[keep],
                           drivers[name].to_numpy(dtype=float)[keep], folds=folds,
                           hac_lags=hac_lags, reference=reference)
        tested.append(result is not None)
        results.append(result or DriverTest(name, driver_group(name), 1.0, 1.0, 0.0, 0.0, 0,
                                            False, False, {}, 0))
    if any(tested):
        adjusted = holm([r.p_value for r, t in zip(results, tested) if t])
        for result, p_adjusted in zip([r for r, t in zip(results, tested) if t], adjusted):
            result.p_adjusted = float(p_adjusted)
            result.significant = bool(p_adjusted < alpha and result.share >= min_share
                                      and result.amplitude >= min_amplitude
                                      and result.sign_consistent)
    return sorted(results, key=lambda r: r.share, reverse=True)


def holm(p_values: list[float] | np.ndarray) -> np.ndarray:
    """Holm's (1979) step-down adjusted p-values, in the input order.

    The k-th smallest of m p-values becomes ``max_{j≤k} (m − j + 1) p_(j)``,
    capped at 1. (statsmodels ``multipletests(method="holm")`` gives the same
    numbers but runs ``gc.collect()`` on every call, a tenth of a second in a
    loaded process; the project tests compare the two.)
    """
    p_values = np.asarray(p_values, dtype=float)
    order = np.argsort(p_values)
    m = len(p_values)
    stepped = np.maximum.accumulate(p_values[order] * (m - np.arange(m)))
    adjusted = np.empty(m)
    adjusted[order] = np.minimum(stepped, 1.0)
    return adjusted


# Not a pytest test, whatever its name (tests import it).
test_drivers.__test__ = False  # type: ignore[attr-defined]


# ---------------------------------------------------------------------------
# Whiteness


def whiteness(residual: pd.Series | np.ndarray, lags: int = 24, alpha: float = 0.05) -> dict:
    """Ljung–Box test that the residuals are white up to ``lags`` (Ljung & Box, 1978).

    Autocorrelation left in the residuals after the drivers are accounted
    for means missing dynamics (a thermal mass, a lagged response) rather
    than a missing driver.

    Parameters
    ----------
    residual : Series or ndarray
        Hourly residuals in time order; missing values are dropped.
    lags : int
        Largest lag (h) in the statistic; 24 covers a day.
    alpha : float
        Level below which the residuals are called not white.

    Returns
    -------
    dict
        ``statistic`` (Q), ``p_value``, ``lags``, ``white`` (bool: p ≥ alpha).
    """
    from statsmodels.stats.diagnostic import acorr_ljungbox

    values = np.asarray(residual, dtype=float)
    values = values[np.isfinite(values)]
    table = acorr_ljungbox(values, lags=[lags], return_df=True)
    statistic = float(table["lb_stat"].iloc[0])
    p_value = float(table["lb_pvalue"].iloc[0])
    return {"statistic": statistic, "p_value": p_value, "lags": int(lags),
            "white": bool(p_value >= alpha)}


def autocorrelation(residual: pd.Series | np.ndarray, lags: int = 48) -> np.ndarray:
    """Sample autocorrelation of the residuals at lags 0..``lags`` (statsmodels ``acf``).

    Missing values are skipped pairwise (``missing="conservative"``).
    """
    from statsmodels.tsa.stattools import acf

    return np.asarray(acf(np.asarray(residual, dtype=float), nlags=lags, fft=True,
                          missing="conservative"))
