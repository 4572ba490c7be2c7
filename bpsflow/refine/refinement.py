"""Uncertainty propagation using detailed measurements (seed §3.4.3–3.5): the whole step.

:func:`refine` turns detailed measurements into tighter input distributions:

- sensor biases and random errors from calibration (eq. 8–11);
- boundary temperatures: bias-corrected equal-area means per surface and hour
  with their eq. 13 (and eq. 14) variance, which replace the measured hours of
  the boundary file and set each surface's ``sensor_std_c`` for the
  per-time-step Monte Carlo sequences (§3.4.5, :mod:`bpsflow.boundary`);
- interior convection: ``log h = log α + n log|ΔT|`` per surface class from
  the heat balance (eq. 15–17) → bounded normals for the curve coefficient
  (multiplier on the IDF's α, delta method) and exponent;
- room air gradient (eq. 18) and ground reflectance (§3.5.4) → empirical
  distributions of the hourly estimates;
- glazing transmittance (§3.5.3): estimated and reported, not refined.

Nothing here writes files; :mod:`bpsflow.refine.report` does.

Design choices
--------------
*Regression residuals.* The source samples the regression residuals beside
the coefficients. A residual is per-time-step scatter (sensor noise and real
turbulent fluctuation); one instance uses one curve for every hour of a test,
so a residual drawn once per instance would act as a persistent offset of
``exp(σ_res)`` on h for the whole test, while hourly scatter averages out
over the ~72 evaluated hours (to ``σ_res/√72``). The refined distributions
hold the coefficients' estimation uncertainty only; ``residual_std`` is
reported.

*Coefficient correlation.* ``log α̂`` and ``n̂`` are correlated (reported);
the config has independent marginals, as in the source.

*Usable convection steps.* ``|ΔT|`` at least 10 standard errors of ΔT, and
an expected convective flux (nominal curve) at least 3 standard errors of the
measured flux difference (:func:`~bpsflow.refine.estimators.usable_convection`).
Standard errors are Newey–West over a day of steps: hourly residuals are
autocorrelated, and ordinary errors would claim several times the precision.

*Uninformative estimates.* A refined distribution whose 90 % interval is not
narrower than the baseline's is dropped and the baseline kept (reported).

*Glazing.* Not refined (as in source §3.5.5). Hourly transmitted/incident
mixes beam at every incidence angle with diffuse sky and ground light, which
the glass transmits less than at normal incidence, so it underestimates the
normal-incidence transmittance the parameter means. Restricting to
near-normal beam does not remove the bias: the vertical south window never
sees the sun closer than the noon solar altitude (≈ 29° in December, ≈ 75° in
July at 37.6° N), and the diffuse share (≥ 15 % on clear days) still enters
at the hemispherical transmittance. Making it unbiased needs the glass's
angular model, i.e. the simulation model itself: that is calibration, not a
measurement-based estimate.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from bpsflow.config import Config, Parameter, period_dates
from bpsflow.errors import BpsflowError
from bpsflow.refine import estimators as est
from bpsflow.refine import inputs as io
from bpsflow.refine.parameters import (
    INTERVAL,
    bounded_normal,
    class_surfaces,
    distribution_from,
    idf_nominal,
    idf_targets,
    in_parameter_units,
    interval,
    parameter_nominal,
    parameters_targeting,
    std_in_parameter_units,
)
from bpsflow.simulation.idf import inside_convection_curve, model_objects
from bpsflow.simulation.targets import targets_field

#: Half-width of a central 90 % normal interval in standard errors.
_Z90 = float(stats.norm.ppf(0.5 + INTERVAL / 2))

_MONTHS = ("January", "February", "March", "April", "May", "June", "July", "August",
           "September", "October", "November", "December")


@dataclass
class SurfaceBoundary:
    """One boundary surface's refined hourly temperature (°C) and its variance (°C²)."""

    surface: str
    column: str
    hourly: pd.DataFrame            # index hour-ending; mean, variance
    rows: np.ndarray                # hour-of-year rows of the boundary file
    areas_m2: list[float]

    @property
    def sensor_std_c(self) -> float:
        """Root mean hourly variance: the sequences' per-time-step standard deviation."""
        return float(np.sqrt(self.hourly["variance"].mean()))


