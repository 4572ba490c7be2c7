"""The test cell as the surrogate sees it: surfaces, layers, glazing, air, controls.

Everything is read from the IDF (nominal values) through
:class:`~bpsflow.surrogate.params.FieldValues` (sampled values where a
parameter targets the field), so a config perturbs the surrogate through the
same object/field names as the EnergyPlus model. Per-instance quantities are
arrays of shape ``(n_instances,)``.

Boundary surfaces with the same construction, inside convection curve and
height (the east, west and north walls) are lumped into one surface whose
imposed outside temperature is their area-weighted boundary temperature:
conduction is linear, so the lumped wall carries the sum of their heat flows.
Each member reports the lumped wall's inside-face quantities.

Outdoor air flows (``ZoneVentilation:DesignFlowRate`` and
``ZoneInfiltration:DesignFlowRate``, method Flow/Zone) follow EnergyPlus's
design-flow-rate model (Engineering Reference, "Infiltration Design Flow
Rate" and "Ventilation Design Flow Rate"):

    flow = design x schedule x (A + B |T_zone - T_out| + C V + D V^2),  >= 0

with ``V`` the local wind speed at the height of the zone's centroid (the
Input Output Reference of ZoneInfiltration:DesignFlowRate: "the local outdoor
wind speed ... is a function of the height of the zone centroid"). An object
whose flow is constant (schedule always 1, ``B = C = D = 0`` in every
instance) is summed into ``Cell.ventilation_m3s``; the others are stepped as
:class:`AirExchange` objects. ``OtherEquipment`` (fuel type None, method
EquipmentLevel) is an :class:`InternalGain`: its convective part heats the air
node, its radiant part is absorbed by the inside faces in proportion to area
x thermal absorptance, as EnergyPlus distributes radiant internal gains.

``InternalMass`` is an opaque surface inside the zone (kind
``internal_mass``) exchanging with the air and the other inside faces like
the walls do. EnergyPlus makes an internal mass its own other side: the
outside face takes the inside face's temperature, so both faces of the slab
see the zone, and the inside face's heat flow is that of half the slab
with an adiabatic mid-plane. The surrogate builds that half (symmetric
constructions only) with an adiabatic back face; its area is per instance
(a parameter may target ``Surface Area``), and its inside convection is the
surface's UserCurve or a fixed ``Value`` from
``SurfaceProperty:ConvectionCoefficients``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bpsflow.config import Config
from bpsflow.errors import BpsflowError
from bpsflow.simulation.idf import (
    IdfObject,
    centroid_height,
    polygon_area,
    surface_user_curves,
)
from bpsflow.surrogate.params import FieldValues
from bpsflow.surrogate.schedules import Schedule, read_schedule
from bpsflow.surrogate.solar import GlazingTables, double_glazing

#: Wind profile exponent and boundary-layer thickness (m) per terrain class
#: (EnergyPlus Engineering Reference, "Local Wind Speed Calculation").
TERRAIN = {"COUNTRY": (0.14, 270.0), "SUBURBS": (0.22, 370.0), "CITY": (0.33, 460.0),
           "OCEAN": (0.10, 210.0), "URBAN": (0.33, 460.0)}
#: Weather-station wind measurement: exponent, boundary layer (m), height (m).
STATION = (0.14, 270.0, 10.0)
#: EnergyPlus bounds a surface's non-dimensional height in the zone to this
#: range before applying a room air temperature pattern (FigureNDheightInZone).
ZETA_BOUNDS = (0.01, 0.99)


@dataclass
class Curve:
    """``h = c1 + c2 * x ** c3`` (a linear curve has ``c3 = 1``)."""

    c1: np.ndarray
    c2: np.ndarray
    c3: np.ndarray
    x_min: float = 0.0
    x_max: float = 1e9

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Per-instance value at ``x`` of shape ``(n,)``."""
        return self.c1 + self.c2 * np.minimum(np.maximum(x, self.x_min), self.x_max) ** self.c3


@dataclass
class Layer:
    thickness: np.ndarray
    conductivity: np.ndarray
    density: np.ndarray
    specific_heat: np.ndarray
    elements: int


