"""Candidate model extensions: real changes to the model, nested at zero.

Each extension is a set of IDF objects (``bpsflow/extensions_idf/<name>.idf``)
that both backends run (EnergyPlus reads them; the surrogate has the same
physics for them), plus the new parameters that target their fields. At the
new parameters' zero the model is the original one (seed §4.3.1: when the
discrepancy is large, revisit the physical model rather than let δ absorb it;
§2.1 lists the sources such an extension stands for).

=======================  =========================================  ============================
extension                IDF objects                                new parameters (unit)
=======================  =========================================  ============================
infiltration             ZoneInfiltration:DesignFlowRate with       infiltration_a_m3s (m³/s),
                         Design Flow Rate 1: flow = A + B|ΔT| +     infiltration_b_m3s_per_k,
                         C V + D V² (EnergyPlus's law, the          infiltration_c_m3s_per_ms,
                         coefficients are flows); Schedule:Constant infiltration_d_m3s_per_m2s2
                         1. Any subset of the terms is fitted       (all ≥ 0)
                         (``terms``), the others stay 0
infiltration_wind        ZoneInfiltration:DesignFlowRate, flow =    infiltration_wind_m3s_per_ms
                         design × wind speed (C = 1);               (m³/s per m/s)
                         Schedule:Constant 1
internal_gain_schedule   OtherEquipment, Schedule:File on/off       scheduled_gain_w (W while
                         block (day type × hours, the block that    on),
                         best explains the calibration residuals;   scheduled_gain_radiant_
                         day types: weekdays, weekends, all days    fraction (-, 0–0.9)
                         or one day of the week)
scheduled_air_exchange   ZoneInfiltration:DesignFlowRate (A = 1),   scheduled_air_flow_m3s
                         Schedule:File on/off block (as the gain's; (m³/s while on)
                         the block whose heat loss best explains
                         the residuals): airing, a door held open
solar_aperture           OtherEquipment, Schedule:File of the       solar_aperture_m2 (m²: W of
                         irradiance on the zone's facade (model     gain per W/m² incident),
                         geometry, pvlib)                           solar_aperture_radiant_
                                                                    fraction (-, 0–0.9)
envelope_ua              ZoneInfiltration:DesignFlowRate, constant  extra_conductance_m3s (m³/s;
                         flow (A = 1): a conductance to outdoors;   ×ρc_p ≈ 1206 J/(m³K) = W/K)
                         Schedule:Constant 1
thermal_mass             Material (0.1 m concrete), Construction,   internal_mass_area_m2 (m²,
                         InternalMass (area 0.001 m² + the          added to the token 0.001 m²)
                         parameter), its inside convection fixed
                         at 2.5 W/(m²K)
=======================  =========================================  ============================

The snippets are templates (:func:`render_snippet`): every extension is
written for one zone of the model (:func:`diagnosis_zone`), its objects are
named ``bpsflow_<extension>`` (with a variant suffix, and a number when the
model already uses the name) and a schedule it needs is created by the
snippet itself, never assumed to exist. No model's zone, surface or schedule
is named here.

Nested at zero: with every new parameter at 0 the extended model is the
original one. ``thermal_mass`` is the one exception in the letter, not in
effect: EnergyPlus refuses an ``InternalMass`` of zero area, so the snippet
carries a token 0.001 m² of concrete (≈ 190 J/K, against tens of kJ/K of
air) and the parameter adds to it; the outputs at the parameter's 0 differ
from the original model's by far less than a measurement resolves
(``tests/test_diagnosis_extensions.py`` measures it on both backends).

Which extension answers which driver (DESIGN.md §8 names) is
:data:`DRIVER_EXTENSIONS`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from bpsflow.config import Config, IdfTarget, Parameter
from bpsflow.distributions import Uniform
from bpsflow.errors import BpsflowError
from bpsflow.files import write_text_atomic
from bpsflow.simulation.targets import TOOL_OBJECT_PREFIX

if TYPE_CHECKING:
    from bpsflow.simulation.idf import IdfModel, IdfObject

#: Volumetric heat capacity of air used to report a flow as a conductance (J/(m³·K)).
AIR_HEAT_CAPACITY_J_M3K = 1.2 * 1005.0

SNIPPET_PACKAGE = "bpsflow.extensions_idf"

#: Prefix of every object name diagnose adds to a model (user patterns never select them).
NAME_PREFIX = TOOL_OBJECT_PREFIX


@dataclass(frozen=True)
class NewParameter:
    """A parameter an extension adds: the field of its main object it sets, and its range."""

    name: str
    object: str
    field: str
    lower: float
    upper: float
    unit: str
    description: str
    #: How the value reaches the field (:func:`bpsflow.simulation.targets.apply_mode`):
    #: ``absolute`` writes it, ``additive`` adds it to the template's value.
    mode: str = "absolute"
    #: Short name of the term in a law (``A``..``D`` for infiltration), for ``terms``.
    term: str = ""
    #: The value at which the extension leaves the model as it was (its template's
    #: value): 0 for a design level or coefficient; a shape parameter (a thickness)
    #: keeps its template value, since the level at 0 already nests the model.
    nested: float = 0.0
    #: Whether the parameter sets the effect's size: the extension changes nothing
    #: while every such parameter is at its nested value (a radiant fraction or a
    #: thickness only shapes an effect whose level is not 0).
    sets_size: bool = True


@dataclass(frozen=True)
class Extension:
    """One candidate extension of the model.

    ``snippet`` is the template in ``bpsflow/extensions_idf``; its main object
    (the one the parameters target) is named from :attr:`object_name`, its
    schedule from :attr:`schedule_name`, and ``schedule_file`` is the CSV a
    ``Schedule:File`` reads (``None``: the snippet creates a constant
    schedule).
    """

    name: str
    description: str
    snippet: str
    parameters: tuple[NewParameter, ...]
    schedule_file: str | None = None
    drivers: tuple[str, ...] = field(default_factory=tuple)

    @property
    def object_name(self) -> str:
        """Base name of the main object (before the variant suffix and de-duplication)."""
        return NAME_PREFIX + self.name

    @property
    def schedule_name(self) -> str:
        """Base name of the snippet's schedule: hourly values from a file, or always 1."""
        return f"{self.object_name}_{'hourly' if self.schedule_file else 'always_on'}"


