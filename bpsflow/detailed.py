"""Detailed measurements of the test cell and their sensor errors (seed §3.4.3–3.5).

The refinement of seed §3.5 estimates inputs from *detailed* measurements:
interior surface heat balances give the convection coefficients (eq. 15–17),
air temperatures near ceiling and floor the stratification gradient (eq. 18),
pyranometers the glazing transmittance and the ground reflectance (§3.5.3–3.5.4),
and 9 sensors per guarded surface its boundary temperature (eq. 12–13). This
module is the one place that defines those measurements:

* the true quantities, as EnergyPlus output variables a truth instance reports
  (:func:`detailed_outputs`; the surrogate computes the same variable/key pairs);
* the columns of ``detailed.csv`` (hour-ending ``timestamp`` over every run
  period's whole span) and ``sensor_calibration.csv``;
* the sensor-error model (seed eq. 8–9, 12, Table 3.2 bounds read as 3 std):

  - temperature sensor *i* (every column ending ``_c``): reading = true +
    δ_i + N(0, σ_i²), a constant bias δ_i ~ U(-0.05, 0.05) °C and a random
    error σ_i ~ U(0.01, 0.02) °C, both drawn once per sensor;
  - the calibration reference: true + N(0, σ_M²), σ_M = 0.05/3 °C;
  - irradiance, net radiation and heat flux: reading = true · (1 + ε),
    ε ~ N(0, (0.05/3)²) per reading. Table 3.2 lists no heat-flux sensor; the
    ±5 % of its irradiance sensors is assumed for heat-flux plates too;
  - ``<class>_h_c_w_m2k``: the convection coefficient a laboratory derives from
    its heat balance (eq. 15–16) at its own logging interval (minutes) and
    averages to the hour, read like a heat flux: true · (1 + ε). It is
    optional in a ``detailed.csv``; without it a refinement falls back on the
    hourly heat balance, which is biased for this model (EnergyPlus couples
    convection to the previous time step's air temperature, and an hourly mean
    of q/ΔT is not q̄/ΔT̄).

Files written by ``bpsflow synth --detailed``: ``detailed.csv``,
``sensor_calibration.csv`` and ``detailed.json`` (metadata a refinement may
use); the true values behind them go to the ``detailed`` block of
``truth.json``.

Where the sensors are (:func:`sensor_surfaces`) is read from the model's
geometry; no name of a shipped model is written here. The zone is the config's
``detailed.zone`` or the model's only zone. Each class is chosen among the
zone's ``BuildingSurface:Detailed`` of its Surface Type (wall: Wall; ceiling:
Ceiling or Roof; floor: Floor):

* ceiling, floor: the largest, then the first in the file;
* wall, ranked by
  (1) no window or door in it (glazing puts sun patches and frame losses
  beside the sensors);
  (2) most nearly perpendicular to the window's facade, i.e. the smallest
  |n_wall · n_window| (a side wall: sunlight through the window reaches it only
  at grazing angles, which keeps the radiation term of eq. 15 small);
  (3) the larger area; (4) the first clockwise from north (the smaller
  azimuth of its outward normal); (5) file order;
* window: the zone's exterior glazing (``FenestrationSurface:Detailed`` of
  type Window or GlassDoor on a surface whose outside boundary is Outdoors)
  with the largest glazed area (area × multiplier), then the first in the
  file; its facade is the surface it is on.

Outward normals are Newell's vector area of the vertices, reversed for
``GlobalGeometryRules`` Clockwise entry. Azimuths are clockwise from true
north: with Relative coordinates (EnergyPlus's default) Building North Axis and
the zone's Direction of Relative North are added; with World coordinates
EnergyPlus ignores both, and so does this. On the shipped test cell the rules
give the surfaces the sensors have always been on: rule (1) drops the south
wall, rule (2) the north wall, the east and west walls tie on (3), and rule
(4) — a convention, kept because the test cell's sensors were put on the east
wall — takes east (90°) before west (270°). Any of them can be named instead:
``detailed.wall``, ``detailed.ceiling``, ``detailed.floor``, ``detailed.window``
(checked against the zone's surfaces of that kind).
"""

from __future__ import annotations

import json
import math
import tempfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.config import BoundaryTarget, Config, IdfTarget, OutputVariable, Test, period_dates
from bpsflow.errors import BpsflowError
from bpsflow.files import write_csv, write_json
from bpsflow.simulation.idf import inside_convection_curve, polygon_area
from bpsflow.tables import read_table

DETAILED_FILE = "detailed.csv"
CALIBRATION_FILE = "sensor_calibration.csv"
METADATA_FILE = "detailed.json"

# Sensor-error model (seed eq. 8-9, 12; Table 3.2 bounds read as 3 standard deviations).
#: Standard deviation of the calibration reference sensor, °C (Table 3.2: ±0.05 °C).
REFERENCE_STD_C = 0.05 / 3
#: Bound of the uniform constant bias of an uncalibrated temperature sensor, °C.
BIAS_BOUND_C = 0.05
#: Range of the uniform draw of a temperature sensor's random-error std, °C.
SENSOR_STD_RANGE_C = (0.01, 0.02)
#: Relative standard deviation of irradiance, net-radiation and heat-flux readings.
RELATIVE_STD = 0.05 / 3
#: Boundary temperature sensors per guarded surface, of equal representative area (§3.4.5).
BOUNDARY_SENSORS = 9
#: Calibration campaign: readings, plateaus of the bath temperature and their range, °C.
CALIBRATION_READINGS = 200
CALIBRATION_PLATEAUS = 20
CALIBRATION_RANGE_C = (15.0, 35.0)

#: Surface classes with their own sensors and convection correlation (seed Table 3.4).
SURFACE_CLASSES = ("wall", "ceiling", "floor")
#: Surface class -> the ``Surface Type`` values of BuildingSurface:Detailed it is chosen from.
CLASS_SURFACE_TYPES = {"wall": ("WALL",), "ceiling": ("CEILING", "ROOF"), "floor": ("FLOOR",)}
#: ``Surface Type`` values of FenestrationSurface:Detailed that are glazing.
WINDOW_TYPES = ("WINDOW", "GLASSDOOR")
#: Config keys (``detailed.<key>``) that name the sensors' zone, surfaces and window.
SETTING_KEYS = ("zone", *SURFACE_CLASSES, "window")
#: EnergyPlus's key of site (weather) variables.
SITE_KEY = "Environment"

