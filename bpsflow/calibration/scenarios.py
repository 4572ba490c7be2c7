"""Data scenarios (seed Table 4.1, Figures 4.8–4.9): which data inform which parameters.

Every scenario (which outputs, daily or hourly) is calibrated on the same
design runs; the comparison table has one row per scenario with the
posterior contraction of every calibration parameter (``1 - posterior 90 %
width / prior 90 % width``) and the held-out accuracy of the calibrated
physical model — per output at daily and hourly resolution — next to the
deterministic baseline's. That table is the data-informativeness result.

Files: ``scenarios.csv``, ``scenarios.json`` and ``figures/scenarios.png``
in the calibration folder; each scenario's own files under
``scenarios/<name>/``.
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from bpsflow.calibration.report import parameter_table
from bpsflow.calibration.workflow import CalibrationRun
from bpsflow.files import save_figure, write_csv, write_json

SCENARIOS_CSV = "scenarios.csv"
SCENARIOS_JSON = "scenarios.json"


def comparison_row(run: CalibrationRun) -> dict:
    """One scenario's line of the comparison table."""
    row: dict = {"scenario": run.scenario.name, "outputs": "+".join(run.scenario.outputs),
                 "resolution": run.scenario.resolution, "observations": len(run.obs_rows)}
    if run.convergence is not None:
        post = run.posterior
        row.update(converged=run.convergence.converged, rhat_max=run.convergence.rhat_max,
                   min_ess_per_second=min(run.convergence.ess_bulk_min,
                                          run.convergence.ess_tail_min) / post.seconds,
                   steps_per_iteration=float(post.num_steps.mean()), mcmc_seconds=post.seconds)
    for entry in parameter_table(run):
        if "contraction" in entry:
            row[f"contraction:{entry['name']}"] = entry["contraction"]
        if "truth_in_90" in entry:
            row[f"truth_in_90:{entry['name']}"] = entry["truth_in_90"]
    for record in run.heldout.to_dict("records"):
        if record["model"] not in ("bayes_physical", "deterministic_physical", "prior"):
            continue
        temperature = record["cv_rmse"] is None or not np.isfinite(record["cv_rmse"])
        metric, value = ("rmse", record["rmse"]) if temperature else ("cv_rmse", record["cv_rmse"])
        row[f"{record['model']}:{record['output']}:{record['resolution']}:{metric}"] = value
    return row


def comparison_table(runs: list[CalibrationRun]) -> pd.DataFrame:
    return pd.DataFrame([comparison_row(r) for r in runs])


def write_comparison(runs: list[CalibrationRun], out_dir: Path) -> dict[str, Path]:
    """Write the comparison table (CSV, JSON) and figure."""
    out_dir.mkdir(parents=True, exist_ok=True)
    table = comparison_table(runs)
    paths = {"csv": out_dir / SCENARIOS_CSV, "json": out_dir / SCENARIOS_JSON,
             "figure": out_dir / "figures" / "scenarios.png"}
    write_csv(table, paths["csv"], index=False, float_format="%.6g")
    # through pandas' JSON first: the file has always held its number and time formats
    write_json(paths["json"], json.loads(table.to_json(orient="records")))
    paths["figure"].parent.mkdir(exist_ok=True)
    plot_comparison(runs, paths["figure"])
    return paths


def plot_comparison(runs: list[CalibrationRun], path: Path) -> Path:
    """Left: posterior 90 % intervals per parameter and scenario on the prior's scale
    (seed Figure 4.8). Right: held-out CV(RMSE) or RMSE per scenario (Figure 4.9)."""
    parameters = runs[0].parameters
    # a bare Figure (no pyplot): renders headless with Agg, no global backend choice
    fig = Figure(figsize=(12, 0.45 * len(parameters) + 2.2), layout="constrained")
    left, right = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.3, 1]})
    colours = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    offsets = np.linspace(-0.3, 0.3, len(runs)) if len(runs) > 1 else [0.0]
    for k, run in enumerate(runs):
        for j, entry in enumerate(parameter_table(run)):
            prior = entry["prior"]
            post = entry.get("posterior")
            if post is None:
                continue

            def scaled(v: float, prior: dict = prior) -> float:
                return (v - prior["q05"]) / prior["width90"]

            left.plot([scaled(post["q05"]), scaled(post["q95"])], [j + offsets[k]] * 2,
                      color=colours[k % len(colours)], lw=3,
                      label=run.scenario.name if j == 0 else None)
            if "truth" in entry:
                left.plot(scaled(entry["truth"]), j + offsets[k], "k|", ms=8)
    left.axvspan(0, 1, color="0.92", zorder=0, label="prior 90 %")
    left.set_yticks(range(len(parameters)), [p.name for p in parameters], fontsize=7)
    left.set_xlabel("posterior 90 % interval, prior 90 % interval = [0, 1]")
    left.legend(fontsize=7)
    table = comparison_table(runs)
    metrics = [c for c in table.columns if c.startswith(("bayes_physical:",
                                                         "deterministic_physical:"))]
    keys = sorted({c.split(":", 1)[1] for c in metrics})
    width = 0.8 / max(len(runs), 1)
    for k, run in enumerate(runs):
        row = table.iloc[k]
        bayes = [row.get(f"bayes_physical:{key}", np.nan) for key in keys]
        det = [row.get(f"deterministic_physical:{key}", np.nan) for key in keys]
        x = np.arange(len(keys)) + (k - (len(runs) - 1) / 2) * width
        right.bar(x, bayes, width, color=colours[k % len(colours)], label=run.scenario.name)
        right.plot(x, det, "kx", ms=5, label="deterministic" if k == 0 else None)
    right.set_xticks(range(len(keys)), [k.replace(":", "\n") for k in keys], fontsize=6)
    right.set_ylabel("held-out CV(RMSE) [-] or RMSE [°C]")
    right.legend(fontsize=7)
    save_figure(fig, path, dpi=110)
    return path
