"""Finished simulations kept by content, so that an interrupted command resumes where it stopped.

``bpsflow diagnose`` on EnergyPlus runs thousands of simulations in a fixed,
seeded order. Each finished instance's output is stored under a key made of
everything that decides it: the backend, the model section of the config,
the parameters and outputs, the bytes of every model, snippet, weather and
schedule file, the boundary sequences, the output's name and hours, and the
instance's parameter values. Re-running the same command after a stop (a
killed job, a full disk, Ctrl-C) finds the same keys and skips those runs;
a changed file or value is a new key, so a stale output is never reused.
Failed instances are not stored: they run again.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.config import Config

#: Per file: (path, inode, size, modification time in ns) -> its SHA-256, read once per process.
_FILE_DIGESTS: dict[tuple[str, int, int, int], str] = {}
#: A file modified less than this long ago (s) is read again at every call: file-system
#: clocks tick in milliseconds, so two writes of the same size in one tick share a time.
SETTLED_SECONDS = 2.0


def file_digest(path: Path) -> str:
    """SHA-256 of a file's bytes (``"missing"`` for a file that does not exist)."""
    try:
        stat = path.stat()
    except OSError:
        return "missing"
    key = (str(path.resolve()), stat.st_ino, stat.st_size, stat.st_mtime_ns)
    if key in _FILE_DIGESTS:
        return _FILE_DIGESTS[key]
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    if time.time() - stat.st_mtime > SETTLED_SECONDS:
        _FILE_DIGESTS[key] = digest
    return digest


def _input_files(config: Config, sequences_dir: Path) -> list[Path]:
    """Every file a run reads: model, snippets and the files beside them, weather, sequences.

    A snippet's ``Schedule:File`` names a file relative to the snippet, so the
    files in each snippet's folder count (not its sub-folders).
    """
    from bpsflow.boundary import SEQUENCES_FILE

    files = [Path(config.model.idf), Path(config.model.weather),
             Path(sequences_dir) / SEQUENCES_FILE]
    folders = {Path(snippet).parent for snippet in config.model.idf_objects}
    folders.add(Path(config.model.idf).parent)
    for folder in sorted(folders):
        if folder.is_dir():
            files += sorted(p for p in folder.iterdir()
                            if p.is_file() and p.suffix.lower() in (".idf", ".csv", ".txt"))
    return files


def model_digest(config: Config, backend: str, sequences_dir: Path) -> str:
    """A digest of everything but the instance values that decides a run's outputs."""
    described = config.model_dump(mode="json", include={"model", "parameters", "outputs"})
    text = json.dumps(described, sort_keys=True, default=str)
    files = [f"{path.name}:{file_digest(path)}" for path in _input_files(config, sequences_dir)]
    return hashlib.sha256("\n".join([backend, text, *files]).encode()).hexdigest()


class RunCache:
    """Outputs of finished instances in ``directory``, one ``.npy`` file per instance key."""

    def __init__(self, directory: Path):
        self.directory = Path(directory)

    @staticmethod
    def keys(digest: str, output: str, timestamps: pd.DatetimeIndex,
             samples: pd.DataFrame) -> list[str]:
        """One key per row of ``samples`` (its values to full precision, by column name)."""
        hours = hashlib.sha256(np.asarray(timestamps.asi8).tobytes()).hexdigest()
        head = f"{digest}|{output}|{hours}|"
        columns = sorted(samples.columns)
        return [hashlib.sha256((head + json.dumps(
            [[c, float(row[c])] for c in columns])).encode()).hexdigest()
            for _, row in samples.iterrows()]

    def get(self, key: str, length: int) -> np.ndarray | None:
        """The stored output of ``key``, or ``None`` (not stored, or unreadable, or not ``length``)."""
        path = self.directory / f"{key}.npy"
        try:
            values = np.load(path, allow_pickle=False)
        except (OSError, ValueError):
            return None
        return values if values.shape == (length,) else None

    def put(self, key: str, values: np.ndarray) -> None:
        """Store ``values``; written to a temporary name and renamed, so a stop leaves no half file."""
        self.directory.mkdir(parents=True, exist_ok=True)
        final = self.directory / f"{key}.npy"
        partial = self.directory / f"{key}.{os.getpid()}.partial.npy"
        np.save(partial, np.asarray(values, dtype=float), allow_pickle=False)
        os.replace(partial, final)