#: ``<class>_<suffix>`` output -> EnergyPlus variable at the surface's inside face, unit.
SURFACE_VARIABLES = {
    "surface_c": ("Surface Inside Face Temperature", "C"),
    "air_c": ("Surface Inside Face Adjacent Air Temperature", "C"),
    "h_c_w_m2k": ("Surface Inside Face Convection Heat Transfer Coefficient", "W/m2-K"),
    "convection_w_m2": ("Surface Inside Face Convection Heat Gain Rate per Area", "W/m2"),
    "conduction_w_m2": ("Surface Inside Face Conduction Heat Transfer Rate per Area", "W/m2"),
    "thermal_radiation_w_m2": (
        "Surface Inside Face Net Surface Thermal Radiation Heat Gain Rate per Area", "W/m2"),
    "solar_radiation_w_m2": ("Surface Inside Face Solar Radiation Heat Gain Rate per Area", "W/m2"),
}
#: Other true quantities: output -> (EnergyPlus variable, what it is of, unit); "window" and
#: "facade" are the :func:`sensor_surfaces` window and its host surface, "site" the weather.
OTHER_OUTPUTS = {
    "window_transmitted_w": ("Surface Window Transmitted Solar Radiation Rate", "window", "W"),
    "window_incident_w_m2": ("Surface Outside Face Incident Solar Radiation Rate per Area",
                             "window", "W/m2"),
    "south_ground_reflected_w_m2": (
        "Surface Outside Face Incident Ground Diffuse Solar Radiation Rate per Area",
        "facade", "W/m2"),
    "site_ground_reflected_w_m2": ("Site Ground Reflected Solar Radiation Rate per Area",
                                   "site", "W/m2"),
    "site_direct_w_m2": ("Site Direct Solar Radiation Rate per Area", "site", "W/m2"),
    "site_diffuse_w_m2": ("Site Diffuse Solar Radiation Rate per Area", "site", "W/m2"),
    "site_solar_altitude_deg": ("Site Solar Altitude Angle", "site", "deg"),
}

#: Per-class columns of ``detailed.csv``.
CLASS_COLUMN_SUFFIXES = ("surface_c", "air_c", "conduction_w_m2", "radiation_w_m2", "h_c_w_m2k")
#: Columns of ``detailed.csv`` that do not depend on the config.
OTHER_COLUMNS = ("window_transmitted_w_m2", "window_incident_w_m2", "global_horizontal_w_m2",
                 "south_ground_reflected_w_m2")
#: Columns a detailed.csv may leave out (the laboratory's derived convection coefficient).
OPTIONAL_SUFFIXES = ("_h_c_w_m2k",)

#: Prefix of the free-floating tests spanning each run period that carry the detailed outputs.
SPAN_TEST_PREFIX = "detailed-"


# Names ----------------------------------------------------------------------

def boundary_columns(surfaces: Iterable[str]) -> list[str]:
    """``boundary_<surface>_s<k>_c``, k = 1..9, for each boundary surface key."""
    return [f"boundary_{surface}_s{k}_c" for surface in surfaces
            for k in range(1, BOUNDARY_SENSORS + 1)]


def class_columns() -> list[str]:
    return [f"{c}_{suffix}" for c in SURFACE_CLASSES for suffix in CLASS_COLUMN_SUFFIXES]


def detailed_columns(surfaces: Iterable[str]) -> list[str]:
    """Every sensor column of ``detailed.csv`` (after ``timestamp``), in file order."""
    return boundary_columns(surfaces) + class_columns() + list(OTHER_COLUMNS)


def temperature_columns(columns: Iterable[str]) -> list[str]:
    """The temperature sensors: every column ending ``_c``."""
    return [c for c in columns if c.endswith("_c")]


def detailed_outputs(config: Config) -> dict[str, OutputVariable]:
    """The true quantities behind the detailed measurements, as config outputs.

    Returns
    -------
    dict
        Output name -> EnergyPlus variable and key (``<class>_<quantity>`` for
        wall/ceiling/floor, window, window facade and site quantities); the
        keys are the :func:`sensor_surfaces` of the model.

    Raises
    ------
    BpsflowError
        When the config already has an output of one of these names that
        reads another variable or key, or the sensors' surfaces cannot be
        chosen (see :func:`select_sensor_surfaces`).
    """
    sensors = sensor_surfaces(config)
    window, facade = sensors.glazing(config.source)
    keys = {"window": window, "facade": facade, "site": SITE_KEY}
    wanted: dict[str, OutputVariable] = {}
    for surface_class, surface in sensors.surfaces.items():
        for suffix, (variable, unit) in SURFACE_VARIABLES.items():
            wanted[f"{surface_class}_{suffix}"] = OutputVariable(variable=variable, key=surface,
                                                                 unit=unit)
    for name, (variable, of, unit) in OTHER_OUTPUTS.items():
        wanted[name] = OutputVariable(variable=variable, key=keys[of], unit=unit)
    for name, spec in wanted.items():
        have = config.outputs.get(name)
        # A meter (no variable or key) or another reporting frequency under the name clashes too.
        if have is not None and ((have.variable or "").upper() != spec.variable.upper()
                                 or (have.key or "").upper() != spec.key.upper()
                                 or have.scale != 1.0
                                 or getattr(have, "frequency", None) != getattr(spec, "frequency",
                                                                                None)):
            raise BpsflowError(f"outputs.{name}: the detailed measurements use this name for "
                               f"'{spec.variable}' of '{spec.key}'; rename the config's output",
                               source=config.source)
    return wanted


def add_detailed_outputs(config: Config) -> list[str]:
    """Make ``config`` (a copy) report the detailed outputs over each run period's whole span.

    Adds the outputs and, per run period, a free-floating test spanning it
    that carries them. The span tests go *first*: the setpoint schedules take
    the last test covering a day, so the real tests keep their control and
    days outside every test float as they would anyway.

    Returns
    -------
    list of str
        Names of the added span tests.
    """
    outputs = detailed_outputs(config)
    config.outputs.update(outputs)
    taken = {t.name for t in config.model.tests}
    span_tests = []
    for period in config.model.periods:
        first, last = period_dates(period, config.model.year)
        name = f"{SPAN_TEST_PREFIX}{period.name}"
        while name in taken:
            name += "_"
        taken.add(name)
        span_tests.append(Test(name=name, period=period.name, start=period.start,
                               days=(last - first).days + 1, warmup_days=0,
                               mode="free_floating", outputs=sorted(outputs)))
    config.model.tests = span_tests + list(config.model.tests)
    return [t.name for t in span_tests]


# The model's geometry and true values ---------------------------------------

def _idf(config: Config):
    # The surrogate's IDD-free reader: geometry and fields without EnergyPlus installed.
    from bpsflow.simulation.idf import model_objects

    return model_objects(config.model)


def _surface(idf, name: str):
    for object_type in ("BUILDINGSURFACE:DETAILED", "FENESTRATIONSURFACE:DETAILED"):
        for obj in idf.of_type(object_type):
            if obj.name.upper() == name.upper():
                return obj
    raise BpsflowError(f"the detailed measurements need a surface named '{name}' in the model",
                       source=idf.path)


def _z_range(vertices) -> tuple[float, float]:
    heights = [v[2] for v in vertices]
    return min(heights), max(heights)


def newell_normal(vertices: Sequence[Sequence[float]]) -> np.ndarray:
    """Newell's vector area of a planar polygon: Σ v_k × v_(k+1).

    Parameters
    ----------
    vertices : sequence of (x, y, z)
        The polygon's vertices in order, m.

    Returns
    -------
    ndarray
        Normal to the polygon's plane, of length twice its area (m²), pointing to
        the side from which the vertices run counterclockwise.
    """
    vertices = list(vertices)
    normal = np.zeros(3)
    for a, b in zip(vertices, vertices[1:] + vertices[:1], strict=True):
        normal += np.cross(np.asarray(a, dtype=float), np.asarray(b, dtype=float))
    return normal


