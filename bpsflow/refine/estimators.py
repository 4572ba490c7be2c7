"""Estimators of model inputs from detailed measurements (seed §3.4.3–3.5, eq. 8–18).

Each function is one estimator of the source, with its equation number:

- sensor bias and random error from calibration against a reference (eq. 8–11);
- bias-corrected area- (or volume-) weighted mean temperature and its
  variance (eq. 12–13), aggregated from sub-hourly steps to hours (eq. 14);
- the interior convection coefficient from the surface heat balance and its
  regression ``log h = log α + n log|ΔT|`` (eq. 15–17, Table 3.4);
- the room air temperature gradient from ceiling and floor air sensors (eq. 18);
- the glazing system's solar transmittance from transmitted and incident
  irradiance, inverted to one pane (§3.5.3);
- ground reflectance from reflected and global horizontal irradiance (§3.5.4).

All functions are pure (arrays and frames in, numbers and frames out).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
import statsmodels.api as sm

#: |ΔT| below this multiple of its standard error is dropped from the convection
#: regression. At 10 standard errors the relative error of |ΔT| (hence the
#: error of log|ΔT| and log h) is at most 0.1, the errors-in-variables
#: attenuation ratio λ stays below about 0.01 (see :func:`fit_convection`), and the sign
#: of ΔT is certain, so the ``h > 0`` filter does not select on sensor noise.
CONVECTION_MIN_SIGMAS = 10.0

#: Time steps whose expected convective flux is under this many standard errors
#: of the measured flux difference ``−(Q_cond + R)`` are dropped: the detection
#: limit of the numerator. (Larger multiples start to select hours by their
#: radiation exchange, which biases the fit on hourly means.)
CONVECTION_MIN_FLUX_SIGMAS = 3.0

#: Irradiance (W/m²) below which hourly ratios of pyranometer readings are not
#: used. The ±5 % rating (seed Table 3.2) holds for ordinary daylight levels;
#: a zero offset of the order of 10 W/m² would exceed 5 % of readings under
#: 200 W/m² and bias the ratio, and low-sun hours are dominated by diffuse light.
MIN_IRRADIANCE_W_M2 = 200.0


# Sensor calibration (eq. 8–11) -----------------------------------------

def sensor_calibration(readings: pd.DataFrame, reference_c: pd.Series,
                       reference_std_c: float) -> pd.DataFrame:
    """Per-sensor bias and random-error variance from calibration readings (seed eq. 8–11).

    With the reference reading ``v_r = v + ε_r``, ``ε_r ~ N(0, σ_M²)`` (eq. 8)
    and a sensor's ``v_c = v + ε_c``, ``ε_c ~ N(δ_c, σ_c²)`` (eq. 9), the
    differences ``Δ_t = v_c − v_r ~ N(δ_c, σ_c² + σ_M²)`` (eq. 10) give
    ``δ̂_c = mean(Δ)`` and ``σ̂_c² = var(Δ) − σ_M²`` (eq. 11; sample variance,
    ``k − 1`` denominator).

    Parameters
    ----------
    readings : DataFrame
        Calibration steps × sensors, °C.
    reference_c : Series
        The reference sensor's readings at the same steps, °C.
    reference_std_c : float
        σ_M, the reference sensor's standard deviation, °C (seed: the rated
        range read as three standard deviations).

    Returns
    -------
    DataFrame
        Index: sensor. Columns ``bias_c`` (δ̂), ``std_c`` (σ̂), ``variance_c2``
        (σ̂²), ``difference_variance_c2`` (var Δ), ``bias_std_error_c``
        (standard error of δ̂, sqrt(var Δ / k)), ``steps`` (k), ``note``.
        A negative eq. 11 variance (sampling error when σ_c ≪ σ_M) is floored
        at 0 and noted.
    """
    differences = readings.sub(reference_c, axis=0)
    steps = differences.count()
    bias = differences.mean()
    difference_variance = differences.var(ddof=1)
    variance = difference_variance - reference_std_c ** 2
    floored = variance < 0
    notes = pd.Series("", index=readings.columns, dtype=object)
    notes[floored] = [
        f"var(Δ) {v:.3g} °C² < σ_M² {reference_std_c ** 2:.3g} °C²: σ̂² floored at 0"
        for v in difference_variance[floored]]
    variance = variance.clip(lower=0.0)
    return pd.DataFrame({
        "bias_c": bias,
        "std_c": np.sqrt(variance),
        "variance_c2": variance,
        "difference_variance_c2": difference_variance,
        "bias_std_error_c": np.sqrt(difference_variance / steps),
        "steps": steps,
        "note": notes,
    }).rename_axis("sensor")


def corrected(readings: pd.DataFrame | pd.Series, calibration: pd.DataFrame
              ) -> pd.DataFrame | pd.Series:
    """Readings minus their sensor's estimated bias δ̂ (°C; seed eq. 13's ``T' − δ̂``)."""
    if isinstance(readings, pd.Series):
        return readings - calibration.loc[readings.name, "bias_c"]
    return readings - calibration.loc[readings.columns, "bias_c"].to_numpy()