#: Upper bounds of the infiltration law's coefficients: a flow of about 0.05 m³/s
#: (≈ 60 W/K) at ΔT = 10 K or V = 5 m/s, the scale of ``infiltration_wind``'s
#: 0.05 m³/s per m/s and ``envelope_ua``'s 0.1 m³/s.
INFILTRATION_BOUNDS = {"A": 0.1, "B": 0.005, "C": 0.05, "D": 0.01}

def _radiant_fraction(prefix: str, of_what: str) -> NewParameter:
    """The radiant fraction (to the inside faces) of an ``OtherEquipment`` extension's gain.

    It only shapes the gain: no effect while the design level is 0, so the
    extension stays nested at zero whatever its value.
    """
    return NewParameter(f"{prefix}_radiant_fraction", "OtherEquipment", "Fraction Radiant",
                        0.0, 0.9, "-", f"radiant fraction of {of_what} (to the inside faces)",
                        sets_size=False)


EXTENSIONS: dict[str, Extension] = {
    "infiltration_wind": Extension(
        name="infiltration_wind",
        description="wind-driven infiltration: outdoor air flow proportional to wind speed",
        snippet="infiltration_wind.idf",
        parameters=(NewParameter(
            "infiltration_wind_m3s_per_ms", "ZoneInfiltration:DesignFlowRate",
            "Design Flow Rate", 0.0, 0.05, "m3/s per m/s",
            "infiltration flow per m/s of wind speed"),),
        drivers=("wind_speed",)),
    "internal_gain_schedule": Extension(
        name="internal_gain_schedule",
        description="an unmodelled internal gain following an hour-of-day / weekday profile",
        snippet="internal_gain_schedule.idf",
        parameters=(
            NewParameter("scheduled_gain_w", "OtherEquipment", "Design Level",
                         0.0, 3000.0, "W", "gain while the block schedule is on"),
            _radiant_fraction("scheduled_gain", "the scheduled gain")),
        schedule_file="internal_gain_profile.csv",
        drivers=("hour_of_day", "weekend")),
    "scheduled_air_exchange": Extension(
        name="scheduled_air_exchange",
        description="an unmodelled outdoor air flow on an hour-of-day / weekday profile "
                    "(airing, a door held open, a fan on a timer): a scheduled heat loss",
        snippet="scheduled_air_exchange.idf",
        parameters=(NewParameter(
            "scheduled_air_flow_m3s", "ZoneInfiltration:DesignFlowRate", "Design Flow Rate",
            0.0, 0.5, "m3/s", "outdoor air flow while the block schedule is on"),),
        schedule_file="air_exchange_profile.csv",
        drivers=("hour_of_day", "weekend")),
    "solar_aperture": Extension(
        name="solar_aperture",
        description="an unmodelled solar gain through a facade (gain factor × incident solar)",
        snippet="solar_aperture.idf",
        parameters=(
            NewParameter("solar_aperture_m2", "OtherEquipment", "Design Level",
                         0.0, 5.0, "m2", "W of gain per W/m² incident on the facade"),
            # sun through an opening lands on the room's surfaces before the air
            _radiant_fraction("solar_aperture", "the aperture's gain")),
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
            "Design Flow Rate", 0.0, 0.1, "m3/s",
            "constant outdoor air flow (× 1206 J/(m³K) = W/K)"),),
        drivers=("outdoor_air_temperature",)),
    "infiltration": Extension(
        name="infiltration",
        description="infiltration following EnergyPlus's design-flow-rate law "
                    "A + B|ΔT| + C·V + D·V² (a subset of the terms, chosen by BIC)",
        snippet="infiltration.idf",
        parameters=(
            NewParameter("infiltration_a_m3s", "ZoneInfiltration:DesignFlowRate",
                         "Constant Term Coefficient", 0.0, INFILTRATION_BOUNDS["A"], "m3/s",
                         "constant infiltration flow", term="A"),
            NewParameter("infiltration_b_m3s_per_k", "ZoneInfiltration:DesignFlowRate",
                         "Temperature Term Coefficient", 0.0, INFILTRATION_BOUNDS["B"],
                         "m3/s per K", "infiltration flow per K of |T_zone - T_out|", term="B"),
            NewParameter("infiltration_c_m3s_per_ms", "ZoneInfiltration:DesignFlowRate",
                         "Velocity Term Coefficient", 0.0, INFILTRATION_BOUNDS["C"],
                         "m3/s per m/s", "infiltration flow per m/s of local wind speed",
                         term="C"),
            NewParameter("infiltration_d_m3s_per_m2s2", "ZoneInfiltration:DesignFlowRate",
                         "Velocity Squared Term Coefficient", 0.0, INFILTRATION_BOUNDS["D"],
                         "m3/s per (m/s)2", "infiltration flow per (m/s)² of local wind speed",
                         term="D")),
        drivers=("wind_speed", "outdoor_air_temperature")),
    "thermal_mass": Extension(
        name="thermal_mass",
        description="unmodelled thermal mass in the zone (an InternalMass of concrete): "
                    "damps and delays the daily swing of the loads",
        snippet="thermal_mass.idf",
        parameters=(NewParameter(
            "internal_mass_area_m2", "InternalMass", "Surface Area", 0.0, 100.0, "m2",
            "exposed area of the concrete internal mass", mode="additive"),
                    NewParameter(
            "internal_mass_thickness_m", "Material", "Thickness", 0.02, 0.4, "m",
            "thickness of the internal mass's concrete layer (its time constant)",
            nested=0.1, sets_size=False)),
        # Mass answers the daily cycle of what drives the loads: outdoor
        # temperature and solar gain, felt hours later. No driver is lagged, so
        # it is nominated by the daily structure those leave in the residuals.
        drivers=("hour_of_day", "outdoor_air_temperature", "global_horizontal_radiation",
                 "incident_solar_south", "incident_solar_east", "incident_solar_west",
                 "incident_solar_north", "incident_solar_roof")),
}

