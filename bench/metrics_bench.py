"""Benchmark: ensemble CRPS throughput of bpsflow.metrics against a reference from PyPI.

Inputs: ``--rows`` observations (default 10⁶) with ``--members``-member
ensembles (default 200), generated chunk by chunk (``--chunk-rows``) from an
explicit seed so memory stays bounded; both implementations score the same
chunks in the same run.

Reference: ``scoringrules.crps_ensemble`` (numpy backend). For the standard
estimator it is timed with ``estimator="qd"`` (its default: exact and
sorting-based, equal to the energy form) on every row. Its energy (``"nrg"``)
and ``"fair"`` estimators build all m² member pairs, so they are timed on the
first ``--pair-rows`` rows only (at most one chunk) and their time is scaled linearly to all rows;
those figures say so in their extra fields.

Agreement: every score of ours must be within 1e-9 (absolute, in the data's
unit, °C here) of the reference's; the script stops otherwise.

Ratio = reference seconds / our seconds, so >= 1 means bpsflow is faster.

    python bench/metrics_bench.py            # 10⁶ × 200
    python bench/metrics_bench.py --rows 100000

scoringrules is a benchmark-only dependency (not in pyproject):
``pip install scoringrules``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bpsflow.metrics import crps_ensemble  # noqa: E402

from benchlib import record  # noqa: E402

AGREEMENT_ABS = 1e-9  # °C
PAIR_BLOCK_ROWS = 500


def temperature_chunk(rows: int, members: int, random_state: np.random.Generator):
    """Observed zone temperatures (°C) and a biased, spread ensemble around them."""
    observed = random_state.normal(21.0, 3.0, size=rows)
    bias = random_state.normal(0.3, 0.5, size=(rows, 1))
    ensemble = observed[:, None] + bias + random_state.normal(0.0, 1.2, size=(rows, members))
    return observed, ensemble


def timed(function, *args, **kwargs):
    started = time.perf_counter()
    value = function(*args, **kwargs)
    return value, time.perf_counter() - started


def check_agreement(ours: np.ndarray, reference: np.ndarray, what: str) -> float:
    difference = float(np.max(np.abs(ours - reference)))
    if not difference <= AGREEMENT_ABS:
        raise SystemExit(f"{what}: bpsflow and the reference differ by {difference:.3g} °C "
                         f"(allowed {AGREEMENT_ABS:g}, absolute)")
    return difference


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=1_000_000)
    parser.add_argument("--members", type=int, default=200)
    parser.add_argument("--chunk-rows", type=int, default=50_000)
    parser.add_argument("--pair-rows", type=int, default=20_000,
                        help="rows (of the first chunk) on which the reference's O(m²) "
                             "estimators are timed")
    parser.add_argument("--seed", type=int, default=20240611)
    args = parser.parse_args()
    args.pair_rows = min(args.pair_rows, args.chunk_rows, args.rows)

    try:
        import scoringrules
    except ImportError:
        raise SystemExit("bench/metrics_bench.py needs the reference CRPS implementation: "
                         "run `pip install scoringrules` in this environment (benchmark only, "
                         "not a bpsflow dependency).") from None
    reference_crps = scoringrules.crps_ensemble

    # Warm up both (imports, first-call dispatch) on a small input.
    warm_y, warm_x = temperature_chunk(100, args.members, np.random.default_rng(0))
    crps_ensemble(warm_y, warm_x)
    reference_crps(warm_y, warm_x, estimator="qd", backend="numpy")

    ours = {"standard": 0.0, "fair": 0.0}
    ours_pair_rows = {"standard": 0.0, "fair": 0.0}
    reference_qd = 0.0
    reference_pairs = {"standard": 0.0, "fair": 0.0}  # nrg / fair on the first pair_rows
    max_difference = {"standard": 0.0, "fair": 0.0}
    mean_crps = 0.0
    for index, start in enumerate(range(0, args.rows, args.chunk_rows)):
        rows = min(args.chunk_rows, args.rows - start)
        observed, ensemble = temperature_chunk(rows, args.members,
                                               np.random.default_rng([args.seed, index]))
        for estimator in ("standard", "fair"):
            scores, seconds = timed(crps_ensemble, observed, ensemble, estimator)
            ours[estimator] += seconds
            if estimator == "standard":
                mean_crps += scores.sum() / args.rows
                reference, seconds = timed(reference_crps, observed, ensemble,
                                           estimator="qd", backend="numpy")
                reference_qd += seconds
                max_difference["standard"] = max(max_difference["standard"], check_agreement(
                    scores, reference, "standard vs scoringrules qd"))
        if index == 0:
            pair_y = observed[:args.pair_rows].copy()
            pair_x = ensemble[:args.pair_rows].copy()

    # The reference's pairwise estimators hold rows × m² values at once: both
    # sides get the same PAIR_BLOCK_ROWS-row blocks, each side timed over all
    # of them in turn.
    pair_rows_done = pair_y.shape[0]
    blocks = [slice(b, b + PAIR_BLOCK_ROWS) for b in range(0, pair_rows_done, PAIR_BLOCK_ROWS)]
    for estimator, name in (("standard", "nrg"), ("fair", "fair")):
        started = time.perf_counter()
        ours_scores = [crps_ensemble(pair_y[b], pair_x[b], estimator) for b in blocks]
        ours_pair_rows[estimator] = time.perf_counter() - started
        started = time.perf_counter()
        reference_scores = [reference_crps(pair_y[b], pair_x[b], estimator=name, backend="numpy")
                            for b in blocks]
        reference_pairs[estimator] = time.perf_counter() - started
        max_difference[estimator] = max(max_difference[estimator], check_agreement(
            np.concatenate(ours_scores), np.concatenate(reference_scores),
            f"{estimator} vs scoringrules {name}"))

    scale = args.rows / pair_rows_done
    command = (f"python bench/metrics_bench.py --rows {args.rows} --members {args.members} "
               f"--chunk-rows {args.chunk_rows} --pair-rows {args.pair_rows}")
    version = getattr(scoringrules, "__version__", "unknown")
    common = {"rows": args.rows, "members": args.members, "chunk_rows": args.chunk_rows,
              "agreement": f"every score within {AGREEMENT_ABS:g} °C (absolute)",
              "reference": f"scoringrules {version} crps_ensemble, numpy backend"}
    print(f"mean CRPS {mean_crps:.4f} °C over {args.rows} × {args.members}; ours: standard "
          f"{ours['standard']:.3f} s, fair {ours['fair']:.3f} s; scoringrules qd "
          f"{reference_qd:.3f} s")
    record("crps_speed_ratio_vs_reference", reference_qd / ours["standard"], "ratio", ">= 1",
           command, **common,
           reference_estimator="qd (exact, sorting-based; timed on all rows)",
           our_estimator="standard", our_seconds=round(ours["standard"], 3),
           reference_seconds=round(reference_qd, 3),
           max_abs_difference=max_difference["standard"])
    record("crps_our_seconds", ours["standard"], "s",
           "informative (standard estimator; see crps_speed_ratio_vs_reference)",
           command, **common, rows_per_second=round(args.rows / ours["standard"]))
    # The reference's pairwise estimators, timed on pair_rows and scaled to all rows.
    for estimator, name in (("standard", "nrg"), ("fair", "fair")):
        record(f"crps_{estimator}_speed_ratio_vs_reference_{name}",
               reference_pairs[estimator] / ours_pair_rows[estimator], "ratio", ">= 1",
               command, **common, reference_estimator=f"{name} (all m² pairs)",
               our_estimator=estimator, timed_rows=pair_rows_done,
               scaled_to_rows=args.rows,
               reference_seconds_scaled=round(reference_pairs[estimator] * scale, 1),
               our_seconds_all_rows=round(ours[estimator], 3),
               max_abs_difference=max_difference[estimator],
               note=f"both sides timed on the first {pair_rows_done} rows, "
                    f"{PAIR_BLOCK_ROWS} rows per call; reference_seconds_scaled = "
                    f"its time there x {scale:g}")


if __name__ == "__main__":
    main()
