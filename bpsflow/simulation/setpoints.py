"""Test setpoints and how they reach the model's own thermostats.

A test (``model.tests[i]``) sets a heating or cooling setpoint, with an
optional night setback, or lets the zones float. Both backends take the
day profiles from :func:`day_setpoints`. The EnergyPlus backend writes them
as two ``Schedule:Compact`` objects and rewires the model's own
``ZoneControl:Thermostat`` objects to a dual setpoint on those schedules
(:func:`thermostat_plan`), so whatever the model's thermostats did before,
the test's setpoints are the ones in force. Names the tool adds start with
``BPSFLOW`` and cannot collide with a model's names that do not.

:func:`thermostat_plan` also checks, before anything runs, that the
setpoints can take effect: a controlled zone needs a thermostat and some
equipment to condition it, or the setpoint would be a silent no-op.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import date, timedelta
from typing import TYPE_CHECKING

from bpsflow.errors import BpsflowError
from bpsflow.simulation.idf import IdfModel, IdfObject

if TYPE_CHECKING:
    from bpsflow.config import Config, Period, Test

#: Setpoints that keep any heating or cooling idle (°C).
HEATING_OFF_C = -60.0
COOLING_OFF_C = 100.0

#: Names of the objects the tool adds to every EnergyPlus instance.
HEATING_SCHEDULE = "BPSFLOW Heating Setpoint"
COOLING_SCHEDULE = "BPSFLOW Cooling Setpoint"
CONTROL_TYPE_SCHEDULE = "BPSFLOW Thermostat Control Type"
TEMPERATURE_LIMITS = "BPSFLOW Temperature"
CONTROL_TYPE_LIMITS = "BPSFLOW Control Type"
DUAL_SETPOINT = "BPSFLOW Dual Setpoint"
#: ``ZoneControl:Thermostat`` control type 4 is a dual (heating and cooling) setpoint.
DUAL_SETPOINT_CONTROL_TYPE = 4

_THERMOSTAT = "ZONECONTROL:THERMOSTAT"
#: Equipment list entries that cannot condition a zone's air on their own.
_NOT_CONDITIONING = ("ZONEHVAC:EXHAUSTCONTROL",)


def day_setpoints(test: Test | None) -> tuple[list[tuple[int, float]], list[tuple[int, float]]]:
    """(heating, cooling) setpoint profiles of one day as ``[(until_hour, °C), ...]``.

    Days outside every test, and free-floating tests, get setpoints that keep
    the equipment idle (:data:`HEATING_OFF_C`, :data:`COOLING_OFF_C`); so do
    ``model`` tests, whose setpoints are the model's own and unknown to the tool
    (no thermostat is rewired to these profiles then).
    """
    if test is None or test.mode in ("free_floating", "model"):
        return [(24, HEATING_OFF_C)], [(24, COOLING_OFF_C)]
    setpoint = float(test.setpoint_c)  # type: ignore[arg-type]
    if test.setback_c is None:
        active = [(24, setpoint)]
    else:
        back, start, end = float(test.setback_c), test.setback_start_hour, test.setback_end_hour
        # a window that crosses midnight (18 -> 8) or lies within the day (0 -> 6, 12 -> 14)
        steps = [(end, back), (start, setpoint), (24, back)] if end < start else \
            [(start, setpoint), (end, back), (24, setpoint)]
        active = [(hour, value) for number, (hour, value) in enumerate(steps)
                  if hour > (steps[number - 1][0] if number else 0)]
    if test.mode == "heating":
        return active, [(24, COOLING_OFF_C)]
    return [(24, HEATING_OFF_C)], active


def setpoint_schedules(config: Config, period: Period) -> tuple[str, str]:
    """Schedule:Compact text for the heating and cooling setpoints over ``period``.

    Each test's days follow its mode (setpoint, setback window or free
    floating); days of the period outside every test float. EnergyPlus's own
    warm-up repeats the period's first day.
    """
    from bpsflow.config import period_dates

    year = config.model.year
    first, last = period_dates(period, year)
    by_day: dict[date, Test] = {}
    for test in config.tests_in(period.name):
        start = date(year, *map(int, test.start.split("-")))
        for d in range(test.days):
            by_day[start + timedelta(days=d)] = test
    days = [first + timedelta(days=d) for d in range((last - first).days + 1)]
    profiles = [day_setpoints(by_day.get(day)) for day in days]
    texts = []
    for which, name in ((0, HEATING_SCHEDULE), (1, COOLING_SCHEDULE)):
        fields = [name, TEMPERATURE_LIMITS]
        runs: list[tuple[date, list[tuple[int, float]]]] = []
        for day, profile in zip(days, profiles):
            if runs and runs[-1][1] == profile[which]:
                runs[-1] = (day, profile[which])
            else:
                runs.append((day, profile[which]))
        runs[-1] = (date(year, 12, 31), runs[-1][1])
        for through, day_profile in runs:
            fields.append(f"Through: {through:%m/%d}")
            fields.append("For: AllDays")
            for until, value in day_profile:
                fields.extend([f"Until: {until:02d}:00", f"{value:g}"])
        texts.append("Schedule:Compact,\n  " + ",\n  ".join(fields) + ";\n")
    # the limits object travels with the heating schedule: EnergyPlus warns of a schedule
    # without limits in every run
    limits = (f"ScheduleTypeLimits,\n  {TEMPERATURE_LIMITS},\n  {HEATING_OFF_C:g},\n  "
              f"{COOLING_OFF_C:g},\n  Continuous,\n  Temperature;\n")
    return limits + texts[0], texts[1]


def sizing_note(config: Config, idf: IdfModel) -> str | None:
    """A note when the tests' setpoints also drive the model's autosizing, else None.

    The tool's schedules hold on every day, design days included, so an
    autosized system is sized for each test's setpoints (a heating test's
    cooling setpoint is off: its cooling coils size to nothing) and for each
    instance's inputs.
    """
    if all(t.mode == "model" for t in config.model.tests):
        return None
    autosized = sum(field.strip().upper() == "AUTOSIZE" for o in idf.objects for field in o.fields)
    if not autosized:
        return None
    return (f"the model autosizes {autosized} field(s): its design days run under the tests' "
            f"setpoints (the tool's schedules hold on every day), so equipment is sized anew "
            f"for each test and instance (a heating test sizes cooling to nothing). To compare "
            f"one fixed system, hard-size it (EnergyPlus's Component Sizing table of one run), "
            f"or run the model's own controls with mode: model")


def control_objects_text() -> str:
    """The control-type schedule and dual setpoint every rewired thermostat points to."""
    return (f"ScheduleTypeLimits,\n  {CONTROL_TYPE_LIMITS},\n  0,\n  4,\n  Discrete;\n\n"
            f"Schedule:Constant,\n  {CONTROL_TYPE_SCHEDULE},\n  {CONTROL_TYPE_LIMITS},\n  "
            f"{DUAL_SETPOINT_CONTROL_TYPE};\n\n"
            f"ThermostatSetpoint:DualSetpoint,\n  {DUAL_SETPOINT},\n  {HEATING_SCHEDULE},\n  "
            f"{COOLING_SCHEDULE};\n")


@dataclass
class ThermostatPlan:
    """Which thermostats the tool rewires, and the zones they control.

    Attributes
    ----------
    thermostats : list of str
        Names of the ``ZoneControl:Thermostat`` objects rewired to the tool's
        dual setpoint.
    zones : dict
        Controlled zone name -> the conditioning equipment found for it.
    """

    thermostats: list[str] = field(default_factory=list)
    zones: dict[str, list[str]] = field(default_factory=dict)


def _field(obj: IdfObject, index: int) -> str:
    return obj.fields[index].strip() if index < len(obj.fields) else ""


def _zone_members(idf: IdfModel, name: str) -> list[str]:
    """A zone name, or the zones of a ``ZoneList`` of that name."""
    for zone_list in idf.of_type("ZONELIST"):
        if zone_list.name.upper() == name.upper():
            return [z for z in zone_list.fields[1:] if z.strip()]
    return [name]


def zone_names(idf: IdfModel) -> list[str]:
    """The model's ``Zone`` object names, in model order."""
    return [z.name for z in idf.of_type("ZONE")]