#: Extensions switched on and off by an hourly block (day type × hours) found in the
#: residuals (:func:`gain_blocks`): the parameter that sets the level while on, and the
#: sign of the effect as a gain (+1: heat into the zone; -1: an air flow's heat loss).
SCHEDULED_BLOCKS: dict[str, tuple[str, float]] = {
    "internal_gain_schedule": ("scheduled_gain_w", 1.0),
    "scheduled_air_exchange": ("scheduled_air_flow_m3s", -1.0),
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
    """The packaged IDF template of ``extension``."""
    return Path(str(resources.files(SNIPPET_PACKAGE).joinpath(extension.snippet)))


# ---------------------------------------------------------------------------
# Which zone: from the settings, the diagnosed output, or the model itself


def model_zones(model: IdfModel) -> list[str]:
    """Names of the model's ``Zone`` objects, in file order."""
    return [o.name for o in model.of_type("ZONE") if o.name]


def zone_floor_areas(model: IdfModel) -> dict[str, float]:
    """Each zone's floor area times its multiplier (m²), from its floor surfaces.

    Detailed floors (``BuildingSurface:Detailed`` of type Floor,
    ``Floor:Detailed``) give their polygon's area; a zone without any falls
    back to the ``Zone`` object's own Floor Area field when it is a number.
    Zones with neither are left out.
    """
    from bpsflow.simulation.idf import polygon_area

    zones = {z.name.upper(): z for z in model.of_type("ZONE") if z.name}
    areas: dict[str, float] = {}
    for object_type, (zone_at, _, _, vertex_at) in _DETAILED.items():
        for obj in model.of_type(object_type):
            is_floor = object_type == "FLOOR:DETAILED" or _field(obj, 1).upper() == "FLOOR"
            zone = zones.get(_field(obj, zone_at).upper())
            if not is_floor or zone is None:
                continue
            values = [_number(v, 0.0) for v in obj.fields[vertex_at:] if v.strip()]
            points = [(values[i], values[i + 1], values[i + 2])
                      for i in range(0, len(values) - 2, 3)]
            if len(points) >= 3:
                areas[zone.name] = areas.get(zone.name, 0.0) + polygon_area(points)
    for zone in zones.values():
        # Zone: Name, Direction of Relative North, X, Y, Z Origin, Type, Multiplier,
        # Ceiling Height, Volume, Floor Area
        if zone.name not in areas and _number(_field(zone, 9), 0.0) > 0:
            areas[zone.name] = _number(_field(zone, 9), 0.0)
        if zone.name in areas:
            areas[zone.name] *= max(_number(_field(zone, 6), 1.0), 1.0)
    return areas


def conditioned_zones(model: IdfModel) -> list[str]:
    """Zones with equipment or a thermostat (not a plenum), in file order; [] if none say so."""
    zones = model_zones(model)
    named = {o.fields[0].strip().upper() for o in model.of_type("ZONEHVAC:EQUIPMENTCONNECTIONS")
             if o.fields}
    named |= {_field(o, 1).upper() for o in model.of_type("ZONECONTROL:THERMOSTAT")}
    return [zone for zone in zones if zone.upper() in named]


def building_level_zone(config: Config, output: str, model: IdfModel | None = None) -> bool:
    """Whether the extensions' zone was chosen for a building-level output of a multi-zone model.

    True when neither ``diagnosis.zone``, ``diagnosis.extension_zones`` nor the
    output's key name a zone and the model has more than one: the zone then
    comes from the floor areas (:func:`diagnosis_zone`), not from the data.
    """
    from bpsflow.diagnosis.settings import DiagnosisSettings
    from bpsflow.simulation.idf import model_objects

    settings = getattr(config, "diagnosis", None) or DiagnosisSettings()
    variable = config.outputs.get(output)
    if settings.zone or settings.extension_zones or getattr(variable, "key", None):
        return False
    model = model if model is not None else model_objects(config.model)
    return len(model_zones(model)) > 1


def zone_of_key(model: IdfModel, key: str | None) -> str | None:
    """The zone an output variable's ``key`` refers to, read from the model; ``None`` if none.

    The key may be the zone itself (``Zone Mean Air Temperature``), a zone
    equipment (e.g. a ``ZoneHVAC:IdealLoadsAirSystem``: the
    ``ZoneHVAC:EquipmentList`` that lists it, then the
    ``ZoneHVAC:EquipmentConnections`` that uses that list), the zone's air
    node, a ``Space`` or a surface. Names compare without case, as EnergyPlus
    compares them. Keys naming no zone (``Environment``, ``*``, a meter's)
    give ``None``.
    """
    if not key:
        return None
    wanted = key.strip().upper()
    zones = {z.upper(): z for z in model_zones(model)}

    def known(name: str) -> str | None:
        return zones.get(name.strip().upper())

    if wanted in zones:
        return zones[wanted]
    # An equipment list: Name, Load Distribution Scheme, then per equipment
    # (type, name, cooling sequence, heating sequence, two fraction schedules).
    lists = {o.name.upper() for o in model.of_type("ZONEHVAC:EQUIPMENTLIST")
             if any(f.strip().upper() == wanted for f in o.fields[3::6])}
    for connection in model.of_type("ZONEHVAC:EQUIPMENTCONNECTIONS"):
        # Zone Name, Conditioning Equipment List Name, Inlet Node, Exhaust Node, Zone Air Node
        fields = [f.strip().upper() for f in connection.fields]
        if (len(fields) > 1 and fields[1] in lists) or (len(fields) > 4 and fields[4] == wanted):
            return known(connection.fields[0])
    for space in model.of_type("SPACE"):
        if space.name.upper() == wanted and len(space.fields) > 1:
            return known(space.fields[1])
    for surface, zone_field in _surface_fields(model):
        if surface.name.upper() == wanted:
            return known(surface.fields[zone_field])
    return None


def diagnosis_zone(config: Config, output: str | None = None, extension: str | None = None,
                   model: IdfModel | None = None) -> str:
    """The zone an extension is written for.

    In this order: ``diagnosis.extension_zones[extension]``, ``diagnosis.zone``,
    the zone the diagnosed ``output`` refers to (:func:`zone_of_key` of its
    ``key``), the model's only zone, and for a building-level output (a
    meter, no key) the conditioned zone with the most floor area
    (:func:`zone_floor_areas`, :func:`conditioned_zones`): such an output
    cannot tell zones apart.

    Parameters
    ----------
    config : Config
        The config whose model is extended (its ``diagnosis`` section, or the
        defaults).
    output : str, optional
        The diagnosed output (a key of ``config.outputs``).
    extension : str, optional
        The extension's name, for ``diagnosis.extension_zones``.
    model : IdfModel, optional
        The model's objects (default: read from ``config.model``).

    Raises
    ------
    BpsflowError
        A configured zone is not a ``Zone`` of the model, or the model has
        several zones and neither the settings, the output nor the floors
        pick one (the message names ``diagnosis.zone`` and lists the zones).
    """
    from bpsflow.diagnosis.settings import DiagnosisSettings
    from bpsflow.simulation.idf import model_objects

    settings = getattr(config, "diagnosis", None) or DiagnosisSettings()
    model = model if model is not None else model_objects(config.model)
    zones = model_zones(model)
    listed = ", ".join(zones) or "none"
    per_extension = {str(k): v for k, v in settings.extension_zones.items()}
    configured = [(f"diagnosis.extension_zones.{extension}",
                   per_extension.get(extension) if extension else None),
                  ("diagnosis.zone", settings.zone)]
    for key, name in configured:
        if name:
            found = {z.upper(): z for z in zones}.get(name.strip().upper())
            if found is None:
                raise BpsflowError(f"{key}: '{name}' is not a Zone of the model (its zones: "
                                   f"{listed})", source=config.source)
            return found
    variable = config.outputs.get(output) if output else None
    output_key: str | None = getattr(variable, "key", None)     # None for a meter
    referred = zone_of_key(model, output_key)
    if referred is not None:
        return referred
    if len(zones) == 1:
        return zones[0]
    if not output_key:
        # a building-level output (a meter): every zone's heat balance reaches it, so the
        # zone of a cause cannot be told from it; the zone holding most floor area stands
        # for them (building_level_zone says so in the report)
        areas = zone_floor_areas(model)
        conditioned = conditioned_zones(model) or zones
        if any(areas.get(zone, 0.0) > 0 for zone in conditioned):
            return max(conditioned, key=lambda zone: areas.get(zone, 0.0))
    said = (f"the output '{output}' (key '{output_key}') refers to none of them" if output_key
            else "the diagnosed output names none of them and the model's floors give no "
                 "zone areas")
    raise BpsflowError(f"diagnosis.zone: the model has {len(zones)} zones ({listed}) and {said}; "
                       f"set diagnosis.zone (or diagnosis.extension_zones) to the zone the "
                       f"candidate extensions are written for", source=config.source)


# ---------------------------------------------------------------------------
# Rendering a template into IDF objects for one zone

#: A placeholder: a lower-case name in braces (IDF unit comments such as
#: ``{m3/s}`` or ``{W}`` never match).
_PLACEHOLDER = re.compile(r"\{([a-z_]+)\}")


def fill_template(text: str, values: dict[str, str]) -> str:
    """``text`` with every ``{name}`` placeholder replaced by ``values[name]``.

    Raises
    ------
    KeyError
        A placeholder has no value (a template and its caller disagree).
    """
    def one(match: re.Match) -> str:
        if match.group(1) not in values:
            raise KeyError(f"template placeholder {{{match.group(1)}}} has no value")
        return values[match.group(1)]

    lines = []
    for line in text.splitlines(keepends=True):
        filled = _PLACEHOLDER.sub(one, line)
        column = line.find("!-")
        if filled != line and column > 0 and "!-" in filled:
            # keep the field comments in their column, as the template has them
            value, comment = filled.split("!-", 1)
            filled = f"{value.rstrip():<{column - 1}} !-{comment}"
        lines.append(filled)
    return "".join(lines)


def model_names(model: IdfModel) -> set[str]:
    """Upper-case names of every named object of the model (any type)."""
    return {o.name.upper() for o in model.objects if o.name}


def free_name(base: str, taken: set[str]) -> str:
    """``base``, or ``base_2``, ``base_3``, …: the first that is not in ``taken`` (upper case).

    The name is added to ``taken``, so that names chosen one after another
    differ too.
    """
    name, number = base, 1
    while name.upper() in taken:
        number += 1
        name = f"{base}_{number}"
    taken.add(name.upper())
    return name


@dataclass(frozen=True)
class Snippet:
    """A rendered extension: IDF text and the names it was given."""

    text: str
    zone: str
    object_name: str
    schedule_name: str
    file_name: str | None
    #: the name given to the template's ``{material}`` (a parameter on a Material targets it)
    material_name: str = ""


def render_snippet(extension: Extension, model: IdfModel, zone: str,
                   variant: int | None = None) -> Snippet:
    """The extension's IDF objects for ``zone`` of ``model``.

    Parameters
    ----------
    extension : Extension
        Whose template (``bpsflow/extensions_idf``) is filled.
    model : IdfModel
        The model the objects are added to: the zone must be one of its
        ``Zone`` objects, and the added names avoid every name it uses
        (:func:`free_name`), whatever the object type.
    zone : str
        The zone the objects are written for.
    variant : int, optional
        Suffix ``_v<variant>`` on the object, schedule and CSV names, so that
        several variants of one extension can sit in one model.

    Raises
    ------
    BpsflowError
        ``zone`` is not a zone of the model.
    """
    zones = {z.upper(): z for z in model_zones(model)}
    if zone.strip().upper() not in zones:
        raise BpsflowError(f"cannot write the {extension.name} extension for zone '{zone}': the "
                           f"model has no such Zone (its zones: {', '.join(zones.values())})",
                           source=model.path)
    zone = zones[zone.strip().upper()]
    tag = "" if variant is None else f"_v{variant}"
    taken = model_names(model)
    object_name = free_name(extension.object_name + tag, taken)
    schedule_name = free_name(extension.schedule_name + tag, taken)
    file_name = None
    if extension.schedule_file:
        stem, suffix = extension.schedule_file.rsplit(".", 1)
        file_name = f"{stem}{tag}.{suffix}"
    # Names of the objects a template defines besides its main object (the
    # thermal mass's material and construction), free in the model like it.
    material_name = free_name(f"{extension.object_name}_material{tag}", taken)
    construction_name = free_name(f"{extension.object_name}_construction{tag}", taken)
    text = fill_template(snippet_path(extension).read_text(),
                         {"object": object_name, "zone": zone, "schedule": schedule_name,
                          "file": file_name or "", "material": material_name,
                          "construction": construction_name})
    return Snippet(text, zone, object_name, schedule_name, file_name, material_name)


def free_parameters(extension: Extension,
                    terms: tuple[str, ...] | list[str] | None = None) -> tuple[NewParameter, ...]:
    """The extension's parameters that ``terms`` leaves free (all of them for ``None``).

    ``terms`` names parameters by their name (``infiltration_d_m3s_per_m2s2``)
    or their term (``D``), in any order and case; the result keeps the
    extension's order.

    Raises
    ------
    ValueError
        A term that is not one of the extension's, or an empty ``terms``.
    """
    if terms is None:
        return extension.parameters
    wanted = {str(t).strip().lower() for t in terms}
    known = {p.name.lower() for p in extension.parameters} \
        | {p.term.lower() for p in extension.parameters if p.term}
    unknown = sorted(wanted - known)
    if unknown or not wanted:
        names = ", ".join(f"{p.name} ({p.term})" if p.term else p.name
                          for p in extension.parameters)
        raise ValueError(f"extension {extension.name}: terms {unknown or '[]'} are not among "
                         f"its parameters: {names}")
    return tuple(p for p in extension.parameters
                 if p.name.lower() in wanted or (p.term and p.term.lower() in wanted))


def term_subsets(extension: Extension, max_size: int | None = None) -> list[tuple[str, ...]]:
    """Every non-empty subset of the extension's terms, smallest first (for a BIC choice).

    Terms are the parameters' :attr:`NewParameter.term` (their names when
    they have none). For ``infiltration``: ``("A",), ("B",), …, ("A", "B"),
    …, ("A", "B", "C", "D")`` — 15 subsets, or fewer with ``max_size``.
    """
    from itertools import combinations

    labels = [p.term or p.name for p in extension.parameters]
    top = len(labels) if max_size is None else min(max_size, len(labels))
    return [subset for size in range(1, top + 1) for subset in combinations(labels, size)]


def new_parameters(extension: Extension, object_name: str, variant: int | None = None,
                   zone: str | None = None,
                   terms: tuple[str, ...] | list[str] | None = None,
                   material_name: str = "") -> list[Parameter]:
    """The extension's parameters as config parameters (uniform over the search range).

    ``object_name`` is the rendered main object's name (:attr:`Snippet.object_name`).
    ``terms`` (default: all) chooses which parameters are free
    (:func:`free_parameters`); the fields of the others keep the template's
    value, 0, so that a subset of a law's terms is fitted.
    """
    tag = "" if variant is None else f"_v{variant}"
    provenance: dict = {"method": "bpsflow diagnose", "extension": extension.name,
                        "nested_at": 0.0}
    if zone is not None:
        provenance["zone"] = zone
    return [Parameter(name=p.name + tag, group="extension", mode=p.mode,  # type: ignore[arg-type]
                      description=f"{p.description} ({p.unit}); added by bpsflow diagnose",
                      distribution=Uniform(type="uniform", lower=p.lower, upper=p.upper),
                      targets=[IdfTarget(object=p.object, field=p.field,
                                         name=material_name if p.object.upper() == "MATERIAL"
                                         and material_name else object_name)],
                      provenance={**provenance, "nested_at": float(p.nested),
                                  "reports_as": p.name, "sets_size": p.sets_size,
                                  **({"term": p.term} if p.term else {})})
            for p in free_parameters(extension, terms)]


def extend_config(config: Config, extension: Extension, directory: Path,
                  schedule: pd.Series | None = None, variant: int | None = None, *,
                  zone: str | None = None, output: str | None = None,
                  terms: tuple[str, ...] | list[str] | None = None) -> Config:
    """A copy of ``config`` whose model includes ``extension`` (files in ``directory``).

    The template is rendered (:func:`render_snippet`) against the model as it
    is (``model.idf`` and its snippets so far) into
    ``directory/<extension><suffix>.idf``, its CSV beside it.

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
    zone : str, optional
        The zone the objects are written for (default: :func:`diagnosis_zone`
        of ``config``, ``output`` and the extension).
    output : str, optional
        The diagnosed output, when ``zone`` is not given.
    terms : tuple of str, optional
        The extension's parameters that are free, by name or term (e.g.
        ``("A", "D")`` for ``infiltration``; default: all). The fields of
        the others stay at the template's 0: no parameter targets them.
    """
    from bpsflow.simulation.idf import model_objects

    free_parameters(extension, terms)      # a bad term fails before any file is written

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    model = model_objects(config.model)
    if zone is None:
        zone = diagnosis_zone(config, output, extension.name, model)
    rendered = render_snippet(extension, model, zone, variant)
    tag = "" if variant is None else f"_v{variant}"
    snippet = directory / extension.snippet.replace(".idf", f"{tag}.idf")
    write_text_atomic(snippet, rendered.text)
    if rendered.file_name is not None:
        if schedule is None:
            raise ValueError(f"extension {extension.name} needs its schedule values")
        write_schedule(np.asarray(schedule, dtype=float), directory / rendered.file_name)
    extended = config.model_copy(deep=True)
    extended.source = config.source
    extended.model.idf_objects = [*config.model.idf_objects, snippet]
    names = {p.name for p in extended.parameters}
    extended.parameters = [*extended.parameters,
                           *[p for p in new_parameters(extension, rendered.object_name, variant,
                                                       rendered.zone, terms,
                                                       rendered.material_name)
                             if p.name not in names]]
    return extended


#: How each infiltration term reads in :func:`law_text`.
_LAW_TERMS = (("infiltration_a_m3s", ""), ("infiltration_b_m3s_per_k", "·|ΔT|"),
              ("infiltration_c_m3s_per_ms", "·V"), ("infiltration_d_m3s_per_m2s2", "·V²"))


def law_text(fitted: dict[str, float], digits: int = 3) -> str:
    """The fitted infiltration law in words, e.g. ``"flow = 0.012 + 0.0031·V² m³/s"``.

    Parameters
    ----------
    fitted : dict
        Fitted values by parameter name (the reported names of the
        ``infiltration`` extension, or with a ``_v<n>`` variant suffix);
        terms that are missing or 0 are left out.
    digits : int
        Significant digits of each coefficient.

    Notes
    -----
    ``ΔT`` is ``T_zone − T_out`` (K) and ``V`` the local wind speed at the
    zone centroid (m/s), as in EnergyPlus's ``ZoneInfiltration:DesignFlowRate``.
    """
    base = {re.sub(r"_v\d+$", "", k): float(v) for k, v in fitted.items()}
    parts = [f"{base[name]:.{digits}g}{suffix}" for name, suffix in _LAW_TERMS
             if base.get(name, 0.0) != 0.0]
    return f"flow = {' + '.join(parts) if parts else '0'} m³/s"


# ---------------------------------------------------------------------------
# Facades from the model geometry

#: Detailed surface types: (zone, outside boundary condition, sun exposure, first
#: vertex) field positions after the object type.
_DETAILED = {"BUILDINGSURFACE:DETAILED": (3, 5, 7, 11), "WALL:DETAILED": (2, 4, 6, 10),
             "ROOFCEILING:DETAILED": (2, 4, 6, 10), "FLOOR:DETAILED": (2, 4, 6, 10)}

#: Simple rectangular exterior surfaces: (zone, azimuth, tilt, default tilt, length,
#: height or width) field positions; they are always outdoors and sun-exposed.
_SIMPLE = {"WALL:EXTERIOR": (2, 4, 5, 90.0, 9, 10), "ROOF": (2, 4, 5, 0.0, 9, 10)}


def _surface_fields(model: IdfModel) -> list[tuple[IdfObject, int]]:
    """Every surface of the model with the position of its zone field."""
    out = []
    for object_type, positions in {**_DETAILED, **_SIMPLE}.items():
        zone_at = int(positions[0])
        out += [(o, zone_at) for o in model.of_type(object_type) if len(o.fields) > zone_at]
    return out


@dataclass(frozen=True)
class ExteriorSurface:
    """A sun-exposed outdoor surface of a zone: true orientation and gross area.

    ``tilt`` from horizontal (0 faces up, 90 vertical) and ``azimuth``
    clockwise from true north of the outward normal, degrees (pvlib's
    convention); ``area`` in m².
    """

    name: str
    tilt: float
    azimuth: float
    area: float


def _number(text: str, default: float) -> float:
    try:
        return float(text) if text.strip() else default
    except ValueError:
        return default


def _field(obj: IdfObject, index: int) -> str:
    return obj.fields[index].strip() if len(obj.fields) > index else ""


def zone_exterior_surfaces(model: IdfModel, zone: str) -> list[ExteriorSurface]:
    """The zone's sun-exposed surfaces to outdoors, oriented in true (compass) coordinates.

    The outward normal of a detailed surface is Newell's normal of its
    vertices, reversed when ``GlobalGeometryRules`` enters vertices
    clockwise. With relative coordinates (the default) it is turned by the
    zone's Direction of Relative North and the building's North Axis
    (clockwise, degrees); with world coordinates EnergyPlus ignores both, and
    so does this. ``Wall:Exterior`` and ``Roof`` give their azimuth and tilt
    (``GlobalGeometryRules``' rectangular surface coordinate system).
    """
    rules = model.of_type("GLOBALGEOMETRYRULES")
    rule = (lambda i: _field(rules[0], i).upper()) if rules else (lambda i: "")
    clockwise = rule(1) == "CLOCKWISE"
    buildings = model.of_type("BUILDING")
    north_axis = _number(_field(buildings[0], 1), 0.0) if buildings else 0.0
    zone_obj = next((z for z in model.of_type("ZONE") if z.name.upper() == zone.upper()), None)
    relative_north = _number(_field(zone_obj, 1), 0.0) if zone_obj is not None else 0.0

    def turn(system: str) -> float:
        # "Absolute" is the IDD's other word for world coordinates
        return 0.0 if system in ("WORLD", "ABSOLUTE") else north_axis + relative_north

    out = []
    for object_type, (zone_at, boundary_at, sun_at, vertex_at) in _DETAILED.items():
        for obj in model.of_type(object_type):
            if _field(obj, zone_at).upper() != zone.upper() \
                    or _field(obj, boundary_at).upper() != "OUTDOORS" \
                    or _field(obj, sun_at).upper() == "NOSUN":
                continue
            values = [float(v) for v in obj.fields[vertex_at:] if v.strip()]
            points = [values[i:i + 3] for i in range(0, len(values) - 2, 3)]
            normal = np.zeros(3)
            for (x1, y1, z1), (x2, y2, z2) in zip(points, points[1:] + points[:1]):
                normal += ((y1 - y2) * (z1 + z2), (z1 - z2) * (x1 + x2), (x1 - x2) * (y1 + y2))
            length = float(np.linalg.norm(normal))
            if length == 0.0:
                continue
            if clockwise:
                normal = -normal
            tilt = math.degrees(math.acos(max(-1.0, min(1.0, normal[2] / length))))
            azimuth = math.degrees(math.atan2(normal[0], normal[1])) + turn(rule(2))
            out.append(_oriented(obj.name, tilt, azimuth, length / 2.0))
    for object_type, (zone_at, azimuth_at, tilt_at, tilt_default, a_at, b_at) in _SIMPLE.items():
        for obj in model.of_type(object_type):
            if _field(obj, zone_at).upper() != zone.upper():
                continue
            azimuth = _number(_field(obj, azimuth_at), 0.0) + turn(rule(4))
            area = _number(_field(obj, a_at), 0.0) * _number(_field(obj, b_at), 0.0)
            out.append(_oriented(obj.name, _number(_field(obj, tilt_at), tilt_default),
                                 azimuth, area))
    return out


def _oriented(name: str, tilt: float, azimuth: float, area: float) -> ExteriorSurface:
    # Rounded so that an axis-aligned wall gets exactly the compass plane (no
    # 1e-14 noise between equal orientations, which are grouped).
    return ExteriorSurface(name, round(tilt, 4), round(azimuth % 360.0, 4) % 360.0, area)


def facade_class(tilt: float, azimuth: float) -> str | None:
    """The facade a surface belongs to: ``roof`` (tilt below 45°), a compass quadrant, or None.

    Walls are classed by the quadrant of their azimuth (``north`` 315–45°,
    ``east`` 45–135°, ``south`` 135–225°, ``west`` 225–315°); a surface
    tilted beyond 135° faces the ground and belongs to no facade.
    """
    if tilt < 45.0:
        return "roof"
    if tilt > 135.0:
        return None
    return ("north", "east", "south", "west")[int(((azimuth + 45.0) % 360.0) // 90.0)]


def plane_irradiance(weather: Path, timestamps: pd.DatetimeIndex,
                     planes: list[tuple[float, float]], albedo: float = 0.2) -> np.ndarray:
    """Total irradiance on tilted planes over each hour, W/m², shape ``(n, len(planes))``.

    The same sky as the facade drivers (:func:`bpsflow.diagnosis.drivers.incident_solar`):
    pvlib's isotropic sky, the sun (SPA, apparent zenith) at the middle of
    each hour, no beam with the sun below the horizon, so that a plane facing
    a compass direction gets exactly that driver's values.

    Parameters
    ----------
    weather : Path
        EPW weather file.
    timestamps : DatetimeIndex
        Hour-ending timestamps, naive local standard time (any year: the
        weather is read by month, day and hour).
    planes : list of (tilt, azimuth)
        Degrees; tilt from horizontal, azimuth clockwise from true north.
    albedo : float
        Ground reflectance (-).
    """
    import pvlib

    from bpsflow.diagnosis.drivers import epw_location
    from bpsflow.weather import epw_rows, read_epw

    epw = read_epw(Path(weather))
    location = epw_location(epw)
    hour_starts = pd.DatetimeIndex(timestamps) - pd.Timedelta(hours=1)
    rows = epw_rows(hour_starts, epw.n_hours)
    ghi, dni, dhi = (epw.columns[c][rows] for c in ("global_horizontal_radiation",
                                                     "direct_normal_radiation",
                                                     "diffuse_horizontal_radiation"))
    middles_utc = (hour_starts + pd.Timedelta(minutes=30)
                   - pd.Timedelta(hours=location["time_zone"])).tz_localize("UTC")
    sun = pvlib.solarposition.get_solarposition(middles_utc, location["latitude"],
                                                location["longitude"],
                                                altitude=location["elevation"])
    zenith = sun["apparent_zenith"].to_numpy()
    dni = np.where(zenith < 90.0, dni, 0.0)
    out = np.zeros((len(hour_starts), len(planes)))
    for j, (tilt, azimuth) in enumerate(planes):
        total = pvlib.irradiance.get_total_irradiance(
            tilt, azimuth, zenith, sun["azimuth"].to_numpy(), dni=dni, ghi=ghi, dhi=dhi,
            albedo=albedo, model="isotropic")
        out[:, j] = np.nan_to_num(np.asarray(total["poa_global"], dtype=float), nan=0.0)
    return out


def facade_irradiance(config: Config, zone: str, facade: str,
                      model: IdfModel | None = None) -> tuple[pd.Series, dict]:
    """Hourly irradiance on the zone's ``facade`` over the config's year, W/m².

    The area-weighted mean over the zone's sun-exposed outdoor surfaces of
    that facade (:func:`zone_exterior_surfaces`, :func:`facade_class`), each
    at its own tilt and azimuth; the aperture's design level then stays "W
    per W/m² incident on the facade". A zone with no such surface (e.g. the
    wall is adiabatic or faces a neighbour) gets the compass plane of the
    driver that named the facade (:data:`bpsflow.diagnosis.drivers.FACADES`):
    the residuals follow that irradiance, whatever carries it.

    Returns
    -------
    Series
        8760 hour-ending values (:func:`year_hours`), W/m².
    dict
        ``facade``, ``zone``, ``surfaces`` (names, empty for the compass
        plane) and ``planes`` (``tilt``, ``azimuth`` in degrees, ``area_m2``;
        ``None`` for the compass plane), for the report.
    """
    from bpsflow.diagnosis.drivers import FACADES
    from bpsflow.simulation.idf import model_objects

    model = model if model is not None else model_objects(config.model)
    stamps = year_hours(config.model.year)
    surfaces = [s for s in zone_exterior_surfaces(model, zone)
                if facade_class(s.tilt, s.azimuth) == facade]
    areas: dict[tuple[float, float], float] = {}
    for s in surfaces:
        areas[(s.tilt, s.azimuth)] = areas.get((s.tilt, s.azimuth), 0.0) + s.area
    if surfaces and sum(areas.values()) > 0:
        planes = sorted(areas)
        weights = np.array([areas[p] for p in planes])
        values = plane_irradiance(config.model.weather, stamps, planes) @ (weights / weights.sum())
        described = [{"tilt": t, "azimuth": a, "area_m2": areas[(t, a)]} for t, a in planes]
    else:
        values = plane_irradiance(config.model.weather, stamps, [FACADES[facade]])[:, 0]
        described = None
    return (pd.Series(values, index=stamps),
            {"facade": facade, "zone": zone, "surfaces": [s.name for s in surfaces],
             "planes": described})


def write_schedule(values: np.ndarray, path: Path) -> Path:
    """One numeric column, no header: what the snippets' ``Schedule:File`` reads."""
    np.savetxt(path, np.asarray(values, dtype=float), fmt="%.6g")
    return path


def year_hours(year: int) -> pd.DatetimeIndex:
    """Hour-ending stamps of the year's first 8760 hours (the rows of an hourly Schedule:File)."""
    return pd.date_range(pd.Timestamp(year=year, month=1, day=1, hour=1), periods=8760, freq="h")


#: Days of the week (0 = Monday), the single-day day types.
WEEK_DAYS = ("monday", "tuesday", "wednesday", "thursday", "friday", "saturday", "sunday")

#: Day types a gain block may cover: name -> the days of the week it is on
#: (7 flags, Monday first).
DAY_TYPES: dict[str, tuple[int, ...]] = {
    "weekdays": (1, 1, 1, 1, 1, 0, 0), "weekends": (0, 0, 0, 0, 0, 1, 1),
    "all days": (1, 1, 1, 1, 1, 1, 1),
    **{day: tuple(int(i == d) for i in range(7)) for d, day in enumerate(WEEK_DAYS)}}


def gain_blocks(residual: pd.Series, output_sign: float,
                fitted_jacobian: np.ndarray | None = None, count: int = 4,
                overlap: float = 0.8,
                responsive: np.ndarray | None = None) -> list[tuple[pd.DataFrame, dict]]:
    """On/off blocks (day type × hours) of an unmodelled gain that best explain the residuals.

    Every block ``[start, end)`` hours of every day type in :data:`DAY_TYPES`
    (weekdays, weekends, all days, each single day of the week) is tried as
    a regressor of the residual, together with a constant and
    ``fitted_jacobian`` (the fitted parameters' responses at the residual's
    hours, ``(n, k)``): the calibration that produced the residual has bent
    those parameters towards the missing gain (e.g. more solar gain for a
    midday bump) and the joint regression partly undoes that. That screen
    is linear and the calibration's moves are not, so it is only a
    shortlist: the ``count`` blocks with the smallest residual sum of
    squares, skipping blocks that share more than ``overlap`` of their hours
    (Jaccard) with a block already listed; the joint nonlinear refit of
    each decides. A block's profile is 1 in the block and 0 elsewhere, so
    the fitted design level is the gain while it is on (W). ``responsive``
    (bool, ``(n,)``) marks the hours at which the output can respond to a
    gain at all: a heating power that is zero in both the model and the
    measurement (the zone floats above its setpoint) does not move, so a
    block's regressor is zero there and the screen compares blocks on the
    hours that carry information.

    The 10 × 300 regressions share their base: the residual and the 168
    day-of-week × hour indicators are projected off the base once, and each
    block's fit follows from prefix sums of their inner products (exact, the
    same least squares as one regression per block).

    Returns
    -------
    list of (profile, block)
        ``profile``: column ``profile`` indexed by ``day_of_week`` (0 =
        Monday … 6) × ``hour`` (0–23, hour start); ``block``: ``day_type``,
        ``start_hour``, ``end_hour`` and the screen's ``level`` (W, oriented
        by ``output_sign``, the output's response to a gain: −1 for heating).
    """
    start = residual.index - pd.Timedelta(hours=1)
    day = np.asarray(start.day_of_week)
    hour = np.asarray(start.hour)
    y = residual.to_numpy(dtype=float)
    base = np.ones((len(y), 1))
    if fitted_jacobian is not None and fitted_jacobian.size:
        base = np.column_stack([base, fitted_jacobian])
    # indicators[:, 24 d + h]: the hour starts at h on day of week d
    indicators = np.zeros((len(y), 168))
    indicators[np.arange(len(y)), 24 * day + hour] = 1.0
    if responsive is not None:
        indicators *= np.asarray(responsive, dtype=float)[:, None]
    stacked = np.column_stack([y, indicators])
    projected = stacked - base @ np.linalg.lstsq(base, stacked, rcond=None)[0]
    y_res, z = projected[:, 0], projected[:, 1:]
    counts = indicators.sum(axis=0).reshape(7, 24)
    z_y = (z.T @ y_res).reshape(7, 24)
    gram = (z.T @ z).reshape(7, 24, 7, 24)
    rss_base = float(y_res @ y_res)
    tolerance = 1e-9 * max(1.0, float(np.max(np.abs(np.diagonal(z.T @ z)))))
    ranked = []
    first, last = np.triu_indices(25, k=1)          # every [first, last) with first < last
    for day_type, days in DAY_TYPES.items():
        on = np.flatnonzero(days)
        hours_on = counts[on].sum(axis=0)                              # (24,)
        cross = z_y[on].sum(axis=0)                                    # (24,)
        inner = gram[on][:, :, on].sum(axis=(0, 2))                    # (24, 24)
        count_prefix = np.concatenate([[0.0], np.cumsum(hours_on)])
        cross_prefix = np.concatenate([[0.0], np.cumsum(cross)])
        inner_prefix = np.zeros((25, 25))
        inner_prefix[1:, 1:] = inner.cumsum(axis=0).cumsum(axis=1)
        size = count_prefix[last] - count_prefix[first]
        b_y = cross_prefix[last] - cross_prefix[first]
        b_b = (inner_prefix[last, last] - inner_prefix[first, last]
               - inner_prefix[last, first] + inner_prefix[first, first])
        usable = (size >= 2) & (size < len(y)) & (b_b > tolerance)
        with np.errstate(divide="ignore", invalid="ignore"):
            coefficient = np.where(usable, b_y / b_b, 0.0)
        rss = rss_base - coefficient * b_y
        for i in np.flatnonzero(usable):
            ranked.append((float(rss[i]), day_type, int(first[i]), int(last[i]),
                           float(coefficient[i]) * output_sign))
    ranked.sort(key=lambda item: item[0])
    chosen: list = []
    for _, day_type, a, b, level in ranked:
        if level <= 0.0:
            # a gain is non-negative: a block that only fits with a negative level would be
            # refitted at zero, and it would crowd out the blocks that can explain a gain
            continue
        block = np.isin(day, np.flatnonzero(DAY_TYPES[day_type])) & (hour >= a) & (hour < b)
        if all((block & c[4]).sum() / (block | c[4]).sum() < overlap for c in chosen):
            chosen.append((day_type, a, b, level, block))
        if len(chosen) >= count:
            break
    return [(block_profile(day_type, a, b),
             {"day_type": day_type, "start_hour": a, "end_hour": b, "level": level})
            for day_type, a, b, level, _ in chosen]


def block_profile(day_type: str, start_hour: int, end_hour: int) -> pd.DataFrame:
    """1 during ``[start_hour, end_hour)`` on the days of ``day_type``, else 0.

    Column ``profile`` indexed by ``day_of_week`` (0 = Monday … 6 = Sunday) ×
    ``hour`` (0–23, hour start).

    Raises
    ------
    ValueError
        ``day_type`` is not one of :data:`DAY_TYPES`.
    """
    if day_type not in DAY_TYPES:
        raise ValueError(f"day type '{day_type}' is not one of {', '.join(DAY_TYPES)}")
    full = pd.MultiIndex.from_product([range(7), range(24)], names=["day_of_week", "hour"])
    days = DAY_TYPES[day_type]
    return pd.DataFrame({"profile": [float(bool(days[d]) and start_hour <= h < end_hour)
                                     for d, h in full]}, index=full)


def profile_schedule(profile: pd.DataFrame, year: int) -> pd.Series:
    """The gain profile over the year's hours (hour-ending stamps, 8760 values).

    ``profile`` is indexed by ``day_of_week`` × ``hour`` (:func:`block_profile`).
    """
    stamps = year_hours(year)
    start = stamps - pd.Timedelta(hours=1)
    keys = pd.MultiIndex.from_arrays([start.day_of_week, start.hour])
    return pd.Series(profile["profile"].reindex(keys).to_numpy(), index=stamps)


def sky_diffuse_irradiance(config: Config) -> pd.Series:
    """Hourly diffuse horizontal irradiance of the config's weather over its year, W/m².

    The schedule of an aperture that sees the sky but no beam (a shaded or
    north-light opening): the weather file's diffuse horizontal irradiance of
    each hour (hour-ending stamps, :func:`year_hours`).
    """
    from bpsflow.weather import epw_rows, read_epw

    epw = read_epw(Path(config.model.weather))
    stamps = year_hours(config.model.year)
    rows = epw_rows(stamps - pd.Timedelta(hours=1), epw.n_hours)
    return pd.Series(np.asarray(epw.columns["diffuse_horizontal_radiation"][rows], dtype=float),
                     index=stamps)

