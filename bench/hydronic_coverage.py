"""Truth coverage of the hydronic floor's posteriors, over several truths, posterior only.

Runs after ``make hydronic-demo`` (it reuses the demo's screened config and design runs).
For the demo's truth and truths 2, 3, ... (drawn as ``hydronic_bench.py --truths`` draws
them, synthesised on the room-by-room floor), each chosen scenario is calibrated without
the physical re-runs (they do not change the posterior intervals), and the share of the
calibration parameters whose 90 % interval holds the equivalent truth is recorded:
``hydronic_truth_coverage_90_scenarios`` (goal 0.80-0.98).

    python bench/hydronic_coverage.py --truths 3 --scenarios H-BI,H-UI,H-EI
    python bench/hydronic_coverage.py --truths 3 --scenarios H-UI --set discrepancy_per_output=false
"""

from __future__ import annotations

import argparse
import json
import subprocess
from pathlib import Path

import numpy as np
from hydronic_bench import HYDRONIC_MEASURED, ROOT, draw_truth, posterior_runs

from benchlib import record


def truth_data(seed: int) -> tuple[Path, Path]:
    """Measured file and equivalent truth of truth ``seed`` (1: the demo's), synthesised once."""
    if seed == 1:
        folder = ROOT / HYDRONIC_MEASURED.parent
    else:
        work = ROOT / "runs" / "hydronic_truths" / f"seed{seed}"
        folder = work / "data"
        if not (folder / "truth_equivalent.json").is_file():
            truth = draw_truth(seed, work / "truth.yaml")
            subprocess.run([str(ROOT / ".venv" / "bin" / "bpsflow"), "synth",
                            "configs/hydronic_baseline.yaml", "--truth", str(truth),
                            "--equivalent-for", "configs/hydronic.yaml", "--out", str(folder),
                            "--no-progress"], cwd=ROOT, check=True)
    return folder / "measured.csv", folder / "truth_equivalent.json"


def model_truth_data(seed: int) -> tuple[Path, Path]:
    """Truth ``seed``'s data from the calibrated (prototype-room) model itself.

    The calibration parameters take their equivalent truth and every screened-out one its
    nominal value, the value calibration fixes it at: no model-form error and no screening
    error, only the measurement model (noise, the heating meter's steps) and the emulator.
    Coverage lost here is lost to the likelihood, not to the model.
    """
    import yaml

    _, equivalent = truth_data(seed)
    screened = yaml.safe_load((ROOT / "runs" / "hydronic_screened.yaml").read_text())
    # the screened config lists only what screening fixed; the rest keep their priors
    fixed = {p["name"] for p in screened["parameters"]
             if p.get("distribution", {}).get("type") == "constant"}
    values = json.loads(equivalent.read_text())["values"]
    calibrated = set(values) - fixed
    work = ROOT / "runs" / "hydronic_model_truths" / f"seed{seed}"
    work.mkdir(parents=True, exist_ok=True)
    noise = yaml.safe_load((ROOT / "configs" / "hydronic_truth.yaml").read_text())["noise"]
    truth = work / "truth.yaml"
    truth.write_text(yaml.safe_dump({"seed": 2017 + seed, "noise": noise,
                                     "values": {k: v for k, v in values.items()
                                                if k in calibrated}}))
    if not (work / "data" / "measured.csv").is_file():
        subprocess.run([str(ROOT / ".venv" / "bin" / "bpsflow"), "synth",
                        "configs/hydronic.yaml", "--truth", str(truth), "--out",
                        str(work / "data"), "--no-progress"], cwd=ROOT, check=True)
    return work / "data" / "measured.csv", truth


def coverage(seed: int, names: list[str], overrides: dict,
             model_truth: bool = False) -> dict[str, list[bool]]:
    """Per scenario: whether each calibration parameter's 90 % interval holds its truth."""
    from bpsflow.calibration.design import unit_to_values

    measured_path, truth_path = model_truth_data(seed) if model_truth else truth_data(seed)
    out: dict[str, list[bool]] = {}
    for run in posterior_runs(names, overrides, measured_path, truth_path):
        values = unit_to_values(run.unit_draws, run.parameters)
        low, high = np.quantile(values, [0.05, 0.95], axis=0)
        out[run.scenario.name] = [bool(low[j] <= run.truth[p.name] <= high[j])
                                  for j, p in enumerate(run.parameters)]
        print(f"truth {seed} {run.scenario.name}: {sum(out[run.scenario.name])}/"
              f"{len(run.parameters)}", flush=True)
        for j, p in enumerate(run.parameters):
            if not out[run.scenario.name][j]:
                rank = float(np.mean(values[:, j] < run.truth[p.name]))
                print(f"  missed {p.name}: truth {run.truth[p.name]:.4g}, 90 % "
                      f"[{low[j]:.4g}, {high[j]:.4g}], posterior quantile {rank:.3f}", flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--truths", type=int, default=3)
    parser.add_argument("--seeds", default="",
                        help="comma-separated truth seeds to run instead of 1..--truths")
    parser.add_argument("--scenarios", default="H-BI,H-UI,H-EI")
    parser.add_argument("--model-truth", action="store_true",
                        help="data from the calibrated model itself (screened inputs nominal)")
    parser.add_argument("--set", action="append", default=[],
                        help="calibration.bayes override, key=JSON value (SECTION.key: "
                        "another calibration section's, e.g. refinement.runs=60)")
    args = parser.parse_args()
    names = args.scenarios.split(",")
    overrides = {k: json.loads(v) for k, v in (item.split("=", 1) for item in args.set)}
    seeds = [int(s) for s in args.seeds.split(",")] if args.seeds else \
        list(range(1, args.truths + 1))
    per_truth = {seed: coverage(seed, names, overrides, args.model_truth) for seed in seeds}
    covered = sum(sum(v) for t in per_truth.values() for v in t.values())
    total = sum(len(v) for t in per_truth.values() for v in t.values())
    which = f"--seeds {args.seeds}" if args.seeds else f"--truths {args.truths}"
    which += " --model-truth" if args.model_truth else ""
    command = f"python bench/hydronic_coverage.py {which} --scenarios " \
        f"{args.scenarios}" + "".join(f" --set {item}" for item in args.set)
    name = "hydronic_truth_coverage_90_model_truth" if args.model_truth \
        else "hydronic_truth_coverage_90_scenarios"
    # an experiment with overrides must not overwrite the figure of the shipped config
    name += "".join("_" + key.replace(".", "_") for key in sorted(overrides))
    record(name, covered / total, "share", "0.80-0.98",
           command, truths=len(seeds), overrides=overrides,
           per_truth={str(seed): {name: f"{sum(v)}/{len(v)}" for name, v in t.items()}
                      for seed, t in per_truth.items()},
           note="posterior intervals only (no physical re-runs), the demo's design runs")


if __name__ == "__main__":
    main()
