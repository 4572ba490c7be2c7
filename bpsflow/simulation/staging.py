"""Input files for workers that cannot see this machine's files (``shared_filesystem: false``).

:func:`stage_inputs` reads, on this machine, every file an instance reads:
the model (``model.idf`` and its ``idf_objects`` snippets), the weather file,
the measured boundary file and the run's boundary sequences. The executor
sends the result to each worker once. :func:`localised_config` writes them on
the worker into its own scratch directory (once per worker and content) and
gives the config that points there, with ``execution.run_dir`` a scratch run
directory as well; instances then run there and their outputs come back
through the executor.

Other files the model names by path (a ``Schedule:File`` that is not the
boundary file) are not staged: they must be at the same path on every worker.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from bpsflow.boundary import SEQUENCES_FILE

if TYPE_CHECKING:
    from bpsflow.config import Config


@dataclass(frozen=True)
class StagedInputs:
    """The bytes of every file an instance reads, keyed by the role they play."""

    key: str
    files: dict[str, tuple[str, bytes]]  # role -> (file name, content)


def stage_inputs(config: Config) -> StagedInputs:
    """Read the files an instance of ``config`` reads (on this machine)."""
    model = config.model
    paths: dict[str, Path] = {"idf": model.idf, "weather": model.weather}
    for k, snippet in enumerate(model.idf_objects):
        paths[f"idf_objects/{k}"] = snippet
    if model.boundary is not None:
        paths["boundary"] = model.boundary.file
        sequences = config.run_dir.resolve() / SEQUENCES_FILE
        if sequences.is_file():
            paths["sequences"] = sequences
    files = {role: (Path(path).name, Path(path).read_bytes()) for role, path in paths.items()}
    digest = hashlib.sha256()
    for role in sorted(files):
        digest.update(role.encode() + b"\0" + files[role][1])
    return StagedInputs(key=digest.hexdigest()[:16], files=files)


def scratch_root() -> Path:
    """Where a worker keeps staged inputs and its instances (``BPSFLOW_SCRATCH`` or the temp dir)."""
    return Path(os.environ.get("BPSFLOW_SCRATCH") or tempfile.gettempdir()) / "bpsflow-worker"


_LOCALISED: dict[tuple[str, str], Config] = {}


def localised_config(config: Config, staged: StagedInputs) -> Config:
    """``config`` pointing at the staged copies on this (worker) machine, written once.

    Built once per worker process, staged content and config: every task of a
    batch calls this.
    """
    key = (staged.key, config.model_dump_json())
    if key not in _LOCALISED or not _LOCALISED[key].run_dir.is_dir():  # scratch cleared since
        if len(_LOCALISED) > 8:
            _LOCALISED.clear()
        _LOCALISED[key] = _localise(config, staged)
    return _LOCALISED[key]


def _localise(config: Config, staged: StagedInputs) -> Config:
    from bpsflow.files import write_bytes_atomic

    root = scratch_root() / staged.key
    local: dict[str, Path] = {}
    for role, (name, content) in staged.files.items():
        path = root / "inputs" / role.replace("/", "_") / name
        if not path.is_file() or path.stat().st_size != len(content):
            path.parent.mkdir(parents=True, exist_ok=True)
            write_bytes_atomic(path, content)
        local[role] = path
    copy = config.model_copy(deep=True)
    copy.source = config.source
    copy.model.idf = local["idf"]
    copy.model.weather = local["weather"]
    copy.model.idf_objects = [local[f"idf_objects/{k}"] for k in range(len(config.model.idf_objects))]
    # one scratch run directory per run directory of the caller: two runs of the same model
    # (other seeds, other run directories) never share instance folders
    caller = hashlib.sha256(str(config.run_dir.resolve()).encode()).hexdigest()[:12]
    run_dir = root / f"run-{caller}"
    run_dir.mkdir(parents=True, exist_ok=True)
    if copy.model.boundary is not None:
        copy.model.boundary.file = local["boundary"]
        if "sequences" in local and not (run_dir / SEQUENCES_FILE).is_file():
            write_bytes_atomic(run_dir / SEQUENCES_FILE, local["sequences"].read_bytes())
    copy.execution.run_dir = run_dir
    return copy