def zone_equipment(idf: IdfModel) -> dict[str, list[str]]:
    """Zone name (upper case) -> ``Type 'Name'`` of the equipment that can condition it.

    Read from ``ZoneHVAC:EquipmentConnections`` and its ``ZoneHVAC:EquipmentList``
    (object type and name pairs after the load distribution scheme).
    """
    lists = {o.name.upper(): o for o in idf.of_type("ZONEHVAC:EQUIPMENTLIST")}
    found: dict[str, list[str]] = {}
    for connection in idf.of_type("ZONEHVAC:EQUIPMENTCONNECTIONS"):
        zone = _field(connection, 0).upper()
        equipment_list = lists.get(_field(connection, 1).upper())
        if equipment_list is None:
            continue
        # Name, load distribution scheme, then groups of six fields starting with type, name.
        items = equipment_list.fields[2:]
        for k in range(0, len(items) - 1, 6):
            kind, name = items[k].strip(), items[k + 1].strip()
            if kind and kind.upper() not in _NOT_CONDITIONING:
                found.setdefault(zone, []).append(f"{kind} '{name}'")
    return found


def bypassed_setpoint_schedules(idf: IdfModel, plan: ThermostatPlan) -> set[str]:
    """Schedules (upper case) that only the rewired thermostats' own setpoints read.

    The tests' setpoints replace those thermostats' control objects, so such a
    schedule no longer acts on the simulation; one that any other object also
    names (an availability schedule, another thermostat) still does.
    """
    chosen = {name.upper() for name in plan.thermostats}
    setpoint_objects: set[tuple[str, str]] = set()
    candidates: set[str] = set()
    for thermostat in idf.of_type(_THERMOSTAT):
        if thermostat.name.upper() not in chosen:
            continue
        candidates.add(_field(thermostat, 2).upper())          # the control type schedule
        pairs = thermostat.fields[3:]
        for kind, name in zip(pairs[0::2], pairs[1::2]):
            setpoint_objects.add((kind.strip().upper(), name.strip().upper()))
    bypassed = [obj for obj in idf.objects if (obj.type, obj.name.upper()) in setpoint_objects]
    for obj in bypassed:
        candidates.update(value.strip().upper() for value in obj.fields[1:])
    skipped = {id(obj) for obj in bypassed} | {
        id(t) for t in idf.of_type(_THERMOSTAT) if t.name.upper() in chosen}
    still_read = {value.strip().upper() for obj in idf.objects if id(obj) not in skipped
                  and not obj.type.startswith("SCHEDULE")
                  for value in obj.fields}
    return {name for name in candidates if name and name not in still_read}


