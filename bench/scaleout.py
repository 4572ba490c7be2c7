"""Scale-out on paper, from measurements: projected wall time and efficiency on a Dask cluster.

Measured here (one run, this machine):

- ``dask_task_overhead_ms`` — wall time per task of ``--noop-tasks`` no-op
  tasks on a 2-worker ``LocalCluster``: what the scheduler (and client)
  spend per task, the serial part of dispatch;
- the bytes that cross the network per instance (the task's samples row,
  the result: tidy output rows + the manifest record) and once per worker
  (backend, config and prepared model templates);
- EnergyPlus seconds per instance of the I600 study (two 18-day season runs)
  and of an annual run of the same cell, and the worker's own seconds
  (writing inputs, reading outputs);
- the client's seconds per result: deserialising it (with a shared
  filesystem, the default, the worker has written the instance's
  ``outputs.parquet``; without one the client writes it too, reported), for
  an I600 result and an annual one (8760 hours × the config's outputs), and
  the rate of writing ``results.parquet``.

The model: instances flow through three stages in series, each with its
own rate: the workers (``W / (EnergyPlus + worker seconds)``), the scheduler
(``1 / task overhead``) and the client (``1 / (client seconds + bytes /
bandwidth)``). The slowest sets the pace; the final ``results.parquet``
write and the cluster start-up are added once. Efficiency is the ideal
wall time (EnergyPlus seconds × N / W) over the projected one. Projections
for the Table 3.5 study (2 × 2000 instances) and a 100,000-run annual
study at 8, 64 and 512 workers go to ``bench/results.json``; the figure
(``bench/scaleout.png``) shows efficiency against workers and which stage
binds.

    python bench/scaleout.py
"""

from __future__ import annotations

import argparse
import pickle
import re
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from bpsflow.config import load_config  # noqa: E402
from bpsflow.files import save_figure, write_parquet  # noqa: E402
from bpsflow.sampling import read_samples  # noqa: E402
from bpsflow.simulation import rundir  # noqa: E402
from bpsflow.simulation.backend import get_backend  # noqa: E402
from bpsflow.simulation.energyplus.engine import find_energyplus, idd_path, run_energyplus  # noqa: E402
from bpsflow.simulation.energyplus.instances import write_instance  # noqa: E402
from bpsflow.simulation.ensemble import run_ensemble  # noqa: E402

from benchlib import WORK, record  # noqa: E402

#: The client's network bandwidth the projection assumes (1 Gbit/s Ethernet), bytes/s.
BANDWIDTH_BYTES_S = 125e6
#: Cluster start-up the projection adds (workers joining), s: measured for a LocalCluster.
WORKERS = (8, 64, 512)


def _noop(value: int) -> int:
    return value


def task_overhead_ms(tasks: int) -> float:
    """Wall ms per no-op task on a 2-worker LocalCluster (submission to last result)."""
    from distributed import Client, LocalCluster, wait

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        client.submit(_noop, 0).result()  # warm
        started = time.perf_counter()
        futures = client.map(_noop, range(tasks), pure=False)
        wait(futures)
        seconds = time.perf_counter() - started
    return 1000.0 * seconds / tasks


def annual_energyplus_seconds(config, work: Path) -> float:
    """One annual run of the model's first period's IDF (the run period stretched to a year)."""
    binary = find_energyplus(config.model.energyplus)
    samples = read_samples(config.run_dir)
    files = write_instance(config, samples.iloc[0].to_dict(), work / "annual", idd_path(binary))
    idf = next(iter(files.idfs.values()))
    original = idf.read_text()
    text = re.sub(r"RunPeriod,\s*([^,]*),\s*\d+,\s*\d+,\s*(\d+),\s*\d+,\s*\d+,\s*(\d+),",
                  lambda m: f"RunPeriod,\n  {m.group(1)},\n  1,\n  1,\n  {m.group(2)},\n  12,\n"
                            f"  31,\n  {m.group(2)},", original, count=1)
    assert text != original, "no RunPeriod to stretch"
    idf.write_text(text)
    outcome = run_energyplus(binary, idf, files.weather, idf.parent)
    assert outcome.ok, outcome.error
    return outcome.seconds


