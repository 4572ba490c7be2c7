"""Candidate drivers of the residuals: weather, solar on each facade, the calendar.

A driver is a quantity the residual (measured − calibrated prediction) may
depend on when the model misses some physics (DESIGN.md §8): the weather
file's temperature, irradiance and wind; the solar irradiance incident on each
facade and the roof (an unmodelled aperture shows up there, and the facade
says which); the hour of day and the weekend (an unmodelled schedule); and any
other measured column (e.g. a neighbouring zone's temperature).

Time axis: measured data carry hour-ENDING timestamps (the value at 01:00
covers 00:00–01:00, local standard time); the weather of that hour is the EPW
row of hour 1 of that day, found by month, day and hour
(:func:`bpsflow.weather.epw_rows`), since a TMY file's year is not the
measurement's year.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.errors import BpsflowError
from bpsflow.weather import EpwFile, epw_rows, read_epw

#: Facades and roof as ``(tilt, azimuth)`` in degrees, pvlib's convention
#: (tilt from horizontal; azimuth clockwise from north: east 90, south 180).
FACADES: dict[str, tuple[float, float]] = {
    "south": (90, 180), "east": (90, 90), "west": (90, 270), "north": (90, 0), "roof": (0, 180),
}

#: Weather drivers and the EPW column (bpsflow.weather.EPW_COLUMNS) each one reads.
WEATHER_DRIVERS: dict[str, str] = {
    "outdoor_air_temperature": "dry_bulb_temperature",
    "global_horizontal_radiation": "global_horizontal_radiation",
    "direct_normal_radiation": "direct_normal_radiation",
    "diffuse_horizontal_radiation": "diffuse_horizontal_radiation",
}

#: The derived drivers (DESIGN.md §8), in the order :func:`derive_drivers` writes
#: them; measured columns follow under their own names.
DRIVER_NAMES: tuple[str, ...] = (
    *WEATHER_DRIVERS,
    *(f"incident_solar_{facade}" for facade in FACADES),
    "wind_speed", "hour_of_day", "weekend", "day_of_week",
)

#: Units of the derived drivers.
DRIVER_UNITS: dict[str, str] = {
    "outdoor_air_temperature": "°C",
    "global_horizontal_radiation": "W/m²",
    "direct_normal_radiation": "W/m²",
    "diffuse_horizontal_radiation": "W/m²",
    **{f"incident_solar_{facade}": "W/m²" for facade in FACADES},
    "wind_speed": "m/s",
    "hour_of_day": "h",
    "weekend": "1",
    "day_of_week": "day (0 = Monday)",
}


def epw_location(epw: EpwFile) -> dict[str, float]:
    """Latitude (°N), longitude (°E), time zone (h from UTC) and elevation (m) of an EPW.

    Read from the ``LOCATION`` header line (fields 7–10).
    """
    fields = epw.header[0].split(",")
    try:
        latitude, longitude, time_zone, elevation = (float(f) for f in fields[6:10])
    except ValueError:
        raise BpsflowError("LOCATION header: fields 7-10 must be latitude, longitude, time zone "
                           f"and elevation (numbers), found {fields[6:10]}",
                           source=epw.path) from None
    return {"latitude": latitude, "longitude": longitude, "time_zone": time_zone,
            "elevation": elevation}


def _standard_time(timestamps: pd.DatetimeIndex, time_zone_h: float) -> pd.DatetimeIndex:
    """Naive local standard time (the EPW's clock); tz-aware stamps are converted first."""
    if timestamps.tz is None:
        return timestamps
    offset = pd.Timedelta(hours=time_zone_h)
    return (timestamps.tz_convert("UTC") + offset).tz_localize(None)


def incident_solar(hour_starts: pd.DatetimeIndex, location: dict[str, float],
                   weather: dict[str, np.ndarray], albedo: float = 0.2) -> dict[str, np.ndarray]:
    """Total irradiance on each of :data:`FACADES` over each hour, W/m².

    ``pvlib.irradiance.get_total_irradiance`` with the isotropic sky: beam
    ``DNI·max(cos θ, 0)`` + sky ``DHI·(1 + cos β)/2`` + ground
    ``GHI·ρ·(1 − cos β)/2`` (θ the angle of incidence, β the tilt, ρ the
    albedo). The sun is pvlib's (SPA, apparent zenith) at the middle of the
    hour (``get_solarposition`` with the site's elevation, standard
    refraction); the beam is zero when the sun is below the horizon then (an
    hour whose EPW DNI is positive at sunrise would otherwise light a
    vertical facade from below the horizon).

    Parameters
    ----------
    hour_starts : DatetimeIndex
        Start of each hour, naive local standard time.
    location : dict
        :func:`epw_location` of the weather file.
    weather : dict of ndarray
        ``global_horizontal_radiation``, ``direct_normal_radiation``,
        ``diffuse_horizontal_radiation`` (W/m²) of each hour.
    albedo : float
        Ground reflectance (-).

    Returns
    -------
    dict
        ``{facade: W/m²}`` for every facade of :data:`FACADES`.
    """
    import pvlib

    zone = pd.Timedelta(hours=location["time_zone"])
    middles_utc = (hour_starts + pd.Timedelta(minutes=30) - zone).tz_localize("UTC")
    sun = pvlib.solarposition.get_solarposition(
        middles_utc, location["latitude"], location["longitude"], altitude=location["elevation"])
    zenith = sun["apparent_zenith"].to_numpy()
    azimuth = sun["azimuth"].to_numpy()
    dni = np.where(zenith < 90.0, weather["direct_normal_radiation"], 0.0)
    out = {}
    for facade, (tilt, surface_azimuth) in FACADES.items():
        total = pvlib.irradiance.get_total_irradiance(
            tilt, surface_azimuth, zenith, azimuth, dni=dni,
            ghi=weather["global_horizontal_radiation"], dhi=weather["diffuse_horizontal_radiation"],
            albedo=albedo, model="isotropic")
        out[facade] = np.nan_to_num(np.asarray(total["poa_global"], dtype=float), nan=0.0)
    return out


def derive_drivers(weather: Path, timestamps: pd.DatetimeIndex, measured: pd.DataFrame | None = None,
                   exclude: Sequence[str] = (), albedo: float = 0.2) -> pd.DataFrame:
    """Every candidate driver at each hour-ending timestamp.

    Parameters
    ----------
    weather : Path
        EPW weather file (its LOCATION header gives latitude, longitude, time
        zone and elevation for the sun).
    timestamps : DatetimeIndex
        Hour-ending timestamps, local standard time (naive; tz-aware stamps
        are converted to the EPW's time zone). Any year: the weather is read
        by month, day and hour.
    measured : DataFrame, optional
        Measured data indexed by ``timestamps`` (or a superset); every numeric
        column not in ``exclude`` becomes a driver under its own name.
    exclude : sequence of str
        Columns that are not drivers: measured ones (the analysed output
        itself, other model outputs) or derived ones.
    albedo : float
        Ground reflectance for the ground-reflected irradiance (-).

    Returns
    -------
    DataFrame
        Indexed by ``timestamps``, columns :data:`DRIVER_NAMES` then the
        measured drivers:

        * ``outdoor_air_temperature`` — EPW dry bulb, °C;
        * ``global_horizontal_radiation``, ``direct_normal_radiation``,
          ``diffuse_horizontal_radiation`` — EPW hourly means, W/m²;
        * ``incident_solar_<south|east|west|north|roof>`` — total irradiance
          on the facade (tilt and azimuth in :data:`FACADES`), W/m²
          (:func:`incident_solar`);
        * ``wind_speed`` — EPW, m/s;
        * ``hour_of_day`` — the hour's start, 0–23 (the value at 01:00 is 0);
        * ``weekend`` — 1.0 when the hour starts on a Saturday or Sunday, else 0.0;
        * ``day_of_week`` — the day the hour starts on, 0 (Monday) to 6 (an
          unmodelled schedule on one day of the week);
        * measured columns in their own units (``measured_<name>`` when the
          name is a derived driver's).

    Raises
    ------
    BpsflowError
        The weather file does not parse, or ``measured`` lacks some of the
        timestamps.
    """
    epw = read_epw(Path(weather))
    location = epw_location(epw)
    timestamps = pd.DatetimeIndex(timestamps)
    hour_starts = _standard_time(timestamps, location["time_zone"]) - pd.Timedelta(hours=1)
    rows = epw_rows(hour_starts, epw.n_hours)
    hourly = {name: values[rows] for name, values in epw.columns.items()}

    out: dict[str, np.ndarray] = {name: hourly[column] for name, column in WEATHER_DRIVERS.items()}
    solar = incident_solar(hour_starts, location, hourly, albedo=albedo)
    out.update({f"incident_solar_{facade}": solar[facade] for facade in FACADES})
    out["wind_speed"] = hourly["wind_speed"]
    out["hour_of_day"] = hour_starts.hour.to_numpy().astype(float)
    out["weekend"] = (hour_starts.day_of_week.to_numpy() >= 5).astype(float)
    out["day_of_week"] = hour_starts.day_of_week.to_numpy().astype(float)
    drivers = pd.DataFrame(out, index=timestamps)

    left_out: list[str] = []
    if measured is not None:
        extra = [c for c in measured.select_dtypes("number").columns if c not in set(exclude)]
        if extra:
            missing = timestamps.difference(measured.index)
            if len(missing):
                raise BpsflowError(
                    f"measured data lack {len(missing)} of the analysed hours (first: "
                    f"{missing[0]}); expected a row per hour-ending timestamp")
            # A measured column named like a derived driver (an on-site outdoor
            # temperature) is kept beside the weather file's, not instead of it.
            columns = measured.loc[timestamps, extra].astype(float)
            # a column with no data over the analysed hours can explain nothing: it is
            # left out, and named in drivers.attrs for the report's notes
            empty = [c for c in extra if columns[c].notna().sum() == 0]
            columns = columns.drop(columns=empty)
            left_out = empty
            drivers = drivers.join(columns.rename(
                columns=lambda c: f"measured_{c}" if c in drivers.columns else c))
    drivers = drivers.drop(columns=[c for c in exclude if c in DRIVER_NAMES])
    drivers.attrs["left_out"] = left_out
    return drivers


def driver_group(name: str) -> str:
    """The group of a driver, which fixes the basis it is tested with.

    Returns
    -------
    str
        ``temperature`` (outdoor air temperature and measured temperatures:
        names containing ``temperature`` or ending in ``_c``), ``hour``,
        ``weekend``, ``irradiance`` (the weather irradiances, the facades, and
        measured names containing ``radiation``, ``irradiance`` or ``solar``),
        ``wind`` (names containing ``wind``, but not ``direction``) or ``other``.
    """
    lowered = name.lower()
    if lowered == "hour_of_day":
        return "hour"
    if lowered == "weekend":
        return "weekend"
    if lowered == "day_of_week":
        return "day"
    if "temperature" in lowered or lowered.endswith("_c"):
        return "temperature"
    if any(word in lowered for word in ("radiation", "irradiance", "solar")):
        return "irradiance"
    if "wind" in lowered and "direction" not in lowered:
        return "wind"
    return "other"