def outward_normal(vertices: Sequence[Sequence[float]], clockwise: bool = False) -> np.ndarray:
    """Unit outward normal of a surface (zero for a degenerate polygon).

    Parameters
    ----------
    vertices : sequence of (x, y, z)
        The surface's vertices as the IDF lists them, m.
    clockwise : bool
        ``GlobalGeometryRules`` Vertex Entry Direction is Clockwise (EnergyPlus
        lists vertices counterclockwise seen from outside unless it says so).
    """
    normal = newell_normal(vertices)
    if clockwise:
        normal = -normal
    length = float(np.linalg.norm(normal))
    return normal / length if length else normal


def azimuth_deg(direction: Sequence[float], north_axis_deg: float = 0.0) -> float:
    """Azimuth of a direction's horizontal part, clockwise from true north, degrees in [0, 360).

    Parameters
    ----------
    direction : (x, y, z)
        In model coordinates: x east and y north of the building.
    north_axis_deg : float
        Clockwise angle from true north to the building's y axis, degrees
        (:func:`north_axis_deg`).
    """
    return (math.degrees(math.atan2(direction[0], direction[1])) + north_axis_deg) % 360.0


def _tilt_deg(vertices, clockwise: bool = False) -> float:
    """Tilt of a surface's outward normal from vertical up (0 facing up, 90 vertical), degrees."""
    normal = newell_normal(vertices)
    if clockwise:
        normal = -normal
    length = float(np.linalg.norm(normal))
    return math.degrees(math.acos(max(-1.0, min(1.0, normal[2] / length)))) if length else 90.0


def geometry_rules(idf) -> tuple[bool, bool]:
    """How the model's vertices are written: (clockwise entry, world coordinates).

    From ``GlobalGeometryRules``; without one, EnergyPlus's defaults
    (counterclockwise, relative coordinates).
    """
    rules = idf.of_type("GLOBALGEOMETRYRULES")
    # The IDD-free reader has no field table for this object: fields by IDD position
    # (Starting Vertex Position, Vertex Entry Direction, Coordinate System).
    fields = [f.strip().upper() for f in rules[0].fields] if rules else []
    direction = fields[1] if len(fields) > 1 else ""
    system = fields[2] if len(fields) > 2 else ""
    return direction == "CLOCKWISE", system in ("WORLD", "ABSOLUTE")


def north_axis_deg(idf, zone: str) -> float:
    """Clockwise angle from true north to the y axis of a zone's vertices, degrees.

    Building North Axis plus the zone's Direction of Relative North for
    relative coordinates; 0 for world coordinates, where EnergyPlus ignores
    both ("World Coordinate System selected. Any non-zero Building/Zone North
    Axes ... are ignored").
    """
    if geometry_rules(idf)[1]:
        return 0.0
    building = idf.of_type("BUILDING")
    angle = building[0].number("North Axis", 0.0) if building else 0.0
    for obj in idf.of_type("ZONE"):
        # No field table for Zone either: Direction of Relative North is its second field.
        text = obj.fields[1].strip() if len(obj.fields) > 1 else ""
        if obj.name.upper() == zone.upper() and text:
            try:
                angle += float(text)
            except ValueError:
                raise BpsflowError(f"Zone '{obj.name}': Direction of Relative North holds "
                                   f"'{text}', not a number", source=idf.path) from None
    return angle


# Where the sensors are ---------------------------------------------------------

#: How each choice was made when the config did not name it (``SensorSurfaces.chosen_by``).
RULES = {
    "zone": "the model's only zone",
    "wall": "window-free wall most nearly perpendicular to the window's facade, then the "
            "largest, then the first clockwise from north",
    "ceiling": "largest ceiling or roof of the zone",
    "floor": "largest floor of the zone",
    "window": "largest exterior window of the zone",
}


@dataclass(frozen=True)
class SensorSurfaces:
    """Where the detailed sensors are: the zone, one surface per class, the window.

    Attributes
    ----------
    zone : str
        The zone measured (spelled as in the model).
    surfaces : dict
        Surface class (``wall``, ``ceiling``, ``floor``) -> BuildingSurface:Detailed name.
    window : str or None
        The FenestrationSurface:Detailed whose transmitted and incident
        irradiance is measured; None when the zone has no exterior window and
        the config names none.
    facade : str or None
        The surface the window is on (its ground-reflected irradiance is measured).
    chosen_by : dict
        ``zone``, each class and ``window`` -> ``detailed.<key>`` when the
        config named it, else the rule that chose it (:data:`RULES`).
    """

    zone: str
    surfaces: dict[str, str]
    window: str | None
    facade: str | None
    chosen_by: dict[str, str]

    def glazing(self, source: str | Path | None = None) -> tuple[str, str]:
        """(window, facade), or a BpsflowError naming ``detailed.window`` when there is none."""
        if self.window is None or self.facade is None:
            raise BpsflowError(
                f"the detailed measurements need an exterior window in zone '{self.zone}' (a "
                f"FenestrationSurface:Detailed of type Window or GlassDoor on a surface whose "
                f"Outside Boundary Condition is Outdoors) and the model has none; name the "
                f"measured window with detailed.window", source=source)
        return self.window, self.facade


def sensor_surfaces(config: Config) -> SensorSurfaces:
    """The zone, surfaces and window of the detailed sensors in ``config``'s model.

    The config's ``detailed`` keys (``zone``, ``wall``, ``ceiling``, ``floor``,
    ``window``) where given, the module's geometric rules for the rest; see
    :func:`select_sensor_surfaces`.
    """
    return select_sensor_surfaces(_idf(config), getattr(config, "detailed", None) or {},
                                  config.source)


