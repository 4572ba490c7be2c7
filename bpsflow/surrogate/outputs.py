"""The EnergyPlus output variables the surrogate reports, their keys, and their hourly values.

A config output is an EnergyPlus output variable and a key. The surrogate
supports the variables of :data:`VARIABLES`; each takes keys of one kind
(:class:`Variable` ``scope``):

* ``zone`` -- the zone (``Zone Mean Air Temperature``, ...);
* ``ideal_loads`` -- the ``ZoneHVAC:IdealLoadsAirSystem``;
* ``inside_face`` -- any surface of the cell, the window included
  (EnergyPlus's ``Surface Inside Face ...`` variables);
* ``opaque_inside_face`` -- any opaque surface: EnergyPlus 25.2 does not
  report inside-face conduction or solar gain for windows;
* ``outside_face`` -- a sun-exposed outside face (the south wall, the window);
* ``window`` -- the window;
* ``site`` -- ``Environment``.

Keys compare without case, as EnergyPlus's do. Every value is the hour-ending
mean of the time-step values (EnergyPlus's hourly reporting). The boundary
walls the surrogate lumps into one (see :mod:`bpsflow.surrogate.cell`) each
report the lumped wall's values.

Signs follow EnergyPlus: inside-face heat flows are gains to the face, so
that convection + conduction + net thermal radiation + solar (+ radiant
internal gains, when the model has any) = 0 at every inside face (seed eq. 15).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from bpsflow.config import Config
from bpsflow.errors import BpsflowError
from bpsflow.surrogate.cell import Cell
from bpsflow.surrogate.forcing import (
    PeriodForcing,
    ground_reflected_irradiance,
    solar_inputs,
    surface_irradiance,
)
from bpsflow.surrogate.network import FaceProbe, Simulation, reported_power

Scope = Literal["zone", "ideal_loads", "inside_face", "opaque_inside_face", "outside_face",
                "window", "site"]

#: The key of EnergyPlus's site output variables.
SITE_KEY = "Environment"


@dataclass(frozen=True)
class Variable:
    """An EnergyPlus output variable the surrogate computes.

    ``quantity`` names the surrogate quantity within its ``scope`` (for the
    inside faces, one of :data:`bpsflow.surrogate.network.FACE_TERMS`).
    """

    name: str
    scope: Scope
    quantity: str
    unit: str


VARIABLES: tuple[Variable, ...] = (
    Variable("Zone Mean Air Temperature", "zone", "air", "C"),
    Variable("Zone Thermostat Air Temperature", "zone", "thermostat", "C"),
    Variable("Zone Ideal Loads Zone Sensible Heating Rate", "ideal_loads", "heating", "W"),
    Variable("Zone Ideal Loads Zone Sensible Cooling Rate", "ideal_loads", "cooling", "W"),
    Variable("Surface Inside Face Temperature", "inside_face", "temperature", "C"),
    Variable("Surface Inside Face Adjacent Air Temperature", "inside_face", "adjacent_air", "C"),
    Variable("Surface Inside Face Convection Heat Transfer Coefficient", "inside_face",
             "convection_coefficient", "W/m2-K"),
    Variable("Surface Inside Face Convection Heat Gain Rate per Area", "inside_face",
             "convection", "W/m2"),
    Variable("Surface Inside Face Conduction Heat Transfer Rate per Area", "opaque_inside_face",
             "conduction", "W/m2"),
    Variable("Surface Inside Face Net Surface Thermal Radiation Heat Gain Rate per Area",
             "inside_face", "radiation", "W/m2"),
    Variable("Surface Inside Face Solar Radiation Heat Gain Rate per Area", "opaque_inside_face",
             "solar", "W/m2"),
    Variable("Surface Inside Face Internal Gains Radiation Heat Gain Rate per Area",
             "inside_face", "internal_gains", "W/m2"),
    Variable("Surface Window Transmitted Solar Radiation Rate", "window", "transmitted", "W"),
    Variable("Surface Outside Face Incident Solar Radiation Rate per Area", "outside_face",
             "incident", "W/m2"),
    Variable("Surface Outside Face Incident Beam Solar Radiation Rate per Area", "outside_face",
             "beam", "W/m2"),
    Variable("Surface Outside Face Incident Sky Diffuse Solar Radiation Rate per Area",
             "outside_face", "sky_diffuse", "W/m2"),
    Variable("Surface Outside Face Incident Ground Diffuse Solar Radiation Rate per Area",
             "outside_face", "ground_diffuse", "W/m2"),
    Variable("Site Ground Reflected Solar Radiation Rate per Area", "site", "ground_reflected",
             "W/m2"),
    Variable("Site Direct Solar Radiation Rate per Area", "site", "direct", "W/m2"),
    Variable("Site Diffuse Solar Radiation Rate per Area", "site", "diffuse", "W/m2"),
    Variable("Site Solar Altitude Angle", "site", "solar_altitude", "deg"),
)

_BY_NAME = {v.name.upper(): v for v in VARIABLES}
#: Upper-case names of the supported variables.
SUPPORTED_OUTPUTS: tuple[str, ...] = tuple(_BY_NAME)

_SCOPE_WORDS = {
    "zone": "the zone",
    "ideal_loads": "the ZoneHVAC:IdealLoadsAirSystem",
    "inside_face": "a surface of the cell",
    "opaque_inside_face": "an opaque surface of the cell (EnergyPlus 25.2 does not report it "
                          "for windows)",
    "outside_face": "a sun-exposed outside face",
    "window": "the window",
    "site": f"'{SITE_KEY}'",
}


@dataclass(frozen=True)
class Request:
    """A config output resolved to a surrogate quantity.

    ``face`` is the face the key names (an opaque surface's index in
    ``cell.opaque``, or ``len(cell.opaque)`` for the window); ``None`` for
    zone, ideal-loads and site variables.
    """

    output: str
    variable: Variable
    face: int | None = None


def variable(name: str) -> Variable | None:
    """The supported variable called ``name`` (any case), or ``None``."""
    return _BY_NAME.get(name.strip().upper())


def check_variables(config: Config, outputs: list[str] | None = None) -> None:
    """Fail clearly on an output whose variable the surrogate does not compute.

    Raises
    ------
    BpsflowError
        Naming the output, its variable and the supported variables.
    """
    for name in outputs if outputs is not None else used_outputs(config):
        spec = config.outputs[name]
        if variable(spec.variable) is None:
            raise BpsflowError(
                f"outputs.{name}: the surrogate does not compute '{spec.variable}' (it has: "
                f"{', '.join(v.name for v in VARIABLES)})", source=config.source)


def used_outputs(config: Config) -> list[str]:
    """The outputs some test asks for, sorted."""
    return sorted({o for t in config.model.tests for o in t.outputs})


def keys_of(cell: Cell, scope: Scope) -> dict[str, int | None]:
    """The keys a variable of ``scope`` takes (as the model spells them) -> face index."""
    window = len(cell.opaque)
    if scope == "zone":
        return {cell.zone_name: None}
    if scope == "ideal_loads":
        return {cell.ideal_loads_name: None} if cell.ideal_loads_name else {}
    if scope == "site":
        return {SITE_KEY: None}
    if scope == "window":
        return {cell.window.name: window}
    keys: dict[str, int | None] = {}
    for i, surface in enumerate(cell.opaque):
        if scope != "outside_face" or surface.outdoor:
            keys.update({member: i for member in surface.members})
    if scope != "opaque_inside_face":
        keys[cell.window.name] = window
    return keys


def resolve_outputs(config: Config, cell: Cell, outputs: list[str] | None = None
                    ) -> dict[str, Request]:
    """Resolve config outputs (default: those the tests ask for) to surrogate quantities.

    Raises
    ------
    BpsflowError
        When the variable is not supported (naming the supported ones) or the
        key names nothing the variable applies to (naming the keys it takes).
    """
    outputs = outputs if outputs is not None else used_outputs(config)
    check_variables(config, outputs)
    requests = {}
    for name in outputs:
        spec = config.outputs[name]
        var = variable(spec.variable)
        keys = keys_of(cell, var.scope)
        by_upper = {k.upper(): face for k, face in keys.items()}
        if spec.key.strip().upper() not in by_upper:
            raise BpsflowError(
                f"outputs.{name}.key: '{spec.key}' is not a key of '{var.name}' in the "
                f"surrogate's model; it takes {_SCOPE_WORDS[var.scope]}: "
                f"{', '.join(sorted(keys)) or '(none in this model)'}", source=config.source)
        requests[name] = Request(output=name, variable=var, face=by_upper[spec.key.strip().upper()])
    return requests


def face_probe(requests: list[Request], hours: int, steps_per_hour: int) -> FaceProbe | None:
    """A probe recording the inside-face quantities ``requests`` ask for (``None``: none)."""
    wanted: dict[int, set[str]] = {}
    for request in requests:
        if request.variable.scope in ("inside_face", "opaque_inside_face"):
            wanted.setdefault(request.face, set()).add(request.variable.quantity)
    return FaceProbe(wanted, hours, steps_per_hour) if wanted else None


def hour_means(values: np.ndarray, n: int, steps_per_hour: int) -> np.ndarray:
    """Hour-ending means ``(n, hours)`` of per-step values ``(M, steps)`` or ``(steps,)``."""
    values = np.broadcast_to(values, (n, np.shape(values)[-1]))
    return values.reshape(n, -1, steps_per_hour).mean(axis=2)


def hourly_outputs(requests: list[Request], cell: Cell, forcing: PeriodForcing,
                   result: Simulation, probe: FaceProbe | None,
                   thermostat_offset: np.ndarray) -> dict[str, np.ndarray]:
    """Hourly values ``(n, hours)`` of each request over a simulated period, by output name.

    Parameters
    ----------
    requests : list of Request
        What to report (from :func:`resolve_outputs`).
    cell, forcing, result
        The cell, the period's boundary conditions and the simulation.
    probe : FaceProbe or None
        The probe the period ran with (:func:`face_probe` of ``requests``).
    thermostat_offset : ndarray
        Per-instance thermostat offset of the room air pattern (K).
    """
    n, tph = cell.n, forcing.steps_per_hour
    steps = slice(0, forcing.steps)
    cache: dict[tuple, object] = {}

    def once(key: tuple, compute):
        if key not in cache:
            cache[key] = compute()
        return cache[key]

    def air() -> np.ndarray:
        return once(("air",), lambda: hour_means(result.air, n, tph))

    def loads() -> tuple[np.ndarray, np.ndarray]:
        def compute():
            heating, cooling = reported_power(cell, result.power, result.air)
            return hour_means(heating, n, tph), hour_means(cooling, n, tph)
        return once(("loads",), compute)

    def ground() -> np.ndarray:
        return once(("ground",), lambda: ground_reflected_irradiance(cell, forcing, steps))

    def outside(face: int) -> tuple:
        surface = cell.window if face == len(cell.opaque) else cell.opaque[face]
        return once(("outside", face), lambda: surface_irradiance(
            cell, forcing, steps, surface.tilt, surface.azimuth, ground()))

    out = {}
    for request in requests:
        scope, quantity, face = (request.variable.scope, request.variable.quantity,
                                 request.face)
        if scope == "zone":
            value = air() if quantity == "air" else air() + thermostat_offset[:, None]
        elif scope == "ideal_loads":
            value = loads()[0 if quantity == "heating" else 1]
        elif scope in ("inside_face", "opaque_inside_face"):
            value = probe.values[(face, quantity)]
        elif scope == "window":
            value = hour_means(once(("transmitted",), lambda: solar_inputs(
                cell, forcing, steps)["transmitted"]), n, tph)
        elif scope == "outside_face":
            beam, sky, from_ground, _ = outside(face)
            parts = {"incident": beam + sky + from_ground, "beam": beam, "sky_diffuse": sky,
                     "ground_diffuse": from_ground}
            value = hour_means(parts[quantity], n, tph)
        else:
            per_step = {"direct": lambda: forcing.dni, "diffuse": lambda: forcing.dhi,
                        "ground_reflected": ground,
                        "solar_altitude": lambda: 90.0 - forcing.zenith}
            value = hour_means(per_step[quantity](), n, tph)
        out[request.output] = value
    return out
