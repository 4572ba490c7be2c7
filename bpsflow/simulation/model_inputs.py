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
    check_thermostat_zones(config)


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
