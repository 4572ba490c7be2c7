"""Candidate model extensions: real changes to the model, nested at zero.

Each extension is a set of IDF objects (``bpsflow/extensions_idf/<name>.idf``)
that both backends run (EnergyPlus reads them; the surrogate has the same
physics for them), plus the new parameters that target their fields. At the
new parameters' zero the model is the original one (seed §4.3.1: when the
discrepancy is large, revisit the physical model rather than let δ absorb it;
§2.1 lists the sources such an extension stands for).

=======================  =========================================  ============================
extension                IDF objects                                new parameter (unit)
=======================  =========================================  ============================
infiltration_wind        ZoneInfiltration:DesignFlowRate, flow =    infiltration_wind_m3s_per_ms
                         design × wind speed (C = 1)                (m³/s per m/s)
internal_gain_schedule   OtherEquipment, Schedule:File profile      scheduled_gain_w (W at the
                         (hour of day × weekday/weekend, estimated  profile's peak)
                         from the calibration residuals)
solar_aperture           OtherEquipment, Schedule:File of the       solar_aperture_m2 (m²: W of
                         facade's incident irradiance (pvlib)       gain per W/m² incident)
envelope_ua              ZoneInfiltration:DesignFlowRate, constant  extra_conductance_m3s (m³/s;
                         flow (A = 1): a conductance to outdoors    ×ρc_p ≈ 1206 J/(m³K) = W/K)
=======================  =========================================  ============================

Which extension answers which driver (DESIGN.md §8 names) is
:data:`DRIVER_EXTENSIONS`.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.config import Config, IdfTarget, Parameter
from bpsflow.distributions import Uniform

#: Volumetric heat capacity of air used to report a flow as a conductance (J/(m³·K)).
AIR_HEAT_CAPACITY_J_M3K = 1.2 * 1005.0

SNIPPET_PACKAGE = "bpsflow.extensions_idf"


@dataclass(frozen=True)
class NewParameter:
    """A parameter an extension adds: the IDF field it sets and its search range."""

    name: str
    object: str
    object_name: str
    field: str
    lower: float
    upper: float
    unit: str
    description: str


@dataclass(frozen=True)
class Extension:
    """One candidate extension of the model."""

    name: str
    description: str
    snippet: str                          # file in bpsflow/extensions_idf
    parameters: tuple[NewParameter, ...]
    schedule_file: str | None = None      # CSV the snippet's Schedule:File reads
    drivers: tuple[str, ...] = field(default_factory=tuple)


EXTENSIONS: dict[str, Extension] = {
    "infiltration_wind": Extension(
        name="infiltration_wind",
        description="wind-driven infiltration: outdoor air flow proportional to wind speed",
        snippet="infiltration_wind.idf",
        parameters=(NewParameter(
            "infiltration_wind_m3s_per_ms", "ZoneInfiltration:DesignFlowRate",
            "DiagnosisWindInfiltration", "Design Flow Rate", 0.0, 0.05, "m3/s per m/s",
            "infiltration flow per m/s of wind speed"),),
        drivers=("wind_speed",)),
    "internal_gain_schedule": Extension(
        name="internal_gain_schedule",
        description="an unmodelled internal gain following an hour-of-day / weekday profile",
        snippet="internal_gain_schedule.idf",
        parameters=(NewParameter(
            "scheduled_gain_w", "OtherEquipment", "DiagnosisScheduledGain", "Design Level",
            -3000.0, 3000.0, "W", "gain at the profile's peak"),),
        schedule_file="internal_gain_profile.csv",
        drivers=("hour_of_day", "weekend")),
    "solar_aperture": Extension(
        name="solar_aperture",
        description="an unmodelled solar gain through a facade (gain factor × incident solar)",
        snippet="solar_aperture.idf",
        parameters=(NewParameter(
            "solar_aperture_m2", "OtherEquipment", "DiagnosisSolarAperture", "Design Level",
            -5.0, 5.0, "m2", "W of gain per W/m² incident on the facade"),),
        schedule_file="facade_irradiance.csv",
        drivers=("incident_solar_south", "incident_solar_east", "incident_solar_west",
                 "incident_solar_north", "incident_solar_roof", "global_horizontal_radiation",
                 "direct_normal_radiation", "diffuse_horizontal_radiation")),
    "envelope_ua": Extension(
        name="envelope_ua",
        description="extra envelope conductance to outdoor air (a constant outdoor air flow)",
        snippet="envelope_ua.idf",
        parameters=(NewParameter(
            "extra_conductance_m3s", "ZoneInfiltration:DesignFlowRate",
            "DiagnosisExtraConductance", "Design Flow Rate", 0.0, 0.1, "m3/s",
            "constant outdoor air flow (× 1206 J/(m³K) = W/K)"),),
        drivers=("outdoor_air_temperature",)),
}

#: Driver name -> the extensions that can produce its signature, most specific first.
DRIVER_EXTENSIONS: dict[str, tuple[str, ...]] = {}
for _ext in EXTENSIONS.values():
    for _driver in _ext.drivers:
        DRIVER_EXTENSIONS.setdefault(_driver, ())
        DRIVER_EXTENSIONS[_driver] += (_ext.name,)


def candidates_for(drivers: list[str], allowed: list[str]) -> list[tuple[str, str]]:
    """``(extension, driver)`` pairs answering the significant ``drivers`` (in their order).

    Each extension appears once, with the first (strongest) driver that names
    it; a solar driver also fixes the facade the aperture faces.
    """
    out: list[tuple[str, str]] = []
    seen: set[str] = set()
    for driver in drivers:
        for name in DRIVER_EXTENSIONS.get(driver, ()):
            if name in allowed and name not in seen:
                out.append((name, driver))
                seen.add(name)
    return out


def facade_of(driver: str) -> str:
    """The facade a solar driver refers to (``roof`` for horizontal/beam/diffuse quantities)."""
    return driver.removeprefix("incident_solar_") if driver.startswith("incident_solar_") \
        else "roof"


def snippet_path(extension: Extension) -> Path:
    """The packaged IDF snippet of ``extension``."""
    return Path(str(resources.files(SNIPPET_PACKAGE).joinpath(extension.snippet)))


def new_parameters(extension: Extension) -> list[Parameter]:
    """The extension's parameters as config parameters (uniform over the search range)."""
    return [Parameter(name=p.name, group="extension", mode="absolute",
                      description=f"{p.description} ({p.unit}); added by bpsflow diagnose",
                      distribution=Uniform(type="uniform", lower=p.lower, upper=p.upper),
                      targets=[IdfTarget(object=p.object, name=p.object_name, field=p.field)],
                      provenance={"method": "bpsflow diagnose", "extension": extension.name,
                                  "nested_at": 0.0})
            for p in extension.parameters]