def project(n: int, workers: np.ndarray, energyplus_s: float, worker_s: float, task_ms: float,
            client_s: float, result_bytes: float, rows: float, parquet_rows_s: float,
            startup_s: float) -> dict[str, np.ndarray]:
    """Projected wall seconds, efficiency and the binding stage for ``n`` instances."""
    rates = {"workers": workers / (energyplus_s + worker_s),
             "scheduler": np.full(workers.shape, 1000.0 / task_ms),
             "client": np.full(workers.shape, 1.0 / (client_s + result_bytes / BANDWIDTH_BYTES_S))}
    stacked = np.vstack(list(rates.values()))
    rate = stacked.min(axis=0)
    binding = np.array(list(rates))[stacked.argmin(axis=0)]
    wall = n / rate + n * rows / parquet_rows_s + startup_s
    ideal = n * energyplus_s / workers
    return {"wall_s": wall, "efficiency": ideal / wall, "binding": binding, **rates}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--noop-tasks", type=int, default=4000)
    parser.add_argument("--work", type=Path, default=WORK / "scaleout")
    args = parser.parse_args()
    work = args.work.resolve()
    shutil.rmtree(work, ignore_errors=True)
    command = "python bench/scaleout.py"

    overhead_ms = task_overhead_ms(args.noop_tasks)
    record("dask_task_overhead_ms", overhead_ms, "ms", "reported", command,
           tasks=args.noop_tasks, cluster="LocalCluster, 2 single-threaded worker processes; "
           "client, scheduler and workers on the same 2 cores")

    # A few real instances, for the per-instance seconds and sizes.
    config = load_config(ROOT / "configs" / "i600.yaml",
                         {"execution": {"run_dir": str(work / "run"), "jobs": 2},
                          "design": {"samples": 12}})
    from bpsflow.sampling import sample, write_design

    write_design(sample(config), config.run_dir)
    from bpsflow.boundary import ensure_sequences

    ensure_sequences(config)
    backend = get_backend("energyplus")
    backend.check(config)
    samples = read_samples(config.run_dir)
    summary = run_ensemble(config, samples, backend, show_progress=False)
    assert summary.ok == len(samples)
    manifest = rundir.read_manifest(config.run_dir)
    energyplus_s = float(manifest["simulate_seconds"].median())
    worker_s = float((manifest["write_seconds"] + manifest["read_seconds"]).median())
    results = rundir.read_results(config.run_dir)
    one = results[results["instance"] == 0].reset_index(drop=True)
    records = rundir.manifest_records(config.run_dir)
    result_bytes = len(pickle.dumps(([records[0]], {0: one})))
    task_bytes = len(pickle.dumps((samples.loc[[0]], config.run_dir, False)))
    shared_bytes = len(pickle.dumps((backend, config, None, backend.prepare(config))))
    rows_per_instance = len(one)

    def client_seconds(frame: pd.DataFrame, write: bool) -> float:
        """The client's seconds per result: deserialise it (and write it, without shared files)."""
        payload = pickle.dumps(([records[0]], {0: frame}))
        started = time.perf_counter()
        for _ in range(10):
            _, outputs = pickle.loads(payload)
            if write:
                rundir.write_instance_outputs(work / "client", 0, outputs[0])
        return (time.perf_counter() - started) / 10

    outputs = len(config.outputs)
    annual_rows = 8760 * outputs
    annual = pd.concat([one] * (annual_rows // len(one) + 1), ignore_index=True).iloc[:annual_rows]
    # the default (shared filesystem): the worker writes outputs.parquet, the client only reads
    # the result; without one the client writes it too (reported, not projected)
    client_s = client_seconds(one, write=False)
    client_staged_s = client_seconds(one, write=True)
    annual_client_s = client_seconds(annual, write=False)
    annual_bytes = len(pickle.dumps(([records[0]], {0: annual})))
    big = pd.concat([one.assign(instance=i) for i in range(2000)], ignore_index=True)
    started = time.perf_counter()
    write_parquet(big, work / "collect.parquet")
    parquet_rows_s = len(big) / (time.perf_counter() - started)
    annual_s = annual_energyplus_seconds(config, work)
    common = dict(task_ms=overhead_ms, parquet_rows_s=parquet_rows_s, startup_s=5.0)
    studies = {
        "table35": dict(n=4000, energyplus_s=energyplus_s, worker_s=worker_s, client_s=client_s,
                        result_bytes=result_bytes, rows=rows_per_instance),
        "annual100k": dict(n=100_000, energyplus_s=annual_s, worker_s=worker_s,
                           client_s=annual_client_s, result_bytes=annual_bytes,
                           rows=annual_rows),
    }
    measured = {"energyplus_seconds_per_i600_instance": energyplus_s,
                "worker_tool_seconds_per_instance": worker_s,
                "energyplus_seconds_annual_run": annual_s,
                "task_bytes": task_bytes, "result_bytes_i600": result_bytes,
                "shared_bytes_once_per_worker": shared_bytes,
                "client_seconds_per_result": client_s,
                "client_seconds_per_result_without_shared_files": client_staged_s,
                "client_seconds_per_annual_result": annual_client_s, "annual_result_bytes": annual_bytes,
                "parquet_rows_per_second": parquet_rows_s,
                "bandwidth_assumed_bytes_s": BANDWIDTH_BYTES_S}
    print({k: round(v, 5) for k, v in measured.items()})

    grid = np.unique(np.round(np.logspace(0, 4, 60)).astype(int))
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    figure = Figure(figsize=(8, 4.2), layout="constrained")
    axes = figure.subplots()
    for name, study in studies.items():
        curve = project(workers=grid.astype(float), **study, **common)
        axes.semilogx(grid, curve["efficiency"], label=f"{name} (N={study['n']:,})")
        change = np.flatnonzero(curve["binding"][1:] != curve["binding"][:-1])
        for k in change:
            axes.axvline(grid[k + 1], color="grey", lw=0.6, ls=":")
            axes.annotate(f"{name}: {curve['binding'][k + 1]} binds", (grid[k + 1], 0.05),
                          rotation=90, fontsize=7, color="grey")
        points = project(workers=np.array(WORKERS, dtype=float), **study, **common)
        for workers, wall, efficiency, binding in zip(WORKERS, points["wall_s"],
                                                      points["efficiency"], points["binding"]):
            record(f"scaleout_{name}_efficiency_{workers}_workers", efficiency, "ratio",
                   "reported (projection)", command, projected_wall_minutes=round(wall / 60, 2),
                   binding_stage=str(binding), instances=study["n"], **{
                       k: (round(v, 6) if isinstance(v, float) else v) for k, v in measured.items()})
    axes.set_xlabel("Dask workers (one core each)")
    axes.set_ylabel("efficiency (ideal / projected wall time)")
    axes.set_ylim(0, 1.05)
    axes.legend(loc="lower left")
    axes.set_title("Projected scale-out of bpsflow on Dask, from measurements on 2 cores")
    save_figure(figure, HERE / "scaleout.png", dpi=110)
    print(f"figure: {HERE / 'scaleout.png'}")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