@dataclass
class Opaque:
    """An opaque surface (or a lumped group): layers outside -> inside."""

    name: str
    kind: str                      # wall | floor | ceiling | internal_mass
    area: float | np.ndarray       # m²; per instance (n,) for an internal mass
    layers: list[Layer]
    inside_curve: Curve
    dz: float                      # centroid height minus zone mid-height (m)
    emissivity_in: np.ndarray
    absorptance_in: np.ndarray
    outdoor: bool
    boundary_weights: dict[str, float] = field(default_factory=dict)
    members: list[str] = field(default_factory=list)   # IDF surfaces lumped into this one
    emissivity_out: np.ndarray | None = None
    absorptance_out: np.ndarray | None = None
    wind_factor: float = 0.0       # local / weather-file wind speed
    outside_wind: Curve | None = None
    outside_natural: Curve | None = None
    tilt: float = 90.0
    azimuth: float = 180.0
    #: No heat crosses the first layer's outer face (an internal mass's mid-plane).
    adiabatic: bool = False


@dataclass
class Window:
    name: str
    area: float
    tilt: float
    azimuth: float
    dz: float
    x_range: tuple[float, float]
    z_range: tuple[float, float]
    glazing: GlazingTables
    emissivity_out: np.ndarray     # outer pane, outside face
    emissivity_gap_out: np.ndarray  # outer pane, gap face
    emissivity_gap_in: np.ndarray   # inner pane, gap face
    emissivity_in: np.ndarray      # inner pane, room face
    pane_resistance: np.ndarray    # sum over both panes of half-thickness / k (m²K/W)
    gap_thickness: float
    inside_curve: Curve
    wind_factor: float
    outside_wind: Curve
    outside_natural: Curve


@dataclass
class AirExchange:
    """An outdoor air flow into the zone whose rate varies (see the module notes).

    Per-instance coefficients, shape ``(n,)``: design flow (m³/s), ``A`` (-),
    ``B`` (1/K), ``C`` (s/m), ``D`` (s²/m²).
    """

    object_type: str
    name: str
    design_m3s: np.ndarray
    constant: np.ndarray
    temperature: np.ndarray
    velocity: np.ndarray
    velocity_squared: np.ndarray
    schedule: Schedule
    #: Density converting volume to mass flow: ``outdoor`` air, or ``standard``
    #: (20 °C, 101325 Pa, dry).
    density_basis: str = "outdoor"


@dataclass
class InternalGain:
    """A scheduled internal gain (``OtherEquipment``): W = design level x schedule.

    ``design_w`` may be negative (a sink). ``fraction_convective`` (of the
    design level) heats the air node; ``fraction_radiant`` is absorbed by the
    inside faces (latent and lost fractions leave the sensible balance).
    """

    name: str
    design_w: np.ndarray
    fraction_radiant: np.ndarray
    fraction_convective: np.ndarray
    schedule: Schedule


@dataclass
class Cell:
    n: int
    volume: float
    height: float
    floor_x: tuple[float, float]
    floor_depth: float
    opaque: list[Opaque]
    window: Window
    ventilation_m3s: np.ndarray
    gradient: np.ndarray           # K/m
    return_offset: np.ndarray      # K
    heating_supply_c: float
    cooling_supply_c: float
    ground_reflectance: np.ndarray  # (n, 12)
    zone_name: str = ""            # the IDF zone (key of zone output variables)
    ideal_loads_name: str = ""     # the ZoneHVAC:IdealLoadsAirSystem (key of its variables)
    air_exchanges: list[AirExchange] = field(default_factory=list)
    internal_gains: list[InternalGain] = field(default_factory=list)
    #: Local wind speed at the zone centroid over the weather-file value.
    zone_wind_factor: float = 1.0

    def schedules(self) -> dict[str, Schedule]:
        """The schedules the time-varying objects read, by upper-case name."""
        used = [a.schedule for a in self.air_exchanges] + [g.schedule for g in self.internal_gains]
        return {s.name.upper(): s for s in used}


def _curve(values: FieldValues, name: str) -> Curve:
    idf = values.idf
    for kind in ("CURVE:EXPONENT", "CURVE:LINEAR"):
        if any(o.name.upper() == name.upper() for o in idf.of_type(kind)):
            obj = idf.find(kind, name)
            lo = obj.number("Minimum Value of x", 0.0)
            hi = obj.number("Maximum Value of x", 1e9)
            c1 = values.get(kind, name, "Coefficient1 Constant")
            if kind == "CURVE:LINEAR":
                return Curve(c1, values.get(kind, name, "Coefficient2 x"), np.ones(values.n),
                             lo, hi)
            return Curve(c1, values.get(kind, name, "Coefficient2 Constant"),
                         values.get(kind, name, "Coefficient3 Constant"), lo, hi)
    raise BpsflowError(f"curve '{name}' is neither a Curve:Exponent nor a Curve:Linear in the "
                       f"model; the surrogate reads only those", source=idf.path)


