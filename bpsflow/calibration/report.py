"""What a calibration writes: calibration.json, posterior.parquet, tables and figures.

Files in the output folder (``RUN_DIR/calibration`` by default)::

    calibration.json        scenario, parameters (prior vs posterior, contraction,
                            deterministic optimum, truth if given), discrepancy and
                            noise, emulator (hyperparameters, hold-out R²/RMSE),
                            diagnostics (R-hat, bulk/tail ESS, steps per iteration,
                            divergences, seconds, ESS/s, verdict), held-out metrics
    posterior.parquet       one row per draw: chain, draw, θ (parameter units),
                            δ and ε standard deviations (standardised and per output)
    heldout.csv             the held-out table (model × output × resolution)
    observations.parquet    the rows used: time, output, split, measured, x
    emulator_points.parquet the (run, row) pairs of the hyperparameter fit
    figures/prior_posterior.png, figures/heldout_<output>_<resolution>.png,
    figures/emulator_test.png, figures/trace.png
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from bpsflow.calibration.design import unit_to_values
from bpsflow.calibration.emulator import Hyperparameters
from bpsflow.calibration.workflow import CalibrationRun
from bpsflow.files import inside, save_figure, write_csv, write_json, write_parquet

CALIBRATION_FILE = "calibration.json"
POSTERIOR_FILE = "posterior.parquet"
HELDOUT_FILE = "heldout.csv"
OBSERVATIONS_FILE = "observations.parquet"
EMULATOR_POINTS_FILE = "emulator_points.parquet"
#: A calibration's own results in its folder, moved aside by the next calibration there
#: (the design runs stay: they are reused when the design is the same).
EARLIER_FILES = (CALIBRATION_FILE, POSTERIOR_FILE, HELDOUT_FILE, OBSERVATIONS_FILE,
                 EMULATOR_POINTS_FILE, "figures", "decision")

_PROBABILITIES = (0.05, 0.5, 0.95)


def _summary(values: np.ndarray) -> dict[str, float]:
    q05, q50, q95 = np.quantile(values, _PROBABILITIES)
    return {"mean": float(np.mean(values)), "sd": float(np.std(values)), "q05": float(q05),
            "median": float(q50), "q95": float(q95), "width90": float(q95 - q05)}


#: Prior-CDF distance from 0 or 1 within which a deterministic optimum sits at its bound.
AT_BOUND_QUANTILE = 0.01


def _at_bound(unit: float) -> str | None:
    """``"lower"``/``"upper"`` when an optimum lies in its prior's outer 1 %, else None."""
    if unit <= AT_BOUND_QUANTILE:
        return "lower"
    if unit >= 1.0 - AT_BOUND_QUANTILE:
        return "upper"
    return None


def parameter_table(run: CalibrationRun) -> list[dict]:
    """Per calibration parameter: prior and posterior summaries, contraction, optimum, truth.

    Contraction is ``1 - posterior 90 % width / prior 90 % width`` (0: the data
    taught nothing; 1: pinned down).
    """
    optimum_unit = run.deterministic.unit
    optimum = unit_to_values(optimum_unit[None, :], run.parameters)[0]
    draws = None if run.unit_draws is None else unit_to_values(run.unit_draws, run.parameters)
    rows = []
    for j, p in enumerate(run.parameters):
        prior = p.distribution.scipy()
        q05, q50, q95 = prior.ppf(_PROBABILITIES)
        entry = {"name": p.name, "group": p.group, "distribution": p.distribution.type,
                 "prior": {"mean": float(prior.mean()), "sd": float(prior.std()),
                           "q05": float(q05), "median": float(q50), "q95": float(q95),
                           "width90": float(q95 - q05)},
                 "sampled": bool(j in set(run.active.tolist())),
                 "emulator_effect": float(run.effects[j]),
                 # the shortest over the emulator's blocks: where the parameter acts most
                 "emulator_lengthscale": float(min(h.t_lengthscales[j]
                                                   for h in run.emulator.hypers)),
                 "deterministic": float(optimum[j]),
                 "deterministic_at_bound": _at_bound(float(optimum_unit[j]))}
        if draws is not None:
            post = _summary(draws[:, j])
            entry["posterior"] = post
            entry["contraction"] = float(1 - post["width90"] / entry["prior"]["width90"])
        if run.truth and p.name in run.truth:
            value = run.truth[p.name]
            entry["truth"] = value
            if draws is not None:
                entry["truth_in_90"] = bool(entry["posterior"]["q05"] <= value
                                            <= entry["posterior"]["q95"])
        rows.append(entry)
    return rows