def _refuse_bypassed_schedule_targets(config: Config, idf: IdfModel,
                                      plan: ThermostatPlan) -> None:
    """A parameter on a schedule the tests' setpoints replace would change nothing."""
    from bpsflow.config import IdfTarget
    from bpsflow.simulation.targets import select_objects

    bypassed = bypassed_setpoint_schedules(idf, plan)
    if not bypassed:
        return
    for i, parameter in enumerate(config.parameters):
        for j, target in enumerate(parameter.targets):
            if not isinstance(target, IdfTarget) or \
                    not target.object.strip().upper().startswith("SCHEDULE"):
                continue
            chosen = select_objects(idf.of_type(target.object.strip().upper()), target.name)
            if chosen and all(obj.name.upper() in bypassed for obj in chosen):
                readers = _thermostats_reading(idf, plan, chosen[0].name) or plan.thermostats
                raise BpsflowError(
                    f"parameters[{i}] ({parameter.name}).targets[{j}]: {target.object} "
                    f"'{chosen[0].name}' is a setpoint schedule of the thermostat(s) "
                    f"{', '.join(readers)}, which the tests' setpoints replace "
                    f"(modes heating, cooling, free_floating): the parameter would change "
                    f"nothing. The tests' setpoint_c sets the setpoint; to vary the model's "
                    f"own setpoint schedules, run its own controls with test mode: model",
                    source=config.source)