def _inside_curve(values: FieldValues, surface: str) -> tuple[str, Curve]:
    name, _ = surface_user_curves(values.idf, surface)
    if name is None:
        raise BpsflowError(f"surface '{surface}' has no inside UserCurve convection "
                           f"(SurfaceProperty:ConvectionCoefficients); the surrogate needs one",
                           source=values.idf.path)
    algorithm = values.idf.find("SurfaceConvectionAlgorithm:Inside:UserCurve", name)
    curve = algorithm.get("Hc Function of Temperature Difference Curve Name")
    return curve, _curve(values, curve)


def _outside_curves(values: FieldValues, surface: str) -> tuple[Curve, Curve, str]:
    _, name = surface_user_curves(values.idf, surface)
    if name is None:
        raise BpsflowError(f"exterior surface '{surface}' has no outside UserCurve convection; "
                           f"the surrogate needs one", source=values.idf.path)
    algorithm = values.idf.find("SurfaceConvectionAlgorithm:Outside:UserCurve", name)
    wind = _curve(values, algorithm.get("Hf Function of Wind Speed Curve Name"))
    natural = _curve(values, algorithm.get("Hn Function of Temperature Difference Curve Name"))
    return wind, natural, algorithm.get("Wind Speed Type for Curve").upper()


def _orientation(vertices) -> tuple[float, float]:
    """(tilt, azimuth) in degrees of the outward normal (counter-clockwise vertices)."""
    nx = ny = nz = 0.0
    for (x1, y1, z1), (x2, y2, z2) in zip(vertices, vertices[1:] + vertices[:1]):
        nx += (y1 - y2) * (z1 + z2)
        ny += (z1 - z2) * (x1 + x2)
        nz += (x1 - x2) * (y1 + y2)
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, nz / norm))))
    azimuth = math.degrees(math.atan2(nx, ny)) % 360.0
    return tilt, azimuth


def pattern_height(centroid_z: float, z_floor: float, height: float) -> float:
    """Height (m) above the zone's mid-height at which a room air pattern puts a surface.

    EnergyPlus's ``RoomAir:TemperaturePattern:ConstantGradient`` sets the air
    next to a surface to ``T_mean + gradient * (zeta - 0.5) * H`` with ``zeta``
    the surface centroid's height over the zone height ``H``, bounded to
    :data:`ZETA_BOUNDS` (so a floor sits at ``-0.49 H``, a ceiling at
    ``+0.49 H``, not at ``-/+ H/2``).

    Parameters
    ----------
    centroid_z : float
        Surface centroid height (m).
    z_floor : float
        Floor height of the zone (m).
    height : float
        Zone height (m).
    """
    zeta = min(max((centroid_z - z_floor) / height, ZETA_BOUNDS[0]), ZETA_BOUNDS[1])
    return (zeta - 0.5) * height


def wind_factor(height: float, terrain: str, speed_type: str) -> float:
    """Local wind speed over the weather-file value at a surface's height."""
    if speed_type not in ("HEIGHTADJUST", ""):
        return 1.0
    alpha, delta = TERRAIN.get(terrain.upper(), TERRAIN["SUBURBS"])
    a_met, d_met, z_met = STATION
    return (d_met / z_met) ** a_met * (max(height, 0.0) / delta) ** alpha


def _elements(layer_props: tuple[float, float, float, float]) -> int:
    """Finite elements for a layer: about one per half-hour penetration depth, 1..4."""
    thickness, k, rho, cp = layer_props
    depth = math.sqrt(k / (rho * cp) * 1800.0)
    return int(min(4, max(1, math.ceil(thickness / depth))))