def _per_output_scale(run: CalibrationRun, values: np.ndarray) -> dict[str, dict]:
    """Standardised draws in each output's unit; a column per output when each has its own."""
    scaling = run.emulator.scaling
    own = values.ndim == 2 and values.shape[1] == len(scaling.outputs) > 1
    return {o: {**_summary((values[:, i] if own else values) * scaling.y_std[i]), "unit": ""}
            for i, o in enumerate(scaling.outputs)}


def diagnostics(run: CalibrationRun) -> dict | None:
    if run.posterior is None:
        return None
    post, conv = run.posterior, run.convergence
    ess = min(conv.ess_bulk_min, conv.ess_tail_min)
    return {
        "converged": conv.converged, "reasons": conv.reasons,
        "chains": int(post.num_steps.shape[0]), "samples_per_chain": int(post.num_steps.shape[1]),
        "warmup_per_chain": int(post.warmup_num_steps.shape[1]),
        "extensions": post.extensions,
        "chain_method": post.chain_method,
        "rhat_max": conv.rhat_max, "ess_bulk_min": conv.ess_bulk_min,
        "ess_tail_min": conv.ess_tail_min,
        "seconds": post.seconds, "warmup_seconds": post.warmup_seconds,
        "sampling_seconds": post.sampling_seconds,
        "min_ess_per_second": ess / post.seconds if post.seconds > 0 else None,
        "steps_per_iteration": float(post.num_steps.mean()),
        "warmup_steps_per_iteration": float(post.warmup_num_steps.mean()),
        "step_size": [float(s) for s in post.step_size],
        "divergences": conv.divergences, "divergence_share": conv.divergence_share,
        "per_quantity": conv.per_quantity,
    }


def _block_record(hyper: Hyperparameters, x_columns: list[str], parameters: list[str],
                  points: int) -> dict:
    """One emulator block's hyperparameters (seed eq. 20) and how they were fitted."""
    return {"signal_variance": hyper.signal_variance, "nugget": hyper.nugget,
            "row_variance": hyper.row_variance,
            "lengthscales": {**dict(zip(x_columns, map(float, hyper.x_lengthscales))),
                             **dict(zip(parameters, map(float, hyper.t_lengthscales)))},
            "fit_points": points, "fit_seconds": hyper.fit_seconds,
            "fit_notes": list(hyper.notes)}


