"""What keeping XLA's compiled programs on disk saves (``BPSFLOW_JAX_CACHE``).

Each NUTS run compiles its warm-up and sampling loops and the likelihood's
gradient. The benchmark times ``--fits`` Kennedy–O'Hagan fits of the same
shapes (new data each: the repeated truths of a coverage study, a scenario
run again) in fresh processes:

* cache ``off``: every fit compiles;
* cache on, an empty folder (cold): the first fit compiles and fills it, the
  later ones read it back;
* cache on, the same folder again (warm): a later ``bpsflow calibrate``.

Recorded as ratios against ``off`` in ``bench/results.json``.

    python bench/compile_cache_bench.py [--fits 4]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

COMMAND = "python bench/compile_cache_bench.py"


def _fits(count: int) -> list[float]:
    """Seconds per fit of ``count`` same-shaped KOH posteriors on a smooth two-input toy."""
    import numpy as np
    import pandas as pd

    from bpsflow.calibration import bayes
    from bpsflow.calibration.emulator import fit_emulator
    from bpsflow.calibration.settings import BayesSettings
    from bpsflow.sampling import latin_hypercube_unit

    bayes.configure_jax(1)
    rows = 12
    x = np.linspace(0.0, 1.0, rows)

    def simulator(unit: np.ndarray) -> np.ndarray:
        return (np.sin(3 * x)[:, None] * (0.5 + unit[:, 0])[None, :]
                + np.cos(2 * x)[:, None] * unit[:, 1][None, :])

    design = latin_hypercube_unit(40, 2, 0)
    emulator = fit_emulator(pd.DataFrame({"x": x}), pd.Series(["y"] * rows), simulator(design),
                            design, points=300, test_fraction=0.1, random_state=0)
    settings = BayesSettings(chains=1, warmup=100, samples=100, seed=1, likelihood="exact")
    rng = np.random.default_rng(3)
    seconds = []
    for _ in range(count):
        truth = rng.uniform(0.1, 0.9, size=(1, 2))
        observed = simulator(truth)[:, 0] + 0.02 * rng.standard_normal(rows)
        y = emulator.scaling.y(observed, np.array(["y"] * rows))
        started = time.perf_counter()
        data = bayes.koh_data(emulator.grid, np.arange(rows), y, np.arange(2), settings)
        bayes.sample_posterior(data, settings, bayes.initial_values(data, None, 1, 1),
                               timed_warmup=False)
        seconds.append(time.perf_counter() - started)
    return seconds


def _child(cache: str, fits: int) -> list[float]:
    env = {**os.environ, "BPSFLOW_JAX_CACHE": cache}
    done = subprocess.run([sys.executable, __file__, "--child", "--fits", str(fits)], env=env,
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fits", type=int, default=4)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(_fits(args.fits)))
        return

    from benchlib import record, scratch

    folder = scratch("jaxcache-") / "jax"
    off = _child("off", args.fits)
    cold = _child(str(folder), args.fits)
    warm = _child(str(folder), args.fits)
    print(f"seconds per fit: off {off}\n  cold {cold}\n  warm {warm}")
    command = f"{COMMAND} --fits {args.fits}"
    later = sum(cold[1:]) / sum(off[1:])
    record("nuts_compile_cache_repeat_ratio", later, "ratio",
           "< 1 (same-shaped fits after the first, in one process: cache on / off)", command,
           seconds_off=off, seconds_cold=cold)
    record("nuts_compile_cache_new_process_ratio", warm[0] / off[0], "ratio",
           "< 1 (the first fit of a later process: warm cache / off)", command,
           seconds_off=off, seconds_warm=warm)


if __name__ == "__main__":
    main()
