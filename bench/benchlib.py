"""Shared helpers for the benchmark scripts: recording figures in bench/results.json.

Each figure is ``{"name": {"value", "unit", "goal", "command", "measured_on"}}``
(DESIGN.md §11). Scripts merge their figures into the file, so one script can
be re-run alone without losing the others'.
"""

from __future__ import annotations

import json
import os
import platform
import tempfile
from datetime import date
from pathlib import Path

from bpsflow.files import write_json

RESULTS = Path(__file__).resolve().parent / "results.json"
#: Every benchmark's scratch lives here: ignored by git, removed by ``make clean``.
WORK = Path(__file__).resolve().parent / "work"


def work_root() -> Path:
    """``bench/work/``, created if needed: the parent of every benchmark's scratch.

    The benchmarks write thousands of instance files; keeping them inside the
    ignored ``bench/work/`` (not the system temp folder) means a crashed or
    interrupted run leaves nothing behind that ``make clean`` does not remove.
    """
    WORK.mkdir(parents=True, exist_ok=True)
    return WORK


def scratch(prefix: str) -> Path:
    """A new, empty folder under ``bench/work/`` for one benchmark run (kept afterwards)."""
    return Path(tempfile.mkdtemp(prefix=prefix, dir=work_root()))


def measured_on() -> str:
    return f"{date.today().isoformat()}, {os.cpu_count()} cores, {platform.machine()}"


def record(name: str, value: float, unit: str, goal: str, command: str, **extra) -> dict:
    """Merge one figure into ``bench/results.json`` and return the entry."""
    data = json.loads(RESULTS.read_text()) if RESULTS.is_file() else {}
    entry = {"value": float(value), "unit": unit, "goal": goal, "command": command,
             "measured_on": measured_on(), **extra}
    data[name] = entry
    write_json(RESULTS, data, sort_keys=True)
    print(f"{name}: {value:.4g} {unit} (goal {goal})")
    return entry