@dataclass
class ConvectionClass:
    """The heat-balance points and regression of one surface class (Table 3.4 row pair)."""

    surface_class: str
    surface: str
    curve: str
    points: pd.DataFrame            # delta_t_c, convection_w_m2, h_w_m2k, used
    delta_t_std_c: float
    min_delta_t_c: float
    fit: est.ConvectionFit | None
    alpha_nominal: float
    exponent_nominal: float
    source: str = "hourly surface heat balance (eq. 15-16)"


@dataclass
class RefinedParameter:
    """A baseline parameter and its refined distribution."""

    baseline: Parameter
    distribution: dict              # the YAML mapping written to refined.yaml
    provenance: dict
    before: tuple[float, float]     # 90 % interval of the baseline distribution
    after: tuple[float, float]      # 90 % interval of the refined one
    samples: pd.DataFrame | None = None   # an empirical distribution's file content

    @property
    def name(self) -> str:
        return self.baseline.name


@dataclass
class Refinement:
    config: Config
    detailed: io.Detailed
    calibration: pd.DataFrame
    boundary: list[SurfaceBoundary]
    convection: list[ConvectionClass]
    gradient: pd.Series
    gradient_std_k_per_m: float
    reflectance: pd.Series
    glazing: dict
    parameters: list[RefinedParameter]
    min_delta_t_sigmas: float = est.CONVECTION_MIN_SIGMAS
    min_irradiance_w_m2: float = est.MIN_IRRADIANCE_W_M2
    skipped: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def _check_in_periods(config: Config, detailed: io.Detailed) -> None:
    """Refuse detailed readings none of which fall in the config's run periods.

    The refined boundary temperatures replace the hours of the readings; readings of
    other days would refine nothing the model simulates, while their sensor
    errors still narrowed its inputs.
    """

    stamps = detailed.frame.index
    inside = np.zeros(len(stamps), bool)
    spans = []
    for period in config.model.periods:
        first, last = period_dates(period, config.model.year)
        start, end = pd.Timestamp(first), pd.Timestamp(last) + pd.Timedelta(days=1)
        inside |= (stamps > start) & (stamps <= end)
        spans.append(f"{period.name}: {first}..{last}")
    if len(stamps) and not inside.any():
        raise BpsflowError(f"no reading falls in the config's run periods ({'; '.join(spans)}, "
                           f"model.year {config.model.year}); the file runs from "
                           f"{stamps[0]} to {stamps[-1]}", source=detailed.detailed_path)


def refine(config: Config, detailed_path: Path,
           min_delta_t_sigmas: float = est.CONVECTION_MIN_SIGMAS,
           min_irradiance_w_m2: float = est.MIN_IRRADIANCE_W_M2) -> Refinement:
    """Estimate refined input distributions from detailed measurements (seed §3.4.3–3.5).

    Parameters
    ----------
    config : Config
        The baseline config (its parameters, IDF and boundary file).
    detailed_path : Path
        ``detailed.csv`` or the folder holding it with ``sensor_calibration.csv``
        and ``detailed.json``.
    min_delta_t_sigmas : float
        Convection points need |ΔT| of at least this many standard errors.
    min_irradiance_w_m2 : float
        Hourly irradiance ratios need the denominator at least this (W/m²).

    Raises
    ------
    BpsflowError
        A missing file or column, a calibration file that does not match, a
        timestamp that does not parse.
    """
    surfaces = list(config.model.boundary.surfaces) if config.model.boundary else []
    detailed = io.read_detailed(detailed_path, surfaces)
    _check_in_periods(config, detailed)
    meta = detailed.metadata
    calibration = est.sensor_calibration(
        detailed.calibration.drop(columns=[c for c in (io.CALIBRATION_STEP,
                                                       io.CALIBRATION_REFERENCE)
                                           if c in detailed.calibration.columns]),
        detailed.calibration[io.CALIBRATION_REFERENCE], meta.reference_sensor_std_c)
    notes = [f"sensor {sensor}: {note}" for sensor, note in calibration["note"].items() if note]
    skipped: list[str] = []
    idf = model_objects(config.model)
    hourly = est.hourly_frame(detailed.frame) if detailed.sub_hourly else detailed.frame
    if detailed.sub_hourly:
        notes.append(f"readings every {detailed.step_minutes:g} min: aggregated to hours "
                     f"(eq. 14) for boundary temperatures, gradient and irradiance ratios; "
                     f"convection uses every step")
    boundary = _boundary(config, detailed, calibration, notes)
    measured_on = class_surfaces(idf, meta.surface_classes, config.detailed, config.source,
                                 detailed.metadata_path)
    for surface_class, surface in measured_on.items():
        if surface_class not in meta.surface_classes:
            notes.append(f"convection {surface_class}: {detailed.metadata_path.name} names no "
                         f"surface; {surface} chosen from the model's geometry")
    convection = _convection(detailed, calibration, idf, measured_on, min_delta_t_sigmas, notes)
    gradient, gradient_std = _gradient(detailed, hourly, calibration)
    reflectance = _reflectance(detailed, hourly, min_irradiance_w_m2)
    refined: list[RefinedParameter] = []
    refined += _convection_parameters(config, detailed, convection, idf, skipped, notes)
    refined += _gradient_parameters(config, detailed, gradient, gradient_std, idf, skipped)
    refined += _reflectance_parameters(config, detailed, reflectance, idf, skipped)
    glazing = _glazing(config, detailed, hourly, idf, min_irradiance_w_m2)
    refined = _informative(refined, skipped)
    return Refinement(config=config, detailed=detailed, calibration=calibration,
                      boundary=boundary, convection=convection, gradient=gradient,
                      gradient_std_k_per_m=gradient_std, reflectance=reflectance,
                      glazing=glazing, parameters=refined, min_delta_t_sigmas=min_delta_t_sigmas,
                      min_irradiance_w_m2=min_irradiance_w_m2, skipped=skipped, notes=notes)


