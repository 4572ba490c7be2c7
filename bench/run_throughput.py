"""Benchmark: `bpsflow run` throughput against a bare EnergyPlus loop on the same IDFs.

Both sides run the same prepared instances (IDF per season, weather and
boundary files) at the same parallelism. The tool's side is the real command
line, end to end: writing every instance, running EnergyPlus, reading the
SQLite outputs, the manifest, results.parquet and the figures. The bare side
is a thread pool that only starts the `energyplus` binary on pre-written
inputs. Ratio = bare seconds / tool seconds (= tool instances/s ÷ bare
instances/s).

    python bench/run_throughput.py --instances 60 --jobs 2
"""

from __future__ import annotations

import argparse
import resource
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pandas as pd

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from bpsflow.config import load_config  # noqa: E402
from bpsflow.sampling import read_samples  # noqa: E402
from bpsflow.simulation.energyplus.engine import (  # noqa: E402
    find_energyplus,
    idd_path,
    run_energyplus,
)
from bpsflow.simulation.energyplus.instances import write_instance  # noqa: E402

from benchlib import WORK, record  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--instances", type=int, default=60)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--work", type=Path, default=WORK / "throughput")
    args = parser.parse_args()
    config_path = ROOT / "configs" / "i600.yaml"
    work = args.work.resolve()
    shutil.rmtree(work, ignore_errors=True)
    tool_dir, bare_dir = work / "tool", work / "bare"
    bps = Path(sys.executable).with_name("bpsflow")
    subprocess.run([str(bps), "sample", str(config_path), "--run-dir", str(tool_dir),
                    "--samples", str(args.instances)], check=True)

    # Bare loop inputs: the same instances, written before the clock starts.
    config = load_config(config_path, {"execution": {"run_dir": str(tool_dir)}})
    samples = read_samples(tool_dir)
    binary = find_energyplus(config.model.energyplus)
    idd = idd_path(binary)
    jobs_list = []
    for instance, row in samples.iterrows():
        files = write_instance(config, row.to_dict(), bare_dir / f"{instance:06d}", idd)
        jobs_list += [(idf, files.weather, idf.parent) for idf in files.idfs.values()]

    started = time.perf_counter()
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        outcomes = list(pool.map(lambda job: run_energyplus(binary, *job), jobs_list))
    bare_seconds = time.perf_counter() - started
    assert all(o.ok for o in outcomes), [o.error for o in outcomes if not o.ok][:2]

    started = time.perf_counter()
    subprocess.run([str(bps), "run", str(config_path), "--run-dir", str(tool_dir),
                    "--jobs", str(args.jobs), "--no-progress"], check=True,
                   stdout=subprocess.DEVNULL)
    tool_seconds = time.perf_counter() - started
    peak_mib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024

    manifest = pd.read_parquet(tool_dir / "manifest.parquet")
    assert (manifest["status"] == "ok").all()
    n = len(samples)
    command = f"python bench/run_throughput.py --instances {n} --jobs {args.jobs}"
    detail = {"instances": n, "runs_per_instance": len(config.model.periods),
              "tool_seconds": round(tool_seconds, 2), "bare_seconds": round(bare_seconds, 2)}
    record("run_throughput_ratio", bare_seconds / tool_seconds, "ratio", ">= 0.95", command, **detail)
    record("idf_write_seconds_per_instance", manifest["write_seconds"].median(), "s", "small next to "
           f"EnergyPlus's own {manifest['simulate_seconds'].median():.2f} s per instance", command)
    record("output_read_seconds_per_instance", manifest["read_seconds"].median(), "s",
           "small next to EnergyPlus's own seconds", command)
    record("energyplus_seconds_per_instance", manifest["simulate_seconds"].median(), "s",
           "reference (two 18-day season runs)", command)
    record("run_peak_memory_mib", peak_mib, "MiB", "largest process of `bpsflow run`", command)
    shutil.rmtree(bare_dir, ignore_errors=True)


if __name__ == "__main__":
    main()