def _thermostats_reading(idf: IdfModel, plan: ThermostatPlan, schedule: str) -> list[str]:
    """The rewired thermostats whose control type or setpoint objects name ``schedule``."""
    wanted = schedule.strip().upper()
    chosen = {name.upper() for name in plan.thermostats}
    controls = {(o.type, o.name.upper()): o for o in idf.objects if o.type.startswith(
        "THERMOSTATSETPOINT:")}
    readers = []
    for thermostat in idf.of_type(_THERMOSTAT):
        if thermostat.name.upper() not in chosen:
            continue
        names = {_field(thermostat, 2).upper()}
        pairs = thermostat.fields[3:]
        for kind, name in zip(pairs[0::2], pairs[1::2]):
            control = controls.get((kind.strip().upper(), name.strip().upper()))
            if control is not None:
                names.update(value.strip().upper() for value in control.fields[1:])
        if wanted in names:
            readers.append(thermostat.name)
    return readers


def thermostat_plan(config: Config, idf: IdfModel) -> ThermostatPlan:
    """Decide which of the model's thermostats carry the tests' setpoints, and check it.

    Every ``ZoneControl:Thermostat`` is rewired, or only those of the zones
    listed in ``model.thermostat_zones``.

    Raises
    ------
    BpsflowError
        When a test sets a setpoint but it cannot take effect: the model has
        no thermostat (or none for a listed zone), a listed zone is not a zone
        of the model, the model uses ``HVACTemplate:Thermostat`` (it needs
        ExpandObjects first), or a controlled zone has no equipment that could
        heat or cool it.
    """
    if all(t.mode == "model" for t in config.model.tests):
        return ThermostatPlan()
    controlled = any(t.mode in ("heating", "cooling") for t in config.model.tests)
    wanted = config.model.thermostat_zones
    zones_upper = {z.upper(): z for z in zone_names(idf)}
    if wanted is not None:
        for i, zone in enumerate(wanted):
            if zone.upper() not in zones_upper:
                raise BpsflowError(
                    f"model.thermostat_zones[{i}]: '{zone}' is not a zone of the model "
                    f"(its zones: {', '.join(zones_upper.values()) or 'none'})",
                    source=config.source)
    equipment = zone_equipment(idf)
    plan = ThermostatPlan()
    for thermostat in idf.of_type(_THERMOSTAT):
        members = _zone_members(idf, _field(thermostat, 1))
        if wanted is not None:
            members = [m for m in members if m.upper() in {w.upper() for w in wanted}]
            if not members:
                continue
        plan.thermostats.append(thermostat.name)
        for zone in members:
            plan.zones[zones_upper.get(zone.upper(), zone)] = equipment.get(zone.upper(), [])
    if not controlled:
        return plan
    templates = idf.of_type("HVACTEMPLATE:THERMOSTAT")
    if templates:
        raise BpsflowError(
            f"the model uses HVACTemplate:Thermostat ('{templates[0].name}'), which EnergyPlus "
            f"expands with ExpandObjects before a run; run ExpandObjects on the model and use "
            f"its expanded.idf, so the tests' setpoints reach real ZoneControl:Thermostat "
            f"objects", source=config.model.idf)
    tests = ", ".join(t.name for t in config.model.tests if t.mode in ("heating", "cooling"))
    if not plan.thermostats:
        which = (f" for the zones of model.thermostat_zones ({', '.join(wanted)})"
                 if wanted is not None else "")
        raise BpsflowError(
            f"tests {tests} set a setpoint, but the model has no ZoneControl:Thermostat"
            f"{which}: the setpoint could not take effect. Add a thermostat and equipment "
            f"(e.g. ZoneHVAC:IdealLoadsAirSystem) to the zones to control, or make the tests "
            f"free_floating", source=config.model.idf)
    if wanted is not None:
        missing = [z for z in wanted if z.upper() not in {k.upper() for k in plan.zones}]
        if missing:
            raise BpsflowError(
                f"model.thermostat_zones: zone(s) {', '.join(missing)} have no "
                f"ZoneControl:Thermostat, so the tests' setpoints could not control them",
                source=config.source)
    _refuse_bypassed_schedule_targets(config, idf, plan)
    idle = [zone for zone, kit in plan.zones.items() if not kit]
    if idle:
        raise BpsflowError(
            f"tests {tests} set a setpoint, but the thermostat-controlled zone(s) "
            f"{', '.join(idle)} have no conditioning equipment (no ZoneHVAC:EquipmentConnections "
            f"with a ZoneHVAC:EquipmentList entry): the setpoint could not take effect. "
            f"Add equipment, or list only conditioned zones in model.thermostat_zones",
            source=config.model.idf)
    return plan