# Boundary temperatures (eq. 12–14) ---------------------------------------

def _boundary(config: Config, detailed: io.Detailed, calibration: pd.DataFrame,
              notes: list[str]) -> list[SurfaceBoundary]:
    if config.model.boundary is None:
        notes.append("the config has no model.boundary: boundary temperatures not refined")
        return []
    from bpsflow.boundary import read_boundary_file

    boundary = config.model.boundary
    columns = tuple(s.column for s in boundary.surfaces.values())
    rows_per_year = len(read_boundary_file(boundary.file, columns))
    sigma_m = detailed.metadata.reference_sensor_std_c
    surfaces = []
    for surface, spec in boundary.surfaces.items():
        sensors = io.boundary_sensor_columns(surface)
        area = detailed.metadata.boundary_sensor_area_m2.get(surface)
        if area is None:
            area = 1.0
            notes.append(f"boundary {surface}: no sensor area in {io.METADATA_FILE}; "
                         f"equal areas assumed")
        # Each sensor stands for an equal share of the surface (seed §3.4.5).
        areas = [area] * len(sensors)
        mean, variance = est.weighted_mean_temperature(detailed.frame[sensors], np.array(areas),
                                                       calibration, sigma_m)
        hourly = est.hourly_mean(mean, variance)[["mean", "variance"]] if detailed.sub_hourly \
            else pd.DataFrame({"mean": mean, "variance": variance})
        rows = io.hour_of_year_rows(hourly.index, rows_per_year)
        outside = (rows < 0) | (rows >= rows_per_year)
        if outside.any():
            notes.append(f"boundary {surface}: {int(outside.sum())} hour(s) have no row in "
                         f"{boundary.file.name}; not replaced")
        surfaces.append(SurfaceBoundary(surface=surface, column=spec.column,
                                        hourly=hourly[~outside], rows=rows[~outside],
                                        areas_m2=[float(a) for a in areas]))
    return surfaces


# Convection (eq. 15–17) --------------------------------------------------