def select_sensor_surfaces(idf, settings: dict[str, str] | None = None,
                           source: str | Path | None = None) -> SensorSurfaces:
    """Choose the zone, a surface per class and the window from the model's geometry.

    The rules are the module's (see its notes): a named setting is checked
    against the model and used; everything else is chosen by Surface Type,
    outward normal, area and azimuth.

    Parameters
    ----------
    idf : IdfModel
        The model (:func:`bpsflow.simulation.idf.model_objects`).
    settings : dict, optional
        ``detailed.<key>`` -> IDF name, keys among :data:`SETTING_KEYS`.
    source : str or Path, optional
        The config file, for messages about its keys (default: the model file).

    Returns
    -------
    SensorSurfaces

    Raises
    ------
    BpsflowError
        Naming the ``detailed.<key>`` to set when the model has several zones
        and none is named, or the key and the model's candidates when a named
        zone, surface or window is not one of them; also when the zone has no
        surface of a class.
    """
    settings = {key: str(value).strip() for key, value in (settings or {}).items()}
    where = source or idf.path
    for key, value in settings.items():
        if key not in SETTING_KEYS:
            raise BpsflowError(f"detailed.{key}: unknown key, expected one of "
                               f"{', '.join(SETTING_KEYS)}", source=where)
        if not value:
            raise BpsflowError(f"detailed.{key}: empty name", source=where)
    zone, chosen_by = _sensor_zone(idf, settings.get("zone"), where)
    clockwise = geometry_rules(idf)[0]
    north = north_axis_deg(idf, zone)
    every = idf.of_type("BUILDINGSURFACE:DETAILED")
    in_zone = [(i, s) for i, s in enumerate(every) if s.get("Zone Name").upper() == zone.upper()]
    window, facade, chosen_by["window"] = _sensor_window(idf, zone, in_zone,
                                                         settings.get("window"), where)
    window_normal = None if window is None else outward_normal(window.vertices(), clockwise)
    hosts = {f.get("Building Surface Name").upper()
             for f in idf.of_type("FENESTRATIONSURFACE:DETAILED")}

    def wall_rank(item):
        index, surface = item
        normal = outward_normal(surface.vertices(), clockwise)
        facing = 0.0 if window_normal is None else abs(float(normal @ window_normal))
        # Rounded so that the last bits of two equal walls' areas and angles do not decide.
        return (surface.name.upper() in hosts, round(facing, 6),
                -round(polygon_area(surface.vertices()), 6),
                round(azimuth_deg(normal, north), 6) % 360.0, index)

    def size_rank(item):
        index, surface = item
        return -round(polygon_area(surface.vertices()), 6), index

    surfaces = {}
    for surface_class in SURFACE_CLASSES:
        types = CLASS_SURFACE_TYPES[surface_class]
        candidates = [(i, s) for i, s in in_zone if s.get("Surface Type").upper() in types]
        kinds = " or ".join(t.title() for t in types)
        named = settings.get(surface_class)
        if named:
            match = [s for _, s in candidates if s.name.upper() == named.upper()]
            if not match:
                other = next((s for s in every if s.name.upper() == named.upper()), None)
                what = (f"it is a {other.get('Surface Type')} of zone '{other.get('Zone Name')}'"
                        if other else "the model has no BuildingSurface:Detailed of that name")
                raise BpsflowError(
                    f"detailed.{surface_class}: '{named}' is not a surface of Surface Type "
                    f"{kinds} in zone '{zone}' ({what}); expected one of: "
                    f"{', '.join(s.name for _, s in candidates) or 'none'}", source=where)
            surfaces[surface_class] = match[0].name
            chosen_by[surface_class] = f"detailed.{surface_class}"
            continue
        if not candidates:
            raise BpsflowError(f"zone '{zone}' has no BuildingSurface:Detailed of Surface Type "
                               f"{kinds}; the detailed measurements need a {surface_class}",
                               source=idf.path)
        rank = wall_rank if surface_class == "wall" else size_rank
        surfaces[surface_class] = min(candidates, key=rank)[1].name
        chosen_by[surface_class] = RULES[surface_class]
    return SensorSurfaces(zone=zone, surfaces=surfaces,
                          window=None if window is None else window.name,
                          facade=None if facade is None else facade.name,
                          chosen_by={key: chosen_by[key] for key in SETTING_KEYS})


def _zones(idf) -> list[str]:
    """The model's zones: its Zone objects, else the zones its surfaces name."""
    names = [z.name for z in idf.of_type("ZONE")]
    if not names:
        seen: dict[str, str] = {}
        for surface in idf.of_type("BUILDINGSURFACE:DETAILED"):
            seen.setdefault(surface.get("Zone Name").upper(), surface.get("Zone Name"))
        names = list(seen.values())
    return names


def _sensor_zone(idf, named: str | None, where) -> tuple[str, dict[str, str]]:
    zones = _zones(idf)
    if named:
        match = [z for z in zones if z.upper() == named.upper()]
        if not match:
            raise BpsflowError(f"detailed.zone: the model has no zone '{named}'; its zones: "
                               f"{', '.join(zones) or 'none'}", source=where)
        return match[0], {"zone": "detailed.zone"}
    if len(zones) == 1:
        return zones[0], {"zone": RULES["zone"]}
    if not zones:
        raise BpsflowError("the model has no zone; the detailed measurements need one",
                           source=idf.path)
    raise BpsflowError(f"the model has {len(zones)} zones ({', '.join(zones)}); set "
                       f"detailed.zone in the config to the zone the detailed sensors are in",
                       source=where)


def _sensor_window(idf, zone: str, in_zone: list, named: str | None, where):
    """(window, its host surface, how chosen); (None, None, reason) without exterior glazing."""
    hosts = {s.name.upper(): s for _, s in in_zone}
    glazing = [(i, f) for i, f in enumerate(idf.of_type("FENESTRATIONSURFACE:DETAILED"))
               if f.get("Surface Type").upper() in WINDOW_TYPES
               and f.get("Building Surface Name").upper() in hosts]
    if named:
        match = [f for _, f in glazing if f.name.upper() == named.upper()]
        if not match:
            raise BpsflowError(
                f"detailed.window: '{named}' is not a window of zone '{zone}' (a "
                f"FenestrationSurface:Detailed of type Window or GlassDoor on one of its "
                f"surfaces); expected one of: {', '.join(f.name for _, f in glazing) or 'none'}",
                source=where)
        window, how = match[0], "detailed.window"
    else:
        exterior = [(i, f) for i, f in glazing
                    if hosts[f.get("Building Surface Name").upper()]
                    .get("Outside Boundary Condition").upper() == "OUTDOORS"]
        if not exterior:
            return None, None, "no exterior window in the zone"
        window = min(exterior, key=lambda item: (
            -round(polygon_area(item[1].vertices()) * item[1].number("Multiplier", 1.0), 6),
            item[0]))[1]
        how = RULES["window"]
    return window, hosts[window.get("Building Surface Name").upper()], how


@dataclass(frozen=True)
class SensorGeometry:
    """What the sensors' placement implies, from the model's geometry.

    Attributes
    ----------
    room_height_m : float
        Zone ceiling height (mean ceiling height − mean floor height), m.
    air_sensor_heights_m : dict
        Height above the floor of the air next to ceiling and floor, m.
    air_sensor_separation_m : float
        Vertical distance between the ceiling and floor air sensors, m.
    glazed_area_m2 : float
        Glazed area of the window, m².
    south_facade_ground_view_factor : float
        View factor to the ground of the window's facade (the south wall on the
        test cell), dimensionless.
    boundary_surface_names : dict
        Boundary surface key -> IDF surfaces whose outside face it imposes.
    boundary_sensor_area_m2 : dict
        Boundary surface key -> representative area of each of its 9 sensors, m².
    """

    room_height_m: float
    air_sensor_heights_m: dict[str, float]
    air_sensor_separation_m: float
    glazed_area_m2: float
    south_facade_ground_view_factor: float
    boundary_surface_names: dict[str, list[str]]
    boundary_sensor_area_m2: dict[str, float]


def air_sensor_heights(floor_z_m: float, ceiling_height_m: float,
                       centroid_z_m: dict[str, float]) -> dict[str, float]:
    """Heights above the floor at which EnergyPlus evaluates each surface's adjacent air.

    EnergyPlus's user-defined room air patterns place a surface's adjacent air
    at its centroid's non-dimensional height ζ = (z_c − z_floor) / H, bounded
    to 0.01 ≤ ζ ≤ 0.99 ("so that floors and ceiling are just in from
    endpoints", RoomAirModelUserTempPattern). The constant-gradient pattern
    then sets T_adj = T_mean + G (ζ − 0.5) H, so the ceiling and floor air
    sensors of eq. 18 are 0.98 H apart, not H.

    Parameters
    ----------
    floor_z_m : float
        Mean floor height of the zone, m.
    ceiling_height_m : float
        Zone ceiling height H, m.
    centroid_z_m : dict
        Surface -> centroid height, m.

    Returns
    -------
    dict
        Surface -> height of its adjacent air above the floor, m.
    """
    return {name: ceiling_height_m * min(0.99, max(0.01, (z - floor_z_m) / ceiling_height_m))
            for name, z in centroid_z_m.items()}