def _layers(values: FieldValues, construction: IdfObject) -> list[Layer]:
    layers = []
    names = [v for v in construction.fields[1:] if v.strip()]
    for name in names:
        materials = [o for o in values.idf.of_type("MATERIAL") if o.name.upper() == name.upper()]
        if not materials:
            raise BpsflowError(f"construction '{construction.name}': layer '{name}' is not a "
                               f"Material (the surrogate reads only Material layers for opaque "
                               f"surfaces)", source=values.idf.path)
        nominal = tuple(materials[0].number(f) for f in
                        ("Thickness", "Conductivity", "Density", "Specific Heat"))
        layers.append(Layer(
            thickness=values.get("MATERIAL", name, "Thickness"),
            conductivity=values.get("MATERIAL", name, "Conductivity"),
            density=values.get("MATERIAL", name, "Density"),
            specific_heat=values.get("MATERIAL", name, "Specific Heat"),
            elements=_elements(nominal)))
    return layers


def build_cell(config: Config, values: FieldValues) -> Cell:
    """Read the single-zone cell from the IDF with the sampled field values applied."""
    idf = values.idf
    n = values.n
    surfaces = idf.of_type("BUILDINGSURFACE:DETAILED")
    zones = {s.get("Zone Name").upper() for s in surfaces}
    if len(zones) != 1:
        raise BpsflowError(f"the surrogate models a single zone; the IDF has surfaces in "
                           f"{sorted(zones)}", source=idf.path)
    windows = idf.of_type("FENESTRATIONSURFACE:DETAILED")
    if len(windows) != 1:
        raise BpsflowError(f"the surrogate models one window; the IDF has {len(windows)}",
                           source=idf.path)
    all_z = [v[2] for s in surfaces for v in s.vertices()]
    z_floor, z_top = min(all_z), max(all_z)
    height = z_top - z_floor
    floor_obj = [s for s in surfaces if s.get("Surface Type").upper() == "FLOOR"]
    floor_vertices = floor_obj[0].vertices() if floor_obj else surfaces[0].vertices()
    floor_area = sum(polygon_area(s.vertices()) for s in floor_obj)
    volume = floor_area * height
    xs = [v[0] for v in floor_vertices]
    ys = [v[1] for v in floor_vertices]
    terrain = idf.one("BUILDING").get("Terrain") or "Suburbs"

    window_obj = windows[0]
    window_area = polygon_area(window_obj.vertices())
    host = window_obj.get("Building Surface Name").upper()

    boundary = config.model.boundary
    schedule_to_surface = {spec.schedule.upper(): key
                           for key, spec in (boundary.surfaces.items() if boundary else [])}

    groups: dict[tuple, Opaque] = {}
    for surface in surfaces:
        name = surface.name
        vertices = surface.vertices()
        area = polygon_area(vertices) - (window_area if name.upper() == host else 0.0)
        kind = surface.get("Surface Type").lower()
        kind = "ceiling" if kind in ("ceiling", "roof") else kind
        construction = idf.find("CONSTRUCTION", surface.get("Construction Name"))
        layers = _layers(values, construction)
        inner = [v for v in construction.fields[1:] if v.strip()][-1]
        outer = construction.fields[1]
        curve_name, inside = _inside_curve(values, name)
        dz = pattern_height(centroid_height(vertices), z_floor, height)
        condition = surface.get("Outside Boundary Condition").upper()
        tilt, azimuth = _orientation(vertices)
        if condition == "OUTDOORS":
            wind, natural, speed_type = _outside_curves(values, name)
            groups[("outdoor", name.upper())] = Opaque(
                name=name, kind=kind, area=area, layers=layers, inside_curve=inside, dz=dz,
                emissivity_in=values.get("MATERIAL", inner, "Thermal Absorptance"),
                absorptance_in=values.get("MATERIAL", inner, "Solar Absorptance"),
                outdoor=True, members=[name],
                emissivity_out=values.get("MATERIAL", outer, "Thermal Absorptance"),
                absorptance_out=values.get("MATERIAL", outer, "Solar Absorptance"),
                wind_factor=wind_factor(centroid_height(vertices), terrain, speed_type),
                outside_wind=wind, outside_natural=natural, tilt=tilt, azimuth=azimuth)
            continue
        if condition != "OTHERSIDECOEFFICIENTS":
            raise BpsflowError(f"surface '{name}': outside boundary '{condition}' is not "
                               f"supported by the surrogate (Outdoors or OtherSideCoefficients)",
                               source=idf.path)
        osc = idf.find("SURFACEPROPERTY:OTHERSIDECOEFFICIENTS",
                       surface.get("Outside Boundary Condition Object"))
        schedule = osc.get("Constant Temperature Schedule Name").upper()
        if schedule not in schedule_to_surface:
            raise BpsflowError(f"surface '{name}' takes its outside temperature from schedule "
                               f"'{schedule}', which is not one of model.boundary.surfaces",
                               source=config.source)
        key = ("boundary", construction.name.upper(), curve_name.upper(), round(dz, 3), kind)
        group = groups.get(key)
        if group is None:
            group = groups[key] = Opaque(
                name=name, kind=kind, area=0.0, layers=layers, inside_curve=inside, dz=dz,
                emissivity_in=values.get("MATERIAL", inner, "Thermal Absorptance"),
                absorptance_in=values.get("MATERIAL", inner, "Solar Absorptance"),
                outdoor=False, tilt=tilt, azimuth=azimuth)
        else:
            group.name += "+" + name
        group.members.append(name)
        group.area += area
        surface_key = schedule_to_surface[schedule]
        group.boundary_weights[surface_key] = group.boundary_weights.get(surface_key, 0.0) + area
    for group in groups.values():
        total = sum(group.boundary_weights.values())
        group.boundary_weights = {k: v / total for k, v in group.boundary_weights.items()}

    masses = _internal_masses(values, surfaces[0].get("Zone Name"))
    window = _window(values, window_obj, window_area, z_floor, height, terrain)
    gradient_obj = idf.of_type("ROOMAIR:TEMPERATUREPATTERN:CONSTANTGRADIENT")
    pattern = gradient_obj[0].name if gradient_obj else None
    zone_name = surfaces[0].get("Zone Name")
    ventilation, exchanges = _air_exchanges(values, zone_name)
    gains = _internal_gains(values, zone_name)
    ideal = idf.of_type("ZONEHVAC:IDEALLOADSAIRSYSTEM")
    heating_supply, cooling_supply = 50.0, 13.0
    if ideal:
        heating_supply = ideal[0].number("Maximum Heating Supply Air Temperature", 50.0)
        cooling_supply = ideal[0].number("Minimum Cooling Supply Air Temperature", 13.0)
    months = ("January", "February", "March", "April", "May", "June", "July", "August",
              "September", "October", "November", "December")
    if idf.of_type("SITE:GROUNDREFLECTANCE"):
        ground = np.stack([values.get("SITE:GROUNDREFLECTANCE", "", f"{m} Ground Reflectance",
                                      0.2) for m in months], axis=1)
    else:
        ground = np.full((n, 12), 0.2)
    gt = "ROOMAIR:TEMPERATUREPATTERN:CONSTANTGRADIENT"
    return Cell(
        n=n, volume=volume, height=height, floor_x=(min(xs), max(xs)),
        floor_depth=max(ys) - min(ys), opaque=[*groups.values(), *masses], window=window,
        ventilation_m3s=ventilation,
        gradient=values.get(gt, pattern, "Temperature Gradient") if pattern else np.zeros(n),
        return_offset=values.get(gt, pattern, "Return Air Offset") if pattern else np.zeros(n),
        heating_supply_c=heating_supply, cooling_supply_c=cooling_supply,
        ground_reflectance=ground, zone_name=zone_name,
        ideal_loads_name=ideal[0].name if ideal else "",
        air_exchanges=exchanges, internal_gains=gains,
        zone_wind_factor=wind_factor(zone_centroid_height(surfaces), terrain, "HEIGHTADJUST"))


