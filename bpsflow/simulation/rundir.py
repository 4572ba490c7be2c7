"""The run directory: file layout, manifest, results, lock and atomic writes (DESIGN §9).

Layout::

    RUN_DIR/
      config.resolved.yaml   the validated config, paths resolved
      samples.parquet        one row per instance
      boundary_sequences.npz Monte Carlo boundary sequences (when sampled)
      manifest.parquet       instance, status, seconds (write/simulate/read), error, backend
      results.parquet        tidy: instance, test, output, timestamp, value
      run.lock               held while a command runs instances here
      instances/000017/      per instance: outputs.parquet, and what the backend keeps
                             (EnergyPlus: per period eplusout.sql and eplusout.err)

An instance is finished when its ``outputs.parquet`` exists and reads back
(written last, atomically), whatever the manifest says; a file that does not
read back counts as unfinished and the instance runs again.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import pandas as pd

from bpsflow.errors import BpsflowError

MANIFEST_FILE = "manifest.parquet"
RESULTS_FILE = "results.parquet"
INSTANCE_OUTPUTS = "outputs.parquet"
LOCK_FILE = "run.lock"
RESULT_COLUMNS = ["instance", "test", "output", "timestamp", "value"]


@dataclass
class InstanceRecord:
    """One manifest row: how an instance went (seconds are wall time)."""

    instance: int
    status: str
    seconds: float
    write_seconds: float = 0.0
    simulate_seconds: float = 0.0
    read_seconds: float = 0.0
    error: str = ""
    backend: str = ""


MANIFEST_COLUMNS = [f.name for f in fields(InstanceRecord)]


def instance_dir(run_dir: Path, instance: int | str) -> Path:
    """The directory of one instance (``instances/000017``; a text label as it is)."""
    label = f"{instance:06d}" if isinstance(instance, int) else str(instance)
    return Path(run_dir) / "instances" / label


def atomic_parquet(frame: pd.DataFrame, path: Path) -> Path:
    """Write ``frame`` to ``path`` through a temporary file, so a crash never leaves half a file."""
    temporary = path.with_name(path.name + f".{os.getpid()}.tmp")
    frame.to_parquet(temporary, index=False)
    temporary.replace(path)
    return path


def read_instance_outputs(run_dir: Path, instance: int | str) -> pd.DataFrame | None:
    """An instance's tidy outputs, or None when it has none that read back."""
    path = instance_dir(run_dir, instance) / INSTANCE_OUTPUTS
    if not path.is_file():
        return None
    try:
        return pd.read_parquet(path)
    except Exception:  # a truncated or foreign file: the instance is unfinished
        return None


def finished_instances(run_dir: Path, instances: Iterable[int]) -> set[int]:
    """The instances whose outputs file exists and is a readable Parquet file."""
    import pyarrow.parquet as pq

    done = set()
    for i in instances:
        path = instance_dir(run_dir, int(i)) / INSTANCE_OUTPUTS
        if not path.is_file():
            continue
        try:
            pq.read_metadata(path)
        except Exception:  # truncated or corrupt: run it again
            continue
        done.add(int(i))
    return done


def write_instance_outputs(run_dir: Path, instance: int | str, tidy: pd.DataFrame) -> Path:
    """Write one instance's tidy outputs (the mark that it is finished)."""
    directory = instance_dir(run_dir, instance)
    directory.mkdir(parents=True, exist_ok=True)
    return atomic_parquet(tidy[RESULT_COLUMNS].reset_index(drop=True),
                          directory / INSTANCE_OUTPUTS)


def read_manifest(run_dir: Path) -> pd.DataFrame:
    """The manifest, or an empty one when it is missing or does not read back."""
    path = Path(run_dir) / MANIFEST_FILE
    if path.is_file():
        try:
            return pd.read_parquet(path)
        except Exception:  # a partial manifest is rebuilt from the instances' files
            pass
    return pd.DataFrame(columns=MANIFEST_COLUMNS)


def manifest_records(run_dir: Path) -> dict[int, InstanceRecord]:
    """The manifest as records by instance."""
    records = {}
    for row in read_manifest(run_dir).to_dict("records"):
        values = {k: row[k] for k in MANIFEST_COLUMNS if k in row}
        values["instance"] = int(values["instance"])
        records[values["instance"]] = InstanceRecord(**values)
    return records


