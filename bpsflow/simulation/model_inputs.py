"""The model's input files, checked the same on every backend before anything runs.

- the IDF and every ``idf_objects`` snippet are IDF objects of EnergyPlus
  object types, checked when the config loads (:mod:`.idf_syntax`);
- :func:`check_model_inputs` (``bpsflow check``, ``sample``, and every command
  that runs instances, through the backends' ``check``) — the weather file
  parses fully (:func:`bpsflow.weather.read_epw`), the boundary-temperature
  file parses, and every parameter's IDF targets are fields of the IDD whose
  values stay within its bounds (:mod:`.target_bounds`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from bpsflow.errors import BpsflowError

if TYPE_CHECKING:
    from bpsflow.config import Config

__all__ = ["check_model_inputs"]

def check_model_inputs(config: Config) -> None:
    """Check the weather file, the boundary data and the parameters' IDF targets.

    Raises
    ------
    BpsflowError
        Naming the config key, the file, and the line and field (or the
        parameter, object and field) of the first problem.
    """
    from bpsflow.boundary import read_boundary_file
    from bpsflow.simulation.target_bounds import check_distribution_support, check_weather_support
    from bpsflow.weather import read_epw

    try:
        epw = read_epw(config.model.weather)
    except BpsflowError as exc:
        raise BpsflowError(f"model.weather: {exc.message}", source=exc.source) from None
    check_weather_support(config, epw.columns)
    boundary = config.model.boundary
    if boundary is not None:
        columns = tuple(surface.column for surface in boundary.surfaces.values())
        try:
            read_boundary_file(boundary.file, columns)
        except BpsflowError as exc:
            raise BpsflowError(f"model.boundary.file: {exc.message}",
                               source=exc.source or boundary.file) from None
    check_distribution_support(config)
    check_boundary_schedules(config)
    check_thermostat_zones(config)
    check_output_keys(config)


#: Output keys that name no object of the model (site, building and wildcard keys).
_MODEL_WIDE_KEYS = {"*", "ENVIRONMENT", "WHOLE BUILDING", "FACILITY", "SIMHVAC"}


def check_output_keys(config: Config) -> None:
    """Refuse an output ``key`` that names nothing in the model, before anything runs.

    A key is the name of what the variable reports for (a zone, surface,
    equipment or node), so it is a field of some object of the model or its
    snippets. A model with ``HVACTemplate`` objects is left to the engine:
    ExpandObjects makes names the file does not hold.
    """
    import difflib

    from bpsflow.simulation.idf import model_objects
    from bpsflow.simulation.setpoints import zone_names

    keyed = {name: spec for name, spec in config.outputs.items()
             if spec.variable is not None and spec.key
             and spec.key.strip().upper() not in _MODEL_WIDE_KEYS}
    if not keyed:
        return
    idf = model_objects(config.model)
    if any(o.type.startswith("HVACTEMPLATE:") for o in idf.objects):
        return
    values = {field.strip().upper() for o in idf.objects for field in o.fields if field.strip()}
    for name, spec in keyed.items():
        key = str(spec.key).strip()
        if key.upper() in values:
            continue
        # a 'Zone ...' variable may report for equipment of the zone (Zone Unit Heater
        # Heating Rate: the unit heater), so every name of the model is a candidate
        names = sorted({o.name for o in idf.objects if o.name})
        close = difflib.get_close_matches(key, names, n=3, cutoff=0.5)
        hint = (f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else
                f"; the model's zones: {', '.join(zone_names(idf)) or 'none'}")
        raise BpsflowError(f"outputs.{name}.key: '{key}' names nothing in the model (expected "
                           f"the zone, surface, equipment or node that '{spec.variable}' "
                           f"reports for){hint}", source=config.source)


def check_boundary_schedules(config: Config) -> None:
    """Refuse a ``model.boundary`` surface whose ``schedule`` names no Schedule:File of the
    model, on every backend (the schedule is where its measured temperatures go)."""
    from bpsflow.simulation.idf import describe_model, model_objects

    boundary = config.model.boundary
    if boundary is None:
        return
    idf = model_objects(config.model)
    files = sorted(o.name for o in idf.of_type("SCHEDULE:FILE"))
    known = {name.upper() for name in files}
    for surface, spec in boundary.surfaces.items():
        if spec.schedule.strip().upper() not in known:
            raise BpsflowError(
                f"model.boundary.surfaces.{surface}.schedule: no Schedule:File named "
                f"'{spec.schedule}' in {describe_model(config.model)} (its Schedule:File "
                f"objects: {files or 'none'})", source=config.source)


def check_thermostat_zones(config: Config) -> None:
    """Refuse ``model.thermostat_zones`` naming a zone the model lacks, on every backend."""
    from bpsflow.simulation.idf import model_objects
    from bpsflow.simulation.setpoints import zone_names

    wanted = config.model.thermostat_zones
    if not wanted:
        return
    zones = {zone.upper(): zone for zone in zone_names(model_objects(config.model))}
    for i, zone in enumerate(wanted):
        if zone.upper() not in zones:
            raise BpsflowError(f"model.thermostat_zones[{i}]: '{zone}' is not a zone of the "
                               f"model (its zones: {', '.join(zones.values()) or 'none'})",
                               source=config.source)
