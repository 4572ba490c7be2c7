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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bpsflow.config import Config
from bpsflow.errors import BpsflowError
from bpsflow.surrogate.idf import IdfModel, IdfObject, centroid_height, polygon_area
from bpsflow.surrogate.params import FieldValues
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
        return self.c1 + self.c2 * np.clip(x, self.x_min, self.x_max) ** self.c3


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
    kind: str                      # wall | floor | ceiling
    area: float
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


def _convection(idf: IdfModel, surface: str) -> tuple[str | None, str | None]:
    """(inside user-curve name, outside user-curve name) assigned to a surface."""
    inside = outside = None
    for obj in idf.of_type("SURFACEPROPERTY:CONVECTIONCOEFFICIENTS"):
        if obj.get("Surface Name").upper() != surface.upper():
            continue
        for k in (1, 2):
            where = obj.get(f"Convection Coefficient {k} Location").upper()
            kind = obj.get(f"Convection Coefficient {k} Type").upper()
            curve = obj.get(f"Convection Coefficient {k} User Curve Name")
            if kind != "USERCURVE" or not curve:
                continue
            if where == "INSIDE":
                inside = curve
            elif where == "OUTSIDE":
                outside = curve
    return inside, outside


def _inside_curve(values: FieldValues, surface: str) -> tuple[str, Curve]:
    name, _ = _convection(values.idf, surface)
    if name is None:
        raise BpsflowError(f"surface '{surface}' has no inside UserCurve convection "
                           f"(SurfaceProperty:ConvectionCoefficients); the surrogate needs one",
                           source=values.idf.path)
    algorithm = values.idf.find("SurfaceConvectionAlgorithm:Inside:UserCurve", name)
    curve = algorithm.get("Hc Function of Temperature Difference Curve Name")
    return curve, _curve(values, curve)


def _outside_curves(values: FieldValues, surface: str) -> tuple[Curve, Curve, str]:
    _, name = _convection(values.idf, surface)
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

    window = _window(values, window_obj, window_area, z_floor, height, terrain)
    gradient_obj = idf.of_type("ROOMAIR:TEMPERATUREPATTERN:CONSTANTGRADIENT")
    pattern = gradient_obj[0].name if gradient_obj else None
    vent = idf.of_type("ZONEVENTILATION:DESIGNFLOWRATE")
    ventilation = np.zeros(n)
    for obj in vent:
        method = obj.get("Design Flow Rate Calculation Method").upper()
        if method != "FLOW/ZONE":
            raise BpsflowError(f"ZoneVentilation:DesignFlowRate '{obj.name}': method {method} "
                               f"not supported by the surrogate (Flow/Zone)", source=idf.path)
        ventilation = ventilation + values.get(vent[0].type, obj.name, "Design Flow Rate") \
            * values.get(vent[0].type, obj.name, "Constant Term Coefficient")
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
        floor_depth=max(ys) - min(ys), opaque=list(groups.values()), window=window,
        ventilation_m3s=ventilation,
        gradient=values.get(gt, pattern, "Temperature Gradient") if pattern else np.zeros(n),
        return_offset=values.get(gt, pattern, "Return Air Offset") if pattern else np.zeros(n),
        heating_supply_c=heating_supply, cooling_supply_c=cooling_supply,
        ground_reflectance=ground, zone_name=surfaces[0].get("Zone Name"),
        ideal_loads_name=ideal[0].name if ideal else "")


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