def extend_config(config: Config, extension: Extension, directory: Path,
                  schedule: pd.Series | None = None) -> Config:
    """A copy of ``config`` whose model includes ``extension`` (files in ``directory``).

    Parameters
    ----------
    schedule : Series, optional
        Hourly values for the extension's ``Schedule:File`` (8760 rows of the
        config's year, hour-ending order as EnergyPlus reads them); required
        when the extension has one.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    snippet = directory / extension.snippet
    shutil.copyfile(snippet_path(extension), snippet)
    if extension.schedule_file is not None:
        if schedule is None:
            raise ValueError(f"extension {extension.name} needs its schedule values")
        write_schedule(np.asarray(schedule, dtype=float), directory / extension.schedule_file)
    extended = config.model_copy(deep=True)
    extended.source = config.source
    extended.model.idf_objects = [*config.model.idf_objects, snippet]
    names = {p.name for p in extended.parameters}
    extended.parameters = [*extended.parameters,
                           *[p for p in new_parameters(extension) if p.name not in names]]
    return extended


def write_schedule(values: np.ndarray, path: Path) -> Path:
    """One numeric column, no header: what the snippets' ``Schedule:File`` reads."""
    np.savetxt(path, np.asarray(values, dtype=float), fmt="%.6g")
    return path


def year_hours(year: int) -> pd.DatetimeIndex:
    """Hour-ending stamps of the year's first 8760 hours (the rows of an hourly Schedule:File)."""
    return pd.date_range(pd.Timestamp(year=year, month=1, day=1, hour=1), periods=8760, freq="h")


def gain_profile(residual: pd.Series, output_sign: float, keep: float = 0.3) -> pd.DataFrame:
    """Hour-of-day × weekday/weekend profile of an unmodelled gain, from residuals.

    The mean residual of each (day type, hour) cell, oriented so that a
    positive gain explains it (``output_sign``: the output's response to a
    gain, −1 for heating power, +1 for a free-floating temperature),
    normalised to 1 at its peak; cells under ``keep`` × the peak are set to
    0 (noise). Index: ``weekend`` (0/1) × ``hour`` (0–23, hour start).
    """
    start = residual.index - pd.Timedelta(hours=1)
    frame = pd.DataFrame({"r": residual.to_numpy() * output_sign,
                          "weekend": (start.dayofweek >= 5).astype(int), "hour": start.hour})
    cells = frame.groupby(["weekend", "hour"])["r"].mean()
    full = pd.MultiIndex.from_product([[0, 1], range(24)], names=["weekend", "hour"])
    cells = cells.reindex(full).fillna(0.0)
    peak = float(cells.max())
    if peak <= 0:
        return (cells * 0.0).rename("profile").to_frame()
    profile = np.where(cells >= keep * peak, cells / peak, 0.0)
    return pd.DataFrame({"profile": profile}, index=full)


def profile_schedule(profile: pd.DataFrame, year: int) -> pd.Series:
    """The gain profile over the year's hours (hour-ending stamps, 8760 values)."""
    stamps = year_hours(year)
    start = stamps - pd.Timedelta(hours=1)
    keys = pd.MultiIndex.from_arrays([(start.dayofweek >= 5).astype(int), start.hour])
    return pd.Series(profile["profile"].reindex(keys).to_numpy(), index=stamps)
