"""Benchmark: `bpsflow run` throughput against a bare EnergyPlus loop on the same IDFs.

All sides run the same instances (IDF per season, weather and boundary
files) at the same parallelism. The tool's side is the real command line, end
to end: writing every instance, running EnergyPlus, reading the SQLite
outputs, the manifest, results.parquet and the figures; once on the local
engine and once on the Dask engine (``--engine dask``: the command starts a
``LocalCluster`` of ``--jobs`` worker processes, counted in its time). The bare
side is a thread pool that only starts the `energyplus` binary on pre-written
inputs. Ratio = bare seconds / tool seconds (= tool instances/s ÷ bare
instances/s).

The sides alternate over ``--rounds`` rounds, the order reversed every other
round (bare, local, dask, dask, local, bare, ...), and each ratio is of the
summed times: a shared machine's drift falls on every side alike.

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
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--work", type=Path, default=WORK / "throughput")
    args = parser.parse_args()
    config_path = ROOT / "configs" / "i600.yaml"
    work = args.work.resolve()
    shutil.rmtree(work, ignore_errors=True)
    tool_dir, bare_dir = work / "tool", work / "bare"
    bps = Path(sys.executable).with_name("bpsflow")
    subprocess.run([str(bps), "sample", str(config_path), "--run-dir", str(tool_dir),
                    "--samples", str(args.instances)], check=True, stdout=subprocess.DEVNULL)

    # Bare loop inputs: the same instances, written before the clock starts.
    config = load_config(config_path, {"execution": {"run_dir": str(tool_dir)}})
    samples = read_samples(tool_dir)
    binary = find_energyplus(config.model.energyplus)
    idd = idd_path(binary)
    jobs_list = []
    for instance, row in samples.iterrows():
        files = write_instance(config, row.to_dict(), bare_dir / f"{instance:06d}", idd)
        jobs_list += [(idf, files.weather, idf.parent) for idf in files.idfs.values()]

    def bare() -> float:
        started = time.perf_counter()
        with ThreadPoolExecutor(max_workers=args.jobs) as pool:
            outcomes = list(pool.map(lambda job: run_energyplus(binary, *job), jobs_list))
        assert all(o.ok for o in outcomes), [o.error for o in outcomes if not o.ok][:2]
        return time.perf_counter() - started

    def tool(engine: str, run_dir: Path) -> float:
        shutil.rmtree(run_dir, ignore_errors=True)
        subprocess.run([str(bps), "sample", str(config_path), "--run-dir", str(run_dir),
                        "--samples", str(args.instances)], check=True, stdout=subprocess.DEVNULL)
        started = time.perf_counter()
        subprocess.run([str(bps), "run", str(config_path), "--run-dir", str(run_dir),
                        "--jobs", str(args.jobs), "--engine", engine, "--no-progress"],
                       check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        seconds = time.perf_counter() - started
        assert (pd.read_parquet(run_dir / "manifest.parquet")["status"] == "ok").all()
        return seconds

    times: dict[str, list[float]] = {"bare": [], "local": [], "dask": []}
    for round_number in range(args.rounds):
        order = ["bare", "local", "dask"]
        for side in order if round_number % 2 == 0 else order[::-1]:
            seconds = bare() if side == "bare" else tool(side, work / side)
            times[side].append(seconds)
            print(f"round {round_number + 1}: {side} {seconds:.1f} s", flush=True)
    bare_seconds, tool_seconds = sum(times["bare"]), sum(times["local"])
    dask_seconds = sum(times["dask"])
    tool_dir = work / "local"
    peak_mib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024

    manifest = pd.read_parquet(tool_dir / "manifest.parquet")
    n = len(samples)
    command = f"python bench/run_throughput.py --instances {n} --jobs {args.jobs}"
    detail = {"instances": n, "runs_per_instance": len(config.model.periods),
              "rounds": args.rounds, "bare_seconds": [round(t, 2) for t in times["bare"]]}
    record("run_throughput_ratio", bare_seconds / tool_seconds, "ratio", ">= 0.95", command,
           tool_seconds=[round(t, 2) for t in times["local"]], **detail)
    record("dask_throughput_ratio", bare_seconds / dask_seconds, "ratio", ">= 0.90", command,
           dask_seconds=[round(t, 2) for t in times["dask"]],
           cluster=f"LocalCluster, {args.jobs} single-threaded worker processes, started by "
                   "the command (its start-up counted)", **detail)
    record("idf_write_seconds_per_instance", manifest["write_seconds"].median(), "s", "small next to "
           f"EnergyPlus's own {manifest['simulate_seconds'].median():.2f} s per instance", command)
    record("output_read_seconds_per_instance", manifest["read_seconds"].median(), "s",
           "small next to EnergyPlus's own seconds", command)
    record("energyplus_seconds_per_instance", manifest["simulate_seconds"].median(), "s",
           "reference (two 18-day season runs)", command)
    record("run_peak_memory_mib", peak_mib, "MiB", "largest process of `bpsflow run`", command)
    shutil.rmtree(bare_dir, ignore_errors=True)
    for side in ("local", "dask"):
        shutil.rmtree(work / side, ignore_errors=True)


if __name__ == "__main__":
    main()
