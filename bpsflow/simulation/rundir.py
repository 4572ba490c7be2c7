"""The run directory: file layout, manifest, results, lock and atomic writes (DESIGN §9).

Layout::

    RUN_DIR/
      config.resolved.yaml   the validated config, paths resolved
      samples.parquet        one row per instance
      boundary_sequences.npz Monte Carlo boundary sequences (when sampled)
      manifest.parquet       instance, status, seconds (write/simulate/read), error, backend
      results.parquet        tidy: instance, test, output, timestamp, value
      run.lock               held while a command writes here (a second one refuses)
      design.json            what determined samples.parquet (compared before it is used)
      previous/<timestamp>/  what 'bpsflow sample --force' moved aside
      instances/000017/      per instance: outputs.parquet, and what the backend keeps
                             (EnergyPlus: per period eplusout.sql and eplusout.err)

An instance is finished when its ``outputs.parquet`` exists and reads back
(written last, atomically), whatever the manifest says; a file that does not
read back counts as unfinished and the instance runs again.
"""

from __future__ import annotations

import os
import socket
import sys
import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import pandas as pd

from bpsflow.errors import BpsflowError
from bpsflow.files import read_parquet, write_parquet

try:  # POSIX: a lock the kernel releases when its process dies
    import fcntl as _fcntl
except ImportError:  # pragma: no cover - Windows
    _fcntl = None  # type: ignore[assignment]

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
    """Write ``frame`` to ``path`` atomically (no index), so a crash never leaves half a file."""
    return write_parquet(frame, path, index=False)


def read_instance_outputs(run_dir: Path, instance: int | str) -> pd.DataFrame | None:
    """An instance's tidy outputs, or None when it has none that read back."""
    path = instance_dir(run_dir, instance) / INSTANCE_OUTPUTS
    if not path.is_file():
        return None
    try:
        return read_parquet(path)
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
            return read_parquet(path)
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
        return read_parquet(path)
    except Exception as exc:
        raise BpsflowError(f"cannot read {path} ({type(exc).__name__}); run 'bpsflow run "
                           f"CONFIG' again to rebuild it from the finished instances") from None


def prepare_run_dir(run_dir: Path, where: str = "execution.run_dir (or --run-dir)") -> Path:
    """Create the run directory, with a clear error when that is not possible.

    ``where`` names the key or option the folder came from, in the messages.

    Raises
    ------
    BpsflowError
        ``run_dir`` (or a parent of it) is a file, cannot be created, or is
        not writable; the message names the path and says what was expected.
    """
    run_dir = Path(run_dir)
    if run_dir.exists() and not run_dir.is_dir():
        raise BpsflowError(f"{where}: {run_dir} is a file; expected a folder (or a path where "
                           f"bpsflow may create one)")
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        blocker = next((p for p in run_dir.parents if p.exists() and not p.is_dir()), run_dir)
        raise BpsflowError(f"{where}: cannot create {run_dir}: {blocker} is a file; expected "
                           f"a folder") from None
    except PermissionError:
        raise BpsflowError(f"{where}: cannot create {run_dir}: no permission to write in "
                           f"{_nearest_existing(run_dir)}; expected a writable folder") from None
    except OSError as exc:  # a read-only file system, a path under /proc
        raise BpsflowError(f"{where}: cannot create {run_dir}: {exc.strerror or exc}; "
                           f"expected a folder bpsflow may create and write in") from None
    if not os.access(run_dir, os.W_OK | os.X_OK):
        raise BpsflowError(f"{where}: {run_dir} is not writable; expected a folder bpsflow may "
                           f"write in")
    return run_dir


def _nearest_existing(path: Path) -> Path:
    return next((p for p in (path, *path.parents) if p.exists()), path)


def move_aside(run_dir: Path, names: Iterable[str], reason: str = "previous") -> Path | None:
    """Move the named files and folders of ``run_dir`` into ``run_dir/previous/<timestamp>/``.

    A rename within one file system: nothing is copied, nothing is lost, and
    the user decides later what to delete.

    Parameters
    ----------
    run_dir : Path
    names : iterable of str
        Entries of ``run_dir`` to move (missing ones are skipped).
    reason : str
        The folder under ``run_dir`` that receives them.

    Returns
    -------
    Path or None
        The folder they went to, or None when none of them existed.
    """
    run_dir = Path(run_dir)
    present = [name for name in names if (run_dir / name).exists()]
    if not present:
        return None
    stamp = time.strftime("%Y%m%d-%H%M%S")
    target = run_dir / reason / stamp
    suffix = 1
    while target.exists():
        suffix += 1
        target = run_dir / reason / f"{stamp}-{suffix}"
    target.mkdir(parents=True)
    for name in present:
        (run_dir / name).rename(target / name)
    return target


#: Lock paths this process holds, with their nesting depth: a command locks its run
#: directory and the ensemble loop it calls locks the same one again.
_HELD: dict[Path, int] = {}