def _convection(detailed: io.Detailed, calibration: pd.DataFrame, idf,
                surfaces: dict[str, str], min_sigmas: float,
                notes: list[str]) -> list[ConvectionClass]:
    frame, meta = detailed.frame, detailed.metadata
    steps_per_day = int(round(24 * 60 / detailed.step_minutes))
    results = []
    for surface_class in io.SURFACE_CLASSES:
        names = {q: io.class_column(surface_class, q)
                 for q in (io.SURFACE_C, io.AIR_C, io.CONDUCTION, io.RADIATION)}
        io.require_columns(frame, list(names.values()), detailed.detailed_path,
                           f"the {surface_class} heat balance, seed eq. 15-16")
        temperatures = [names[io.SURFACE_C], names[io.AIR_C]]
        delta_t_std = float(np.sqrt(est.reading_variance(temperatures, calibration,
                                                         meta.reference_sensor_std_c).sum()))
        surface = surfaces[surface_class]
        curve_name = inside_convection_curve(idf, surface)
        curve = idf.find("Curve:Exponent", curve_name)
        alpha_nominal = curve.number("Coefficient2 Constant")
        exponent_nominal = curve.number("Coefficient3 Constant")
        if abs(curve.number("Coefficient1 Constant", 0.0)) > 0:
            notes.append(f"convection {surface_class}: {curve_name} has a constant term "
                         f"{curve.number('Coefficient1 Constant')}; the regression fits "
                         f"h = α|ΔT|^n without it")
        surface_c = est.corrected(frame[names[io.SURFACE_C]], calibration)
        air_c = est.corrected(frame[names[io.AIR_C]], calibration)
        derived = io.class_column(surface_class, io.MODEL_H_C)
        from_readings = derived in frame.columns
        if from_readings:
            # The laboratory's coefficient from its per-step balance: an hourly ratio of
            # hourly means is biased when ΔT is small or changes within the hour.
            points = est.convection_points(surface_c, air_c, frame[derived])
            flux_std = 0.0
        else:
            points = est.convection_coefficient(surface_c, air_c, frame[names[io.CONDUCTION]],
                                                frame[names[io.RADIATION]])
            flux_std = est.convection_flux_std(frame[names[io.CONDUCTION]],
                                               frame[names[io.RADIATION]],
                                               meta.heat_flux_relative_std,
                                               meta.radiation_relative_std)
        points["used"] = est.usable_convection(points, delta_t_std, flux_std, alpha_nominal,
                                               exponent_nominal, min_sigmas)
        fit = None
        if points["used"].sum() >= 3:
            used = points[points["used"]]
            fit = est.fit_convection(used["delta_t_c"], used["h_w_m2k"], delta_t_std,
                                     hac_lags=steps_per_day)
        else:
            notes.append(f"convection {surface_class}: {int(points['used'].sum())} usable time "
                         f"steps (|ΔT| ≥ {min_sigmas * delta_t_std:.3g} K, flux above its "
                         f"detection limit, h > 0); no regression")
        results.append(ConvectionClass(
            surface_class=surface_class, surface=surface, curve=curve_name, points=points,
            delta_t_std_c=delta_t_std, min_delta_t_c=min_sigmas * delta_t_std, fit=fit,
            source=("derived convection coefficient readings (per-step heat balance, eq. 15-16, "
                    "hour means)" if from_readings else "hourly surface heat balance (eq. 15-16)"),
            alpha_nominal=alpha_nominal, exponent_nominal=exponent_nominal))
    return results


def _convection_parameters(config: Config, detailed: io.Detailed,
                           convection: list[ConvectionClass], idf, skipped: list[str],
                           notes: list[str]) -> list[RefinedParameter]:
    refined, seen = [], set()
    for result in convection:
        if result.fit is None:
            continue
        if result.curve.upper() in seen:
            skipped.append(f"convection {result.surface_class}: curve {result.curve} already "
                           f"refined from another surface class")
            continue
        seen.add(result.curve.upper())
        fit = result.fit
        common = {"method": f"{result.source}, OLS of log h on log|dT|, Newey-West "
                            "standard errors",
                  "equation": "seed eq. 15-17",
                  "source": str(detailed.detailed_path),
                  "surface_class": result.surface_class, "surface": result.surface,
                  "n": fit.points, "r_squared": round(fit.r_squared, 4),
                  "residual_std_log_h": round(fit.residual_std, 4),
                  "estimate_correlation": round(fit.correlation, 4)}
        # Table 3.2's ±5 % on a heat-flux or derived-h reading may be a constant calibration
        # error of that sensor rather than per-reading noise: α cannot be known better than
        # that, however many hours are averaged, so it adds in quadrature.
        systematic = fit.alpha * detailed.metadata.heat_flux_relative_std
        alpha_std = float(np.hypot(fit.alpha_std_error, systematic))
        common["alpha_systematic_std"] = _r(systematic)
        for field_name, what, value, std in (
                ("Coefficient2 Constant", "alpha", fit.alpha, alpha_std),
                ("Coefficient3 Constant", "n", fit.exponent, fit.exponent_std_error)):
            parameters = parameters_targeting(config, "Curve:Exponent", field_name, result.curve)
            if not parameters:
                skipped.append(f"convection {result.surface_class}: {what} estimated "
                               f"({value:.4g}) but no parameter targets Curve:Exponent "
                               f"{result.curve} field '{field_name}'; skipped")
            for parameter in parameters:
                targets = idf_targets(parameter)
                matched = next(t for t in targets
                               if targets_field(t, "Curve:Exponent", field_name, result.curve))
                if len(targets) > 1:
                    notes.append(f"{parameter.name}: also targets fields other than "
                                   f"{result.curve} '{field_name}'; refined from the "
                                   f"{result.surface_class} estimate for all of them")
                nominal = idf_nominal(idf, matched)
                mean = float(in_parameter_units(value, parameter.mode, nominal))
                spread = std_in_parameter_units(std, parameter.mode, nominal)
                spec = bounded_normal(mean, spread, floor=1e-6 if parameter.mode != "additive"
                                      else None)
                provenance = {**common, "quantity": what, "estimate": _r(value),
                              "std_error": _r(std), "idf_nominal": _r(nominal),
                              "interval_90_physical": [_r(value - _Z90 * std),
                                                       _r(value + _Z90 * std)]}
                if what == "alpha":
                    provenance.update(log_alpha=_r(fit.log_alpha),
                                      log_alpha_std_error=_r(fit.log_alpha_std_error),
                                      delta_method="se(alpha) = alpha * se(log alpha)")
                refined.append(_refined(parameter, spec, provenance))
    return refined


