"""Surrogate stepping time: best of ``--repeats`` simulations of 6 LHS instances per shipped config.

Compare two commits in one session (same machine, same load) by running it
against each checkout's package, e.g.::

    git worktree add /tmp/old REV
    PYTHONPATH=/tmp/old python bench/surrogate_timing.py
    PYTHONPATH=. python bench/surrogate_timing.py
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--configs", nargs="+", default=["diagnosis", "i600"])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    import bpsflow
    from bpsflow.config import load_config
    from bpsflow.sampling import read_samples
    from bpsflow.surrogate.run import simulate_instances

    print(f"bpsflow from {Path(bpsflow.__file__).parent}")
    bps = str(Path(sys.executable).with_name("bpsflow"))
    with tempfile.TemporaryDirectory() as scratch:
        for name in args.configs:
            config_path = ROOT / "configs" / f"{name}.yaml"
            run = Path(scratch) / name
            subprocess.run([bps, "sample", str(config_path), "--run-dir", str(run),
                            "--samples", "6", "--force"], check=True, capture_output=True)
            config, samples = load_config(config_path), read_samples(run)
            seconds = []
            for _ in range(args.repeats):
                started = time.perf_counter()
                simulate_instances(config, samples, run)
                seconds.append(time.perf_counter() - started)
            print(f"{name}: {min(seconds):.3f} s (best of {args.repeats})")


if __name__ == "__main__":
    main()
