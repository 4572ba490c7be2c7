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
internal_gain_schedule   OtherEquipment, Schedule:File on/off       scheduled_gain_w (W while
                         block (day type × hours, the block that    on)
                         best explains the residuals)
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
    schedule_name: str | None = None      # that Schedule:File object's name
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
            -3000.0, 3000.0, "W", "gain while the block schedule is on"),),
        schedule_file="internal_gain_profile.csv", schedule_name="DiagnosisGainProfile",
        drivers=("hour_of_day", "weekend")),
    "solar_aperture": Extension(
        name="solar_aperture",
        description="an unmodelled solar gain through a facade (gain factor × incident solar)",
        snippet="solar_aperture.idf",
        parameters=(NewParameter(
            "solar_aperture_m2", "OtherEquipment", "DiagnosisSolarAperture", "Design Level",
            -5.0, 5.0, "m2", "W of gain per W/m² incident on the facade"),),
        schedule_file="facade_irradiance.csv", schedule_name="DiagnosisFacadeIrradiance",
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


def new_parameters(extension: Extension, variant: int | None = None) -> list[Parameter]:
    """The extension's parameters as config parameters (uniform over the search range)."""
    tag = "" if variant is None else f"_v{variant}"
    return [Parameter(name=p.name + tag, group="extension", mode="absolute",
                      description=f"{p.description} ({p.unit}); added by bpsflow diagnose",
                      distribution=Uniform(type="uniform", lower=p.lower, upper=p.upper),
                      targets=[IdfTarget(object=p.object, name=p.object_name + tag,
                                         field=p.field)],
                      provenance={"method": "bpsflow diagnose", "extension": extension.name,
                                  "nested_at": 0.0, "reports_as": p.name})
            for p in extension.parameters]


def extend_config(config: Config, extension: Extension, directory: Path,
                  schedule: pd.Series | None = None, variant: int | None = None) -> Config:
    """A copy of ``config`` whose model includes ``extension`` (files in ``directory``).

    Parameters
    ----------
    schedule : Series, optional
        Hourly values for the extension's ``Schedule:File`` (8760 rows of the
        config's year, hour-ending order as EnergyPlus reads them); required
        when the extension has one.
    variant : int, optional
        Suffix ``_v<variant>`` on the snippet's object, schedule, file and
        parameter names, so that several variants of one extension (e.g.
        gain schedules) can sit in one model and be fitted in one batch.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    tag = "" if variant is None else f"_v{variant}"
    text = snippet_path(extension).read_text()
    renames = [(p.object_name, p.object_name + tag) for p in extension.parameters]
    if extension.schedule_name:
        renames.append((extension.schedule_name, extension.schedule_name + tag))
    schedule_file = extension.schedule_file
    if schedule_file and tag:
        stem, suffix = schedule_file.rsplit(".", 1)
        renames.append((schedule_file, f"{stem}{tag}.{suffix}"))
        schedule_file = f"{stem}{tag}.{suffix}"
    for old, new in renames:
        text = text.replace(old, new)
    snippet = directory / extension.snippet.replace(".idf", f"{tag}.idf")
    snippet.write_text(text)
    if schedule_file is not None:
        if schedule is None:
            raise ValueError(f"extension {extension.name} needs its schedule values")
        write_schedule(np.asarray(schedule, dtype=float), directory / schedule_file)
    extended = config.model_copy(deep=True)
    extended.source = config.source
    extended.model.idf_objects = [*config.model.idf_objects, snippet]
    names = {p.name for p in extended.parameters}
    extended.parameters = [*extended.parameters,
                           *[p for p in new_parameters(extension, variant)
                             if p.name not in names]]
    return extended


def write_schedule(values: np.ndarray, path: Path) -> Path:
    """One numeric column, no header: what the snippets' ``Schedule:File`` reads."""
    np.savetxt(path, np.asarray(values, dtype=float), fmt="%.6g")
    return path


def year_hours(year: int) -> pd.DatetimeIndex:
    """Hour-ending stamps of the year's first 8760 hours (the rows of an hourly Schedule:File)."""
    return pd.date_range(pd.Timestamp(year=year, month=1, day=1, hour=1), periods=8760, freq="h")


#: Day types a gain block may cover: name -> (weekdays on, weekend days on).
DAY_TYPES = {"weekdays": (1, 0), "weekends": (0, 1), "all days": (1, 1)}


def gain_blocks(residual: pd.Series, output_sign: float,
                fitted_jacobian: np.ndarray | None = None, count: int = 4,
                overlap: float = 0.8) -> list[tuple[pd.DataFrame, dict]]:
    """On/off blocks (day type × hours) of an unmodelled gain that best explain the residuals.

    Every block ``[start, end)`` hours of every day type in :data:`DAY_TYPES`
    is tried as a regressor of the residual, together with a constant and
    ``fitted_jacobian`` (the fitted parameters' responses at the residual's
    hours, ``(n, k)``): the calibration that produced the residual has bent
    those parameters towards the missing gain (e.g. more solar gain for a
    midday bump) and the joint regression partly undoes that. That screen
    is linear and the calibration's moves are not, so it is only a
    shortlist: the ``count`` blocks with the smallest residual sum of
    squares, skipping blocks that share more than ``overlap`` of their hours
    (Jaccard) with a block already listed; the joint nonlinear refit of
    each decides. A block's profile is 1 in the block and 0 elsewhere, so
    the fitted design level is the gain while it is on (W).

    Returns
    -------
    list of (profile, block)
        ``profile``: column ``profile`` indexed by ``weekend`` (0/1) × ``hour``
        (0–23, hour start); ``block``: ``day_type``, ``start_hour``,
        ``end_hour`` and the screen's ``level`` (W, oriented by
        ``output_sign``, the output's response to a gain: −1 for heating).
    """
    start = residual.index - pd.Timedelta(hours=1)
    weekend = np.asarray(start.day_of_week >= 5)
    hour = np.asarray(start.hour)
    y = residual.to_numpy(dtype=float)
    base = np.ones((len(y), 1))
    if fitted_jacobian is not None and fitted_jacobian.size:
        base = np.column_stack([base, fitted_jacobian])
    ranked = []
    for day_type, (on_weekday, on_weekend) in DAY_TYPES.items():
        day_on = np.where(weekend, on_weekend, on_weekday).astype(bool)
        for first in range(24):
            for last in range(first + 1, 25):
                block = day_on & (hour >= first) & (hour < last)
                if block.sum() < 2 or block.all():
                    continue
                design = np.column_stack([block.astype(float), base])
                coefficients = np.linalg.lstsq(design, y, rcond=None)[0]
                rss = float(np.sum((y - design @ coefficients) ** 2))
                ranked.append((rss, day_type, first, last, block,
                               float(coefficients[0]) * output_sign))
    ranked.sort(key=lambda item: item[0])
    chosen: list = []
    for item in ranked:
        if all((item[4] & c[4]).sum() / (item[4] | c[4]).sum() < overlap for c in chosen):
            chosen.append(item)
        if len(chosen) >= count:
            break
    return [(block_profile(day_type, first, last),
             {"day_type": day_type, "start_hour": first, "end_hour": last, "level": level})
            for _, day_type, first, last, _, level in chosen]


def block_profile(day_type: str, start_hour: int, end_hour: int) -> pd.DataFrame:
    """1 during ``[start_hour, end_hour)`` on the days of ``day_type``, else 0.

    Column ``profile`` indexed by ``weekend`` (0/1) × ``hour`` (0–23, hour start).
    """
    full = pd.MultiIndex.from_product([[0, 1], range(24)], names=["weekend", "hour"])
    on_weekday, on_weekend = DAY_TYPES[day_type]
    return pd.DataFrame({"profile": [float(bool(on_weekend if w else on_weekday)
                                           and start_hour <= h < end_hour) for w, h in full]},
                        index=full)


def profile_schedule(profile: pd.DataFrame, year: int) -> pd.Series:
    """The gain profile over the year's hours (hour-ending stamps, 8760 values)."""
    stamps = year_hours(year)
    start = stamps - pd.Timedelta(hours=1)
    keys = pd.MultiIndex.from_arrays([(start.day_of_week >= 5).astype(int), start.hour])
    return pd.Series(profile["profile"].reindex(keys).to_numpy(), index=stamps)
