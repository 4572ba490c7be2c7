"""Time-step boundary conditions of one run period for an ensemble.

Timing follows EnergyPlus: time step ``k`` ends at ``start + (k + 1) dt``;
weather-file temperatures, wind and sky radiation are hour-ending values
interpolated linearly to the step end; weather-file irradiances are hourly
integrals placed at mid-hour and interpolated the same way; the sun position
is taken at the step end. Boundary temperatures and setpoints are stepwise
hourly (``Schedule:File`` without interpolation, ``Until: HH:00``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import date, timedelta

import numpy as np
import pandas as pd

from bpsflow.boundary import SEQUENCES_FILE, read_boundary_file, read_sequences
from bpsflow.config import BoundaryTarget, Config, Period, Test, WeatherTarget, period_dates
from bpsflow.errors import BpsflowError
from bpsflow.simulation.idf import model_objects
from bpsflow.simulation.setpoints import day_setpoints
from bpsflow.surrogate.cell import Cell
from bpsflow.surrogate.solar import (
    SHADING_DAYS,
    beam_floor_fraction,
    facade_irradiance,
    sun_positions,
)
from bpsflow.weather import perturb, read_epw
from bpsflow.yearhours import day_rows

SIGMA = 5.670374419e-8
_IR_COLUMN = 12  # horizontal infrared radiation intensity, Wh/m²


@dataclass
class PeriodForcing:
    period: str
    first: date
    days: int
    steps_per_hour: int
    t_out: np.ndarray        # (M, S) °C, M = 1 or n
    wind: np.ndarray         # (M, S) m/s at the weather station
    t_sky: np.ndarray        # (1, S) °C
    pressure: np.ndarray     # (1, S) Pa
    humidity: np.ndarray     # (M, S) kg/kg
    dni: np.ndarray          # (M, S) W/m²
    dhi: np.ndarray          # (M, S)
    zenith: np.ndarray       # (S,) deg
    azimuth: np.ndarray      # (S,)
    times_utc: pd.DatetimeIndex
    month: np.ndarray        # (S,) 0..11
    boundary: list[np.ndarray | None]  # per opaque surface of the cell: (n, S) °C
    heating_setpoint: np.ndarray  # (S,)
    cooling_setpoint: np.ndarray  # (S,)
    #: The sun EnergyPlus takes for the beam's incidence (shading-period mean);
    #: ``None``: the sun of the step.
    beam_zenith: np.ndarray | None = None     # (S,) deg
    beam_azimuth: np.ndarray | None = None    # (S,) deg
    #: Values per step ``(S,)`` of the schedules the cell's air exchanges and
    #: internal gains read, by upper-case schedule name.
    schedules: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def steps_per_day(self) -> int:
        return 24 * self.steps_per_hour

    @property
    def steps(self) -> int:
        return self.days * self.steps_per_day

    def step_ends(self) -> pd.DatetimeIndex:
        """Naive local-standard-time end of each step."""
        start = pd.Timestamp(self.first)
        dt = pd.Timedelta(hours=1) / self.steps_per_hour
        return start + dt * np.arange(1, self.steps + 1)


def _interp(values: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Linear interpolation of ``values[..., rows]`` at fractional row ``position``."""
    i0 = np.clip(np.floor(position).astype(int), 0, values.shape[-1] - 2)
    w = position - i0
    return values[..., i0] * (1 - w) + values[..., i0 + 1] * w


def _humidity_ratio(dew_point_c: np.ndarray, pressure_pa: np.ndarray) -> np.ndarray:
    vapour = 611.2 * np.exp(17.62 * dew_point_c / (243.12 + dew_point_c))
    return 0.621945 * vapour / (pressure_pa - vapour)


def _period_setpoints(config: Config, period: Period, first: date, days: int,
                      steps_per_hour: int) -> tuple[np.ndarray, np.ndarray]:
    """Heating and cooling setpoint of each step (the tests' day profiles)."""
    by_day: dict[date, Test] = {}
    for test in config.tests_in(period.name):
        start = date(first.year, *map(int, test.start.split("-")))
        for d in range(test.days):
            by_day[start + timedelta(days=d)] = test
    hours = np.arange(24)
    heating, cooling = [], []
    for d in range(days):
        profiles = day_setpoints(by_day.get(first + timedelta(days=d)))
        for which, out in ((0, heating), (1, cooling)):
            day = np.empty(24)
            lower = 0
            for until, value in profiles[which]:
                day[(hours >= lower) & (hours < until)] = value
                lower = until
            out.append(np.repeat(day, steps_per_hour))
    return np.concatenate(heating), np.concatenate(cooling)