def calibration_record(run: CalibrationRun) -> dict:
    """The content of ``calibration.json``."""
    em = run.emulator
    scaling = em.scaling
    rows = run.paired.rows
    record = {
        "scenario": {"name": run.scenario.name, "outputs": run.scenario.outputs,
                     "resolution": run.scenario.resolution},
        "method": run.method, "backend": run.backend,
        "observations": {
            "calibration": int(len(run.obs_rows)), "heldout": int(len(run.heldout_rows)),
            "calibration_period": _period(rows.iloc[run.obs_rows]["time"]),
            "heldout_period": _period(rows.iloc[run.heldout_rows]["time"]),
            "notes": run.paired.notes,
            "variable_inputs": list(scaling.x_columns),
            "variable_inputs_dropped": list(scaling.dropped)},
        "parameters": parameter_table(run),
        "emulator": {
            "kernel": "ARD squared exponential + nugget (seed eq. 20), MLE (scikit-learn)",
            "blocks": {name: _block_record(hyper, [scaling.x_columns[c] for c in columns],
                                           [p.name for p in run.parameters],
                                           int(np.sum(em.fit_points["block"] == name)))
                       for name, hyper, columns in zip(em.grid.names, em.hypers,
                                                       em.grid.columns)},
            "parameter_inputs": dict(zip([p.name for p in run.parameters],
                                         em.grid.inputs.kinds)),
            "fit_points": int(len(em.fit_points)),
            "fit_seconds": float(sum(h.fit_seconds for h in em.hypers)),
            "runs": int(em.grid.t.shape[0]), "rows": int(em.grid.x.shape[0]),
            "output_scaling": {o: {"mean": float(scaling.y_mean[i]),
                                   "std": float(scaling.y_std[i])}
                               for i, o in enumerate(scaling.outputs)},
            "holdout": None if em.test is None else {
                "runs": int(len(em.test.test_runs)), "r2": em.test.r2,
                "rmse_standardised": em.test.rmse_standardised, "per_output": em.test.per_output},
        },
        "screened_error": run.screened_error,
        "refinement": run.refinement,
        "deterministic": {
            "objective": run.deterministic.objective, "evaluations": run.deterministic.evaluations,
            "seconds": run.deterministic.seconds, "starts": run.deterministic.starts},
        "diagnostics": diagnostics(run),
        "heldout": json.loads(run.heldout.to_json(orient="records")) if run.heldout is not None
        else [],
        "timings": run.timings,
    }
    if run.posterior is not None:
        from bpsflow.calibration.bayes import flat_draws

        flat = flat_draws(run.posterior)
        record["likelihood"] = {
            "kind": "lowrank" if run.koh.lowrank else "exact",
            "description": ("observations given the simulations; delta FITC on "
                            f"{len(run.koh.x_inducing)} inducing inputs, emulator variances"
                            if run.koh.lowrank else
                            "observations given the simulations, full covariances"),
            "sampled_parameters": [run.parameters[i].name for i in run.active],
            "emulator_error_std_standardised": None if run.extra_variance is None else {
                o: float(np.sqrt(run.emulator.test.per_output[o]["mse_standardised"]))
                for o in scaling.outputs},
            "laplace_seconds": run.timings.get("laplace_seconds")}
        record["discrepancy"] = {
            "std_standardised": _summary(np.exp(flat["log_discrepancy_std"])),
            "std_per_output": _per_output_scale(run, np.exp(flat["log_discrepancy_std"])),
            "lengthscale": {name: _summary(np.exp(flat["log_discrepancy_lengthscale"][:, i]))
                            for i, name in enumerate(
                                scaling.x_columns if run.koh.ard else ["shared"])},
            "prior": {"std_median": float(np.exp(run.koh.priors["log_discrepancy_std"][0])),
                      "std_log_sd": float(run.koh.priors["log_discrepancy_std"][1])}}
        rows = run.paired.rows
        bias = {}
        for output in scaling.outputs:
            entry = {"unit": run.units.get(output, "")}
            for split, key, indices in (("calibration", "discrepancy_calibration", run.obs_rows),
                                        ("heldout", "discrepancy_heldout", run.heldout_rows)):
                mine = (rows["output"].to_numpy()[indices] == output)
                if mine.any():
                    entry[split] = float(run.predictive[key][:, mine].mean())
            bias[output] = entry
        record["discrepancy"]["mean_per_output"] = bias
        record["noise"] = {
            "std_standardised": _summary(np.exp(flat["log_noise_std"])),
            "std_per_output": _per_output_scale(run, np.exp(flat["log_noise_std"])),
            "prior": {"std_median": float(np.exp(run.koh.priors["log_noise_std"][0])),
                      "std_log_sd": float(run.koh.priors["log_noise_std"][1])}}
        for section in (record["discrepancy"]["std_per_output"],
                        record["noise"]["std_per_output"]):
            for output, entry in section.items():
                entry["unit"] = run.units.get(output, "")
    truth = [p for p in record["parameters"] if "truth_in_90" in p]
    if truth:
        record["truth_coverage_90"] = {"covered": sum(p["truth_in_90"] for p in truth),
                                       "parameters": len(truth)}
    return record


def _period(times: pd.Series) -> list[str] | None:
    if times.empty:
        return None
    return [str(times.min()), str(times.max())]


def posterior_frame(run: CalibrationRun) -> pd.DataFrame:
    """One row per draw: chain, draw, θ in parameter units, δ and ε standard deviations."""
    from bpsflow.calibration.bayes import flat_draws

    post = run.posterior
    chains, samples = post.num_steps.shape
    values = unit_to_values(run.unit_draws, run.parameters)
    frame = pd.DataFrame(values, columns=[p.name for p in run.parameters])
    frame.insert(0, "draw", np.tile(np.arange(samples), chains))
    frame.insert(0, "chain", np.repeat(np.arange(chains), samples))
    flat = flat_draws(post)
    delta = np.exp(flat["log_discrepancy_std"])
    own_delta = delta.ndim == 2
    if not own_delta:
        frame["discrepancy_std"] = delta
    lengthscales = np.exp(flat["log_discrepancy_lengthscale"])
    names = run.emulator.scaling.x_columns if run.koh.ard else ["shared"]
    for i, name in enumerate(names):
        frame[f"discrepancy_lengthscale_{name}"] = lengthscales[:, i]
    noise = np.exp(flat["log_noise_std"])
    own = noise.ndim == 2
    if not own:
        frame["noise_std"] = noise
    for i, output in enumerate(run.emulator.scaling.outputs):
        scale = run.emulator.scaling.y_std[i]
        frame[f"discrepancy_std_{output}"] = (delta[:, i] if own_delta else delta) * scale
        frame[f"noise_std_{output}"] = (noise[:, i] if own else noise) * scale
    frame["diverging"] = post.diverging.reshape(-1)
    return frame


