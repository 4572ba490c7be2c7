"""What the surrogate can represent, stated up front.

The bundled surrogate is a reduced-order model of a single zone with one
window, opaque surfaces to the outdoors or at imposed boundary temperatures,
scheduled air flows and internal gains, and an ideal air system. A model
with anything else (more zones, people and lights objects, real HVAC,
ground contact, other constructions) is not silently simplified:
:func:`unsupported_features` lists every such feature, so ``backend: auto``
can say that the model needs EnergyPlus before anything runs.
"""

from __future__ import annotations

from collections import Counter
from typing import TYPE_CHECKING

from bpsflow.errors import BpsflowError
from bpsflow.simulation.idf import FIELDS, model_objects
from bpsflow.simulation.model_inputs import check_boundary_schedules
from bpsflow.simulation.target_bounds import check_target_fields

if TYPE_CHECKING:
    from bpsflow.config import Config

#: Object types the surrogate reads (its field table) or that do not change its physics.
_KNOWN = set(FIELDS) | {
    "VERSION", "SIMULATIONCONTROL", "TIMESTEP", "GLOBALGEOMETRYRULES", "RUNPERIOD",
    "RUNPERIODCONTROL:DAYLIGHTSAVINGTIME", "RUNPERIODCONTROL:SPECIALDAYS", "SITE:LOCATION",
    "SCHEDULETYPELIMITS", "SCHEDULE:COMPACT", "ZONE", "ROOMAIRMODELTYPE",
    "ROOMAIR:TEMPERATUREPATTERN:USERDEFINED", "ZONEHVAC:EQUIPMENTCONNECTIONS",
    "ZONEHVAC:EQUIPMENTLIST", "ZONECONTROL:THERMOSTAT", "THERMOSTATSETPOINT:DUALSETPOINT",
    "THERMOSTATSETPOINT:SINGLEHEATING", "THERMOSTATSETPOINT:SINGLECOOLING",
    "THERMOSTATSETPOINT:SINGLEHEATINGORCOOLING", "HEATBALANCEALGORITHM",
    "SURFACECONVECTIONALGORITHM:INSIDE", "SURFACECONVECTIONALGORITHM:OUTSIDE",
    "ZONEAIRHEATBALANCEALGORITHM", "NODELIST", "SIZINGPERIOD:DESIGNDAY",
    "SIZINGPERIOD:WEATHERFILEDAYS", "SIZINGPERIOD:WEATHERFILECONDITIONTYPE",
    "CONVERGENCELIMITS", "ZONECAPACITANCEMULTIPLIER:RESEARCHSPECIAL",
}
_IGNORED_PREFIXES = ("OUTPUT", "METER:")


#: Object types named in the "no physics for" phrase; the rest are counted.
_LISTED_TYPES = 12


def unsupported_features(config: Config) -> list[str]:
    """Every feature of ``config``'s model and outputs the surrogate cannot represent.

    Returns
    -------
    list of str
        One phrase per feature (empty when the surrogate can run the model).
    """
    idf = model_objects(config.model)
    # A target EnergyPlus has no field for is the config's mistake, whatever the backend;
    # so is a boundary surface on a schedule the model lacks.
    check_target_fields(config)
    check_boundary_schedules(config)
    lacking: list[str] = []
    zones = [o.name for o in idf.of_type("ZONE")]
    if len(zones) != 1:
        lacking.append(f"it models a single zone, the model has {len(zones)} "
                       f"({', '.join(zones[:6])}{', ...' if len(zones) > 6 else ''})")
    windows = idf.of_type("FENESTRATIONSURFACE:DETAILED")
    if len(windows) != 1:
        lacking.append(f"it models exactly one FenestrationSurface:Detailed window, the model "
                       f"has {len(windows)}")
    conditions = Counter(s.get("Outside Boundary Condition").strip().upper()
                         for s in idf.of_type("BUILDINGSURFACE:DETAILED"))
    other = {c: n for c, n in conditions.items() if c not in ("OUTDOORS", "OTHERSIDECOEFFICIENTS")}
    if other:
        lacking.append("surfaces with outside boundary " + ", ".join(
            f"{c.title()} ({n})" for c, n in sorted(other.items()))
            + " (it has Outdoors and OtherSideCoefficients only)")
    types = Counter(o.spelling or o.type for o in idf.objects
                    if o.type not in _KNOWN and not o.type.startswith(_IGNORED_PREFIXES))
    if types:
        # the kinds most objects belong to first; a long tail is counted, not listed
        ranked = sorted(types.items(), key=lambda item: (-item[1], item[0]))
        shown = ", ".join(f"{kind} ({n})" for kind, n in ranked[:_LISTED_TYPES])
        rest = ranked[_LISTED_TYPES:]
        lacking.append("no physics for " + shown + (
            f" and {len(rest)} more object types ({sum(n for _, n in rest)} objects)"
            if rest else ""))
    lacking += _output_features(config)
    own = [t.name for t in config.model.tests if t.mode == "model"]
    if own:
        lacking.append(f"tests {', '.join(own)} run the model's own controls (mode model); "
                       f"it runs the tests' setpoints only")
    if not lacking:
        # The structure is one it knows: building it finds what the scan cannot see
        # (a construction layer it does not read, a missing convection curve, ...).
        from bpsflow.surrogate.run import ignored_targets

        try:
            ignored_targets(config)
        except BpsflowError as exc:
            lacking.append(str(exc))
    return lacking


def _output_features(config: Config) -> list[str]:
    from bpsflow.surrogate.outputs import VARIABLES, used_outputs, variable

    lacking = []
    for name in used_outputs(config):
        spec = config.outputs[name]
        if spec.meter is not None:
            lacking.append(f"outputs.{name}: meters ({spec.meter}) are EnergyPlus's")
        elif variable(str(spec.variable)) is None:
            lacking.append(f"outputs.{name}: it does not compute '{spec.variable}' (it has: "
                           f"{', '.join(v.name for v in VARIABLES)})")
        if spec.frequency != "hourly":
            lacking.append(f"outputs.{name}: it reports hourly values only, not "
                           f"{spec.frequency}")
    return lacking