def weather_errors(config: Config, samples: pd.DataFrame) -> list[dict[str, tuple[str, float]]]:
    """Per instance ``{quantity: (mode, value)}`` for :func:`bpsflow.weather.perturb`."""
    targeted = [(p, t.weather) for p in config.parameters for t in p.targets
                if isinstance(t, WeatherTarget)]
    if not targeted:
        return []
    rows = []
    for k in range(len(samples)):
        rows.append({quantity: (p.mode, float(samples[p.name].iloc[k]))
                     for p, quantity in targeted})
    return rows


def boundary_selection(config: Config, samples: pd.DataFrame) -> dict[str, np.ndarray]:
    """Boundary surface -> per-instance sequence index chosen by its sampler."""
    out = {}
    for p in config.parameters:
        for t in p.targets:
            if isinstance(t, BoundaryTarget):
                out[t.boundary] = samples[p.name].to_numpy(dtype=float).astype(int)
    return out


def period_forcing(config: Config, cell: Cell, period: Period, samples: pd.DataFrame,
                   run_dir=None) -> PeriodForcing:
    """Build the boundary conditions of ``period`` for every instance in ``samples``."""
    first, last = period_dates(period, config.model.year)
    days = (last - first).days + 1
    tph = config.model.timesteps_per_hour
    steps = days * 24 * tph
    epw = read_epw(config.model.weather)
    n_rows = epw.n_hours
    # Position of each step end in hours since the start of the weather file. Days
    # are found in the file one by one (bpsflow.yearhours): across the end of
    # February a leap model.year repeats or skips a day of the file.
    day_starts = day_rows(first, days, n_rows)
    row0 = int(day_starts[0])
    jumps = day_starts - (row0 + 24 * np.arange(days))   # 0 unless a day repeats or is skipped
    ends = row0 + np.arange(1, steps + 1) / tph + np.repeat(jumps, 24 * tph)
    lo = max(int(day_starts.min()) - 2, 0)
    hi = min(int(day_starts.max()) + 24 + 2, n_rows)
    window = slice(lo, hi)
    temperature_pos = ends - 1 - lo   # hour-ending values: row r sits at hour r + 1
    solar_pos = ends - 0.5 - lo       # hourly integrals: row r sits at hour r + 0.5

    errors = weather_errors(config, samples)
    names = ("dry_bulb_temperature", "dew_point_temperature", "wind_speed",
             "direct_normal_radiation", "diffuse_horizontal_radiation")
    base = {name: epw.columns[name][window][None, :] for name in names}
    if errors:
        changed = {name: np.repeat(base[name], len(samples), axis=0) for name in names}
        for k, instance_errors in enumerate(errors):
            new = perturb(epw, instance_errors)
            for name in names:
                if name in new:
                    changed[name][k] = new[name][window]
        base = changed
    pressure = epw.columns["atmospheric_pressure"][window][None, :]
    infrared = np.array([float(row[_IR_COLUMN]) for row in epw.rows[window]])[None, :]

    t_out = _interp(base["dry_bulb_temperature"], temperature_pos)
    pressure_s = _interp(pressure, temperature_pos)
    humidity = _humidity_ratio(np.minimum(_interp(base["dew_point_temperature"], temperature_pos),
                                          t_out), pressure_s)
    t_sky = (_interp(infrared, temperature_pos) / SIGMA) ** 0.25 - 273.15

    header = epw.header[0].split(",")
    latitude, longitude, tz = float(header[6]), float(header[7]), float(header[8])
    local_ends = pd.Timestamp(first) + pd.to_timedelta(np.arange(1, steps + 1) / tph, unit="h")
    utc = pd.DatetimeIndex(local_ends - pd.Timedelta(hours=tz)).tz_localize("UTC")
    zenith, azimuth, beam_zenith, beam_azimuth = sun_positions(
        pd.DatetimeIndex(local_ends), latitude, longitude, tz, shading_days(config))
    # EnergyPlus has no sun (and no solar irradiance) in time steps whose sun
    # is below the horizon, whatever the interpolated weather-file values say.
    sun_up = zenith < 90.0

    boundary = _boundary(config, cell, samples, first, days, tph, run_dir)
    heating, cooling = _period_setpoints(config, period, first, days, tph)
    return PeriodForcing(
        period=period.name, first=first, days=days, steps_per_hour=tph, t_out=t_out,
        wind=np.clip(_interp(base["wind_speed"], temperature_pos), 0.0, None),
        t_sky=t_sky, pressure=pressure_s, humidity=humidity,
        dni=np.where(sun_up, np.clip(_interp(base["direct_normal_radiation"], solar_pos), 0.0,
                                     None), 0.0),
        dhi=np.where(sun_up, np.clip(_interp(base["diffuse_horizontal_radiation"], solar_pos),
                                     0.0, None), 0.0),
        zenith=zenith, azimuth=azimuth, times_utc=utc,
        month=np.array(local_ends.month - 1), boundary=boundary,
        heating_setpoint=heating, cooling_setpoint=cooling, beam_zenith=beam_zenith,
        beam_azimuth=beam_azimuth, schedules=schedule_steps(cell, first, days, tph))


