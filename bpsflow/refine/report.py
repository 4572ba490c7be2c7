"""Writing a refinement: ``refined.yaml``, its data files, ``refine.json``, CSV and figures.

``refined.yaml`` extends the baseline config and holds only what changed:
its own run directory, the refined parameters (same names, targets, group
and mode, with ``provenance``) and the refined boundary section (a copy of
the boundary file with the measured hours replaced, and per-surface
``sensor_std_c``). Empirical distributions and the boundary file are written
beside it and referenced by relative paths, so the folder moves as a whole.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from bpsflow.files import inside, jsonable, save_figure, write_csv, write_json, write_text_atomic
from bpsflow.refine.parameters import BOUND_SIGMAS, INTERVAL, distribution_from, relative_file
from bpsflow.refine.refinement import Refinement, samples_file

REFINED_CONFIG = "refined.yaml"
REFINE_JSON = "refine.json"
CONVECTION_CSV = "refine_convection.csv"
BOUNDARY_FILE = "refined_boundary_temperatures.csv"
DISTRIBUTIONS_FIGURE = "refined_distributions.png"
CONVECTION_FIGURE = "convection_regression.png"

#: The first words of every refined config bpsflow writes (an earlier one may be replaced).
REFINED_HEADER = "# Refined by 'bpsflow refine'"


def write_refinement(refinement: Refinement, out_dir: Path,
                     config_path: Path | None = None) -> dict[str, Path]:
    """Write every output of a refinement; returns the paths by kind.

    ``refined.yaml`` goes to ``config_path`` (default ``out_dir/refined.yaml``)
    with its data files (empirical samples, boundary file) beside it;
    ``refine.json``, the convection table and ``figures/`` go to ``out_dir``.
    """
    out_dir = Path(out_dir).resolve()
    config_path = Path(config_path).resolve() if config_path else out_dir / REFINED_CONFIG
    if (out_dir / REFINE_JSON).is_file():
        # an earlier refinement (perhaps of other readings) is kept, not overwritten
        from bpsflow.simulation.rundir import move_aside

        # only what a refinement writes: --out may be a folder that holds the user's files
        names = [REFINE_JSON, CONVECTION_CSV, "figures"]
        if config_path.parent == out_dir:
            names += [REFINED_CONFIG if config_path.name == REFINED_CONFIG else config_path.name,
                      BOUNDARY_FILE] + [p.name for p in out_dir.glob("*_samples.csv")]
        refinement.notes.append(f"the earlier refinement in {out_dir} was moved to "
                                f"{move_aside(out_dir, names)}")
    (out_dir / "figures").mkdir(parents=True, exist_ok=True)
    config_path.parent.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}
    for refined in refinement.parameters:
        if refined.samples is not None:
            write_csv(refined.samples, inside(config_path.parent, samples_file(refined.baseline)),
                      index_label="timestamp", float_format="%.6g")
    if refinement.boundary:
        paths["boundary"] = write_boundary(refinement, config_path.parent / BOUNDARY_FILE)
    paths["config"] = write_config(refinement, config_path)
    paths["convection_csv"] = out_dir / CONVECTION_CSV
    write_csv(convection_table(refinement), paths["convection_csv"], index=False,
              float_format="%.6g")
    paths["json"] = out_dir / REFINE_JSON
    write_json(paths["json"], summary(refinement, paths))
    paths["distributions_figure"] = plot_distributions(
        refinement, out_dir / "figures" / DISTRIBUTIONS_FIGURE)
    paths["convection_figure"] = plot_convection(refinement,
                                                 out_dir / "figures" / CONVECTION_FIGURE)
    return paths


def write_boundary(refinement: Refinement, path: Path) -> Path:
    """The baseline boundary file with the measured hours replaced by the refined means."""
    boundary = refinement.config.model.boundary
    table = pd.read_csv(boundary.file)
    for surface in refinement.boundary:
        column = table.columns.get_loc(surface.column)
        table.iloc[surface.rows, column] = surface.hourly["mean"].to_numpy()
    write_csv(table, path, index=False, float_format="%.4f")
    return path


def write_config(refinement: Refinement, path: Path) -> Path:
    """``refined.yaml``: extends the baseline; own run dir, refined parameters and boundary."""
    config = refinement.config
    folder = path.parent
    raw: dict = {"extends": relative_file(config.source, folder),
                 "execution": {"run_dir": relative_file(
                     Path(str(config.run_dir.resolve()) + "_refined"), folder)}}
    if refinement.boundary:
        surfaces = {}
        for name, spec in config.model.boundary.surfaces.items():
            entry = {"schedule": spec.schedule, "column": spec.column}
            refined = next((s for s in refinement.boundary if s.surface == name), None)
            if refined is not None:
                entry["sensor_std_c"] = float(f"{refined.sensor_std_c:.6g}")
            elif spec.sensor_std_c is not None:
                entry["sensor_std_c"] = spec.sensor_std_c
            surfaces[name] = entry
        raw["model"] = {"boundary": {"file": BOUNDARY_FILE, "surfaces": surfaces}}
    # no refined parameter: no 'parameters' key (an empty list over a base is refused)
    for refined in refinement.parameters:
        parameter = refined.baseline
        raw.setdefault("parameters", []).append({
            "name": parameter.name, "group": parameter.group, "mode": parameter.mode,
            "description": f"refined from detailed measurements ({refined.provenance['equation']})"
                           + (f"; baseline: {parameter.description}" if parameter.description
                              else ""),
            "distribution": refined.distribution,
            "targets": [t.model_dump(mode="json") for t in parameter.targets],
            "provenance": _plain(refined.provenance)})
    header = (f"{REFINED_HEADER} from {refinement.detailed.detailed_path}\n"
              f"# (seed §3.4.3-3.5). Only refined inputs are listed; the rest come from the\n"
              f"# baseline config named in 'extends'. See refine.json for all estimates.\n")
    write_text_atomic(path, header + yaml.safe_dump(raw, sort_keys=False, allow_unicode=True,
                                                 width=100))
    return path


def convection_table(refinement: Refinement) -> pd.DataFrame:
    """The Table 3.4 analogue: log α and n per surface class with errors, R², N."""
    rows = []
    for result in refinement.convection:
        fit = result.fit
        for coefficient in ("log_alpha", "n"):
            row = {"surface_class": result.surface_class, "surface": result.surface,
                   "curve": result.curve, "coefficient": coefficient}
            if fit is not None:
                row.update(
                    estimate=fit.log_alpha if coefficient == "log_alpha" else fit.exponent,
                    std_error=(fit.log_alpha_std_error if coefficient == "log_alpha"
                               else fit.exponent_std_error),
                    iid_std_error=(fit.iid_log_alpha_std_error if coefficient == "log_alpha"
                                   else fit.iid_exponent_std_error),
                    r_squared=fit.r_squared, n=fit.points)
            row["nominal"] = (np.log(result.alpha_nominal) if coefficient == "log_alpha"
                              else result.exponent_nominal)
            row["min_delta_t_c"] = result.min_delta_t_c
            rows.append(row)
    return pd.DataFrame(rows)


def interval_table(refinement: Refinement) -> pd.DataFrame:
    """Per refined parameter: the 90 % interval before and after, and the width ratio."""
    rows = []
    for refined in refinement.parameters:
        before, after = refined.before, refined.after
        rows.append({"parameter": refined.name, "mode": refined.baseline.mode,
                     "before_low": before[0], "before_high": before[1],
                     "after_low": after[0], "after_high": after[1],
                     "width_before": before[1] - before[0], "width_after": after[1] - after[0],
                     "width_ratio": (after[1] - after[0]) / (before[1] - before[0])})
    return pd.DataFrame(rows)


def summary(refinement: Refinement, paths: dict[str, Path]) -> dict:
    """Everything ``refine.json`` holds."""
    from bpsflow.refine import estimators as est
    from bpsflow.refine.refinement import period_summaries

    detailed = refinement.detailed
    convection = {}
    for result in refinement.convection:
        entry = {"surface": result.surface, "curve": result.curve,
                 "alpha_nominal": result.alpha_nominal,
                 "exponent_nominal": result.exponent_nominal,
                 "delta_t_std_c": result.delta_t_std_c, "min_delta_t_c": result.min_delta_t_c,
                 "steps": int(len(result.points)), "used": int(result.points["used"].sum())}
        if result.fit is not None:
            fit = result.fit
            entry.update(log_alpha=fit.log_alpha, log_alpha_std_error=fit.log_alpha_std_error,
                         alpha=fit.alpha, alpha_std_error=fit.alpha_std_error,
                         n=fit.exponent, n_std_error=fit.exponent_std_error,
                         r_squared=fit.r_squared, points=fit.points,
                         residual_std_log_h=fit.residual_std, correlation=fit.correlation,
                         hac_lags=fit.hac_lags,
                         iid_log_alpha_std_error=fit.iid_log_alpha_std_error,
                         iid_n_std_error=fit.iid_exponent_std_error,
                         attenuation_lambda=fit.attenuation,
                         n_attenuation_first_order=fit.exponent_attenuation)
        convection[result.surface_class] = entry
    return {
        "detailed": str(detailed.detailed_path),
        "calibration": str(detailed.calibration_path),
        "metadata": str(detailed.metadata_path),
        "time_step_minutes": detailed.step_minutes,
        "aggregated_to_hours_eq14": detailed.sub_hourly,
        "readings": int(len(detailed.frame)),
        "reference_sensor_std_c": detailed.metadata.reference_sensor_std_c,
        "sensors": {sensor: {k: row[k] for k in ("bias_c", "std_c", "bias_std_error_c",
                                                 "steps", "note")}
                    for sensor, row in refinement.calibration.iterrows()},
        "boundary": {s.surface: {"column": s.column, "hours_replaced": int(len(s.rows)),
                                 "sensor_std_c": s.sensor_std_c, "areas_m2": s.areas_m2,
                                 "mean_c": float(s.hourly["mean"].mean())}
                     for s in refinement.boundary},
        "convection": convection,
        "gradient": {**est.summary(refinement.gradient),
                     "per_hour_sensor_std_k_per_m": refinement.gradient_std_k_per_m,
                     "per_period": period_summaries(refinement.config, refinement.gradient)},
        "ground_reflectance": {**est.summary(refinement.reflectance),
                               "per_period": period_summaries(refinement.config,
                                                              refinement.reflectance)},
        "glazing": refinement.glazing,
        "parameters": {
            r.name: {"mode": r.baseline.mode,
                     "before": {"interval_90": list(r.before), "width": r.before[1] - r.before[0],
                                "distribution": r.baseline.distribution.model_dump(mode="json")},
                     "after": {"interval_90": list(r.after), "width": r.after[1] - r.after[0],
                               "distribution": r.distribution},
                     "provenance": r.provenance}
            for r in refinement.parameters},
        "choices": {
            "convection_min_delta_t_sigmas": refinement.min_delta_t_sigmas,
            "convection_min_flux_sigmas": est.CONVECTION_MIN_FLUX_SIGMAS,
            "convection_standard_errors": "Newey-West (HAC), lags = one day of steps",
            "convection_residuals": (
                "not sampled: a regression residual is per-time-step scatter that averages out "
                "over a test's hours; drawn once per instance it would act as a persistent "
                "offset on h. residual_std_log_h is reported per class"),
            "min_irradiance_w_m2": refinement.min_irradiance_w_m2,
            "bounded_normal_sigmas": BOUND_SIGMAS,
            "interval": INTERVAL,
            "uninformative_estimates": "kept the baseline when the refined 90 % interval is "
                                       "not narrower",
        },
        "skipped": refinement.skipped,
        "notes": refinement.notes,
        "files": {k: str(v) for k, v in paths.items()},
    }


# Figures -------------------------------------------------------------------

def plot_distributions(refinement: Refinement, path: Path) -> Path:
    """Baseline vs refined distribution per parameter (the seed's Figure 3.4 analogue)."""
    refined = refinement.parameters
    columns = max(1, min(4, len(refined)))
    rows = max(1, int(np.ceil(len(refined) / columns)))
    figure = Figure(figsize=(3.6 * columns, 2.8 * rows))
    axes = figure.subplots(rows, columns, squeeze=False)
    u = (np.arange(4000) + 0.5) / 4000
    for ax, item in zip(axes.flat, refined):
        after = distribution_from(item.distribution, None if item.samples is None
                                  else item.samples.iloc[:, 0].to_numpy())
        before_values = item.baseline.distribution.ppf(u)
        after_values = after.ppf(u)
        low = min(before_values.min(), after_values.min())
        high = max(before_values.max(), after_values.max())
        bins = np.linspace(low, high, 60) if high > low else 10
        # stepfilled: one polygon per histogram, not one patch per bar
        ax.hist(before_values, bins=bins, density=True, color="0.75", histtype="stepfilled")
        twin = ax.twinx()
        twin.hist(after_values, bins=bins, density=True, color="tab:red", alpha=0.7,
                  histtype="stepfilled")
        twin.set_yticks([])
        ax.set_yticks([])
        for bound in item.after:
            ax.axvline(bound, color="tab:red", lw=0.8, ls="--")
        ax.set_title(item.name, fontsize=9)
        ax.set_xlabel(f"{item.baseline.mode} value", fontsize=8)
    for ax in list(axes.flat)[len(refined):]:
        ax.axis("off")
    handles = [Rectangle((0, 0), 1, 1, color="0.75"),
               Rectangle((0, 0), 1, 1, color="tab:red", alpha=0.7)]
    figure.legend(handles, ["baseline", f"refined ({INTERVAL:.0%} interval dashed)"],
                  loc="lower center", ncol=2, fontsize=8)
    figure.suptitle("Refined vs baseline input distributions (densities scaled per panel)",
                    fontsize=10)
    figure.tight_layout(rect=(0, 0.05, 1, 0.95))
    save_figure(figure, path, dpi=110)
    return path


def plot_convection(refinement: Refinement, path: Path) -> Path:
    """log h vs log|ΔT| per surface class with the fitted line (seed eq. 17)."""
    figure = Figure(figsize=(4 * max(1, len(refinement.convection)), 3.4))
    axes = figure.subplots(1, len(refinement.convection), squeeze=False)
    for ax, result in zip(axes.flat, refinement.convection):
        points = result.points.replace([np.inf, -np.inf], np.nan).dropna()
        points = points[(points["h_w_m2k"] > 0) & (points["delta_t_c"] != 0)]
        x = np.log(points["delta_t_c"].abs())
        y = np.log(points["h_w_m2k"])
        used = points["used"].to_numpy()
        ax.scatter(x[~used], y[~used], s=4, color="0.8", label="not used (|ΔT| or flux too small)")
        ax.scatter(x[used], y[used], s=5, color="tab:blue", label="used")
        if result.fit is not None:
            grid = np.linspace(x[used].min(), x[used].max(), 50)
            fit = result.fit
            ax.plot(grid, fit.log_alpha + fit.exponent * grid, color="tab:red",
                    label=f"log α {fit.log_alpha:.3f}, n {fit.exponent:.3f}, "
                          f"R² {fit.r_squared:.2f}")
            ax.plot(grid, np.log(result.alpha_nominal) + result.exponent_nominal * grid,
                    color="k", ls=":", label="IDF nominal")
        ax.set_title(f"{result.surface_class} ({result.curve})", fontsize=9)
        ax.set_xlabel("log |T_air − T_surface| (K)")
        ax.set_ylabel("log h_c (W/m²K)")
        ax.legend(fontsize=7)
    figure.tight_layout()
    save_figure(figure, path, dpi=110)
    return path


def _plain(value):
    """JSON- and YAML-safe copy (:func:`bpsflow.files.jsonable`)."""
    return jsonable(value)
    return str(value)