def zone_centroid_height(surfaces: list[IdfObject]) -> float:
    """Height (m) of the zone centroid as EnergyPlus computes it.

    The gross-area-weighted mean of the centroids of the zone's walls, roofs
    and ceilings and floors (EnergyPlus's ``Zone.Centroid``, which sets the
    local wind speed and outdoor temperature of the zone's air flows).
    """
    weighted = total = 0.0
    for surface in surfaces:
        if surface.get("Surface Type").upper() in ("WALL", "ROOF", "CEILING", "FLOOR"):
            vertices = surface.vertices()
            area = polygon_area(vertices)
            weighted += centroid_height(vertices) * area
            total += area
    return weighted / total


def _where(obj: IdfObject) -> str:
    return f"{obj.where} (in {obj.source})" if obj.source else obj.where


def _check_zone(obj: IdfObject, field_name: str, zone_name: str) -> None:
    zone = obj.get(field_name)
    if zone.upper() != zone_name.upper():
        raise BpsflowError(f"{_where(obj)}: field '{field_name}' is '{zone}'; the surrogate "
                           f"models one zone, '{zone_name}' (no zone lists or spaces)")


def _choice(obj: IdfObject, field_name: str, default: str, allowed: tuple[str, ...]) -> str:
    value = obj.get(field_name).strip() or default
    if value.upper() not in {a.upper() for a in allowed}:
        raise BpsflowError(f"{_where(obj)}: field '{field_name}' is '{value}'; the surrogate "
                           f"supports {' or '.join(allowed)}")
    return value.upper()