class RunLock:
    """An exclusive lock on a run directory while a command writes there.

    The lock file names the holder (host, process id, start time, command).
    On POSIX the file is also ``flock``-ed: the kernel releases that lock
    when its process dies, however it dies, so a lock left by a killed
    process is taken over without guessing from process ids. Elsewhere a
    lock whose process no longer exists on this host is taken over. The
    same process may take the lock again (nested), e.g. a command and the
    ensemble loop it calls.
    """

    def __init__(self, run_dir: Path):
        self.path = Path(run_dir).resolve() / LOCK_FILE
        self.held = False
        self._descriptor: int | None = None

    def __enter__(self) -> RunLock:
        if self.path in _HELD:
            _HELD[self.path] += 1
            self.held = True
            return self
        command = " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]) if sys.argv else "python"
        me = (f"{socket.gethostname()} {os.getpid()} {time.strftime('%Y-%m-%dT%H:%M:%S')}\n"
              f"{command}\n")
        acquire = self._acquire_flock if _fcntl is not None else self._acquire_exclusive
        acquire(me)
        _HELD[self.path] = 1
        self.held = True
        return self

    def _refuse(self) -> BpsflowError:
        holder = self._holder()
        text = ", ".join(holder[2]) if holder else "unknown process"
        return BpsflowError(
            f"{self.path.parent} is in use by another bpsflow process ({text}); wait for it to "
            f"finish, or use another --run-dir")

    def _acquire_flock(self, me: str) -> None:
        assert _fcntl is not None
        for _ in range(20):
            descriptor = os.open(self.path, os.O_CREAT | os.O_RDWR, 0o644)
            try:
                _fcntl.flock(descriptor, _fcntl.LOCK_EX | _fcntl.LOCK_NB)
            except OSError:
                os.close(descriptor)
                raise self._refuse() from None
            # The holder before us may have removed the file between our open and our
            # flock: then we locked a file nobody else sees. Start again on the new one.
            try:
                same = os.stat(self.path).st_ino == os.fstat(descriptor).st_ino
            except FileNotFoundError:
                same = False
            if not same:
                os.close(descriptor)
                continue
            os.ftruncate(descriptor, 0)
            os.write(descriptor, me.encode())
            self._descriptor = descriptor
            return
        raise BpsflowError(f"could not lock {self.path.parent}: its lock file keeps changing")

    def _acquire_exclusive(self, me: str) -> None:
        for _ in range(2):
            try:
                descriptor = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = self._holder()
                if holder is not None and not _alive(*holder[:2]):
                    self.path.unlink(missing_ok=True)
                    continue
                raise self._refuse() from None
            with os.fdopen(descriptor, "w") as handle:
                handle.write(me)
            return
        raise BpsflowError(f"could not lock {self.path.parent}")

    def __exit__(self, *exc) -> None:
        if not self.held:
            return
        self.held = False
        _HELD[self.path] -= 1
        if _HELD[self.path]:
            return
        del _HELD[self.path]
        # Remove the file while still holding the flock, so that nobody locks a stale inode.
        self.path.unlink(missing_ok=True)
        if self._descriptor is not None:
            os.close(self._descriptor)
            self._descriptor = None

    def _holder(self) -> tuple[str, int, list[str]] | None:
        try:
            lines = self.path.read_text().splitlines()
            host, pid, since = lines[0].split()[:3]
            described = [f"pid {pid}", f"host {host}", f"since {since}"]
            if len(lines) > 1 and lines[1].strip():
                described.append(f"command '{lines[1].strip()}'")
            return host, int(pid), described
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


def ensemble_gap_note(run_dir: Path, results: pd.DataFrame) -> str | None:
    """A note when the results hold fewer instances than the design drew, else ``None``.

    Scores over a partial ensemble are still computed (a crashed simulation never stops
    the others), but a user must see that the ensemble is smaller than designed.
    """
    from bpsflow.sampling import SAMPLES_FILE

    records = manifest_records(run_dir)
    designed = set(records)
    samples_path = Path(run_dir) / SAMPLES_FILE
    if samples_path.is_file():
        try:
            # an interrupted run's manifest holds only what finished (or nothing)
            designed |= set(read_parquet(samples_path, columns=["instance"])["instance"])
        except Exception:  # unreadable samples: the manifest is all there is to compare
            pass
    if not designed:
        return None
    present = set(pd.unique(results["instance"])) if len(results) else set()
    failed = sorted(i for i, r in records.items() if r.status != "ok")
    missing = sorted(designed - present - set(failed))
    if not failed and not missing:
        return None
    parts = []
    if failed:
        parts.append(f"{len(failed)} failed (instance(s) {', '.join(map(str, failed[:5]))}"
                     f"{', ...' if len(failed) > 5 else ''})")
    if missing:
        parts.append(f"{len(missing)} not run or without results")
    return (f"the ensemble has {len(present)} of {len(designed)} instances: "
            f"{' and '.join(parts)}; scores are over the {len(present)} that ran "
            f"('bpsflow run' runs the rest; --retry-failed runs the failed ones again)")
