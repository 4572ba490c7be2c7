"""Reading detailed measurements: ``detailed.csv``, ``sensor_calibration.csv``, ``detailed.json``.

The three files (written by ``bpsflow synth --detailed``, or by an experiment)
sit in one directory:

``detailed.csv``
    ``timestamp`` (hour-ending) and the sensor readings: nine equal-area
    sensors per boundary surface (``boundary_<surface>_s<k>_c``); per surface
    class (wall, ceiling, floor) the surface and adjacent air temperatures,
    conduction and net radiation gain at the inside face (W/m²), and the
    model's own convection coefficient (for checking only, never used here);
    transmitted and incident window irradiance; global horizontal and
    ground-reflected south-facade irradiance (W/m²).
``sensor_calibration.csv``
    ``step``, ``reference_c`` and one column per temperature sensor of
    ``detailed.csv``: readings of a common true temperature (seed eq. 8–9).
``detailed.json``
    metadata: air sensor separation (m), glazed area (m²), south facade view
    factor to the ground, reference sensor standard deviation σ_M (°C),
    relative irradiance sensor standard deviation, boundary sensor areas per
    surface (m²), and surface class → IDF surface name.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from bpsflow import detailed as contract
from bpsflow.errors import BpsflowError
from bpsflow.yearhours import NON_LEAP_ROWS, hour_rows

# File and column names come from bpsflow.detailed, which writes these files.
DETAILED_FILE = contract.DETAILED_FILE
CALIBRATION_FILE = contract.CALIBRATION_FILE
METADATA_FILE = contract.METADATA_FILE

TIMESTAMP = "timestamp"
CALIBRATION_STEP = "step"
CALIBRATION_REFERENCE = "reference_c"

#: Surface classes with their own convection correlation (seed Table 3.4).
SURFACE_CLASSES = tuple(contract.SURFACE_CLASSES)
SURFACE_C = "surface_c"
AIR_C = "air_c"
CONDUCTION = "conduction_w_m2"
RADIATION = "radiation_w_m2"
MODEL_H_C = "h_c_w_m2k"  # derived coefficient readings (optional): preferred when present
CEILING_AIR = "ceiling_air_c"
FLOOR_AIR = "floor_air_c"
WINDOW_TRANSMITTED = "window_transmitted_w_m2"
WINDOW_INCIDENT = "window_incident_w_m2"
GLOBAL_HORIZONTAL = "global_horizontal_w_m2"
GROUND_REFLECTED = "south_ground_reflected_w_m2"


def class_column(surface_class: str, quantity: str) -> str:
    """``<class>_<quantity>``, e.g. ``wall_surface_c``."""
    return f"{surface_class}_{quantity}"


def boundary_sensor_columns(surface: str) -> list[str]:
    """A boundary surface's sensor columns, s1..s9."""
    return contract.boundary_columns([surface])


temperature_columns = contract.temperature_columns


@dataclass
class Metadata:
    """``detailed.json``: geometry and sensor specifications of the experiment."""

    air_sensor_separation_m: float
    reference_sensor_std_c: float
    irradiance_relative_std: float
    heat_flux_relative_std: float
    radiation_relative_std: float
    south_facade_ground_view_factor: float
    glazed_area_m2: float | None
    boundary_sensor_area_m2: dict[str, float]
    surface_classes: dict[str, str]
    raw: dict[str, Any] = field(default_factory=dict)


@dataclass
class Detailed:
    """Detailed measurements read and checked: readings, calibration, metadata."""

    frame: pd.DataFrame          # timestamp (hour-ending) index, one column per reading
    calibration: pd.DataFrame    # calibration steps x (step, reference_c, sensors)
    metadata: Metadata
    detailed_path: Path
    calibration_path: Path
    metadata_path: Path

    @property
    def step_minutes(self) -> float:
        """The median time step of the readings (min)."""
        if len(self.frame) < 2:
            return 60.0
        return float(self.frame.index.to_series().diff().median() / pd.Timedelta(minutes=1))

    @property
    def sub_hourly(self) -> bool:
        return self.step_minutes < 59.5


def hour_of_year_rows(hour_ending: pd.DatetimeIndex, rows_per_year: int = 8760) -> np.ndarray:
    """0-based row of a one-row-per-hour year file (hour-ending ``01/01 01:00`` is row 0).

    The rows of :func:`bpsflow.yearhours.hour_rows`, except that 29 February
    gets ``-1`` in an 8760-row file: a measurement of that day has no row of
    its own to replace (it would overwrite 28 February's).
    """
    start = pd.DatetimeIndex(hour_ending) - pd.Timedelta(hours=1)
    rows = hour_rows(start, rows_per_year)
    if rows_per_year == NON_LEAP_ROWS:
        rows[(start.month == 2) & (start.day == 29)] = -1
    return rows


def require_columns(frame: pd.DataFrame, columns: list[str], source: Path, why: str) -> None:
    """Raise naming the missing column(s) of ``source`` and what they are for."""
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise BpsflowError(f"missing column(s) {missing} ({why})", source=source)


def _number(raw: dict, key: str, source: Path, default: float | None = None) -> float:
    value = raw.get(key, default)
    if value is None:
        raise BpsflowError(f"key '{key}' is missing (expected a number)", source=source)
    try:
        return float(value)
    except (TypeError, ValueError):
        raise BpsflowError(f"key '{key}': expected a number, got {value!r}",
                           source=source) from None