def schedule_steps(cell: Cell, first: date, days: int, steps_per_hour: int
                   ) -> dict[str, np.ndarray]:
    """Per-step values ``(days * 24 * tph,)`` of every schedule the cell's objects read."""
    return {name: schedule.steps(first, days, steps_per_hour)
            for name, schedule in cell.schedules().items()}


def shading_days(config: Config) -> int | None:
    """The model's shading-calculation update frequency (days; ``None``: every time step)."""
    objects = model_objects(config.model).of_type("SHADOWCALCULATION")
    if not objects:
        return SHADING_DAYS
    shadow = objects[0]
    if shadow.get("Shading Calculation Update Frequency Method").strip().upper() == "TIMESTEP":
        return None
    return max(1, int(shadow.number("Shading Calculation Update Frequency", SHADING_DAYS)))


def _boundary(config: Config, cell: Cell, samples: pd.DataFrame, first: date, days: int,
              tph: int, run_dir) -> list[np.ndarray | None]:
    boundary = config.model.boundary
    needed = {k for surface in cell.opaque for k in surface.boundary_weights}
    if not needed:
        return [None] * len(cell.opaque)
    columns = tuple(boundary.surfaces[s].column for s in boundary.surfaces)
    table = read_boundary_file(boundary.file, columns)
    # the boundary file's own rows (its length may differ from the weather file's)
    rows = (day_rows(first, days, len(table))[:, None] + np.arange(24)[None, :]).ravel()
    selection = boundary_selection(config, samples)
    sequences = None
    if selection:
        directory = (run_dir or config.run_dir).resolve()
        sequences = read_sequences(directory / SEQUENCES_FILE)
        position = np.searchsorted(sequences.hours, rows)
        if np.any(position >= len(sequences.hours)) or \
                np.any(sequences.hours[np.minimum(position, len(sequences.hours) - 1)] != rows):
            raise BpsflowError(f"{directory / SEQUENCES_FILE} does not cover the run periods; "
                               f"run 'bpsflow sample' again")
    hourly = {}
    n = len(samples)
    for surface in needed:
        measured = table[boundary.surfaces[surface].column].to_numpy(dtype=float)[rows]
        if surface in selection:
            index = selection[surface]
            if index.min() < 0 or index.max() >= sequences.values.shape[1]:
                raise BpsflowError(f"boundary sampler for '{surface}' selects a sequence "
                                   f"outside 0..{sequences.values.shape[1] - 1}")
            s = sequences.surfaces.index(surface)
            hourly[surface] = sequences.values[s][index][:, position].astype(float)
        else:
            hourly[surface] = np.broadcast_to(measured, (n, len(rows)))
    out: list[np.ndarray | None] = []
    for surface in cell.opaque:
        if not surface.boundary_weights:
            out.append(None)
            continue
        total = sum(w * hourly[s] for s, w in surface.boundary_weights.items())
        out.append(np.repeat(total, tph, axis=1))
    return out


def beam_sun(forcing: PeriodForcing, steps: slice) -> tuple[np.ndarray, np.ndarray]:
    """Zenith and azimuth (degrees) of the sun that casts the beam over ``steps``."""
    if forcing.beam_zenith is None:
        return forcing.zenith[steps], forcing.azimuth[steps]
    return forcing.beam_zenith[steps], forcing.beam_azimuth[steps]