def write_manifest(run_dir: Path, records: dict[int, InstanceRecord]) -> Path:
    frame = pd.DataFrame([asdict(r) for r in records.values()], columns=MANIFEST_COLUMNS)
    frame = frame.sort_values("instance").reset_index(drop=True)
    return atomic_parquet(frame, Path(run_dir) / MANIFEST_FILE)


def collect_results(run_dir: Path, instances: Iterable[int],
                    fresh: dict[int, pd.DataFrame] | None = None) -> pd.DataFrame:
    """Concatenate the finished instances' outputs into ``results.parquet``.

    ``fresh`` holds outputs already in memory (just simulated); the others
    are read from their instance files.
    """
    fresh = fresh or {}
    frames = []
    for i in instances:
        frame = fresh.get(int(i))
        if frame is None:
            frame = read_instance_outputs(run_dir, int(i))
        if frame is not None and len(frame):
            frames.append(frame)
    results = pd.concat(frames, ignore_index=True)[RESULT_COLUMNS] if frames else \
        pd.DataFrame(columns=RESULT_COLUMNS)
    atomic_parquet(results, Path(run_dir) / RESULTS_FILE)
    return results


def read_results(run_dir: Path) -> pd.DataFrame:
    """``results.parquet`` of a run directory."""
    path = Path(run_dir) / RESULTS_FILE
    if not path.is_file():
        raise BpsflowError(f"no results in {run_dir}: run 'bpsflow run CONFIG' first "
                           f"(expected {path})")
    try:
        return pd.read_parquet(path)
    except Exception as exc:
        raise BpsflowError(f"cannot read {path} ({type(exc).__name__}); run 'bpsflow run "
                           f"CONFIG' again to rebuild it from the finished instances") from None


def prepare_run_dir(run_dir: Path) -> Path:
    """Create the run directory, with a clear error when that is not possible."""
    run_dir = Path(run_dir)
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise BpsflowError(f"execution.run_dir: {run_dir} exists and is not a directory "
                           f"(or a parent of it is a file)") from None
    except PermissionError:
        raise BpsflowError(f"execution.run_dir: no permission to create {run_dir}") from None
    if not os.access(run_dir, os.W_OK | os.X_OK):
        raise BpsflowError(f"execution.run_dir: {run_dir} is not writable")
    return run_dir


class RunLock:
    """An exclusive lock on a run directory while instances run there.

    The lock file names the holder (host, process id, start time); a lock
    left by a process that no longer exists on this host is taken over.
    """

    def __init__(self, run_dir: Path):
        self.path = Path(run_dir) / LOCK_FILE
        self.held = False

    def __enter__(self) -> RunLock:
        me = f"{socket.gethostname()} {os.getpid()} {time.strftime('%Y-%m-%dT%H:%M:%S')}"
        for _ in range(2):
            try:
                descriptor = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = self._holder()
                if holder is not None and not _alive(*holder[:2]):
                    self.path.unlink(missing_ok=True)
                    continue
                text = " ".join(holder[2]) if holder else "unknown"
                raise BpsflowError(
                    f"{self.path.parent} is in use by another bpsflow process ({text}); wait for "
                    f"it to finish, or remove {self.path} if that process is gone") from None
            with os.fdopen(descriptor, "w") as handle:
                handle.write(me + "\n")
            self.held = True
            return self
        raise BpsflowError(f"could not lock {self.path.parent}")

    def __exit__(self, *exc) -> None:
        if self.held:
            self.path.unlink(missing_ok=True)
            self.held = False

    def _holder(self) -> tuple[str, int, list[str]] | None:
        try:
            parts = self.path.read_text().split()
            return parts[0], int(parts[1]), [f"host {parts[0]}", f"pid {parts[1]}",
                                             f"since {parts[2]}"]
        except (OSError, IndexError, ValueError):
            return None


def _alive(host: str, pid: int) -> bool:
    if host != socket.gethostname():
        return True  # another machine's process: assume it runs
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
