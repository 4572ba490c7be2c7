"""Diagnosis benchmark: hidden effects found, false alarms, detection limit, wall time (issue 7).

On the shipped example (``configs/diagnosis.yaml``: 38 days of hourly heating
power, four fitted parameters, the last week held out) on the surrogate:

(1) one truth per hidden effect (wind infiltration, an office-hours gain, an
    east-facing aperture, a constant leak), a pure parameter error (all solar
    30 % stronger) and a null case: truth vs verdict, driver, extension,
    fitted magnitude, held-out CV(RMSE) and nMCRPS before → after, wall time;
(2) ``--nulls`` null datasets (AR(1) sensor noise only, different seeds): the
    share of false ``model_form`` verdicts;
(3) the detection limit: the wind infiltration coefficient swept over a few
    values, ``--seeds`` noise seeds each: the share of datasets where
    the infiltration law is found; the smallest value found in ≥ 9 of 10;
(4) with ``--energyplus``: the two EnergyPlus cases of the tests (20 days);
(5) with ``--random N``: the randomised benchmark of issue 14 instead of (1)-(4):
    ``N`` truths drawn by ``bench/diagnosis_random.py`` (effect family, shape,
    size in detection limits, season, setpoint regime, noise, model, backend)
    from ``--seed S`` (default: drawn from the clock and printed), plus
    ``--nulls K`` null datasets (default 40); writes ``bench/diagnosis_random.md``
    and the ``diagnose_random_*`` figures. Each finished row is kept in the run's
    scratch folder, so ``--summarise WORK`` scores an interrupted run (the
    figures then say how much of it finished).

Writes ``bench/results.json`` (names ``diagnose_*``) and
``bench/diagnosis_cases.md`` (the table).

    python bench/diagnosis_bench.py [--nulls 30] [--seeds 10] [--energyplus] [--parts cases,nulls,sweep]
    python bench/diagnosis_bench.py --random 60 [--seed S] [--nulls 40] [--backends surrogate,energyplus]
    python bench/diagnosis_bench.py --summarise bench/work/diagnosis-random-XXXX
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
sys.path.insert(0, str(ROOT / "tests"))

from bpsflow.config import load_config  # noqa: E402
from bpsflow.diagnosis.hidden import EXPECTED, MEASURE, make_case, null_measurements  # noqa: E402
from bpsflow.diagnosis.workflow import diagnose, diagnose_many  # noqa: E402
from bpsflow.measured import read_measured  # noqa: E402

from benchlib import record, scratch  # noqa: E402

CONFIG = ROOT / "configs" / "diagnosis.yaml"
COMMAND = "python bench/diagnosis_bench.py"
FITTED_TRUTH = {"glazing_dirt_correction": 0.92, "south_wall_insulation_conductivity": 1.05,
                "wall_stack_coefficient": 1.2, "return_air_offset": -0.2}
CASES = [("wind_infiltration", 0.004, {}), ("office_gain", 150.0, {}),
         ("east_aperture", 1.0, {}), ("constant_infiltration", 0.02, {}),
         (None, 0.0, {"global_irradiance_gain": 1.3}), (None, 0.0, {})]
UNITS = {"wind_infiltration": "m3/s per m/s", "office_gain": "W", "east_aperture": "m2",
         "constant_infiltration": "m3/s"}


def quiet(_text: str) -> None:
    pass


def base_config(work: Path) -> Path:
    import yaml

    path = work / "base.yaml"
    path.write_text(yaml.safe_dump({"extends": str(CONFIG),
                                    "execution": {"run_dir": str(work / "base_run")}}))
    return path


def row(label: str, truth: str, result, seconds: float, expected: str = "") -> dict:
    accepted = [e for e in result.extensions if e.get("accepted")]
    fitted = "; ".join(f"{k} = {v:.4g}" for e in accepted for k, v in e["fitted"].items())
    if result.verdict == "parameter":
        fitted = f"{result.parameter_fit['name']} = {result.parameter_fit['fitted']:.4g}"
    return {"case": label, "truth": truth, "expected": expected, "verdict": result.verdict,
            "driver": result.cause.get("driver"), "extension": result.cause.get("extension"),
            "parameter": result.cause.get("parameter"), "fitted": fitted,
            "cvrmse_before": result.gain["before"], "cvrmse_after": result.gain["after"],
            "nmcrps_before": result.gain["nmcrps_before"],
            "nmcrps_after": result.gain["nmcrps_after"], "seconds": seconds}


def cases_table(work: Path, base: Path) -> list[dict]:
    config = load_config(base)
    rows = []
    for effect, value, extra in CASES:
        label = effect or ("parameter_error" if extra else "null")
        case = make_case(base, work / label, effect, value, {**FITTED_TRUTH, **extra}, seed=3,
                         noise_bound=0.005 if extra else 0.03)
        started = time.perf_counter()
        result = diagnose(config, read_measured(case.measured, config).frame, work / label / "out",
                          backend="surrogate", announce=quiet)
        seconds = time.perf_counter() - started
        if effect:
            truth = f"{effect}: {MEASURE[effect]} = {value:g} {UNITS[effect]}"
            drivers, extension = EXPECTED[effect]
            expected = f"model_form, {'/'.join(drivers)}, {extension}"
        elif extra:
            truth = ", ".join(f"{k} = {v:g}" for k, v in extra.items())
            expected = f"parameter, {next(iter(extra))}"
        else:
            truth, expected = "AR(1) noise only", "none"
        rows.append(row(label, truth, result, seconds, expected))
        print(rows[-1], flush=True)
    return rows


def false_alarms(work: Path, base: Path, count: int) -> tuple[float, float]:
    case = make_case(base, work / "null_clean", None, 0.0, FITTED_TRUTH, seed=0,
                     noise_bound=0.0)
    clean = read_measured(case.measured, load_config(base)).frame
    noisy = null_measurements(clean["heating_power_w"].to_numpy(), list(range(1000, 1000 + count)))
    started = time.perf_counter()
    results = diagnose_many(load_config(base), [clean.assign(heating_power_w=v) for v in noisy],
                            [work / f"null_{i}" for i in range(count)], backend="surrogate",
                            announce=quiet)
    seconds = time.perf_counter() - started
    rate = sum(r.verdict == "model_form" for r in results) / count
    other = sum(r.verdict != "none" for r in results) / count
    record("diagnose_null_false_alarm_rate", rate, "share", "<= 0.10",
           f"{COMMAND} --nulls {count}", datasets=count, any_verdict_rate=other,
           seconds=seconds, noise="AR(1) phi 0.8, std 1 % of the value")
    return rate, other


def detection_limit(work: Path, base: Path, seeds: int,
                    values=(0.0001, 0.0002, 0.0003, 0.0004, 0.0005)) -> dict:
    found = {}
    for value in values:
        case = make_case(base, work / f"wind_{value:g}", "wind_infiltration", value,
                         FITTED_TRUTH, seed=0, noise_bound=0.0)
        clean = read_measured(case.measured, load_config(base)).frame
        noisy = null_measurements(clean["heating_power_w"].to_numpy(),
                                  list(range(2000, 2000 + seeds)))
        results = diagnose_many(load_config(base),
                                [clean.assign(heating_power_w=v) for v in noisy],
                                [work / f"wind_{value:g}_{i}" for i in range(seeds)],
                                backend="surrogate", announce=quiet)
        found[value] = sum(r.cause.get("extension") == EXPECTED["wind_infiltration"][1]
                           for r in results) / seeds
        print(f"wind infiltration {value:g}: found in {found[value]:.0%}", flush=True)
    reliable = [v for v, share in found.items() if share >= 0.9]
    record("diagnose_wind_detection_limit", min(reliable) if reliable else float("nan"),
           "m3/s per m/s", "smallest coefficient found in >= 9 of 10 datasets",
           f"{COMMAND} --seeds {seeds}", found_share={f"{v:g}": s for v, s in found.items()},
           reference="0.004 m3/s per m/s adds ~20 % to the heating power at 5 m/s wind")
    return found


def energyplus_cases(work: Path) -> list[dict]:
    from test_diagnosis import base_config as test_base

    rows = []
    for effect, value in (("wind_infiltration", 0.004), ("office_gain", 150.0)):
        base = test_base(work / f"ep_{effect}", days=20, backend="energyplus", extra={
            "diagnosis": {"output": "heating_power_w", "holdout_days": 5,
                          "parameters": ["glazing_dirt_correction", "return_air_offset"],
                          "parameter_candidates": 1, "gain_blocks": 3, "max_rounds": 2,
                          "suspects": ["global_irradiance_gain", "exterior_wind_coefficient"]}})
        case = make_case(base, work / f"ep_{effect}" / "truth", effect, value,
                         {"glazing_dirt_correction": 0.92, "return_air_offset": -0.2}, seed=3,
                         backend="energyplus")
        started = time.perf_counter()
        result = diagnose(load_config(base), read_measured(case.measured, load_config(base)).frame,
                          work / f"ep_{effect}" / "out", backend="energyplus", jobs=2,
                          announce=quiet)
        seconds = time.perf_counter() - started
        drivers, extension = EXPECTED[effect]
        rows.append(row(f"{effect} (EnergyPlus, 20 days)",
                        f"{effect}: {MEASURE[effect]} = {value:g} {UNITS[effect]}", result,
                        seconds, f"model_form, {'/'.join(drivers)}, {extension}"))
        print(rows[-1], flush=True)
    return rows


def shipped_energyplus(work: Path, jobs: int) -> dict:
    """``bpsflow diagnose configs/diagnosis.yaml --backend energyplus`` as shipped, timed.

    The user's two commands, default settings (every fixed input a suspect,
    no limits): ``synth`` of ``configs/diagnosis_truth.yaml`` (its hidden wind
    leak) on EnergyPlus, then ``diagnose`` of its measurements.
    """
    import json
    import subprocess

    bpsflow = str(Path(sys.executable).parent / "bpsflow")
    truth = work / "shipped_truth"
    subprocess.run([bpsflow, "synth", "diagnosis_truth.yaml", "--truth",
                    "diagnosis_truth_values.yaml", "--backend", "energyplus", "--run-dir",
                    str(work / "shipped_truth_run"), "--out", str(truth)],
                   cwd=ROOT / "configs", check=True)
    started = time.perf_counter()
    done = subprocess.run([bpsflow, "diagnose", "diagnosis.yaml", "--backend", "energyplus",
                           "--measured", str(truth / "measured.csv"), "--out",
                           str(work / "shipped_out"), "--run-dir", str(work / "shipped_run"),
                           "--jobs", str(jobs), "--no-progress"], cwd=ROOT / "configs")
    seconds = time.perf_counter() - started
    record_path = work / "shipped_out" / "diagnosis.json"
    diagnosis = json.loads(record_path.read_text()) if record_path.is_file() else {}
    accepted = [e for e in diagnosis.get("extensions", []) if e.get("accepted")]
    figure = {"exit_code": done.returncode, "wrote_diagnosis_json": record_path.is_file(),
              "verdict": diagnosis.get("verdict"), "cause": diagnosis.get("cause"),
              "fitted": [e["fitted"] for e in accepted], "gain": diagnosis.get("gain"),
              "notes": len(diagnosis.get("notes", [])),
              "truth": "ZoneInfiltration:DesignFlowRate, C = 0.004 m3/s per m/s "
                       "(configs/diagnosis_hidden_effect.idf)"}
    record("diagnose_shipped_energyplus_seconds", seconds, "s",
           "completes with default settings (today 24-105 s with limited suspects)",
           f"{COMMAND} --parts shipped-energyplus --jobs {jobs}", **figure)
    print(f"shipped config on EnergyPlus: {seconds:.0f} s, {figure}", flush=True)
    return figure


def correct(r: dict) -> bool:
    """Verdict, driver and extension (or parameter) as the truth says."""
    verdict, *rest = [part.strip() for part in r["expected"].split(",")]
    if r["verdict"] != verdict:
        return False
    if verdict == "model_form":
        return r["driver"] in rest[0].split("/") and r["extension"] == rest[1]
    if verdict == "parameter":
        return r["parameter"] == rest[0]
    return True


def markdown(rows: list[dict]) -> str:
    lines = ["| case | truth | expected | verdict | driver | extension / parameter | fitted | "
             "held-out CV(RMSE) before → after | nMCRPS before → after | seconds |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['truth']} | {r['expected']} | {r['verdict']} | "
                     f"{r['driver'] or '-'} | {r['extension'] or r['parameter'] or '-'} | "
                     f"{r['fitted'] or '-'} | {r['cvrmse_before']:.2%} → {r['cvrmse_after']:.2%} "
                     f"| {r['nmcrps_before']:.2%} → {r['nmcrps_after']:.2%} | "
                     f"{r['seconds']:.0f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--nulls", type=int, default=None,
                        help="null datasets (default 30; 40 with --random)")
    parser.add_argument("--random", type=int, default=0, metavar="N",
                        help="run the randomised benchmark with N drawn truths instead")
    parser.add_argument("--seed", type=int, default=None,
                        help="seed of --random's draws (default: from the clock, printed)")
    parser.add_argument("--backends", default="surrogate",
                        help="comma-separated backends --random draws from")
    parser.add_argument("--jobs", type=int, default=None, help="parallel runs per diagnosis")
    parser.add_argument("--parallel", type=int, default=1,
                        help="--random: truths diagnosed at once, one process each (surrogate)")
    parser.add_argument("--summarise", type=Path, default=None, metavar="WORK",
                        help="score the rows a --random run in WORK finished (an interrupted "
                             "run too), and write its table and figures")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--energyplus", action="store_true")
    parser.add_argument("--sweep", default="0.0001,0.0002,0.0003,0.0004,0.0005",
                        help="wind infiltration coefficients (m3/s per m/s) to sweep")
    parser.add_argument("--parts", default="cases,nulls,sweep",
                        help="comma-separated: cases, nulls, sweep, shipped-energyplus")
    args = parser.parse_args()
    if args.summarise:
        from diagnosis_random import summarise_work

        summarise_work(args.summarise)
        return
    if args.random:
        from diagnosis_random import main as random_main

        random_main(args.random, args.seed, 40 if args.nulls is None else args.nulls,
                    tuple(args.backends.split(",")), jobs=args.jobs,
                    parallel=args.parallel)
        return
    args.nulls = 30 if args.nulls is None else args.nulls
    parts = set(args.parts.split(","))
    work = scratch("diagnosis-")
    base = base_config(work)
    rows = []
    if "cases" in parts:
        rows = cases_table(work, base)
        surrogate_seconds = [r["seconds"] for r in rows]
        record("diagnose_hidden_effect_accuracy", sum(map(correct, rows)) / len(rows), "share",
               "1.0 (verdict, driver and extension or parameter all right)", COMMAND,
               cases=rows)
        record("diagnose_seconds_surrogate", float(sum(surrogate_seconds) / len(rows)), "s",
               "minutes, not hours", COMMAND, per_case=surrogate_seconds,
               note="one diagnose run of configs/diagnosis.yaml (38 days) on the surrogate")
    if "shipped-energyplus" in parts:
        shipped_energyplus(work, args.jobs or 2)
    if "nulls" in parts:
        false_alarms(work, base, args.nulls)
    if "sweep" in parts:
        detection_limit(work, base, args.seeds,
                        tuple(float(v) for v in args.sweep.split(",")))
    if args.energyplus:
        ep = energyplus_cases(work)
        rows += ep
        record("diagnose_hidden_effect_accuracy_energyplus", sum(map(correct, ep)) / len(ep),
               "share", "1.0", f"{COMMAND} --energyplus", cases=ep)
        record("diagnose_seconds_energyplus", float(sum(r["seconds"] for r in ep) / len(ep)),
               "s", "minutes", f"{COMMAND} --energyplus", per_case=[r["seconds"] for r in ep],
               note="20-day test config, 2 fitted parameters, 2 suspects, 3 gain blocks")
    if rows:
        (ROOT / "bench" / "diagnosis_cases.md").write_text(markdown(rows))
        print(markdown(rows))


if __name__ == "__main__":
    main()