# Stratification (eq. 18) -------------------------------------------------

def _gradient(detailed: io.Detailed, hourly: pd.DataFrame, calibration: pd.DataFrame
              ) -> tuple[pd.Series, float]:
    io.require_columns(detailed.frame, [io.CEILING_AIR, io.FLOOR_AIR], detailed.detailed_path,
                       "air near ceiling and floor, seed eq. 18")
    meta = detailed.metadata
    gradient = est.gradient_samples(est.corrected(hourly[io.CEILING_AIR], calibration),
                                    est.corrected(hourly[io.FLOOR_AIR], calibration),
                                    meta.air_sensor_separation_m)
    # Per-estimate sensor error; with sub-hourly readings the hourly mean divides it by s.
    steps = 60.0 / detailed.step_minutes if detailed.sub_hourly else 1.0
    variance = est.reading_variance([io.CEILING_AIR, io.FLOOR_AIR], calibration,
                                    meta.reference_sensor_std_c).sum() / steps
    return gradient, float(np.sqrt(variance) / meta.air_sensor_separation_m)


def _gradient_parameters(config: Config, detailed: io.Detailed, gradient: pd.Series,
                         gradient_std: float, idf, skipped: list[str]) -> list[RefinedParameter]:
    parameters = parameters_targeting(config, "RoomAir:TemperaturePattern:ConstantGradient",
                                      "Temperature Gradient")
    if not parameters:
        skipped.append(f"gradient estimated (median {gradient.median():.4g} K/m) but no "
                       f"parameter targets RoomAir:TemperaturePattern:ConstantGradient field "
                       f"'Temperature Gradient'; skipped")
    gradient = gradient.dropna()
    if parameters and gradient.empty:
        skipped.append("no hour has both ceiling and floor air readings; gradient not refined")
        return []
    refined = []
    for parameter in parameters:
        values = in_parameter_units(gradient.to_numpy(), parameter.mode,
                                    parameter_nominal(idf, parameter))
        provenance = {"method": "hourly (T_ceiling - T_floor) / separation of bias-corrected "
                                "air sensors, pooled as an empirical sample",
                      "equation": "seed eq. 18", "source": str(detailed.detailed_path),
                      "separation_m": detailed.metadata.air_sensor_separation_m,
                      "per_hour_sensor_std_k_per_m": _r(gradient_std),
                      **_sample_summary(values)}
        refined.append(_empirical(parameter, values, gradient.index, provenance))
    return refined


# Ground reflectance (§3.5.4) ---------------------------------------------

def _reflectance(detailed: io.Detailed, hourly: pd.DataFrame, min_irradiance: float
                 ) -> pd.Series:
    io.require_columns(detailed.frame, [io.GLOBAL_HORIZONTAL, io.GROUND_REFLECTED],
                       detailed.detailed_path, "ground reflectance, seed §3.5.4")
    return est.ground_reflectance_samples(hourly[io.GROUND_REFLECTED],
                                          hourly[io.GLOBAL_HORIZONTAL],
                                          detailed.metadata.south_facade_ground_view_factor,
                                          min_irradiance)


