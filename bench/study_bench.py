"""Benchmark: the Table 3.5-style validation study at the source's scale, timed, on both backends.

Runs ``make study-energyplus`` and ``make study`` (the surrogate) as a user
would: 2000 baseline instances × 6 tests, the truth's detailed measurements,
``bpsflow refine``, 2000 refined instances, and ``bpsflow validate`` of both
(seed §3.5–3.6, Table 3.5). Records the wall minutes of each
(``i600_study_energyplus_minutes``, goal ≤ 30 on 2 cores) and writes the two
validation tables side by side to ``bench/study_table.md``: per test, the
threshold (q = 0.9 quantile of the refined ensemble's nMCRPS / MCRPS), the
type II risk of the baseline ensemble and the reduced risk (q − type II).

    python bench/study_bench.py [--jobs 2] [--backends energyplus surrogate]

The study's size is ``configs/i600_study.yaml``'s (2000 instances per ensemble).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from benchlib import record  # noqa: E402

TARGETS = {"energyplus": "study-energyplus", "surrogate": "study"}
COLUMNS = ["test", "output", "threshold", "type_ii_risk", "reduced_risk"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--backends", nargs="+", default=["energyplus", "surrogate"],
                        choices=list(TARGETS))
    args = parser.parse_args()
    from bpsflow.config import load_config

    samples = load_config(ROOT / "configs" / "i600_study.yaml").design.samples
    command = f"python bench/study_bench.py --jobs {args.jobs} --backends {' '.join(args.backends)}"
    tables = {}
    for backend in args.backends:
        started = time.perf_counter()
        subprocess.run(["make", TARGETS[backend], f"JOBS={args.jobs}"], cwd=ROOT, check=True)
        minutes = (time.perf_counter() - started) / 60
        table = pd.read_csv(ROOT / "runs" / f"study_{backend}" / "refined" / "validation.csv")
        tables[backend] = table
        record(f"i600_study_{backend}_minutes", minutes, "min",
               "<= 30" if backend == "energyplus" else "reported", command,
               samples=samples, jobs=args.jobs,
               instances=2 * samples, test_runs=2 * samples * len(table),
               mean_reduced_risk=round(float(table["reduced_risk"].mean()), 4),
               mean_type_ii_risk=round(float(table["type_ii_risk"].mean()), 4))
    lines = ["# Table 3.5-style validation study: both backends", "",
             f"`{command}` — {samples} baseline + {samples} refined instances; "
             "threshold = q 0.9 quantile of the refined ensemble's scores against the truth's "
             "measurements (nMCRPS, or MCRPS in °C for temperatures); type II = share of the "
             "baseline ensemble below it; reduced risk = q − type II (seed §3.6.2).", ""]
    merged = None
    for backend, table in tables.items():
        part = table[COLUMNS].rename(columns={c: f"{c} ({backend})" for c in COLUMNS[2:]})
        merged = part if merged is None else merged.merge(part, on=["test", "output"])
    if merged is not None:
        header = "| " + " | ".join(merged.columns) + " |"
        lines += [header, "|" + "---|" * len(merged.columns)]
        for row in merged.itertuples(index=False):
            lines.append("| " + " | ".join(f"{v:.4g}" if isinstance(v, float) else str(v)
                                           for v in row) + " |")
    (HERE / "study_table.md").write_text("\n".join(lines) + "\n")
    print(f"table: {HERE / 'study_table.md'}")


if __name__ == "__main__":
    main()