def cell_geometry(config: Config) -> SensorGeometry:
    """Sensor separation, glazed area, view factor and boundary sensor areas from the model.

    The ceiling, floor, window and facade are the :func:`sensor_surfaces`; the
    room height is that of their zone.
    """
    from bpsflow.simulation.idf import centroid_height

    idf = _idf(config)
    sensors = sensor_surfaces(config)
    window_name, facade_name = sensors.glazing(config.source)
    ceiling = _surface(idf, sensors.surfaces["ceiling"])
    floor = _surface(idf, sensors.surfaces["floor"])
    zone = sensors.zone.upper()
    in_zone = [s for s in idf.of_type("BUILDINGSURFACE:DETAILED")
               if s.get("Zone Name").upper() == zone]
    floors = [s for s in in_zone if s.get("Surface Type").upper() == "FLOOR"]
    tops = [s for s in in_zone if s.get("Surface Type").upper() in ("CEILING", "ROOF")]
    floor_z = float(np.mean([sum(_z_range(s.vertices())) / 2 for s in floors]))
    height = float(np.mean([sum(_z_range(s.vertices())) / 2 for s in tops])) - floor_z
    heights = air_sensor_heights(floor_z, height, {
        "ceiling": centroid_height(ceiling.vertices()), "floor": centroid_height(floor.vertices())})

    window = _surface(idf, window_name)
    multiplier = float(window.get("Multiplier") or 1.0)
    glazed = polygon_area(window.vertices()) * multiplier

    facade = _surface(idf, facade_name)
    view = facade.get("View Factor to Ground").strip()
    try:
        view_factor = float(view)
    except ValueError:  # autocalculate: an unobstructed surface sees (1 - cos tilt) / 2 of ground
        tilt = _tilt_deg(facade.vertices(), geometry_rules(idf)[0])
        view_factor = (1 - math.cos(math.radians(tilt))) / 2

    names: dict[str, list[str]] = {}
    areas: dict[str, float] = {}
    if config.model.boundary is not None:
        coefficients = idf.of_type("SURFACEPROPERTY:OTHERSIDECOEFFICIENTS")
        for key, spec in config.model.boundary.surfaces.items():
            osc = {o.name.upper() for o in coefficients
                   if o.get("Constant Temperature Schedule Name").upper() == spec.schedule.upper()}
            surfaces = [s for s in idf.of_type("BUILDINGSURFACE:DETAILED")
                        if s.get("Outside Boundary Condition Object").upper() in osc]
            if not surfaces:
                raise BpsflowError(
                    f"model.boundary.surfaces.{key}: no surface of the model has an "
                    f"OtherSideCoefficients boundary fed by schedule '{spec.schedule}'",
                    source=config.source)
            names[key] = [s.name for s in surfaces]
            areas[key] = sum(polygon_area(s.vertices()) for s in surfaces) / BOUNDARY_SENSORS
    return SensorGeometry(
        room_height_m=height, air_sensor_heights_m=heights,
        air_sensor_separation_m=heights["ceiling"] - heights["floor"], glazed_area_m2=glazed,
        south_facade_ground_view_factor=view_factor, boundary_surface_names=names,
        boundary_sensor_area_m2=areas)


def true_field_value(config: Config, sample: dict[str, float], object_type: str, name: str,
                     field: str, default: float | None = None) -> float:
    """An IDF field's value in the instance of ``sample``: the model's value with every
    parameter targeting the field applied in config order (as instances are written)."""
    from bpsflow.simulation.targets import apply_mode, targets_field

    idf = _idf(config)
    object_type = object_type.upper()
    candidates = [o for o in idf.of_type(object_type) if not name or o.name.upper() == name.upper()]
    if not candidates:
        raise BpsflowError(f"the model has no {object_type} '{name}'", source=idf.path)
    value = candidates[0].number(field, default)
    for parameter in config.parameters:
        for target in parameter.targets:
            if isinstance(target, IdfTarget) and targets_field(target, object_type, field, name):
                value = apply_mode(parameter.mode, value, float(sample[parameter.name]))
    return float(value)


def true_convection(config: Config, sample: dict[str, float]) -> dict[str, dict]:
    """Per class the true h = α |ΔT|^n (+ constant) of its inside convection curve (eq. 16).

    The class's surface is its :func:`sensor_surfaces` one.
    """
    from bpsflow.simulation.idf import surface_user_curves

    idf = _idf(config)
    out: dict[str, dict] = {}
    for surface_class, surface in sensor_surfaces(config).surfaces.items():
        if surface_user_curves(idf, surface)[0] is None:
            # EnergyPlus's own inside algorithm (no fitted law to compare a refinement with)
            out[surface_class] = {"surface": surface, "curve": None}
            continue
        curve = inside_convection_curve(idf, surface)
        # Curve:Exponent is C1 + C2 x^C3 with x = |ΔT|: α = C2, n = C3 (C1 = 0 in the model).
        out[surface_class] = {"surface": surface, "curve": curve, **{
            key: true_field_value(config, sample, "Curve:Exponent", curve, field)
            for key, field in (("alpha", "Coefficient2 Constant"), ("n", "Coefficient3 Constant"),
                               ("constant", "Coefficient1 Constant"))}}
    return out


def true_glazing(config: Config, sample: dict[str, float]) -> dict[str, float | str]:
    """The window's true normal-incidence solar transmittance, per pane and of the system.

    EnergyPlus applies the dirt correction factor to the outer pane only; the
    double-glazed system transmits τ_o τ_i / (1 − ρ_o,back ρ_i,front) at
    normal incidence (inter-reflections between the panes). Checked against
    EnergyPlus 25.2's own report of the construction (eio WindowConstruction).
    The window is the :func:`sensor_surfaces` one.
    """
    idf = _idf(config)
    window = _surface(idf, sensor_surfaces(config).glazing(config.source)[0])
    construction = idf.find("CONSTRUCTION", window.get("Construction Name"))
    glass_names = {g.name.upper() for g in idf.of_type("WINDOWMATERIAL:GLAZING")}
    layers = [f for f in construction.fields[1:] if f.strip().upper() in glass_names]
    g = "WindowMaterial:Glazing"
    if len(layers) != 2:
        # only the double-glazed system has the closed form below; other windows report
        # their outer pane (or nothing for a simple-glazing window)
        if not layers:
            return {"outer_pane": "", "inner_pane": "",
                    "note": f"window construction '{construction.name}' has no "
                            f"WindowMaterial:Glazing layer; no true transmittance reported"}
        pane = layers[0]
        tau = true_field_value(config, sample, g, pane, "Solar Transmittance at Normal Incidence")
        dirt = true_field_value(config, sample, g, pane, "Dirt Correction Factor for Solar and "
                                "Visible Transmittance", 1.0) or 1.0
        return {"outer_pane": pane, "inner_pane": "", "single_pane_solar_transmittance": tau,
                "dirt_correction_factor": dirt,
                "single_pane_solar_transmittance_with_dirt": tau * dirt,
                **({"system_solar_transmittance": tau * dirt} if len(layers) == 1 else
                   {"note": f"{len(layers)} glass layers: the system transmittance is "
                            f"not reported"})}
    outer, inner = layers

    def field(pane: str, name: str, default: float | None = None) -> float:
        return true_field_value(config, sample, g, pane, name, default)

    tau_outer = field(outer, "Solar Transmittance at Normal Incidence")
    tau_inner = field(inner, "Solar Transmittance at Normal Incidence")
    # EnergyPlus reads a blank or zero dirt correction factor as 1 (clean glass).
    dirt = field(outer, "Dirt Correction Factor for Solar and Visible Transmittance", 1.0) or 1.0
    rho_back = field(outer, "Back Side Solar Reflectance at Normal Incidence")
    rho_front = field(inner, "Front Side Solar Reflectance at Normal Incidence")
    system = tau_outer * dirt * tau_inner / (1 - rho_back * rho_front)
    return {"outer_pane": outer, "inner_pane": inner,
            "single_pane_solar_transmittance": tau_outer,
            "dirt_correction_factor": dirt,
            "single_pane_solar_transmittance_with_dirt": tau_outer * dirt,
            "system_solar_transmittance": system}