def reading_variance(sensors: list[str], calibration: pd.DataFrame,
                     reference_std_c: float) -> np.ndarray:
    """Error variance ``σ̂_c² + σ_M²`` (°C²) of each bias-corrected reading (seed eq. 12)."""
    return calibration.loc[sensors, "variance_c2"].to_numpy() + reference_std_c ** 2


# Spatial and temporal means (eq. 12–14) --------------------------------

def weighted_mean_temperature(readings: pd.DataFrame, weights: np.ndarray,
                              calibration: pd.DataFrame, reference_std_c: float
                              ) -> tuple[pd.Series, float]:
    """Bias-corrected area- (or volume-) weighted mean and its variance (seed eq. 12–13).

    ``T̂_t = (1/A) Σ A_i (T'_ti − δ̂_i)``,
    ``Var(T̂_t) = (1/A²) Σ A_i² (σ̂_i² + σ_M²)``, ``A = Σ A_i``.

    Parameters
    ----------
    readings : DataFrame
        Time steps × sensors, °C.
    weights : array
        Representative area (m²) or volume (m³) of each sensor, in column order.
    calibration : DataFrame
        :func:`sensor_calibration` of (at least) these sensors.
    reference_std_c : float
        σ_M, °C.

    Returns
    -------
    (Series, float)
        The mean temperature per time step (°C) and its variance (°C²).
    """
    weights = np.asarray(weights, dtype=float)
    total = weights.sum()
    mean = corrected(readings, calibration).to_numpy() @ weights / total
    variance = float(np.sum(weights ** 2 * reading_variance(list(readings.columns), calibration,
                                                            reference_std_c)) / total ** 2)
    return pd.Series(mean, index=readings.index), variance


def hourly_mean(estimates: pd.Series, variance: pd.Series | float) -> pd.DataFrame:
    """Hourly means of sub-hourly estimates and their variance (seed eq. 14).

    ``T̂_ts = (1/s) Σ_j T̂_j``, ``Var(T̂_ts) = (1/s²) Σ_j Var(T̂_j)`` over the
    ``s`` steps of each hour (independent random errors). Timestamps are
    hour-ending: steps in (h − 1 h, h] belong to the hour ending at ``h``.

    Returns
    -------
    DataFrame
        Index: hour-ending timestamp. Columns ``mean``, ``variance``, ``steps``.
    """
    if np.isscalar(variance):
        variance = pd.Series(float(variance), index=estimates.index)
    hours = estimates.index.ceil("h")
    grouped = pd.DataFrame({"value": estimates.to_numpy(), "variance": variance.to_numpy()},
                           index=hours).groupby(level=0)
    steps = grouped["value"].count()
    return pd.DataFrame({"mean": grouped["value"].mean(),
                         "variance": grouped["variance"].sum() / steps ** 2,
                         "steps": steps}).rename_axis(estimates.index.name)


def hourly_frame(frame: pd.DataFrame) -> pd.DataFrame:
    """Hourly (hour-ending) means of every column: eq. 14's mean for each reading."""
    return frame.groupby(frame.index.ceil("h")).mean().rename_axis(frame.index.name)


# Convection (eq. 15–17) ------------------------------------------------