def _months(parameter: Parameter) -> set[int]:
    months = set()
    for target in parameter.targets:
        text = getattr(target, "field", "").lower()
        months |= {i + 1 for i, m in enumerate(_MONTHS) if text.startswith(m.lower())}
    return months


def _reflectance_parameters(config: Config, detailed: io.Detailed, reflectance: pd.Series,
                            idf, skipped: list[str]) -> list[RefinedParameter]:
    parameters = [p for p in config.parameters
                  if any(t.object.upper() == "SITE:GROUNDREFLECTANCE"
                         for t in p.targets if hasattr(t, "object"))]
    if not parameters:
        skipped.append(f"ground reflectance estimated (median {reflectance.median():.4g}) but "
                       f"no parameter targets Site:GroundReflectance; skipped")
    refined = []
    hour_months = (reflectance.index - pd.Timedelta(hours=1)).month
    for parameter in parameters:
        months = _months(parameter)
        chosen = reflectance[np.isin(hour_months, sorted(months))]
        if chosen.empty:
            skipped.append(f"{parameter.name}: no daylight hours measured in its months "
                           f"{sorted(months)}; skipped")
            continue
        values = in_parameter_units(chosen.to_numpy(), parameter.mode,
                                    parameter_nominal(idf, parameter))
        provenance = {"method": "hourly reflected / (view factor x global horizontal) "
                                "irradiance, pooled as an empirical sample",
                      "equation": "seed §3.5.4", "source": str(detailed.detailed_path),
                      "view_factor": detailed.metadata.south_facade_ground_view_factor,
                      "months": sorted(months), **_sample_summary(values)}
        refined.append(_empirical(parameter, values, chosen.index, provenance))
    return refined


def period_summaries(config: Config, samples: pd.Series) -> dict[str, dict]:
    """Summaries of hourly estimates within each run period of the config."""
    days = (samples.index - pd.Timedelta(hours=1)).normalize()
    out = {}
    for period in config.model.periods:
        chosen = []
        for year in sorted(set(days.year)):
            first, last = period_dates(period, year)
            chosen.append((days >= pd.Timestamp(first)) & (days <= pd.Timestamp(last)))
        mask = np.logical_or.reduce(chosen) if chosen else np.zeros(len(samples), bool)
        out[period.name] = est.summary(samples[mask])
    return out


# Glazing (§3.5.3) ----------------------------------------------------------