def true_boundary_temperatures(config: Config, sample: dict[str, float],
                               timestamps: pd.DatetimeIndex) -> pd.DataFrame:
    """The boundary temperatures (°C) the truth instance imposed, at hour-ending timestamps.

    Written exactly as an instance's boundary file is (the measured data with
    each sampled surface's selected Monte Carlo sequence substituted, seed
    §3.4.5), then read back, so the values are the ones the model used.
    """
    from bpsflow.boundary import SEQUENCES_FILE, read_sequences, write_boundary_file

    boundary = config.model.boundary
    if boundary is None:
        return pd.DataFrame(index=timestamps)
    selection = {target.boundary: int(sample[p.name]) for p in config.parameters
                 for target in p.targets if isinstance(target, BoundaryTarget)}
    sequences = read_sequences(config.run_dir.resolve() / SEQUENCES_FILE) if selection else None
    with tempfile.TemporaryDirectory() as folder:
        path = write_boundary_file(boundary, sequences, selection, Path(folder) / "boundary.csv")
        table = pd.read_csv(path)
    start = pd.Timestamp(year=config.model.year, month=1, day=1)
    rows = ((timestamps - start) // pd.Timedelta(hours=1)).to_numpy() - 1
    return pd.DataFrame({surface: table[spec.column].to_numpy(dtype=float)[rows]
                         for surface, spec in boundary.surfaces.items()}, index=timestamps)


#: EnergyPlus's ground reflectance when a model has no Site:GroundReflectance object.
DEFAULT_GROUND_REFLECTANCE = 0.2


def true_ground_reflectance(config: Config, sample: dict[str, float]) -> dict[str, float]:
    """Month name -> the instance's ground reflectance (Site:GroundReflectance)."""
    from bpsflow.simulation.idf import FIELDS

    months = [field.split()[0] for field in FIELDS["SITE:GROUNDREFLECTANCE"]]
    if not _idf(config).of_type("SITE:GROUNDREFLECTANCE"):
        # without the object EnergyPlus takes 0.2 in every month (no parameter can move it:
        # a target on it finds no object and is refused by check)
        return dict.fromkeys(months, DEFAULT_GROUND_REFLECTANCE)
    return {month: true_field_value(config, sample, "Site:GroundReflectance", "", field)
            for month, field in zip(months, FIELDS["SITE:GROUNDREFLECTANCE"])}


def true_gradient(config: Config, sample: dict[str, float]) -> float | None:
    """The instance's constant room air temperature gradient, K/m (None without that pattern)."""
    patterns = _idf(config).of_type("ROOMAIR:TEMPERATUREPATTERN:CONSTANTGRADIENT")
    if not patterns:
        return None
    return true_field_value(config, sample, "RoomAir:TemperaturePattern:ConstantGradient",
                            patterns[0].name, "Temperature Gradient")


def true_values(config: Config, sample: dict[str, float], errors: SensorErrors,
                boundary_c: pd.DataFrame) -> dict:
    """The true values behind the detailed measurements (``truth.json``'s ``detailed`` block).

    A refinement must not read these; tests compare its estimates with them.

    Parameters
    ----------
    config : Config
    sample : dict
        The truth instance's parameter values.
    errors : SensorErrors
        The temperature sensors' biases and standard deviations.
    boundary_c : DataFrame
        True boundary temperatures per surface (°C) at the detailed timestamps.
    """
    reflectance = true_ground_reflectance(config, sample)
    months = list(reflectance)
    hour_months = (boundary_c.index - pd.Timedelta(minutes=1)).month
    selection = {target.boundary: int(sample[p.name]) for p in config.parameters
                 for target in p.targets if isinstance(target, BoundaryTarget)}
    by_period = {}
    for period in config.model.periods:
        first, last = period_dates(period, config.model.year)
        begin, end = pd.Timestamp(first), pd.Timestamp(last) + pd.Timedelta(days=1)
        by_period[period.name] = (boundary_c.index > begin) & (boundary_c.index <= end)
    return {
        "sensors": {c: {"bias_c": errors.bias_c[c], "std_c": errors.std_c[c]}
                    for c in errors.bias_c},
        "convection": true_convection(config, sample),
        "stratification_gradient_k_m": true_gradient(config, sample),
        "ground_reflectance": float(np.mean([reflectance[months[m - 1]] for m in hour_months])),
        "ground_reflectance_by_month": reflectance,
        "glazing": true_glazing(config, sample),
        "boundary": {surface: {
            "sequence": selection.get(surface),
            "mean_c": float(boundary_c[surface].mean()),
            "mean_c_by_period": {name: float(boundary_c[surface][mask].mean())
                                 for name, mask in by_period.items()}}
            for surface in boundary_c.columns},
    }


# From true outputs to true detailed quantities -------------------------------

def global_horizontal_irradiance(direct_normal_w_m2: np.ndarray, diffuse_horizontal_w_m2: np.ndarray,
                                 solar_altitude_deg: np.ndarray) -> np.ndarray:
    """Global horizontal irradiance as EnergyPlus forms it: beam · sin(altitude) + diffuse.

    EnergyPlus's ground-reflected irradiance is ρ_g (I_b sin α + I_d), so this
    is the global horizontal irradiance the simulation used. At each timestep
    the identity is exact; from *hourly means* of I_b and α (a mean of a
    product) it stays within 3 % of the simulation's hourly mean when that
    hour's mean solar altitude is at least 10° (I600 run, both seasons) and
    can be off by up to ~50 % in the partly sunlit hours at sunrise and sunset.

    Parameters
    ----------
    direct_normal_w_m2, diffuse_horizontal_w_m2 : array
        Beam normal and diffuse horizontal irradiance, W/m².
    solar_altitude_deg : array
        Solar altitude, degrees (negative below the horizon).

    Returns
    -------
    array
        Global horizontal irradiance, W/m².
    """
    altitude = np.radians(np.asarray(solar_altitude_deg, dtype=float))
    return (np.asarray(direct_normal_w_m2, dtype=float) * np.clip(np.sin(altitude), 0.0, None)
            + np.asarray(diffuse_horizontal_w_m2, dtype=float))


def true_detailed(outputs: pd.DataFrame, boundary_c: pd.DataFrame,
                  geometry: SensorGeometry) -> pd.DataFrame:
    """The true value behind every ``detailed.csv`` column, hourly.

    Parameters
    ----------
    outputs : DataFrame
        Tidy outputs of the truth instance (``timestamp``, ``output``, ``value``)
        holding :func:`detailed_outputs`.
    boundary_c : DataFrame
        True boundary temperature per boundary surface (°C), indexed by timestamp.
    geometry : SensorGeometry

    Returns
    -------
    DataFrame
        Indexed by hour-ending timestamp, the ``detailed.csv`` columns (true values).
    """
    wanted = [f"{c}_{s}" for c in SURFACE_CLASSES for s in SURFACE_VARIABLES] + list(OTHER_OUTPUTS)
    wide = (outputs[outputs["output"].isin(wanted)].drop_duplicates(["timestamp", "output"])
            .pivot(index="timestamp", columns="output", values="value").sort_index())
    missing = [name for name in wanted if name not in wide.columns]
    if missing:
        raise BpsflowError(f"the truth instance reported no values for detailed output(s) "
                           f"{missing}")
    frame = pd.DataFrame(index=wide.index)
    boundary_c = boundary_c.reindex(wide.index)
    for surface in boundary_c.columns:
        for column in boundary_columns([surface]):
            frame[column] = boundary_c[surface].to_numpy()
    for c in SURFACE_CLASSES:
        frame[f"{c}_surface_c"] = wide[f"{c}_surface_c"]
        frame[f"{c}_air_c"] = wide[f"{c}_air_c"]
        frame[f"{c}_conduction_w_m2"] = wide[f"{c}_conduction_w_m2"]
        # A net radiometer at the inside face sees long-wave and short-wave gains together.
        frame[f"{c}_radiation_w_m2"] = (wide[f"{c}_thermal_radiation_w_m2"]
                                        + wide[f"{c}_solar_radiation_w_m2"])
        frame[f"{c}_h_c_w_m2k"] = wide[f"{c}_h_c_w_m2k"]
    frame["window_transmitted_w_m2"] = wide["window_transmitted_w"] / geometry.glazed_area_m2
    frame["window_incident_w_m2"] = wide["window_incident_w_m2"]
    frame["global_horizontal_w_m2"] = global_horizontal_irradiance(
        wide["site_direct_w_m2"], wide["site_diffuse_w_m2"], wide["site_solar_altitude_deg"])
    frame["south_ground_reflected_w_m2"] = wide["south_ground_reflected_w_m2"]
    frame.index.name = "timestamp"
    return frame


# Sensor errors -----------------------------------------------------------------

@dataclass(frozen=True)
class SensorErrors:
    """The error model of one set of sensors (seed eq. 8–9, 12).

    Attributes
    ----------
    bias_c : dict
        Temperature column -> constant bias δ_i, °C.
    std_c : dict
        Temperature column -> random-error standard deviation σ_i, °C.
    reference_std_c : float
        Calibration reference's random-error standard deviation σ_M, °C.
    relative_std : float
        Relative standard deviation of irradiance, radiation and heat-flux readings.
    """

    bias_c: dict[str, float]
    std_c: dict[str, float]
    reference_std_c: float = REFERENCE_STD_C
    relative_std: float = RELATIVE_STD


def _rng(random_state: int | Sequence[int] | np.random.Generator | None) -> np.random.Generator:
    return random_state if isinstance(random_state, np.random.Generator) else \
        np.random.default_rng(random_state)


def draw_sensor_errors(columns: Iterable[str],
                       random_state: int | Sequence[int] | np.random.Generator | None = None,
                       bias_bound_c: float = BIAS_BOUND_C,
                       std_range_c: tuple[float, float] = SENSOR_STD_RANGE_C) -> SensorErrors:
    """Draw each temperature sensor's bias δ_i ~ U(−b, b) and std σ_i ~ U(lo, hi), °C.

    Parameters
    ----------
    columns : iterable of str
        Sensor columns; the temperature ones (ending ``_c``) get a bias and std.
    random_state : int, sequence of int or Generator
    bias_bound_c : float
        Bound b of the bias, °C.
    std_range_c : (float, float)
        Range of σ_i, °C.
    """
    rng = _rng(random_state)
    names = temperature_columns(columns)
    bias = rng.uniform(-bias_bound_c, bias_bound_c, len(names))
    std = rng.uniform(*std_range_c, len(names))
    return SensorErrors(bias_c=dict(zip(names, bias.tolist())), std_c=dict(zip(names, std.tolist())))


def sensor_readings(true: pd.DataFrame, errors: SensorErrors,
                    random_state: int | Sequence[int] | np.random.Generator | None = None
                    ) -> pd.DataFrame:
    """Sensor readings of true values.

    Temperature columns (ending ``_c``): true + δ_i + N(0, σ_i²) (eq. 9, 12).
    Every other column (irradiance, net radiation, heat flux, the derived
    convection coefficient): true · (1 + ε),
    ε ~ N(0, relative_std²).

    Parameters
    ----------
    true : DataFrame
        True values, one column per sensor.
    errors : SensorErrors
        Must hold a bias and std for every temperature column.
    random_state : int, sequence of int or Generator

    Returns
    -------
    DataFrame
        Same index and columns as ``true``.
    """
    rng = _rng(random_state)
    readings = true.copy()
    for column in true.columns:
        values = true[column].to_numpy(dtype=float)
        if column.endswith("_c"):
            if column not in errors.bias_c:
                raise KeyError(f"no sensor error drawn for temperature column '{column}'")
            readings[column] = (values + errors.bias_c[column]
                                + errors.std_c[column] * rng.standard_normal(values.shape))
        else:
            readings[column] = values * (1 + errors.relative_std * rng.standard_normal(values.shape))
    return readings


def calibration_campaign(errors: SensorErrors,
                         random_state: int | Sequence[int] | np.random.Generator | None = None,
                         readings: int = CALIBRATION_READINGS, plateaus: int = CALIBRATION_PLATEAUS,
                         range_c: tuple[float, float] = CALIBRATION_RANGE_C) -> pd.DataFrame:
    """A pre-experiment calibration of every temperature sensor against a reference (eq. 8–9).

    All sensors and the reference read a common bath whose true temperature
    steps through ``plateaus`` levels evenly spread over ``range_c``.

    Returns
    -------
    DataFrame
        Columns ``step`` (0..readings-1), ``reference_c`` (true + N(0, σ_M²)) and
        one column per sensor (true + δ_i + N(0, σ_i²)), °C.
    """
    rng = _rng(random_state)
    levels = np.linspace(*range_c, plateaus)
    bath_c = levels[np.arange(readings) * plateaus // readings]
    frame = pd.DataFrame({"step": np.arange(readings),
                          "reference_c": bath_c + errors.reference_std_c * rng.standard_normal(readings)})
    true = pd.DataFrame({name: bath_c for name in errors.bias_c})
    sensors = sensor_readings(true, errors, rng)
    return pd.concat([frame, sensors], axis=1)


# Files -----------------------------------------------------------------------

def sensor_error_description() -> str:
    return (
        "Temperature sensors (columns ending _c): reading = true + bias_i + N(0, std_i^2), with a "
        f"constant bias_i ~ U(-{BIAS_BOUND_C:g}, {BIAS_BOUND_C:g}) C and std_i ~ "
        f"U({SENSOR_STD_RANGE_C[0]:g}, {SENSOR_STD_RANGE_C[1]:g}) C drawn once per sensor (seed eq. 9, "
        "12); the same bias and std hold in sensor_calibration.csv, where a reference sensor reads "
        f"true + N(0, {REFERENCE_STD_C:.6g}^2) C (eq. 8; Table 3.2 +-0.05 C read as 3 std). "
        "Irradiance (window_*, global_horizontal, south_ground_reflected), net radiation "
        "(<class>_radiation_w_m2) and heat flux (<class>_conduction_w_m2): reading = true * "
        f"(1 + N(0, {RELATIVE_STD:.6g}^2)) per reading (Table 3.2 +-5 % read as 3 std; Table 3.2 "
        "has no heat-flux sensor, the irradiance bound is assumed). <class>_h_c_w_m2k is the "
        "laboratory's convection coefficient from its per-step heat balance averaged to the "
        "hour, with the heat-flux error. Boundary sensors: 9 per "
        "surface, equal representative area, each reading the surface's true boundary "
        "temperature (eq. 13 averages them)."
    )


def detailed_metadata(config: Config, geometry: SensorGeometry,
                      calibration: pd.DataFrame) -> dict:
    """What ``detailed.json`` tells a refinement about the measurements.

    Among it the surfaces the sensors are on (:func:`sensor_surfaces`): ``zone``,
    ``surface_classes``, ``window_surface``, ``south_facade_surface`` (the
    window's facade, whatever its orientation) and how each was chosen
    (``surface_selection``).
    """
    sensors = sensor_surfaces(config)
    window, facade = sensors.glazing(config.source)
    periods = {}
    for period in config.model.periods:
        first, last = period_dates(period, config.model.year)
        periods[period.name] = {"first_hour_ending": f"{first:%Y-%m-%d} 01:00:00",
                                "last_hour_ending": f"{last + timedelta(days=1):%Y-%m-%d} 00:00:00"}
    return {
        "timestamps": "hour-ending, like measured.csv; every run period's whole span",
        "periods": periods,
        "air_sensor_separation_m": geometry.air_sensor_separation_m,
        "air_sensor_heights_m": geometry.air_sensor_heights_m,
        "room_height_m": geometry.room_height_m,
        "air_sensor_note": (
            "ceiling_air_c and floor_air_c are the air next to ceiling and floor. EnergyPlus "
            "evaluates a surface's adjacent air at its non-dimensional height bounded to "
            "0.01..0.99 of the room height, so the two are 0.98 room heights apart: use "
            "air_sensor_separation_m as h in eq. 18, not the room height"),
        "glazed_area_m2": geometry.glazed_area_m2,
        "zone": sensors.zone,
        "window_surface": window,
        "south_facade_surface": facade,
        "south_facade_ground_view_factor": geometry.south_facade_ground_view_factor,
        "global_horizontal_note": (
            "global_horizontal_w_m2 is beam normal * sin(solar altitude) + diffuse horizontal from "
            "the simulation's hourly means (EnergyPlus reflects rho_g times that from the ground); "
            "exact per timestep, within 3 % of the hourly mean for hours whose mean solar "
            "altitude is at least 10 deg, off by up to ~50 % in partly sunlit sunrise/sunset "
            "hours: use hours with solar altitude >= 10 deg for ground reflectance"),
        "convection_note": (
            "per EnergyPlus zone timestep, h_t = alpha |T_air,t-1 - T_surf,t-1|^n and convection_t "
            "= h_t (T_air,t-1 - T_surf,t) (the adjacent air of the previous timestep); hourly means "
            "satisfy eq. 16-17 only approximately, worst where |air - surface| is a few tenths "
            "of a kelvin (on the I600 test cell, the wall)"),
        "reference_sensor_std_c": REFERENCE_STD_C,
        "irradiance_relative_std": RELATIVE_STD,
        "heat_flux_relative_std": RELATIVE_STD,
        "radiation_relative_std": RELATIVE_STD,
        "boundary_sensors_per_surface": BOUNDARY_SENSORS,
        "boundary_sensor_area_m2": geometry.boundary_sensor_area_m2,
        "boundary_surface_names": geometry.boundary_surface_names,
        "surface_classes": dict(sensors.surfaces),
        "surface_selection": dict(sensors.chosen_by),
        "calibration": {"readings": int(len(calibration)), "plateaus": CALIBRATION_PLATEAUS,
                        "range_c": list(CALIBRATION_RANGE_C)},
        "sensor_error_model": sensor_error_description(),
        "units": {"_c": "degC", "_w_m2": "W/m2", "_w_m2k": "W/m2-K"},
    }


def write_detailed(out_dir: Path, readings: pd.DataFrame, calibration: pd.DataFrame,
                   metadata: dict) -> dict[str, Path]:
    """Write ``detailed.csv``, ``sensor_calibration.csv`` and ``detailed.json`` into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"detailed": out_dir / DETAILED_FILE, "calibration": out_dir / CALIBRATION_FILE,
             "metadata": out_dir / METADATA_FILE}
    write_csv(readings, paths["detailed"], index_label="timestamp", float_format="%.7g")
    write_csv(calibration, paths["calibration"], index=False, float_format="%.7g")
    write_json(paths["metadata"], metadata)
    return paths


def _read_table(path: Path, required: Sequence[str], what: str) -> pd.DataFrame:
    return read_table(path, required, what)


def read_detailed(path: Path, surfaces: Iterable[str] | None = None) -> pd.DataFrame:
    """Read a ``detailed.csv``: timestamp index, one column per sensor.

    Parameters
    ----------
    path : Path
    surfaces : iterable of str, optional
        Boundary surface keys whose 9 sensor columns must be present (default:
        those listed in ``detailed.json`` beside the file, if there is one).

    Raises
    ------
    BpsflowError
        Naming the file and the missing column, or the row whose timestamp
        does not parse.
    """
    path = Path(path)
    if surfaces is None:
        meta = path.parent / METADATA_FILE
        surfaces = json.loads(meta.read_text()).get("boundary_sensor_area_m2", {}) \
            if meta.is_file() else []
    required = [c for c in detailed_columns(list(surfaces)) if not c.endswith(OPTIONAL_SUFFIXES)]
    frame = _read_table(path, ["timestamp"] + required, "detailed measurements")
    if frame.empty:
        raise BpsflowError("the file has a header but no rows; expected hourly sensor "
                           "readings", source=path)
    empty = [c for c in required if frame[c].isna().all()]
    if empty:
        raise BpsflowError(f"column '{empty[0]}' holds no reading in any row"
                           + (f" (nor do {len(empty) - 1} other sensor column(s))"
                              if len(empty) > 1 else "")
                           + "; expected readings of every sensor the file lists", source=path)
    stamps = pd.to_datetime(frame["timestamp"], errors="coerce")
    if stamps.isna().any():
        row = int(stamps.isna().to_numpy().argmax())
        raise BpsflowError(f"row {row + 2}: timestamp '{frame['timestamp'].iloc[row]}' does not "
                           f"parse (expected e.g. 2025-12-05 01:00:00, hour-ending)", source=path)
    frame["timestamp"] = stamps
    return frame.set_index("timestamp")


def read_calibration(path: Path) -> pd.DataFrame:
    """Read a ``sensor_calibration.csv`` (``step``, ``reference_c``, one column per sensor)."""
    return _read_table(path, ["step", "reference_c"], "sensor calibration")