def convection_coefficient(surface_c: pd.Series, air_c: pd.Series, conduction_w_m2: pd.Series,
                           radiation_w_m2: pd.Series) -> pd.DataFrame:
    """Interior convection coefficient per time step from the heat balance (seed eq. 15–16).

    Eq. 15: ``R_ir + R_sw + Q_cond + Q_conv = 0``, so the convective gain of
    the surface is ``Q_conv = −(Q_cond + R)`` (W/m²), and eq. 16:
    ``h_c = Q_conv / (T_air − T_surf)``.

    Parameters
    ----------
    surface_c, air_c : Series
        Bias-corrected surface and adjacent air temperatures, °C.
    conduction_w_m2, radiation_w_m2 : Series
        Conduction gain and net (thermal + solar) radiation gain at the inside
        face, W/m².

    Returns
    -------
    DataFrame
        ``delta_t_c`` (air − surface, K), ``convection_w_m2`` (gain, W/m²),
        ``h_w_m2k`` (W/m²·K).
    """
    delta_t = air_c - surface_c
    convection = -(conduction_w_m2 + radiation_w_m2)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = convection / delta_t
    return pd.DataFrame({"delta_t_c": delta_t, "convection_w_m2": convection, "h_w_m2k": h})


def convection_points(surface_c: pd.Series, air_c: pd.Series, h_w_m2k: pd.Series) -> pd.DataFrame:
    """Convection points from derived coefficient readings (seed eq. 16–17).

    For a laboratory that already applies eq. 15–16 at its logging interval
    and reports the hour-mean coefficient: the regression needs only the
    temperature difference next to it.

    Parameters
    ----------
    surface_c, air_c : Series
        Bias-corrected surface and adjacent air temperatures, °C.
    h_w_m2k : Series
        Convection coefficient readings, W/m²·K.

    Returns
    -------
    DataFrame
        Like :func:`convection_coefficient`: ``delta_t_c`` (K),
        ``convection_w_m2`` (``h·ΔT``, W/m²), ``h_w_m2k``.
    """
    delta_t = air_c - surface_c
    return pd.DataFrame({"delta_t_c": delta_t, "convection_w_m2": h_w_m2k * delta_t,
                         "h_w_m2k": h_w_m2k})


def convection_flux_std(conduction_w_m2: pd.Series, radiation_w_m2: pd.Series,
                        conduction_relative_std: float, radiation_relative_std: float
                        ) -> pd.Series:
    """Standard error (W/m²) of the convective gain ``−(Q_cond + R)`` from relative flux errors.

    The convective gain is the difference of two measured fluxes; where they
    nearly cancel, its relative error is large even with good sensors.
    """
    return np.sqrt((conduction_relative_std * conduction_w_m2) ** 2
                   + (radiation_relative_std * radiation_w_m2) ** 2)


def usable_convection(points: pd.DataFrame, delta_t_std_c: float,
                      flux_std_w_m2: pd.Series | float = 0.0,
                      nominal_alpha: float = 0.0, nominal_exponent: float = 0.0,
                      min_delta_t_sigmas: float = CONVECTION_MIN_SIGMAS,
                      min_flux_sigmas: float = CONVECTION_MIN_FLUX_SIGMAS) -> pd.Series:
    """Which time steps give a stable ``h_c`` (seed eq. 16).

    A step is used when

    - ``|ΔT| ≥ min_delta_t_sigmas · σ_ΔT`` (:data:`CONVECTION_MIN_SIGMAS`):
      the denominator is well determined;
    - the *expected* convective flux ``α₀ |ΔT|^(n₀+1)`` of the model's nominal
      curve is at least ``min_flux_sigmas`` standard errors of the measured
      flux difference (:data:`CONVECTION_MIN_FLUX_SIGMAS`): below that the
      numerator is not distinguishable from zero. The expected, not the
      measured, flux decides, so the choice does not select on the noise of
      the regression's dependent variable;
    - ``h_c > 0`` and finite.
    """
    magnitude = points["delta_t_c"].abs()
    expected_flux = nominal_alpha * magnitude ** (nominal_exponent + 1)
    return ((magnitude >= min_delta_t_sigmas * delta_t_std_c)
            & (expected_flux >= min_flux_sigmas * flux_std_w_m2)
            & (points["h_w_m2k"] > 0) & np.isfinite(points["h_w_m2k"]))