def read_metadata(path: Path) -> Metadata:
    """Read ``detailed.json`` (keys as :func:`bpsflow.detailed.detailed_metadata` writes them)."""
    if not path.is_file():
        raise BpsflowError(f"detailed measurement metadata not found: {path}")
    try:
        raw = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise BpsflowError(f"not valid JSON: {exc}", source=path) from None
    if not isinstance(raw, dict):
        raise BpsflowError("expected a JSON object", source=path)
    areas = raw.get("boundary_sensor_area_m2") or {}
    classes = raw.get("surface_classes") or {}
    if not isinstance(areas, dict) or not isinstance(classes, dict):
        raise BpsflowError("keys 'boundary_sensor_area_m2' and 'surface_classes' must be "
                           "mappings (surface -> m², class -> surface name)", source=path)
    glazed = raw.get("glazed_area_m2")
    return Metadata(
        air_sensor_separation_m=_number(raw, "air_sensor_separation_m", path),
        reference_sensor_std_c=_number(raw, "reference_sensor_std_c", path),
        irradiance_relative_std=_number(raw, "irradiance_relative_std", path),
        # Flux sensor errors default to the irradiance sensors' (seed Table 3.2 has none).
        heat_flux_relative_std=_number(raw, "heat_flux_relative_std", path,
                                       raw.get("irradiance_relative_std")),
        radiation_relative_std=_number(raw, "radiation_relative_std", path,
                                       raw.get("irradiance_relative_std")),
        south_facade_ground_view_factor=_number(raw, "south_facade_ground_view_factor", path),
        glazed_area_m2=None if glazed is None else float(glazed),
        boundary_sensor_area_m2={k: _number(areas, k, path) for k in areas},
        surface_classes={str(k): str(v) for k, v in classes.items()},
        raw=raw,
    )


def locate(path: Path) -> tuple[Path, Path, Path]:
    """(detailed.csv, sensor_calibration.csv, detailed.json) from the CSV or its directory."""
    path = Path(path).resolve()
    directory = path if path.is_dir() else path.parent
    detailed = directory / DETAILED_FILE if path.is_dir() else path
    return detailed, directory / CALIBRATION_FILE, directory / METADATA_FILE


#: Air and surface temperatures (°C) a building's sensors can read; outside them the file
#: is in kelvin or °F, or a sensor is broken.
SENSOR_RANGE_C = (-50.0, 100.0)


def _check_complete_rows(path: Path) -> None:
    """Refuse a row with fewer fields than the header (a file cut mid-row)."""
    import csv

    with open(path, newline="", encoding="utf-8", errors="replace") as handle:
        reader = csv.reader(handle)
        header = next(reader, [])
        for record in reader:
            if record and len(record) != len(header):
                raise BpsflowError(f"line {reader.line_num}: {len(record)} fields, but the "
                                   f"header has {len(header)} (a file cut short or a stray "
                                   f"separator?)", source=path)


def _check_temperatures(frame: pd.DataFrame, sensors: list[str], path: Path) -> None:
    """Refuse a temperature sensor's readings outside :data:`SENSOR_RANGE_C`."""
    low, high = SENSOR_RANGE_C
    for column in sensors:
        values = frame[column].to_numpy(dtype=float)
        outside = np.isfinite(values) & ((values < low) | (values > high))
        if outside.any():
            value = float(values[np.flatnonzero(outside)[0]])
            hint = ("; kelvin in a °C column?" if low <= value - 273.15 <= high else
                    "; °F in a °C column?" if low <= (value - 32) / 1.8 <= high else "")
            raise BpsflowError(f"column '{column}': {value:g} °C is outside the {low:g}..{high:g} "
                               f"°C a building's sensor reads ({int(outside.sum())} value(s)){hint}",
                               source=path)


def read_detailed(path: Path, surfaces: list[str]) -> Detailed:
    """Read and check the detailed measurements (``detailed.csv`` or the folder holding it).

    The readings and calibration are read by :mod:`bpsflow.detailed` (every
    contract column present and numeric, timestamps parse); here the
    timestamps must also increase, and the calibration file must hold exactly
    the temperature sensors of ``detailed.csv``.

    Parameters
    ----------
    path : Path
    surfaces : list of str
        Boundary surface keys (``model.boundary.surfaces``) whose sensors must be present.

    Raises
    ------
    BpsflowError
        Naming the file and column.
    """
    detailed_path, calibration_path, metadata_path = locate(path)
    frame = contract.read_detailed(detailed_path, surfaces)
    if not frame.index.is_monotonic_increasing or frame.index.has_duplicates:
        raise BpsflowError(f"timestamps must increase strictly (column '{TIMESTAMP}')",
                           source=detailed_path)
    _check_complete_rows(detailed_path)
    calibration = contract.read_calibration(calibration_path)
    sensors = temperature_columns(list(frame.columns))
    _check_temperatures(frame, sensors, detailed_path)
    calibrated = [c for c in calibration.columns if c not in (CALIBRATION_STEP,
                                                              CALIBRATION_REFERENCE)]
    uncalibrated = [c for c in sensors if c not in calibrated]
    unknown = [c for c in calibrated if c not in sensors]
    if uncalibrated or unknown:
        parts = []
        if uncalibrated:
            parts.append(f"no calibration readings for sensor(s) {uncalibrated} of "
                         f"{detailed_path.name}")
        if unknown:
            parts.append(f"column(s) {unknown} are not temperature sensors of "
                         f"{detailed_path.name}")
        raise BpsflowError("the calibration file does not match the detailed measurements: "
                           + "; ".join(parts) + " (expected one column per '*_c' sensor)",
                           source=calibration_path)
    if len(calibration) < 3:
        raise BpsflowError(f"{len(calibration)} calibration step(s); eq. 11 needs at least 3",
                           source=calibration_path)
    return Detailed(frame=frame, calibration=calibration, metadata=read_metadata(metadata_path),
                    detailed_path=detailed_path, calibration_path=calibration_path,
                    metadata_path=metadata_path)