#: Standard air density (kg/m³): 20 °C, 101325 Pa, dry (EnergyPlus's StdRhoAir).
STANDARD_AIR_DENSITY = 101325.0 / (287.042 * 293.15)


def _air_exchanges(values: FieldValues, zone_name: str) -> tuple[np.ndarray, list[AirExchange]]:
    """Constant outdoor air flow (m³/s, ``(n,)``) and the time-varying air exchanges."""
    idf, n = values.idf, values.n
    constant_flow = np.zeros(n)
    exchanges = []
    for object_type in ("ZONEVENTILATION:DESIGNFLOWRATE", "ZONEINFILTRATION:DESIGNFLOWRATE"):
        for obj in idf.of_type(object_type):
            _check_zone(obj, "Zone or ZoneList or Space or SpaceList Name", zone_name)
            _choice(obj, "Design Flow Rate Calculation Method", "Flow/Zone", ("Flow/Zone",))
            basis = "OUTDOOR"
            if object_type == "ZONEVENTILATION:DESIGNFLOWRATE":
                _refuse_ventilation_limits(obj)
            if object_type == "ZONEINFILTRATION:DESIGNFLOWRATE":
                basis = _choice(obj, "Density Basis", "Outdoor", ("Outdoor", "Standard"))
            get = lambda f, d, kind=object_type, name=obj.name: values.get(kind, name, f, d)  # noqa: E731
            design = get("Design Flow Rate", None)
            a = get("Constant Term Coefficient", 1.0)
            b = get("Temperature Term Coefficient", 0.0)
            c = get("Velocity Term Coefficient", 0.0)
            d = get("Velocity Squared Term Coefficient", 0.0)
            schedule = read_schedule(idf, obj.get("Schedule Name"), _where(obj))
            if schedule.is_always_one and basis == "OUTDOOR" and not (b.any() or c.any()
                                                                      or d.any()):
                constant_flow = constant_flow + np.maximum(design * a, 0.0)
                continue
            exchanges.append(AirExchange(
                object_type=obj.spelling, name=obj.name, design_m3s=design, constant=a,
                temperature=b, velocity=c, velocity_squared=d, schedule=schedule,
                density_basis=basis.lower()))
    return constant_flow, exchanges


#: ZoneVentilation:DesignFlowRate's on/off limits and the values that leave them open.
_VENTILATION_LIMITS = {"Minimum Indoor Temperature": -100.0, "Maximum Indoor Temperature": 100.0,
                       "Delta Temperature": -100.0, "Minimum Outdoor Temperature": -100.0,
                       "Maximum Outdoor Temperature": 100.0, "Maximum Wind Speed": 40.0}


def _refuse_ventilation_limits(obj: IdfObject) -> None:
    """The surrogate ventilates whenever the schedule says: a temperature or wind limit that
    would shut the flow off (ventilation only above 40 °C outdoors) would be ignored."""
    for name, open_value in _VENTILATION_LIMITS.items():
        text = obj.get(name).strip()
        schedule = obj.get(f"{name} Schedule Name").strip() if name != "Maximum Wind Speed" \
            else ""
        try:
            limited = bool(text) and float(text) != open_value
        except ValueError:
            limited = True
        if limited or schedule:
            raise BpsflowError(f"{_where(obj)}: field '{name}{' Schedule Name' if schedule else ''}'"
                               f" is '{schedule or text}'; the surrogate ventilates whenever the "
                               f"schedule is on and has no temperature or wind limits (leave "
                               f"them blank, or use EnergyPlus)")