@dataclass(frozen=True)
class ConvectionFit:
    """``log h = log α + n log|ΔT|`` fitted to one surface class (seed eq. 17, Table 3.4).

    Natural logarithms, h in W/m²·K and ΔT in K (the source's Table 3.4 uses
    the same: its wall ``log α`` 0.2245 is α ≈ 1.25). Standard errors are
    heteroscedasticity- and autocorrelation-consistent (Newey–West); the
    ordinary ones are kept for comparison.
    """

    log_alpha: float
    log_alpha_std_error: float
    exponent: float
    exponent_std_error: float
    correlation: float          # of the two estimates
    r_squared: float
    points: int
    residual_std: float         # of log h, per time step
    hac_lags: int
    iid_log_alpha_std_error: float
    iid_exponent_std_error: float
    attenuation: float          # λ = mean(σ_ΔT²/ΔT²) / var(log|ΔT|)

    @property
    def alpha(self) -> float:
        return float(np.exp(self.log_alpha))

    @property
    def alpha_std_error(self) -> float:
        """Delta method: ``se(α̂) = α̂ · se(log α̂)``."""
        return self.alpha * self.log_alpha_std_error

    @property
    def exponent_attenuation(self) -> float:
        """First-order bias of n̂ from the ΔT sensor error, ``−(n + 1) λ`` (diagnostic)."""
        return -(self.exponent + 1) * self.attenuation