def ground_reflected_irradiance(cell: Cell, forcing: PeriodForcing, steps: slice) -> np.ndarray:
    """Solar irradiance reflected by the ground, ``rho_g (DNI cos Z + DHI)``; W/m², ``(n, s)``.

    EnergyPlus's "Site Ground Reflected Solar Radiation Rate per Area", with
    the month's ground reflectance of each instance.
    """
    cos_zenith = np.clip(np.cos(np.radians(forcing.zenith[steps])), 0.0, None)
    ghi = forcing.dni[:, steps] * cos_zenith + forcing.dhi[:, steps]
    return cell.ground_reflectance[:, forcing.month[steps]] * ghi


def surface_irradiance(cell: Cell, forcing: PeriodForcing, steps: slice, tilt: float,
                       surface_azimuth: float, ground: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Solar irradiance incident on an unshaded outside face over ``steps``.

    Parameters
    ----------
    tilt, surface_azimuth : float
        Orientation of the face's outward normal (degrees).
    ground : ndarray, optional
        :func:`ground_reflected_irradiance` over ``steps`` when already known.

    Returns
    -------
    beam, sky, ground, cos_incidence
        Beam and sky-diffuse irradiance (W/m², ``(M, s)``, M = 1 or n), the
        ground-reflected irradiance the face sees, ``(1 - cos tilt) / 2`` of
        the ground's (W/m², ``(n, s)``), and the cosine of the beam's angle of
        incidence ``(s,)``.
    """
    if ground is None:
        ground = ground_reflected_irradiance(cell, forcing, steps)
    beam_zenith, beam_azimuth = beam_sun(forcing, steps)
    beam, sky, cos_incidence = facade_irradiance(
        forcing.times_utc[steps], forcing.zenith[steps], forcing.azimuth[steps],
        forcing.dni[:, steps], forcing.dhi[:, steps], tilt, surface_azimuth,
        beam_zenith, beam_azimuth)
    view = (1 - np.cos(np.radians(tilt))) / 2
    return beam, sky, view * ground, cos_incidence


def solar_inputs(cell: Cell, forcing: PeriodForcing, steps: slice) -> dict[str, np.ndarray]:
    """Absorbed solar power (W) per receiving node group over ``steps``: ``(n, s)`` each.

    Keys: ``"out:<i>"`` outside face of opaque surface ``i``, ``"in:<i>"`` its
    inside face, ``"pane_out"``, ``"pane_in"``, and ``"lost"`` (transmitted back
    out through the window).
    """
    from bpsflow.surrogate.solar import angle_lookup, lookup

    n = cell.n
    zenith = forcing.zenith[steps]
    ground = ground_reflected_irradiance(cell, forcing, steps)
    cache: dict[tuple[float, float], tuple] = {}

    def incident(tilt, surface_azimuth):
        key = (round(tilt, 3), round(surface_azimuth, 3))
        if key not in cache:
            beam, sky, from_ground, cos_i = surface_irradiance(cell, forcing, steps, tilt,
                                                               surface_azimuth, ground)
            cache[key] = (np.broadcast_to(beam, (n, len(zenith))), sky + from_ground, cos_i)
        return cache[key]

    out: dict[str, np.ndarray] = {}
    for i, surface in enumerate(cell.opaque):
        if surface.outdoor:
            beam, diffuse, _ = incident(surface.tilt, surface.azimuth)
            out[f"out:{i}"] = surface.absorptance_out[:, None] * (beam + diffuse) * surface.area
    w = cell.window
    g = w.glazing
    beam, diffuse, cos_i = incident(w.tilt, w.azimuth)
    index, weight = angle_lookup(cos_i)
    out["pane_out"] = (lookup(g.absorbed_out, index, weight) * beam
                       + g.diffuse_absorbed_out[:, None] * diffuse) * w.area
    out["pane_in"] = (lookup(g.absorbed_in, index, weight) * beam
                      + g.diffuse_absorbed_in[:, None] * diffuse) * w.area
    transmitted_beam = lookup(g.transmittance, index, weight) * beam * w.area
    transmitted_diffuse = g.diffuse_transmittance[:, None] * diffuse * w.area
    pool = np.zeros_like(transmitted_diffuse)
    # Beam: onto the floor where the sunlit patch lies inside it, else the walls.
    if abs(w.azimuth - 180.0) < 1.0 and abs(w.tilt - 90.0) < 1.0:
        on_floor = beam_floor_fraction(*beam_sun(forcing, steps), w.x_range, w.z_range,
                                       cell.floor_x, cell.floor_depth)
    else:
        on_floor = np.ones(len(zenith))
    floors = [i for i, s in enumerate(cell.opaque) if s.kind == "floor"]
    walls = [i for i, s in enumerate(cell.opaque) if s.kind == "wall" and not s.outdoor]
    if not walls:
        on_floor = np.ones_like(on_floor)
    for i in range(len(cell.opaque)):
        out[f"in:{i}"] = np.zeros((n, len(zenith)))
    # Transmitted diffuse first falls on the surfaces the window sees (not its
    # own wall), in proportion to their area (approximate view factors).
    # Areas as (n, 1): an internal mass's area may differ between instances.
    areas = [np.broadcast_to(np.asarray(s.area, dtype=float), (n,))[:, None]
             for s in cell.opaque]
    seen = [i for i, s in enumerate(cell.opaque) if not s.outdoor]
    seen_area = sum(areas[i] for i in seen)
    targets = [(floors, transmitted_beam * on_floor), (walls, transmitted_beam * (1 - on_floor))]
    targets += [([i], transmitted_diffuse * (areas[i] / seen_area)) for i in seen]
    for group, light in targets:
        area = sum(areas[i] for i in group)
        for i in group:
            hit = light * (areas[i] / area)
            absorbed = cell.opaque[i].absorptance_in[:, None] * hit
            out[f"in:{i}"] += absorbed
            pool = pool + hit - absorbed
    # Diffuse light inside: absorbed in proportion to area x absorptance; the
    # window takes its share by what it does not reflect back.
    back_t, back_in, back_out = (g.back_transmittance, g.back_absorbed_in, g.back_absorbed_out)
    weights = [s.area * s.absorptance_in for s in cell.opaque]
    window_weight = w.area * (back_t + back_in + back_out)
    total = sum(weights) + window_weight
    for i, weight_i in enumerate(weights):
        out[f"in:{i}"] += pool * (weight_i / total)[:, None]
    window_share = pool * (window_weight / total)[:, None]
    fraction = (back_t + back_in + back_out)[:, None]
    out["pane_in"] = out["pane_in"] + window_share * back_in[:, None] / fraction
    out["pane_out"] = out["pane_out"] + window_share * back_out[:, None] / fraction
    out["lost"] = window_share * back_t[:, None] / fraction
    out["transmitted"] = transmitted_beam + g.diffuse_transmittance[:, None] * diffuse * w.area
    return out


def constant_forcing(cell: Cell, days: int = 10, steps_per_hour: int = 6, t_out: float = 10.0,
                     boundary_c: float | dict[int, float] = 20.0, heating_c: float = -60.0,
                     cooling_c: float = 100.0, wind: float = 0.0, t_sky: float | None = None,
                     first: date = date(2025, 1, 1)) -> PeriodForcing:
    """Steady, sunless boundary conditions (for checks of the network's physics).

    ``boundary_c`` is one temperature for every boundary surface or a mapping
    from the index of an opaque surface of ``cell`` to its temperature.
    """
    steps = days * 24 * steps_per_hour
    n = cell.n
    row = lambda value: np.full((1, steps), float(value))  # noqa: E731
    boundary = []
    for i, surface in enumerate(cell.opaque):
        if surface.outdoor or surface.adiabatic:
            boundary.append(None)
        else:
            value = boundary_c.get(i, 20.0) if isinstance(boundary_c, dict) else boundary_c
            boundary.append(np.full((n, steps), float(value)))
    local = pd.Timestamp(first) + pd.to_timedelta(np.arange(1, steps + 1) / steps_per_hour,
                                                  unit="h")
    return PeriodForcing(
        period="constant", first=first, days=days, steps_per_hour=steps_per_hour,
        t_out=row(t_out), wind=row(wind), t_sky=row(t_out if t_sky is None else t_sky),
        pressure=row(101325.0), humidity=row(0.006), dni=row(0.0), dhi=row(0.0),
        zenith=np.full(steps, 120.0), azimuth=np.full(steps, 0.0),
        times_utc=pd.DatetimeIndex(local).tz_localize("UTC"), month=np.array(local.month - 1),
        boundary=boundary, heating_setpoint=np.full(steps, heating_c),
        cooling_setpoint=np.full(steps, cooling_c),
        schedules=schedule_steps(cell, first, days, steps_per_hour))