def _glazing(config: Config, detailed: io.Detailed, hourly: pd.DataFrame, idf,
             min_irradiance: float) -> dict:
    io.require_columns(detailed.frame, [io.WINDOW_TRANSMITTED, io.WINDOW_INCIDENT],
                       detailed.detailed_path, "glazing transmittance, seed §3.5.3")
    ratios = est.glazing_transmittance_samples(hourly[io.WINDOW_TRANSMITTED],
                                               hourly[io.WINDOW_INCIDENT], min_irradiance)
    parameters = parameters_targeting(config, "WindowMaterial:Glazing",
                                      "Solar Transmittance at Normal Incidence")
    glass = next((t.name for p in parameters for t in p.targets
                  if getattr(t, "name", "*") != "*"), None)
    glasses = idf.of_type("WindowMaterial:Glazing")
    if glass is None and not glasses:
        return {"refined": False, "hourly_system_transmittance": est.summary(ratios),
                "note": "the model has no WindowMaterial:Glazing"}
    material = idf.find("WindowMaterial:Glazing", glass) if glass else glasses[0]
    tau0 = material.number("Solar Transmittance at Normal Incidence")
    rho = 0.5 * (material.number("Back Side Solar Reflectance at Normal Incidence")
                 + material.number("Front Side Solar Reflectance at Normal Incidence"))
    keep = hourly[io.WINDOW_INCIDENT] >= min_irradiance
    weighted = float(hourly.loc[keep, io.WINDOW_TRANSMITTED].sum()
                     / hourly.loc[keep, io.WINDOW_INCIDENT].sum()) if keep.any() else float("nan")
    single = est.single_pane_transmittance(weighted, rho) if keep.any() else float("nan")
    hourly_single = np.sqrt(ratios.to_numpy() * (1 - rho ** 2))
    report = {
        "refined": False,
        "why_not_refined": (
            "seed §3.5.5 leaves glazing transmittance out of the refined model. Hourly "
            "transmitted/incident mixes beam at every incidence angle with diffuse sky and "
            "ground light, which the glass transmits less than at normal incidence, so it "
            "underestimates the normal-incidence value the parameter means; restricting to "
            "near-normal beam leaves the diffuse share (and the south window never sees the sun "
            "closer than the noon solar altitude). An unbiased estimate needs the glass's "
            "angular model, i.e. the simulation model: calibration, not measurement."),
        "material": material.name, "pane_reflectance": rho,
        "min_incident_w_m2": min_irradiance,
        "hourly_system_transmittance": est.summary(ratios),
        "system_transmittance_energy_weighted": weighted,
        "single_pane_estimate": single,
        "hourly_single_pane": est.summary(hourly_single),
        "per_period_system_transmittance": period_summaries(config, ratios),
        "normal_incidence_single_pane_nominal": tau0,
        "normal_incidence_system_nominal": est.double_pane_transmittance(tau0, rho),
        "bias_single_pane": single - tau0,
        "relative_bias_single_pane": single / tau0 - 1,
        "bias_explanation": (
            "negative: off-normal incidence and diffuse sky and ground light transmit less than "
            "beam at normal incidence (the summer ratio, with the sun high above the south "
            "window, is lower than the winter one). The estimate also folds in the dirt "
            "correction factor, which EnergyPlus applies to the outer pane: the data identify "
            "tau^2 x dirt, so the single-pane inversion gives tau x sqrt(dirt). The model has no "
            "frames or dividers, so unlike the source's experiment (its 'frames and dividers' "
            "reading) none of the bias here comes from them."),
    }
    for parameter in parameters:
        nominal = parameter_nominal(idf, parameter)
        report.setdefault("in_parameter_units", {})[parameter.name] = {
            "mode": parameter.mode,
            "estimate": float(in_parameter_units(single, parameter.mode, nominal)),
            "baseline_interval_90": list(interval(parameter.distribution))}
    return report


# Helpers -------------------------------------------------------------------

def _informative(refined: list[RefinedParameter], skipped: list[str]) -> list[RefinedParameter]:
    """Keep the refinements narrower than their baseline; the others keep the baseline.

    An estimate whose 90 % interval is as wide as the baseline's (few usable
    hours, a poorly determined coefficient) says less than the prior
    knowledge; replacing the baseline with it would widen the input.
    """
    kept = []
    for item in refined:
        before, after = item.before[1] - item.before[0], item.after[1] - item.after[0]
        if after < before:
            kept.append(item)
            continue
        skipped.append(f"{item.name}: estimate {item.provenance.get('estimate')} has a 90 % "
                       f"interval [{item.after[0]:.4g}, {item.after[1]:.4g}] no narrower than "
                       f"the baseline's [{item.before[0]:.4g}, {item.before[1]:.4g}]; the data "
                       f"are less informative than the baseline, which is kept")
    return kept


def _r(value: float) -> float:
    return float(f"{float(value):.6g}")


def _sample_summary(values: np.ndarray) -> dict:
    s = est.summary(values)
    return {"n": s["n"], "estimate": _r(s["median"]), "mean": _r(s["mean"]),
            "std": _r(s["std"]), "interval_90": [_r(s["q05"]), _r(s["q95"])]}


def _refined(parameter: Parameter, spec: dict, provenance: dict,
             values: np.ndarray | None = None, samples: pd.DataFrame | None = None
             ) -> RefinedParameter:
    refined = distribution_from(spec, values)
    return RefinedParameter(baseline=parameter, distribution=spec, provenance=provenance,
                            before=interval(parameter.distribution, INTERVAL),
                            after=interval(refined, INTERVAL), samples=samples)


def samples_file(parameter: Parameter) -> str:
    """File name (beside refined.yaml) of an empirical parameter's values."""
    return f"{parameter.name}_samples.csv"


def _empirical(parameter: Parameter, values: np.ndarray, index: pd.DatetimeIndex,
               provenance: dict) -> RefinedParameter:
    spec = {"type": "empirical", "file": samples_file(parameter), "column": parameter.name}
    samples = pd.DataFrame({parameter.name: values}, index=index)
    return _refined(parameter, spec, provenance, values, samples)
