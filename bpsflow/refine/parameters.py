"""From estimates to config parameters: finding them by target, units, refined distributions.

A refined quantity is matched to the config's parameters by what they
target (IDF object type, object name, field), never by parameter name, so a
config may name its parameters freely. Estimates are physical values (α in
W/m²·K^(1+n), a gradient in K/m); a parameter may be ``relative`` (a
multiplier on the IDF's nominal value), ``absolute`` or ``additive``, so each
estimate is expressed in its parameter's units with the nominal read from the
IDF (:func:`bpsflow.simulation.idf.read_idf`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import TypeAdapter

from bpsflow.config import Config, IdfTarget, Parameter
from bpsflow.distributions import Distribution, Empirical
from bpsflow.errors import BpsflowError
from bpsflow.simulation.idf import UNNAMED, IdfModel
from bpsflow.simulation.targets import select_objects, targets_field

#: Central probability of the intervals reported before and after refinement.
INTERVAL = 0.90

#: Refined bounded normals are cut at this many standard errors.
BOUND_SIGMAS = 3.0

_DISTRIBUTION = TypeAdapter(Distribution)


def idf_targets(parameter: Parameter) -> list[IdfTarget]:
    return [t for t in parameter.targets if isinstance(t, IdfTarget)]


def parameters_targeting(config: Config, object_type: str, field: str,
                         name: str | None = None) -> list[Parameter]:
    """The config's parameters with a target on ``object_type`` ``name`` ``field``."""
    return [p for p in config.parameters
            if any(targets_field(t, object_type, field, name) for t in idf_targets(p))]


def idf_nominal(idf: IdfModel, target: IdfTarget) -> float:
    """The model's value of a target field (the first object when the name is ``*``)."""
    objects = idf.of_type(target.object)
    if target.object.upper() not in UNNAMED:
        objects = select_objects(objects, target.name)
    if not objects:
        raise BpsflowError(f"the model has no {target.object} '{target.name}' (a refined "
                           f"parameter targets it)", source=idf.path)
    try:
        return objects[0].number(target.field)
    except KeyError:
        raise BpsflowError(f"{target.object} field '{target.field}' cannot be read without "
                           f"EnergyPlus's IDD", source=idf.path) from None


def parameter_nominal(idf: IdfModel, parameter: Parameter) -> float | None:
    """The IDF value a parameter's mode refers to (``None`` for absolute parameters)."""
    if parameter.mode == "absolute":
        return None
    return idf_nominal(idf, idf_targets(parameter)[0])


def in_parameter_units(values, mode: str, nominal: float | None):
    """Physical values expressed as a parameter's values (multiplier, value, or offset)."""
    values = np.asarray(values, dtype=float)
    if mode == "relative":
        return values / nominal
    if mode == "additive":
        return values - nominal
    return values


def std_in_parameter_units(std: float, mode: str, nominal: float | None) -> float:
    return std / abs(nominal) if mode == "relative" else std


def bounded_normal(mean: float, std: float, floor: float | None = None) -> dict:
    """A normal cut at ±:data:`BOUND_SIGMAS` standard errors (and at ``floor``), as YAML."""
    lower, upper = mean - BOUND_SIGMAS * std, mean + BOUND_SIGMAS * std
    if floor is not None:
        lower = max(lower, floor)
    return {"type": "normal", "mean": _round(mean), "std": _round(std),
            "lower": _round(lower), "upper": _round(upper)}


def _round(value: float) -> float:
    return float(f"{value:.6g}")


def distribution_from(spec: dict, values: np.ndarray | None = None) -> Distribution:
    """A distribution object from its YAML mapping (empirical: with ``values`` loaded)."""
    distribution = _DISTRIBUTION.validate_python(spec)
    if isinstance(distribution, Empirical):
        distribution = distribution.model_copy(
            update={"values_": tuple(np.sort(np.asarray(values, dtype=float)))})
    return distribution


def interval(distribution: Distribution, level: float = INTERVAL) -> tuple[float, float]:
    """The central ``level`` interval of a distribution (its quantiles)."""
    tail = (1 - level) / 2
    low, high = distribution.ppf(np.array([tail, 1 - tail]))
    return float(low), float(high)


def class_surfaces(idf: IdfModel, named: dict[str, str], settings: dict[str, str] | None = None,
                   source: str | Path | None = None,
                   named_source: str | Path | None = None) -> dict[str, str]:
    """The IDF surface each surface class was measured on.

    ``detailed.json``'s ``surface_classes`` names them when the measurements
    say where the sensors were (``synth --detailed`` always writes it). A class
    it leaves out, as a laboratory's own metadata may, is chosen from the
    model's geometry by the rules and config keys (``detailed.zone``,
    ``detailed.<class>``) of :func:`bpsflow.detailed.select_sensor_surfaces`,
    the same that place the sensors of ``synth --detailed``.

    Parameters
    ----------
    idf : IdfModel
    named : dict
        Surface class -> surface name, from ``detailed.json``.
    settings : dict, optional
        The config's ``detailed`` keys.
    source : str or Path, optional
        The config file (for messages about its keys).
    named_source : str or Path, optional
        The ``detailed.json`` file (for messages about its names).

    Returns
    -------
    dict
        Class (every one of :data:`bpsflow.detailed.SURFACE_CLASSES`) -> surface
        name as the model spells it.

    Raises
    ------
    BpsflowError
        When ``detailed.json`` names a surface the model does not have, or the
        geometry cannot choose one (see ``select_sensor_surfaces``).
    """
    from bpsflow.detailed import SURFACE_CLASSES, select_sensor_surfaces

    surfaces = {s.name.upper(): s.name for s in idf.of_type("BuildingSurface:Detailed")}
    chosen = {}
    for surface_class in SURFACE_CLASSES:
        name = named.get(surface_class)
        if name is None:
            continue
        if name.upper() not in surfaces:
            raise BpsflowError(f"surface_classes.{surface_class}: the model ({idf.path.name}) has "
                               f"no BuildingSurface:Detailed '{name}'; its surfaces: "
                               f"{', '.join(surfaces.values())}", source=named_source)
        chosen[surface_class] = surfaces[name.upper()]
    if len(chosen) < len(SURFACE_CLASSES):
        selection = select_sensor_surfaces(idf, settings, source)
        chosen = {c: chosen.get(c, selection.surfaces[c]) for c in SURFACE_CLASSES}
    return chosen


def relative_file(path: Path, start: Path) -> str:
    """``path`` relative to ``start`` where possible (configs stay movable together)."""
    import os

    try:
        return os.path.relpath(path, start)
    except ValueError:  # another drive on Windows
        return str(path)
