"""Probabilistic validation: thresholds from the internal ensemble, type I and type II risk.

Seed §3.6.2 (Table 3.5): every instance of the internal (refined) ensemble is
taken as a point prediction and scored against the observations (nMAE; MAE
in °C for temperatures, which are not normalised, DESIGN.md §5). The
validation threshold is the q-quantile of those scores, so a valid model is
rejected with probability about 1 − q (type I risk). Predictions known to be
invalid (the baseline ensemble, or deliberately wrong models) are accepted
when their score is at or under the threshold: that share is the type II
risk, and the reduced risk is q − type II. Beside them: the ensemble's
nMCRPS (eq. 7), NMBE and CV(RMSE) of the ensemble mean (eq. 1–2) and the
ASHRAE Guideline 14 hourly criteria.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from bpsflow import metrics
from bpsflow.alignment import Aligned, align
from bpsflow.config import Config
from bpsflow.files import save_figure, write_csv, write_json
from bpsflow.measured import MeasuredData

TEMPERATURE_UNITS = {"C", "°C", "DEGC", "K"}


def is_temperature(config: Config, output: str) -> bool:
    return config.outputs[output].unit.strip().upper() in TEMPERATURE_UNITS


def instance_scores(aligned: Aligned, temperature: bool) -> np.ndarray:
    """Per-instance point-prediction score: nMAE (–), or MAE (°C) for temperatures."""
    if temperature:
        return np.mean(np.abs(aligned.ensemble - aligned.observed[:, None]), axis=0)
    return np.asarray(metrics.instance_nmae(aligned.observed, aligned.ensemble), dtype=float)


@dataclass
class TestValidation:
    """One row of the validation table, plus the score distributions behind it."""

    row: dict
    scores: np.ndarray
    invalid_scores: np.ndarray | None


def validate_test(config: Config, aligned: Aligned, q: float, estimator: str,
                  invalid: Aligned | None = None) -> TestValidation:
    temperature = is_temperature(config, aligned.output)
    scores = instance_scores(aligned, temperature)
    threshold = metrics.validation_threshold(scores, q)
    mean_prediction = aligned.ensemble.mean(axis=1)
    if temperature:
        crps = metrics.mcrps(aligned.observed, aligned.ensemble, estimator)
        probabilistic = {"metric": "MAE", "metric_unit": "C", "mcrps_c": float(crps),
                         "mbe_c": metrics.mbe(aligned.observed, mean_prediction),
                         "rmse_c": metrics.rmse(aligned.observed, mean_prediction)}
        notes = []
    else:
        crps = metrics.nmcrps(aligned.observed, aligned.ensemble, estimator)
        nmbe = metrics.nmbe(aligned.observed, mean_prediction)
        cv = metrics.cv_rmse(aligned.observed, mean_prediction)
        check = metrics.guideline14_check(nmbe, cv, "hourly")
        probabilistic = {"metric": "nMAE", "metric_unit": "-", "nmcrps": float(crps),
                         "nmbe": float(nmbe), "cv_rmse": float(cv),
                         "guideline14_hourly": "pass" if check.passed else "fail"}
        notes = [n for n in (crps.note, nmbe.note, cv.note) if n]
    row = {"test": aligned.test, "output": aligned.output, "hours": len(aligned.timestamps),
           "instances": aligned.ensemble.shape[1], "q": q,
           "threshold": threshold, **probabilistic, "crps_estimator": estimator}
    invalid_scores = None
    if invalid is not None:
        invalid_scores = instance_scores(invalid, temperature)
        type_ii = metrics.type_ii_risk(threshold, invalid_scores)
        row.update({"invalid_instances": invalid.ensemble.shape[1],
                    "invalid_quantile": metrics.validation_threshold(invalid_scores, q),
                    "type_ii_risk": type_ii, "reduced_risk": metrics.reduced_risk(q, type_ii)})
    row["notes"] = "; ".join(notes)
    return TestValidation(row=row, scores=scores, invalid_scores=invalid_scores)


def validate(config: Config, results: pd.DataFrame, measured: pd.DataFrame, q: float = 0.9,
             estimator: str = "standard", invalid_results: pd.DataFrame | None = None,
             measured_source: Path | str | None = None) -> list[TestValidation]:
    """Validate every test and output of ``config`` against ``measured``."""
    rows = []
    for test in config.model.tests:
        for output in test.outputs:
            aligned = align(config, results, measured, test, output, measured_source)
            invalid = None
            if invalid_results is not None:
                invalid = align(config, invalid_results, measured, test, output, measured_source)
            rows.append(validate_test(config, aligned, q, estimator, invalid))
    return rows


def note_measured(validations: list[TestValidation], measured: MeasuredData) -> None:
    """Add how each output's measurements were aggregated to its rows' notes."""
    for v in validations:
        note = measured.note_for(v.row["output"])
        if note:
            v.row["notes"] = "; ".join(n for n in (note, v.row["notes"]) if n)


def write_outputs(validations: list[TestValidation], out_dir: Path, q: float,
                  measured: dict | None = None) -> dict[str, Path]:
    """``validation.json``, ``validation.csv`` and the score-distribution figure.

    ``measured`` (:meth:`bpsflow.measured.MeasuredData.record`: the file, the
    notes of reading it, the aggregation per column) is recorded in the JSON.
    """
    from bpsflow.simulation.rundir import prepare_run_dir

    # both folders first: a figures path that is a file is refused before anything is written
    prepare_run_dir(out_dir / "figures", where="the validation folder")
    table = pd.DataFrame([v.row for v in validations])
    csv = write_csv(table, out_dir / "validation.csv", index=False, float_format="%.6g")
    payload = {"q": q, "type_i_risk": 1 - q, **({"measured": measured} if measured else {}),
               "tests": [
        {**v.row, "scores": {"valid": np.round(v.scores, 8).tolist(),
                             "invalid": None if v.invalid_scores is None
                             else np.round(v.invalid_scores, 8).tolist()}}
        for v in validations]}
    path = write_json(out_dir / "validation.json", payload)
    figure = plot_scores(validations, out_dir / "figures" / "validation_scores.png")
    return {"json": path, "csv": csv, "figure": figure}


def plot_scores(validations: list[TestValidation], path: Path) -> Path:
    """Per-instance score distributions of both ensembles, with the threshold drawn."""
    path.parent.mkdir(parents=True, exist_ok=True)
    n = len(validations)
    columns = min(3, n)
    rows = int(np.ceil(n / columns))
    # a bare Figure (no pyplot): renders headless with Agg, no global backend choice
    fig = Figure(figsize=(4.2 * columns, 3.2 * rows), layout="constrained")
    axes = fig.subplots(rows, columns, squeeze=False)
    for ax, v in zip(axes.ravel(), validations):
        scores = np.concatenate(
            [v.scores] + ([v.invalid_scores] if v.invalid_scores is not None else []))
        if not np.isfinite(scores).any():
            # a metric undefined for these data (an observation mean near zero): the
            # table's note says why; the panel says there is nothing to draw
            ax.text(0.5, 0.5, f"{v.row['test']}: no finite {v.row['metric']} scores",
                    ha="center", va="center", fontsize=8, transform=ax.transAxes)
            ax.set_axis_off()
            continue
        bins = np.histogram_bin_edges(scores[np.isfinite(scores)], 30)
        if v.invalid_scores is not None:
            ax.hist(v.invalid_scores, bins=bins, color="tab:red", alpha=0.5,
                    label="invalid (baseline)")
        ax.hist(v.scores, bins=bins, color="tab:blue", alpha=0.6, label="internal")
        ax.axvline(v.row["threshold"], color="black", lw=1.5,
                   label=f"threshold (q={v.row['q']:g})")
        title = f"{v.row['test']}"
        if "type_ii_risk" in v.row:
            title += f"\ntype II {v.row['type_ii_risk']:.1%}, reduced {v.row['reduced_risk']:.1%}"
        ax.set_title(title, fontsize=9)
        ax.set_xlabel(f"{v.row['metric']} [{v.row['metric_unit']}]")
        ax.legend(fontsize=7)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    save_figure(fig, path, dpi=110)
    return path


def invalid_ensemble_problems(config: Config, invalid_dir: Path) -> tuple[list[str], list[str]]:
    """Why ``invalid_dir`` cannot serve as ``config``'s known-invalid ensemble, and notes.

    The invalid ensemble is another model's (other distributions, perhaps
    other boundary data) by design, but it must simulate the same tests over
    the same days with the same output definitions, and be a random
    ensemble: a Morris design steps one input at a time from a few points.

    Returns
    -------
    (problems, notes)
        ``problems``: key changes (``model.tests[0].start: 11-08 -> 11-09``)
        or the design's kind, each a reason to refuse; ``notes``: what the
        record cannot confirm, and the instances that failed.
    """
    from bpsflow.calibration.design import CONFIG_FINGERPRINT_FILE
    from bpsflow.design_record import (
        DESIGN_FILE,
        SIMULATION_FILE,
        changed_keys,
        read_design_file,
        read_simulation_record,
        simulation_inputs,
    )
    from bpsflow.sensitivity import SETTINGS_FILE as MORRIS_FILE
    from bpsflow.simulation.rundir import read_manifest

    notes: list[str] = []
    problems: list[str] = []
    design = read_design_file(invalid_dir)
    method = (design or {}).get("inputs", {}).get("design.method") if design else None
    if (Path(invalid_dir) / MORRIS_FILE).is_file():
        method = "morris"
    if method is not None and method != "lhs":
        problems.append(f"its design is {method} (one input stepped at a time), not a random "
                        f"ensemble")
    elif (Path(invalid_dir) / CONFIG_FINGERPRINT_FILE).is_file():
        problems.append("it holds a calibration's runs (a space-filling design over the "
                        "calibrated inputs), not a random ensemble of a model's uncertainty")
    elif design is None:
        notes.append(f"{invalid_dir} has no {DESIGN_FILE}: its samples cannot be confirmed "
                     f"to be a random ensemble")
    manifest = read_manifest(invalid_dir)
    failed = int((manifest["status"] != "ok").sum()) if "status" in manifest else 0
    if failed:
        notes.append(f"{failed} instance(s) of the invalid ensemble failed and are left out "
                     f"of its scores")
    record = read_simulation_record(invalid_dir)
    if record is None:
        notes.append(f"{invalid_dir} has no {SIMULATION_FILE}: its tests and outputs cannot be "
                     f"compared with this config's")
        return problems, notes
    current = simulation_inputs(config)
    keys = ["model.year", "model.tests", "model.timesteps_per_hour"] + \
        [k for k in current if k.startswith("outputs.")]
    problems += changed_keys({k: record["inputs"].get(k, "-") for k in keys},
                             {k: current.get(k, "-") for k in keys})
    return problems, notes