def fit_convection(delta_t_c: np.ndarray, h_w_m2k: np.ndarray, delta_t_std_c: float,
                   hac_lags: int = 24) -> ConvectionFit:
    """Regression of ``log h_c`` on ``log|ΔT|`` (seed eq. 17) by ordinary least squares.

    The estimates are the source's (statsmodels OLS). Their standard errors
    are Newey–West (HAC, ``hac_lags`` steps, a day of hours by default): the
    residuals of hourly heat balances are autocorrelated (consecutive hours
    share the test's conditions, and the hourly means of q and ΔT depart from
    the instantaneous ``h = α|ΔT|^n`` in the same way hour after hour), so
    ordinary standard errors would claim several times the precision the
    data hold.

    The sensors' error in ΔT (standard deviation ``σ_ΔT``) enters both sides
    (``x = log|ΔT|`` carries ``δ ≈ e/ΔT``, ``log h = log Q − x`` carries
    ``−δ``), which attenuates the slope by about ``(n + 1) λ``,
    ``λ = mean(σ_ΔT²/ΔT²) / var(x)``. With |ΔT| ≥ 10 σ_ΔT
    (:func:`usable_convection`) λ is below 0.01; the selection on the
    observed |ΔT| biases the slope the other way by a similar amount, so no
    correction is applied and λ is reported.

    Parameters
    ----------
    delta_t_c : array
        Air − surface temperature difference per time step (K), usable steps only.
    h_w_m2k : array
        Convection coefficient per time step (W/m²·K), positive.
    delta_t_std_c : float
        Standard error of each ΔT (K).
    hac_lags : int
        Newey–West lags (time steps); capped at a quarter of the points.
    """
    delta_t = np.asarray(delta_t_c, dtype=float)
    x = np.log(np.abs(delta_t))
    y = np.log(np.asarray(h_w_m2k, dtype=float))
    if x.size < 3:
        raise ValueError(f"{x.size} usable time steps; the regression needs at least 3")
    design = sm.add_constant(x)
    lags = int(max(1, min(hac_lags, x.size // 4)))
    iid = sm.OLS(y, design).fit()
    hac = sm.OLS(y, design).fit(cov_type="HAC", cov_kwds={"maxlags": lags})
    covariance = np.asarray(hac.cov_params())
    se_log_alpha, se_exponent = np.sqrt(np.diag(covariance))
    x_variance = float(np.var(x))
    attenuation = float(np.mean(delta_t_std_c ** 2 / delta_t ** 2) / x_variance) \
        if x_variance > 0 else 0.0
    return ConvectionFit(
        log_alpha=float(hac.params[0]), log_alpha_std_error=float(se_log_alpha),
        exponent=float(hac.params[1]), exponent_std_error=float(se_exponent),
        correlation=float(covariance[0, 1] / (se_log_alpha * se_exponent)),
        r_squared=float(iid.rsquared), points=int(x.size),
        residual_std=float(np.sqrt(iid.scale)), hac_lags=lags,
        iid_log_alpha_std_error=float(iid.bse[0]), iid_exponent_std_error=float(iid.bse[1]),
        attenuation=attenuation)


# Stratification (eq. 18) -----------------------------------------------

def gradient_samples(ceiling_air_c: pd.Series, floor_air_c: pd.Series,
                     separation_m: float) -> pd.Series:
    """Room air gradient per time step, ``G_i = (T_ceiling − T_floor)/h`` (seed eq. 18).

    Parameters
    ----------
    ceiling_air_c, floor_air_c : Series
        Bias-corrected air temperatures near the ceiling and the floor, °C.
    separation_m : float
        Vertical distance between the two sensors, m.

    Returns
    -------
    Series
        K/m per time step; the source pools them as an empirical sample.
    """
    return ((ceiling_air_c - floor_air_c) / separation_m).rename("gradient_k_per_m")


# Solar quantities (§3.5.3–3.5.4) -----------------------------------------

def irradiance_ratio(numerator_w_m2: pd.Series, denominator_w_m2: pd.Series,
                     min_denominator_w_m2: float, scale: float = 1.0) -> pd.Series:
    """Per-hour ``numerator / (scale · denominator)`` where the denominator is large enough."""
    keep = denominator_w_m2 >= min_denominator_w_m2
    return (numerator_w_m2[keep] / (scale * denominator_w_m2[keep])).dropna()


def ground_reflectance_samples(reflected_w_m2: pd.Series, global_horizontal_w_m2: pd.Series,
                               view_factor: float,
                               min_global_w_m2: float = MIN_IRRADIANCE_W_M2) -> pd.Series:
    """Hourly ground reflectance ``ρ̂ = I_reflected / (F_ground · GHI)`` (seed §3.5.4).

    The ground-reflected irradiance on a vertical facade is ``ρ · GHI · F``
    with ``F = (1 − cos 90°)/2 = 0.5`` (isotropic ground).

    Parameters
    ----------
    reflected_w_m2 : Series
        Ground-reflected irradiance incident on the south facade, W/m².
    global_horizontal_w_m2 : Series
        Global horizontal irradiance, W/m².
    view_factor : float
        The facade's view factor to the ground (–).
    min_global_w_m2 : float
        Daylight hours only: GHI at least this (W/m², :data:`MIN_IRRADIANCE_W_M2`).
    """
    return irradiance_ratio(reflected_w_m2, global_horizontal_w_m2, min_global_w_m2,
                            view_factor).rename("ground_reflectance")


def glazing_transmittance_samples(transmitted_w_m2: pd.Series, incident_w_m2: pd.Series,
                                  min_incident_w_m2: float = MIN_IRRADIANCE_W_M2) -> pd.Series:
    """Hourly solar transmittance of the glazing system, transmitted / incident (seed §3.5.3).

    Both per glazed area (W/m²). Each hour mixes beam at its incidence angle
    with diffuse sky and ground light, so the ratio is an *effective*
    transmittance, lower than the normal-incidence value a glazing parameter
    means.
    """
    return irradiance_ratio(transmitted_w_m2, incident_w_m2,
                            min_incident_w_m2).rename("system_transmittance")


def double_pane_transmittance(pane_transmittance: float, pane_reflectance: float) -> float:
    """Normal-incidence solar transmittance of two identical panes, ``τ²/(1 − ρ²)``.

    The inter-reflections between the panes (ρ the pane reflectance seen from
    the gap) add the geometric series ``Σ (ρ²)^k``.
    """
    return pane_transmittance ** 2 / (1 - pane_reflectance ** 2)


def single_pane_transmittance(system_transmittance: float, pane_reflectance: float) -> float:
    """Invert :func:`double_pane_transmittance`: ``τ = sqrt(τ_sys (1 − ρ²))``."""
    return float(np.sqrt(system_transmittance * (1 - pane_reflectance ** 2)))


def summary(values: pd.Series | np.ndarray) -> dict[str, float]:
    """n, mean, std, 5/50/95 % quantiles of a sample (for reports)."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return {"n": 0}
    q05, q50, q95 = np.quantile(values, [0.05, 0.5, 0.95])
    return {"n": int(values.size), "mean": float(values.mean()),
            "std": float(values.std(ddof=1)) if values.size > 1 else 0.0,
            "q05": float(q05), "median": float(q50), "q95": float(q95)}
