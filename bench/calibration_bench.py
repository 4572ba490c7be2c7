"""Calibration benchmark: time, convergence and recovery of known truth (DESIGN.md §11).

On the shipped example (``configs/calibration.yaml``: 840 surrogate runs, nine
calibration parameters, four weeks calibrating and one held out):

(1) daily heating energy (28 observations): wall time of the whole
    ``bpsflow calibrate`` (design runs, emulator fit, deterministic baseline,
    NUTS, physical re-runs, report), NUTS seconds, min ESS/s, R-hat, steps per
    iteration, emulator hold-out R², held-out CV(RMSE) Bayes vs deterministic;
(2) hourly heating power and cell air temperature (300 observations): the same;
(3) ``--truths`` synthetic truths with θ drawn from its prior (other inputs at
    nominal, Table 3.3 sensor noise): the share of calibration parameters whose
    90 % posterior interval contains the true value, over all truths, and the
    held-out CV(RMSE) of the calibrated physical model, Bayes vs deterministic.

    python bench/calibration_bench.py [--truths 5] [--skip-hourly]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bpsflow.calibration.bayes import configure_jax  # noqa: E402

configure_jax(4)

import numpy as np  # noqa: E402
from rich.console import Console  # noqa: E402

from bpsflow.calibration.command import apply_overrides, calibrate  # noqa: E402
from bpsflow.calibration.design import calibration_parameters, unit_to_values  # noqa: E402
from bpsflow.calibration.report import parameter_table  # noqa: E402
from bpsflow.calibration.workflow import settings_of  # noqa: E402
from bpsflow.config import load_config  # noqa: E402
from bpsflow.synth import Truth, load_truth, synthesize  # noqa: E402

from benchlib import record, scratch  # noqa: E402

CONFIG = ROOT / "configs" / "calibration.yaml"
TRUTH = ROOT / "configs" / "calibration_truth.yaml"
COMMAND = "python bench/calibration_bench.py"


def _load(run_dir: Path):
    return load_config(CONFIG, {"execution": {"run_dir": str(run_dir)}})


def _heldout(run, model: str, output: str = "heating_power_w") -> float:
    rows = run.heldout[(run.heldout["model"] == model) & (run.heldout["output"] == output)
                       & (run.heldout["resolution"] == run.scenario.resolution)]
    return float(rows["cv_rmse"].iloc[0])


def _one(work: Path, measured: Path, truth: Path | None, quiet: Console, **overrides):
    config = _load(work)
    settings = apply_overrides(settings_of(config), **overrides)
    started = time.perf_counter()
    outcome = calibrate(config, measured, settings=settings, truth_path=truth,
                        out=work / "calibration", show_progress=False, console=quiet)
    return outcome.runs[0], time.perf_counter() - started


def _report_speed(prefix: str, label: str, run, seconds: float, goal_seconds: str) -> None:
    post, conv = run.posterior, run.convergence
    ess = min(conv.ess_bulk_min, conv.ess_tail_min)
    extra = {"observations": len(run.obs_rows), "rhat_max": conv.rhat_max,
             "ess_bulk_min": conv.ess_bulk_min, "ess_tail_min": conv.ess_tail_min,
             "mcmc_seconds": post.seconds, "divergences": conv.divergences,
             "converged": conv.converged, "chain_method": post.chain_method,
             "likelihood": "lowrank" if run.koh.lowrank else "exact",
             "load_average_1min": os.getloadavg()[0]}
    record(f"{prefix}seconds", seconds, "s", goal_seconds,
           f"{COMMAND} ({label})", **extra)
    record(f"{prefix}min_ess_per_second", ess / post.seconds, "ESS/s",
           ">= 5 with R-hat <= 1.01", f"{COMMAND} ({label})", **extra)
    record(f"{prefix}steps_per_iteration", float(post.num_steps.mean()), "leapfrog steps",
           "as few as the geometry allows", f"{COMMAND} ({label})",
           warmup_steps_per_iteration=float(post.warmup_num_steps.mean()))
    record(f"{prefix}rhat_max", conv.rhat_max, "", "<= 1.01", f"{COMMAND} ({label})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--truths", type=int, default=5)
    parser.add_argument("--skip-hourly", action="store_true")
    parser.add_argument("--work", type=Path, default=None)
    args = parser.parse_args()
    quiet = Console(file=open(os.devnull, "w"))
    work = args.work or scratch("calibration-")
    print(f"work folder: {work}")

    # the shipped truth
    config = _load(work)
    measured = synthesize(config, load_truth(TRUTH, config), work / "truth", backend="surrogate")
    truth_json = work / "truth" / "truth.json"

    run, seconds = _one(work, measured, truth_json, quiet)
    _report_speed("calibration_", "daily heating energy, 28 observations", run, seconds,
                  "<= 180 s on 2 cores")
    record("emulator_holdout_r2", run.emulator.test.r2, "", ">= 0.99",
           f"{COMMAND} (daily)", rmse_w=run.emulator.test.per_output["heating_power_w"]["rmse"],
           test_runs=len(run.emulator.test.test_runs))
    record("calibration_heldout_cvrmse_bayes", _heldout(run, "bayes_physical"), "fraction",
           "compare with calibration_heldout_cvrmse_deterministic",
           f"{COMMAND} (daily, shipped truth)",
           note="posterior draws re-run on the physical model, CV(RMSE) of their mean, daily "
                "heating energy of the held-out week")
    record("calibration_heldout_cvrmse_deterministic", _heldout(run, "deterministic_physical"),
           "fraction", "reference for calibration_heldout_cvrmse_bayes",
           f"{COMMAND} (daily, shipped truth)")

    if not args.skip_hourly:
        run, seconds = _one(work, measured, truth_json, quiet, resolution="hourly",
                            outputs=["heating_power_w", "zone_air_temperature_c"])
        _report_speed("calibration_hourly_", "hourly heating + air temperature, 300 "
                      "observations", run, seconds, "<= 900 s on 2 cores")
        record("emulator_hourly_holdout_r2", run.emulator.test.r2, "", ">= 0.99",
               f"{COMMAND} (hourly)")

    # recovery of known truth over truths drawn from the prior
    parameters = calibration_parameters(config, settings_of(config))
    rng = np.random.default_rng(2024)
    covered = total = 0
    bayes_cv, det_cv, per_truth = [], [], []
    for k in range(args.truths):
        values = unit_to_values(rng.uniform(0.05, 0.95, size=(1, len(parameters))), parameters)[0]
        truth = Truth(values={p.name: float(v) for p, v in zip(parameters, values)}, seed=100 + k)
        folder = work / f"truth_{k}"
        measured_k = synthesize(_load(work), truth, folder, backend="surrogate")
        run, _ = _one(work, measured_k, folder / "truth.json", quiet)
        table = parameter_table(run)
        inside = [entry["truth_in_90"] for entry in table]
        covered += sum(inside)
        total += len(inside)
        bayes_cv.append(_heldout(run, "bayes_physical"))
        det_cv.append(_heldout(run, "deterministic_physical"))
        per_truth.append({"truth": k, "covered": int(sum(inside)), "parameters": len(inside),
                          "converged": run.convergence.converged,
                          "rhat_max": run.convergence.rhat_max,
                          "heldout_cvrmse_bayes": bayes_cv[-1],
                          "heldout_cvrmse_deterministic": det_cv[-1]})
        print(json.dumps(per_truth[-1]))
    if total:
        share = covered / total
        low, high = _binomial_band(total, 0.9)
        record("calibration_truth_coverage_90", share, "fraction",
               f"about 0.9 (binomial 95 % band for {total} intervals: {low:.2f}-{high:.2f})",
               f"{COMMAND} --truths {args.truths}", covered=covered, intervals=total,
               truths=per_truth)
        record("calibration_truths_heldout_cvrmse_bayes", float(np.mean(bayes_cv)), "fraction",
               "compare with calibration_truths_heldout_cvrmse_deterministic",
               f"{COMMAND} --truths {args.truths}", per_truth=bayes_cv)
        record("calibration_truths_heldout_cvrmse_deterministic", float(np.mean(det_cv)),
               "fraction", "reference", f"{COMMAND} --truths {args.truths}", per_truth=det_cv)


def _binomial_band(n: int, p: float) -> tuple[float, float]:
    from scipy import stats

    return stats.binom.ppf(0.025, n, p) / n, stats.binom.ppf(0.975, n, p) / n


if __name__ == "__main__":
    main()