def _internal_gains(values: FieldValues, zone_name: str) -> list[InternalGain]:
    gains = []
    for obj in values.idf.of_type("OTHEREQUIPMENT"):
        _check_zone(obj, "Zone or ZoneList or Space or SpaceList Name", zone_name)
        _choice(obj, "Fuel Type", "None", ("None",))
        _choice(obj, "Design Level Calculation Method", "EquipmentLevel", ("EquipmentLevel",))
        get = lambda f, d, name=obj.name: values.get("OTHEREQUIPMENT", name, f, d)  # noqa: E731
        latent, radiant, lost = (get("Fraction Latent", 0.0), get("Fraction Radiant", 0.0),
                                 get("Fraction Lost", 0.0))
        if np.any(latent + radiant + lost > 1.0 + 1e-9) or np.any(
                np.minimum(np.minimum(latent, radiant), lost) < 0):
            raise BpsflowError(f"{_where(obj)}: fractions latent, radiant and lost must be "
                               f"in 0..1 and sum to at most 1")
        gains.append(InternalGain(
            name=obj.name, design_w=get("Design Level", None), fraction_radiant=radiant,
            fraction_convective=1.0 - latent - radiant - lost,
            schedule=read_schedule(values.idf, obj.get("Schedule Name"), _where(obj))))
    return gains


def _fixed_inside_coefficient(values: FieldValues, surface: str) -> np.ndarray | None:
    """A surface's fixed inside convection coefficient (W/m²K, ``(n,)``), or None.

    Read from its ``SurfaceProperty:ConvectionCoefficients`` entry of
    location Inside and type Value.
    """
    kind = "SURFACEPROPERTY:CONVECTIONCOEFFICIENTS"
    for obj in values.idf.of_type(kind):
        if obj.get("Surface Name").upper() != surface.upper():
            continue
        for k in (1, 2):
            if obj.get(f"Convection Coefficient {k} Location").upper() == "INSIDE" and \
                    obj.get(f"Convection Coefficient {k} Type").upper() == "VALUE":
                return np.full(values.n, obj.number(f"Convection Coefficient {k}"))
    return None