def observations_frame(run: CalibrationRun) -> pd.DataFrame:
    frame = run.paired.rows[["time", "output", "test", "split"]].copy()
    frame["measured"] = run.paired.observed
    return pd.concat([frame, run.x.add_prefix("x_")], axis=1)


def write(run: CalibrationRun, out_dir: Path, provenance: dict | None = None) -> dict[str, Path]:
    """Write every file and figure of one calibration into ``out_dir``.

    ``provenance`` (the measured file, the config and its fingerprint) goes into
    ``calibration.json`` so that ``bpsflow decide`` can check what it is given.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    if (out_dir / CALIBRATION_FILE).is_file():
        # an earlier calibration's posterior, figures and decisions must not sit beside this
        # record (a deterministic run over a Bayesian one left its posterior for decide)
        from bpsflow.simulation.rundir import move_aside

        earlier = move_aside(out_dir, EARLIER_FILES)
    else:
        earlier = None
    paths = {"json": out_dir / CALIBRATION_FILE, "heldout": out_dir / HELDOUT_FILE}
    if earlier is not None:
        paths["earlier"] = earlier
    record = calibration_record(run)
    record.update(provenance or {})
    write_json(paths["json"], record)
    write_csv(run.heldout, paths["heldout"], index=False, float_format="%.6g")
    write_parquet(observations_frame(run), out_dir / OBSERVATIONS_FILE, index=False)
    write_parquet(run.emulator.fit_points, out_dir / EMULATOR_POINTS_FILE, index=False)
    if run.posterior is not None:
        paths["posterior"] = out_dir / POSTERIOR_FILE
        write_parquet(posterior_frame(run), paths["posterior"], index=False)
    figures = out_dir / "figures"
    figures.mkdir(exist_ok=True)
    paths["figures"] = figures
    plot_prior_posterior(run, figures / "prior_posterior.png")
    plot_emulator_test(run, figures / "emulator_test.png")
    for path in plot_heldout(run, figures):
        paths[path.stem] = path
    if run.posterior is not None:
        plot_trace(run, figures / "trace.png")
    return paths


# ---------------------------------------------------------------------------
# Figures


def _grid(n: int, width: float = 3.0, height: float = 2.3):
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    # a bare Figure (no pyplot): renders headless with Agg, no global backend choice
    fig = Figure(figsize=(width * cols, height * rows), layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    return fig, axes.ravel()


def plot_prior_posterior(run: CalibrationRun, path: Path) -> Path:
    """Prior density vs posterior histogram per parameter (seed Figure 4.8)."""
    fig, axes = _grid(len(run.parameters))
    draws = None if run.unit_draws is None else unit_to_values(run.unit_draws, run.parameters)
    optimum = unit_to_values(run.deterministic.unit[None, :], run.parameters)[0]
    for j, (ax, p) in enumerate(zip(axes, run.parameters)):
        prior = p.distribution.scipy()
        lo, hi = prior.ppf([0.001, 0.999])
        grid = np.linspace(lo, hi, 200)
        ax.plot(grid, prior.pdf(grid), color="0.4", lw=1.2, label="prior")
        if draws is not None:
            ax.hist(draws[:, j], bins=40, range=(lo, hi), density=True, color="tab:blue",
                    alpha=0.55, label="posterior" + ("" if j in run.active else " (= prior)"))
        ax.axvline(optimum[j], color="tab:red", ls="--", lw=1, label="deterministic")
        if run.truth and p.name in run.truth:
            ax.axvline(run.truth[p.name], color="black", lw=1.2, label="truth")
        ax.set_title(p.name, fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0].legend(fontsize=6)
    fig.suptitle(f"{run.scenario.name}: prior vs posterior", fontsize=9)
    save_figure(fig, path, dpi=110)
    return path


def plot_emulator_test(run: CalibrationRun, path: Path) -> Path | None:
    """Emulator prediction vs simulation on the held-out runs (seed Figure 4.6)."""
    test = run.emulator.test
    if test is None:
        return None
    outputs = list(run.emulator.scaling.outputs)
    fig, axes = _grid(len(outputs), 3.4, 3.2)
    for ax, output in zip(axes, outputs):
        mine = run.emulator.row_outputs == output
        sim, pred = test.simulated[:, mine].ravel(), test.predicted[:, mine].ravel()
        ax.scatter(sim, pred, s=3, alpha=0.3)
        lo, hi = min(sim.min(), pred.min()), max(sim.max(), pred.max())
        ax.plot([lo, hi], [lo, hi], color="black", lw=0.8)
        stats = test.per_output[output]
        ax.set_title(f"{output}\nR² {stats['r2']:.4f}, RMSE {stats['rmse']:.3g}", fontsize=8)
        ax.set_xlabel("simulated", fontsize=8)
        ax.set_ylabel("emulator", fontsize=8)
    fig.suptitle(f"{run.scenario.name}: emulator test ({len(test.test_runs)} held-out runs)",
                 fontsize=9)
    save_figure(fig, path, dpi=110)
    return path


def plot_heldout(run: CalibrationRun, folder: Path) -> list[Path]:
    """Held-out days per output at the scenario's resolution: measured vs predictions."""
    resolution = run.scenario.resolution
    physical = run.physical.get(resolution)
    prior = run.prior.get(resolution)
    if physical is None:
        return []
    paths = []
    for output in pd.unique(physical.rows["output"]):
        mine = (physical.rows["output"] == output).to_numpy()
        times = physical.rows["time"][mine]
        fig = Figure(figsize=(9, 3.4), layout="constrained")
        ax = fig.subplots()
        prior_mine = (prior.rows["output"] == output).to_numpy()
        lo, hi = np.quantile(prior.simulated[prior_mine], [0.05, 0.95], axis=1)
        ax.fill_between(times, lo, hi, color="0.85", label="prior 90 %")
        if physical.simulated.shape[1] > 1:
            draws = physical.simulated[mine, :-1]
            lo, hi = np.quantile(draws, [0.05, 0.95], axis=1)
            ax.fill_between(times, lo, hi, color="tab:blue", alpha=0.35,
                            label="posterior physical 90 %")
            ax.plot(times, draws.mean(axis=1), color="tab:blue", lw=1.2,
                    label="posterior physical mean")
        if run.predictive is not None:
            rows = run.paired.rows.iloc[run.heldout_rows]
            gp = (rows["output"] == output).to_numpy()
            if gp.any():
                lo, hi = np.quantile(run.predictive["samples"][:, gp], [0.05, 0.95], axis=0)
                ax.plot(rows["time"][gp], lo, color="tab:orange", lw=0.8, ls=":")
                ax.plot(rows["time"][gp], hi, color="tab:orange", lw=0.8, ls=":",
                        label="KOH predictive 90 %")
        ax.plot(times, physical.simulated[mine, -1], color="tab:red", lw=1, ls="--",
                label="deterministic")
        ax.plot(times, physical.observed[mine], color="black", lw=1.3, marker=".", ms=3,
                label="measured")
        ax.set_title(f"{run.scenario.name}: held-out {resolution} {output}", fontsize=9)
        ax.legend(fontsize=7, ncol=3)
        ax.grid(alpha=0.3)
        path = inside(folder, f"heldout_{output}_{resolution}.png")
        save_figure(fig, path, dpi=110)
        paths.append(path)
    return paths


def plot_trace(run: CalibrationRun, path: Path) -> Path:
    """Trace of every sampled quantity per chain (non-centred scale)."""
    from bpsflow.calibration.bayes import scalar_draws

    draws = scalar_draws(run.posterior, run.labels)
    fig, axes = _grid(len(draws), 3.0, 1.8)
    for ax, (name, values) in zip(axes, draws.items()):
        for chain in values:
            ax.plot(chain, lw=0.4)
        rhat = run.convergence.per_quantity[name]["rhat"]
        ax.set_title(f"{name} (R-hat {rhat:.3f})", fontsize=7)
        ax.tick_params(labelsize=6)
    # the sampler's own coordinates, not the inputs' units: said on the figure itself
    fig.suptitle("NUTS traces on the sampler's scale: calibration inputs as standard-normal z "
                 "(z = Φ⁻¹ of the prior CDF), δ and ε hyperparameters as logarithms; the "
                 "inputs' own values are in prior_posterior.png", fontsize=7)
    save_figure(fig, path, dpi=100)
    return path
