"""Surrogate benchmark: speed on the I600 ensemble and fidelity against EnergyPlus.

(1) Speed: ``--instances`` (2000) LHS instances of ``configs/i600.yaml`` on the
    surrogate with ``--jobs`` (2) processes -> ``surrogate_i600_2000_seconds``
    and ``surrogate_speedup_vs_energyplus`` (EnergyPlus core-seconds per
    instance from an EnergyPlus run's manifest over surrogate core-seconds
    per instance).
(2) Fidelity: the same LHS instances on both backends (``--energyplus-run DIR``
    reuses an EnergyPlus run's samples, boundary sequences and results;
    otherwise EnergyPlus runs ``--fidelity-instances`` (50) instances here),
    over the evaluated days of each test:
    FF tests: hourly cell air temperature RMSE (°C);
    CT/ST tests: daily heating/cooling energy CV(RMSE), hourly power
    CV(RMSE) and NMBE; every test: Spearman correlation of the per-instance
    test means (does the surrogate rank the ensemble like EnergyPlus?).

    python bench/surrogate_bench.py [--energyplus-run /tmp/r1]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import spearmanr

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bpsflow.boundary import draw_sequences, period_hours, write_sequences  # noqa: E402
from bpsflow.config import load_config, test_dates  # noqa: E402
from bpsflow.sampling import sample, write_design  # noqa: E402
from bpsflow.simulation.backend import get_backend  # noqa: E402
from bpsflow.simulation.ensemble import run_config, run_ensemble  # noqa: E402
from bpsflow.surrogate.run import simulate_instances  # noqa: E402

from benchlib import record, work_root  # noqa: E402


def _design(config, run_dir: Path, samples: int) -> pd.DataFrame:
    config.design.samples = samples
    config.execution.run_dir = run_dir
    design = sample(config)
    write_design(design, run_dir)
    write_sequences(draw_sequences(config.model.boundary, period_hours(config)), run_dir)
    return design.values


def fidelity(config, surrogate: pd.DataFrame, energyplus: pd.DataFrame) -> pd.DataFrame:
    """Per-test and pooled fidelity figures (evaluated days only)."""
    key = ["instance", "test", "output", "timestamp"]
    both = surrogate.merge(energyplus, on=key, suffixes=("_s", "_e"))
    evaluated = []
    for test in config.model.tests:
        _, first_evaluated, _ = test_dates(test, config.model.year)
        part = both[(both.test == test.name) & (both.timestamp > pd.Timestamp(first_evaluated))]
        evaluated.append(part.assign(mode=test.mode))
    both = pd.concat(evaluated, ignore_index=True)
    rows = {}
    groups = [(t.name, both[both.test == t.name]) for t in config.model.tests]
    groups += [("all FF", both[both["mode"] == "free_floating"]),
               ("all CT/ST", both[both["mode"] != "free_floating"])]
    for name, part in groups:
        if part.empty:
            continue
        diff = part.value_s - part.value_e
        row = {"instances": part.instance.nunique()}
        if (part["mode"] == "free_floating").all():
            row["hourly_rmse_c"] = float(np.sqrt((diff ** 2).mean()))
            row["hourly_bias_c"] = float(diff.mean())
        else:
            row["hourly_cvrmse"] = float(np.sqrt((diff ** 2).mean()) / part.value_e.mean())
            row["hourly_nmbe"] = float(diff.sum() / part.value_e.sum())
            day = (part.assign(day=(part.timestamp - pd.Timedelta(hours=1)).dt.date)
                   .groupby(["test", "instance", "day"])[["value_s", "value_e"]].sum())
            row["daily_cvrmse"] = float(np.sqrt(((day.value_s - day.value_e) ** 2).mean())
                                        / day.value_e.mean())
        if not name.startswith("all"):
            means = part.groupby("instance")[["value_s", "value_e"]].mean()
            row["spearman"] = float(spearmanr(means.value_s, means.value_e)[0])
        rows[name] = row
    return pd.DataFrame(rows).T


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default=str(ROOT / "configs" / "i600.yaml"))
    parser.add_argument("--instances", type=int, default=2000)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--fidelity-instances", type=int, default=50)
    parser.add_argument("--energyplus-run", type=Path, default=None,
                        help="an EnergyPlus run directory (samples, sequences, results, manifest)")
    parser.add_argument("--skip-speed", action="store_true")
    args = parser.parse_args()
    command = "python bench/surrogate_bench.py" + (
        f" --energyplus-run {args.energyplus_run}" if args.energyplus_run else "")

    with tempfile.TemporaryDirectory(prefix="surrogate-", dir=work_root()) as tmp:
        tmp = Path(tmp)
        # Fidelity ------------------------------------------------------
        config = load_config(args.config)
        if args.energyplus_run is not None:
            ep_dir = args.energyplus_run.resolve()
            samples = pd.read_parquet(ep_dir / "samples.parquet").set_index("instance")
        else:
            ep_dir = tmp / "energyplus"
            samples = _design(config, ep_dir, args.fidelity_instances)
            print(f"running {len(samples)} instances on EnergyPlus in {ep_dir}")
            run_ensemble(run_config(config, ep_dir), samples, get_backend("energyplus"),
                         jobs=args.jobs, show_progress=True)
        energyplus = pd.read_parquet(ep_dir / "results.parquet")
        manifest = pd.read_parquet(ep_dir / "manifest.parquet")
        ok = manifest[manifest.status == "ok"]
        samples = samples.loc[sorted(set(ok.instance) & set(samples.index))]
        started = time.perf_counter()
        surrogate, _ = simulate_instances(config, samples, ep_dir)
        print(f"surrogate: {len(samples)} instances in {time.perf_counter() - started:.1f} s "
              f"(one process)")
        table = fidelity(config, surrogate, energyplus)
        with pd.option_context("display.width", 200, "display.max_columns", 20):
            print(table.round(4))
        tests = [t for t in table.index if not t.startswith("all")]
        per_test = {t: {k: (None if pd.isna(v) else round(float(v), 4))
                        for k, v in table.loc[t].items()} for t in tests}
        n = int(table["instances"].max())
        ff, cs = table.loc["all FF"], table.loc["all CT/ST"]
        note = dict(instances=n, per_test=per_test)
        record("surrogate_ff_hourly_rmse_c", ff["hourly_rmse_c"], "°C", "< 1.0", command, **note)
        record("surrogate_daily_energy_cvrmse", cs["daily_cvrmse"], "", "< 0.15", command, **note)
        record("surrogate_hourly_energy_cvrmse", cs["hourly_cvrmse"], "", "(reported)", command,
               **note)
        record("surrogate_hourly_energy_nmbe", cs["hourly_nmbe"], "", "(reported)", command,
               **note)
        record("surrogate_rank_spearman_min", table.loc[tests, "spearman"].min(), "",
               "(reported; 1 = same ranking)", command, **note)

        # Speed ---------------------------------------------------------
        if args.skip_speed:
            return
        config = load_config(args.config)
        run_dir = tmp / "speed"
        samples = _design(config, run_dir, args.instances)
        started = time.perf_counter()
        summary = run_ensemble(run_config(config, run_dir), samples, get_backend("surrogate"),
                               jobs=args.jobs, show_progress=True)
        seconds = time.perf_counter() - started
        assert summary.ok == args.instances, summary
        surrogate_core = seconds * args.jobs / args.instances
        ep_core = float(ok.seconds.mean())
        speed_command = f"python bench/surrogate_bench.py --instances {args.instances} " \
                        f"--jobs {args.jobs}"
        record(f"surrogate_i600_{args.instances}_seconds", seconds, "s", "< 60", speed_command,
               jobs=args.jobs, instances=args.instances)
        record("surrogate_speedup_vs_energyplus", ep_core / surrogate_core, "x", "(reported)",
               speed_command, energyplus_core_seconds_per_instance=round(ep_core, 4),
               surrogate_core_seconds_per_instance=round(surrogate_core, 5),
               energyplus_manifest=str(ep_dir / "manifest.parquet"))


if __name__ == "__main__":
    main()