def _half_layers(values: FieldValues, construction: IdfObject, where: str) -> list[Layer]:
    """The inside half of a symmetric construction, mid-plane first (outside -> inside).

    An odd middle layer is halved (thickness and, from the nominal
    thickness, its finite elements).
    """
    names = [v.strip().upper() for v in construction.fields[1:] if v.strip()]
    if names != names[::-1]:
        raise BpsflowError(f"{where}: construction '{construction.name}' is not symmetric "
                           f"({', '.join(names)}); the surrogate models an InternalMass as two "
                           f"faces seeing the zone, which needs the same layers read from "
                           f"either side", source=values.idf.path)
    layers = _layers(values, construction)
    half = layers[len(layers) // 2:]
    if len(layers) % 2:
        middle = half[0]
        material = values.idf.find("MATERIAL", names[len(names) // 2])
        nominal = (material.number("Thickness") / 2, material.number("Conductivity"),
                   material.number("Density"), material.number("Specific Heat"))
        half[0] = Layer(thickness=middle.thickness / 2, conductivity=middle.conductivity,
                        density=middle.density, specific_heat=middle.specific_heat,
                        elements=_elements(nominal))
    return half


def _internal_masses(values: FieldValues, zone_name: str) -> list[Opaque]:
    """The zone's ``InternalMass`` objects as adiabatic-backed opaque surfaces."""
    out = []
    for obj in values.idf.of_type("INTERNALMASS"):
        where = _where(obj)
        _check_zone(obj, "Zone or ZoneList Name", zone_name)
        if obj.get("Space or SpaceList Name").strip():
            raise BpsflowError(f"{where}: field 'Space or SpaceList Name' is set; the surrogate "
                               f"models one zone and no spaces")
        construction = values.idf.find("CONSTRUCTION", obj.get("Construction Name"))
        layers = _half_layers(values, construction, where)
        inner = [v for v in construction.fields[1:] if v.strip()][-1]
        area = values.get("INTERNALMASS", obj.name, "Surface Area")
        if np.any(area <= 0):
            raise BpsflowError(f"{where}: Surface Area must be > 0 m² (EnergyPlus refuses 0); "
                               f"found {float(area.min()):g}")
        fixed = _fixed_inside_coefficient(values, obj.name)
        if fixed is not None:
            inside = Curve(fixed, np.zeros(values.n), np.ones(values.n))
        else:
            inside = _inside_curve(values, obj.name)[1]
        # An internal mass has no vertices, so no height in the zone: it sees the
        # mean air temperature (dz = 0). Against EnergyPlus (test cell, 100 m2,
        # 4 November days) this matches its hourly response better than the
        # floor-level air (rms ratio surrogate/EnergyPlus 1.06 against 1.22).
        out.append(Opaque(
            name=obj.name, kind="internal_mass", area=area, layers=layers,
            inside_curve=inside, dz=0.0,
            emissivity_in=values.get("MATERIAL", inner, "Thermal Absorptance"),
            absorptance_in=values.get("MATERIAL", inner, "Solar Absorptance"),
            outdoor=False, members=[obj.name], adiabatic=True))
    return out


def _window(values: FieldValues, obj: IdfObject, area: float, z_floor: float, height: float,
            terrain: str) -> Window:
    idf = values.idf
    construction = idf.find("CONSTRUCTION", obj.get("Construction Name"))
    layers = [v for v in construction.fields[1:] if v.strip()]
    glass = [n for n in layers if any(o.name.upper() == n.upper()
                                      for o in idf.of_type("WINDOWMATERIAL:GLAZING"))]
    gases = [n for n in layers if any(o.name.upper() == n.upper()
                                      for o in idf.of_type("WINDOWMATERIAL:GAS"))]
    if len(glass) != 2 or len(gases) != 1 or len(layers) != 3:
        raise BpsflowError(f"window construction '{construction.name}': the surrogate models "
                           f"double glazing (glass / gas / glass)", source=idf.path)
    gas = idf.find("WINDOWMATERIAL:GAS", gases[0])
    if gas.get("Gas Type").upper() != "AIR":
        raise BpsflowError(f"gas layer '{gas.name}': only Air is modelled", source=idf.path)
    g = "WINDOWMATERIAL:GLAZING"
    outer, inner = glass
    get = lambda pane, f: values.get(g, pane, f)  # noqa: E731
    # Both panes may be the same material: properties per pane, dirt only on the outer one.
    tables = _glazing(get, outer, inner)
    vertices = obj.vertices()
    tilt, azimuth = _orientation(vertices)
    wind, natural, speed_type = _outside_curves(values, obj.name)
    _, inside = _inside_curve(values, obj.name)
    resistance = (get(outer, "Thickness") / get(outer, "Conductivity")
                  + get(inner, "Thickness") / get(inner, "Conductivity")) / 2
    return Window(
        name=obj.name, area=area, tilt=tilt, azimuth=azimuth,
        dz=pattern_height(centroid_height(vertices), z_floor, height),
        x_range=(min(v[0] for v in vertices), max(v[0] for v in vertices)),
        z_range=(min(v[2] for v in vertices) - z_floor, max(v[2] for v in vertices) - z_floor),
        glazing=tables,
        emissivity_out=get(outer, "Front Side Infrared Hemispherical Emissivity"),
        emissivity_gap_out=get(outer, "Back Side Infrared Hemispherical Emissivity"),
        emissivity_gap_in=get(inner, "Front Side Infrared Hemispherical Emissivity"),
        emissivity_in=get(inner, "Back Side Infrared Hemispherical Emissivity"),
        pane_resistance=resistance, gap_thickness=gas.number("Thickness"),
        inside_curve=inside,
        wind_factor=wind_factor(centroid_height(vertices), terrain, speed_type),
        outside_wind=wind, outside_natural=natural)


def _glazing(get, outer: str, inner: str) -> GlazingTables:
    # Two different glasses would be represented by their mean optical properties;
    # the shipped model uses one glass for both panes.
    tau_o = get(outer, "Solar Transmittance at Normal Incidence")
    tau_i = get(inner, "Solar Transmittance at Normal Incidence")
    dirt = get(outer, "Dirt Correction Factor for Solar and Visible Transmittance")
    rho_f = 0.5 * (get(outer, "Front Side Solar Reflectance at Normal Incidence")
                   + get(inner, "Front Side Solar Reflectance at Normal Incidence"))
    rho_b = 0.5 * (get(outer, "Back Side Solar Reflectance at Normal Incidence")
                   + get(inner, "Back Side Solar Reflectance at Normal Incidence"))
    return double_glazing(0.5 * (tau_o + tau_i), rho_f, rho_b, dirt)
