"""Shared fixtures: small configs on the shipped test cell, written to a temporary folder."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml

# The tests run on two xdist workers on two cores. Multi-threaded BLAS in each worker (and
# in the CLI subprocesses they start) oversubscribes the cores, and OpenBLAS's waiting
# threads then make a 200 x 200 Cholesky about a hundred times slower. One BLAS thread per
# process; set before numpy is first imported, and inherited by subprocesses.
for _threads in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_threads, "1")

ROOT = Path(__file__).resolve().parents[1]
I600 = ROOT / "configs" / "i600.yaml"


def pytest_collection_modifyitems(config, items):
    """Run the ``slow`` tests first; skip ``energyplus`` tests, with the reason, when no
    EnergyPlus binary is found.

    Slow first, and of those the EnergyPlus ones (the surrogate's are compiled and
    short): the xdist workers then share the long tests from the start and end on
    short ones, instead of one worker finishing a two-minute test alone.
    """
    items.sort(key=lambda item: ("slow" not in item.keywords,
                                 "energyplus" not in item.keywords))
    from bpsflow.errors import BpsflowError
    from bpsflow.simulation.energyplus.engine import find_energyplus

    try:
        binary = find_energyplus()
    except BpsflowError:
        binary = None
    if binary is not None:
        return
    skip = pytest.mark.skip(reason="no EnergyPlus binary found (run 'make install', or set "
                                   "BPSFLOW_ENERGYPLUS to an EnergyPlus 25.2 binary)")
    for item in items:
        if "energyplus" in item.keywords:
            item.add_marker(skip)


def i600_raw() -> dict:
    """The shipped I600 config as a dict, with absolute paths so it can be written anywhere."""
    raw = yaml.safe_load(I600.read_text())
    raw["model"]["idf"] = str(ROOT / "sample_idf" / "flexlab_x3b.idf")
    raw["model"]["boundary"]["file"] = str(ROOT / "sample_idf" / "boundary_temperatures.csv")
    return raw


def write_config(folder: Path, raw: dict, name: str = "case.yaml") -> Path:
    raw = dict(raw)
    raw.setdefault("execution", {})
    raw["execution"] = {**raw["execution"], "run_dir": str(folder / "run")}
    path = folder / name
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def short_raw(samples: int = 3, boundary_sequences: int = 20) -> dict:
    """A two-test, one-period, two-day variant of I600: seconds per EnergyPlus run."""
    raw = i600_raw()
    raw["model"]["periods"] = [{"name": "winter", "start": "12-05", "end": "12-08"}]
    raw["model"]["tests"] = [
        {"name": "H-ST", "period": "winter", "start": "12-05", "days": 2, "warmup_days": 1,
         "mode": "heating", "setpoint_c": 30.0, "setback_c": 20.0, "outputs": ["heating_power_w"]},
        {"name": "H-FF", "period": "winter", "start": "12-07", "days": 2, "warmup_days": 1,
         "mode": "free_floating", "outputs": ["zone_air_temperature_c"]},
    ]
    raw["model"]["boundary"]["sequences"] = boundary_sequences
    for parameter in raw["parameters"]:
        if parameter["distribution"]["type"] == "sampler":
            parameter["distribution"]["sequences"] = boundary_sequences
    raw["design"] = {"method": "lhs", "samples": samples, "seed": 1}
    raw["execution"] = {"jobs": 2}
    return raw


@pytest.fixture
def short_config(tmp_path: Path) -> Path:
    return write_config(tmp_path, short_raw())
