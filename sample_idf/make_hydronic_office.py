"""Write the hydronic office floor models (seed §4.1-4.2) for EnergyPlus 25.2.

Two models of one office floor heated by radiators on a varying-temperature
hot-water loop:

* ``hydronic_office.idf`` -- the prototype-room model (the source's M2): one
  zone per room type; the cellular office stands for its 16 identical rooms
  through a zone multiplier.
* ``hydronic_office_baseline.idf`` -- the "real" floor behind the synthetic
  field data (the source's baseline): every cellular office modelled as its
  own zone, coupled to its neighbours and the corridor through real
  partitions, with per-room usage (people, lights, plug loads, window
  opening area) varied by a normal factor of standard deviation 5 % and
  per-room thermostat setpoints spread by a normal offset of 0.5 °C.

Objects the configs target carry the same names in both (the baseline's per-room
objects add a room number: ``Cellular Office 07 Lights``), so one config drives
either. Run ``python sample_idf/make_hydronic_office.py`` to rewrite both files;
the draw of the baseline's room variations is seeded and so reproducible.
See ``sample_idf/README.md`` for the floor plan and what each object stands for.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent

HEIGHT_M = 3.0
SOUTH_DEPTH_M = 4.5
CORRIDOR_DEPTH_M = 2.0
NORTH_DEPTH_M = 4.5
OFFICE_WIDTH_M = 3.0
OFFICES = 16
FLOOR_LENGTH_M = OFFICE_WIDTH_M * OFFICES
MEETING_WIDTH_M = 9.0
CORRIDOR_Y0 = SOUTH_DEPTH_M
NORTH_Y0 = SOUTH_DEPTH_M + CORRIDOR_DEPTH_M

#: Rated radiator output per zone (W) at the rated mean water temperature; per
#: cellular office for the prototype. Generous, as radiators sized for a hotter loop are:
#: the margin is what a lower supply temperature spends.
RADIATOR_CAPACITY_W = {"Cellular Office": 1500.0, "Meeting Room": 4000.0,
                       "Open Office": 13000.0, "Stair Corridor": 1500.0}
RATED_MEAN_WATER_C = 70.0
RATED_WATER_DELTA_K = 20.0
WATER_CP = 4180.0

#: Design levels per room type: people per m², lighting and plug loads in W/m².
PEOPLE_PER_M2 = {"Cellular Office": 0.074, "Meeting Room": 0.4, "Open Office": 0.1}
LIGHTS_W_M2 = {"Cellular Office": 8.0, "Meeting Room": 8.0, "Open Office": 8.0,
               "Stair Corridor": 5.0}
PLUG_W_M2 = {"Cellular Office": 8.0, "Meeting Room": 3.0, "Open Office": 8.0}
#: Occupied-hours and off-hours fractions of the occupancy schedules.
OCCUPANCY_PEAK = {"Cellular Office": 0.6, "Meeting Room": 0.4, "Open Office": 0.6}
OCCUPANCY_BASE = 0.05
#: Additive-parameter base of the thermostat setpoints (°C): the configs add a
#: Beta(2, 2) x 3 K draw to it, so the nominal setpoints span Table A.7's ranges.
SETPOINT_BASE_C = {"Cellular Office": 19.5, "Meeting Room": 19.5, "Open Office": 19.5,
                   "Stair Corridor": 14.5}
SETPOINT_NOMINAL_OFFSET_K = 1.5

#: Open area of the openable windows as a fraction of the glazing (Table A.7's mean).
OPENING_FRACTION = 0.01

LEAKAGE_CM2_PER_M2 = float(np.exp(1.28))

ROOM_SPREAD = 0.05
SETPOINT_SPREAD_K = 0.5
BASELINE_SEED = 2017


def obj(kind: str, *fields: object) -> str:
    """One IDF object, fields one per line."""
    text = [str(f) if not isinstance(f, float) else f"{f:.6g}" for f in fields]
    return f"{kind},\n    " + ",\n    ".join(text) + ";\n"


@dataclass
class Surface:
    name: str
    kind: str            # Wall, Floor, Ceiling
    construction: str
    zone: str
    boundary: str        # Outdoors, Adiabatic, Surface
    other: str
    vertices: list[tuple[float, float, float]]

    def text(self) -> str:
        exposed = self.boundary == "Outdoors"
        coords = [f"{c:.4f}" for v in self.vertices for c in v]
        return obj("BuildingSurface:Detailed", self.name, self.kind, self.construction,
                   self.zone, "", self.boundary, self.other,
                   "SunExposed" if exposed else "NoSun", "WindExposed" if exposed else "NoWind",
                   "autocalculate", len(self.vertices), *coords)


def wall(face: str, x0: float, x1: float, y0: float, y1: float) -> list[tuple[float, float, float]]:
    """Wall vertices, counter-clockwise seen from outside, upper-left first."""
    h = HEIGHT_M
    if face == "south":
        return [(x0, y0, h), (x0, y0, 0), (x1, y0, 0), (x1, y0, h)]
    if face == "north":
        return [(x1, y1, h), (x1, y1, 0), (x0, y1, 0), (x0, y1, h)]
    if face == "east":
        return [(x1, y0, h), (x1, y0, 0), (x1, y1, 0), (x1, y1, h)]
    return [(x0, y1, h), (x0, y1, 0), (x0, y0, 0), (x0, y0, h)]


def floor(x0: float, x1: float, y0: float, y1: float) -> list[tuple[float, float, float]]:
    return [(x0, y0, 0), (x0, y1, 0), (x1, y1, 0), (x1, y0, 0)]


def ceiling(x0: float, x1: float, y0: float, y1: float) -> list[tuple[float, float, float]]:
    return [(x0, y1, HEIGHT_M), (x0, y0, HEIGHT_M), (x1, y0, HEIGHT_M), (x1, y1, HEIGHT_M)]


def window(name: str, host: str, face: str, x0: float, x1: float, y: float,
           width: float, sill: float = 0.9, height: float = 1.5) -> str:
    """A window centred on a south or north wall (or an east/west one when face says so)."""
    top = sill + height
    if face in ("south", "north"):
        mid = 0.5 * (x0 + x1)
        a, b = mid - width / 2, mid + width / 2
        if face == "south":
            vertices = [(a, y, top), (a, y, sill), (b, y, sill), (b, y, top)]
        else:
            vertices = [(b, y, top), (b, y, sill), (a, y, sill), (a, y, top)]
    else:
        mid = 0.5 * (x0 + x1)   # here x0, x1 are the wall's y extent and y its x
        a, b = mid - width / 2, mid + width / 2
        if face == "east":
            vertices = [(y, a, top), (y, a, sill), (y, b, sill), (y, b, top)]
        else:
            vertices = [(y, b, top), (y, b, sill), (y, a, sill), (y, a, top)]
    coords = [f"{c:.4f}" for v in vertices for c in v]
    return obj("FenestrationSurface:Detailed", name, "Window", "Double Glazing Window", host, "",
               "autocalculate", "", 1, 4, *coords)


@dataclass
class Room:
    """One zone: its type, name, extent and per-room usage factors."""

    kind: str
    name: str
    x0: float
    x1: float
    y0: float
    y1: float
    multiplier: int = 1
    usage: float = 1.0
    setpoint_offset_k: float = 0.0

    @property
    def area_m2(self) -> float:
        return (self.x1 - self.x0) * (self.y1 - self.y0)


def constructions() -> list[str]:
    return [
        obj("Material", "Brick Outer Leaf", "MediumRough", 0.105, 0.77, 1700, 800, 0.9, 0.7, 0.7),
        obj("Material", "Wall Insulation", "MediumRough", 0.03, 0.035, 30, 1400, 0.9, 0.7, 0.7),
        obj("Material", "Dense Block", "MediumRough", 0.1, 1.13, 2000, 1000, 0.9, 0.7, 0.7),
        obj("Material", "Gypsum Plaster", "Smooth", 0.013, 0.4, 1000, 1000, 0.9, 0.5, 0.5),
        obj("Material", "Concrete Slab", "MediumRough", 0.2, 1.4, 2100, 840, 0.9, 0.7, 0.7),
        obj("Material", "Floor Screed", "MediumSmooth", 0.05, 0.41, 1200, 840, 0.9, 0.7, 0.7),
        obj("Material", "Plasterboard", "Smooth", 0.0125, 0.25, 900, 1000, 0.9, 0.5, 0.5),
        obj("Material", "Partition Insulation", "Rough", 0.05, 0.04, 30, 1000, 0.9, 0.7, 0.7),
        obj("Material", "Pipe Insulation", "Smooth", 0.04, 0.04, 40, 1000, 0.9, 0.5, 0.5),
        obj("Material", "Steel Pipe Wall", "Smooth", 0.003, 45.0, 7800, 500, 0.9, 0.5, 0.5),
        obj("WindowMaterial:SimpleGlazingSystem", "Double Glazing", 2.8, 0.65, 0.75),
        obj("WindowMaterial:Shade", "Interior Blind Fabric", 0.2, 0.6, 0.2, 0.6, 0.9, 0.0,
            0.001, 0.1, 0.05, 0.5, 0.5, 0.5, 0.5, 0.0),
        obj("Construction", "Exterior Wall", "Brick Outer Leaf", "Wall Insulation", "Dense Block",
            "Gypsum Plaster"),
        obj("Construction", "Intermediate Floor", "Concrete Slab", "Floor Screed"),
        obj("Construction", "Intermediate Ceiling", "Floor Screed", "Concrete Slab"),
        obj("Construction", "Partition", "Plasterboard", "Partition Insulation", "Plasterboard"),
        obj("Construction", "Double Glazing Window", "Double Glazing"),
        obj("Construction", "Insulated Pipe", "Pipe Insulation", "Steel Pipe Wall"),
    ]


def schedules(room_kinds: list[str]) -> list[str]:
    """Type limits, occupancy/lighting/plug-load day profiles per room type, heating operation."""
    out = [
        obj("ScheduleTypeLimits", "Fraction", 0, 1, "Continuous"),
        obj("ScheduleTypeLimits", "Temperature", -60, 200, "Continuous"),
        obj("ScheduleTypeLimits", "On Off", 0, 1, "Discrete"),
        obj("ScheduleTypeLimits", "Any Number"),
        obj("ScheduleTypeLimits", "Control Type", 0, 4, "Discrete"),
        obj("Schedule:Constant", "Always On", "On Off", 1),
        obj("Schedule:Constant", "Heating Only Control", "Control Type", 1),
        obj("Schedule:Constant", "Activity Level", "Any Number", 120),
        # Heating runs 06:00-19:00 on weekdays, off at night and on weekends.
        obj("Schedule:Compact", "Heating Operation", "On Off", "Through: 12/31",
            "For: Weekdays", "Until: 06:00", 0, "Until: 19:00", 1, "Until: 24:00", 0,
            "For: AllOtherDays", "Until: 24:00", 0),
        # Windows may open during office hours (and then only when the room is warm).
        obj("Schedule:Compact", "Window Opening Hours", "Fraction", "Through: 12/31",
            "For: Weekdays", "Until: 08:00", 0, "Until: 18:00", 1, "Until: 24:00", 0,
            "For: AllOtherDays", "Until: 24:00", 0),
    ]
    for kind in room_kinds:
        if kind in OCCUPANCY_PEAK:
            out += _week(f"{kind} Occupancy", OCCUPANCY_PEAK[kind], OCCUPANCY_BASE)
            out += _week(f"{kind} Plug Loads", 0.8, 0.3)
        out += _week(f"{kind} Lighting", 0.9, 0.05)
        base = SETPOINT_BASE_C[kind] + SETPOINT_NOMINAL_OFFSET_K
        out.append(obj("Schedule:Constant", f"{kind} Heating Setpoint", "Temperature", base))
    return out


def _week(name: str, peak: float, base: float) -> list[str]:
    """A weekday 08:00-18:00 peak over a base, base all weekend (targetable Day:Interval values)."""
    return [
        obj("Schedule:Day:Interval", f"{name} Weekday", "Fraction", "No",
            "08:00", base, "18:00", peak, "24:00", base),
        obj("Schedule:Day:Interval", f"{name} Weekend", "Fraction", "No", "24:00", base),
        obj("Schedule:Week:Daily", f"{name} Week", f"{name} Weekend", f"{name} Weekday",
            f"{name} Weekday", f"{name} Weekday", f"{name} Weekday", f"{name} Weekday",
            f"{name} Weekend", f"{name} Weekend", f"{name} Weekend", f"{name} Weekend",
            f"{name} Weekend", f"{name} Weekend"),
        obj("Schedule:Year", name, "Fraction", f"{name} Week", 1, 1, 12, 31),
    ]


def room_objects(room: Room, surfaces: list[Surface], window_names: list[str]) -> list[str]:
    """Zone, loads, thermostat, radiator, infiltration and shading of one room."""
    kind, name = room.kind, room.name
    out = [obj("Zone", name, 0, 0, 0, 0, 1, room.multiplier, HEIGHT_M, "autocalculate")]
    out += [s.text() for s in surfaces]
    if kind in PEOPLE_PER_M2:
        out.append(obj("People", f"{name} People", name, f"{kind} Occupancy", "People/Area", "",
                       PEOPLE_PER_M2[kind] * room.usage, "", 0.3, "autocalculate",
                       "Activity Level"))
        out.append(obj("ElectricEquipment", f"{name} Plug Loads", name, f"{kind} Plug Loads",
                       "Watts/Area", "", PLUG_W_M2[kind] * room.usage, "", 0, 0.3, 0))
    out.append(obj("Lights", f"{name} Lights", name, f"{kind} Lighting", "Watts/Area", "",
                   LIGHTS_W_M2[kind] * room.usage, "", 0, 0.37, 0.18, 1, "General"))
    # Leakage: Table A.7's median effective leakage area per m² of exterior envelope,
    # exp(1.28) cm²/m²; a relative lognormal(0, 0.88²) multiplier makes it lognormal(1.28, 0.88²).
    envelope = sum(_area(s.vertices) for s in surfaces if s.boundary == "Outdoors")
    if envelope > 0:
        out.append(obj("ZoneInfiltration:EffectiveLeakageArea", f"{name} Leakage", name, "Always On",
                       envelope * LEAKAGE_CM2_PER_M2, 0.000145, 0.000174))
    glazing = 0.0
    if window_names:
        out.append(obj("WindowShadingControl", f"{name} Shading", name, 1, "InteriorShade", "",
                       "OnIfHighSolarOnWindow", "", 200, "No", "No", "Interior Blind Fabric",
                       "FixedSlatAngle", "", "", "", "Sequential", *window_names))
        glazing = sum(WINDOW_AREAS[w] for w in window_names)
    if glazing > 0 and kind in PEOPLE_PER_M2:
        azimuth = 180.0 if room.y0 < CORRIDOR_Y0 else 0.0
        out.append(obj("ZoneVentilation:WindandStackOpenArea", f"{name} Window Opening", name,
                       OPENING_FRACTION * glazing * room.usage, "Window Opening Hours", "autocalculate", azimuth,
                       1.0, "autocalculate", 23.0, "", 100, "", -100, "", -100, "", 100, "", 40))
    if kind != "Stair Corridor":
        # Air exchanged with the corridor through door gaps (Table A.7's inter-room rate).
        out.append(obj("ZoneCrossMixing", f"{name} Corridor Air Exchange", name, "Always On",
                       "Flow/Zone", 0.0015, "", "", "", "Stair Corridor", 0))
        out.append(obj("ZoneCapacitanceMultiplier:ResearchSpecial", f"{name} Air Capacity", name,
                       1.0, 1.0, 1.0, 1.0))
    setpoint = f"{kind} Heating Setpoint"
    if room.setpoint_offset_k:
        base = SETPOINT_BASE_C[kind] + SETPOINT_NOMINAL_OFFSET_K + room.setpoint_offset_k
        setpoint = f"{name} Own Heating Setpoint"
        out.append(obj("Schedule:Constant", setpoint, "Temperature", base))
    out.append(obj("ThermostatSetpoint:SingleHeating", f"{name} Setpoint", setpoint))
    out.append(obj("ZoneControl:Thermostat", f"{name} Thermostat", name, "Heating Only Control",
                   "ThermostatSetpoint:SingleHeating", f"{name} Setpoint"))
    # EnergyPlus gives a multiplied zone the output of its one radiator spread over all
    # the copies (and the loop sees one radiator's flow), so the prototype's radiator
    # carries the whole group's rating.
    capacity = RADIATOR_CAPACITY_W[kind] * (room.x1 - room.x0) / _width(kind) * room.multiplier
    flow_kg_s = capacity / (WATER_CP * RATED_WATER_DELTA_K)
    exterior = next(s.name for s in surfaces if s.boundary == "Outdoors")
    floor_name = next(s.name for s in surfaces if s.kind == "Floor")
    ceiling_name = next(s.name for s in surfaces if s.kind == "Ceiling")
    out += [
        obj("ZoneHVAC:EquipmentConnections", name, f"{name} Equipment", "", "",
            f"{name} Air Node", f"{name} Return Node"),
        obj("ZoneHVAC:EquipmentList", f"{name} Equipment", "SequentialLoad",
            "ZoneHVAC:Baseboard:RadiantConvective:Water", f"{name} Radiator", 1, 1, "", ""),
        obj("ZoneHVAC:Baseboard:RadiantConvective:Water", f"{name} Radiator", "Radiator Design",
            "Heating Operation", f"{name} Radiator Water Inlet", f"{name} Radiator Water Outlet",
            RATED_MEAN_WATER_C, flow_kg_s, capacity, flow_kg_s * 1.5 / 1000.0,
            exterior, 0.4, floor_name, 0.25, ceiling_name, 0.15),
    ]
    return out


def _width(kind: str) -> float:
    return {"Cellular Office": OFFICE_WIDTH_M, "Meeting Room": MEETING_WIDTH_M,
            "Open Office": FLOOR_LENGTH_M - MEETING_WIDTH_M, "Stair Corridor": FLOOR_LENGTH_M}[kind]


def _area(vertices: list[tuple[float, float, float]]) -> float:
    points = np.asarray(vertices)
    normal = np.zeros(3)
    for i in range(len(points)):
        normal += np.cross(points[i], points[(i + 1) % len(points)])
    return float(np.linalg.norm(normal) / 2)


WINDOW_AREAS: dict[str, float] = {}


def envelope(rooms: list[Room], individual_offices: bool
             ) -> tuple[dict[str, list[Surface]], list[str], dict[str, list[str]]]:
    """Surfaces and windows of every room; interzone partitions matched pairwise."""
    surfaces: dict[str, list[Surface]] = {r.name: [] for r in rooms}
    windows: list[str] = []
    windows_of: dict[str, list[str]] = {r.name: [] for r in rooms}

    def add_window(room: Room, host: str, face: str, a: float, b: float, at: float, width: float):
        name = f"{host} Window"
        windows.append(window(name, host, face, a, b, at, width))
        windows_of[room.name].append(name)
        WINDOW_AREAS[name] = width * 1.5

    corridor = next(r for r in rooms if r.kind == "Stair Corridor")
    for room in rooms:
        n, x0, x1, y0, y1 = room.name, room.x0, room.x1, room.y0, room.y1
        own = surfaces[n]
        own.append(Surface(f"{n} Floor", "Floor", "Intermediate Floor", n, "Adiabatic", "",
                           floor(x0, x1, y0, y1)))
        own.append(Surface(f"{n} Ceiling", "Ceiling", "Intermediate Ceiling", n, "Adiabatic", "",
                           ceiling(x0, x1, y0, y1)))
        if room.kind == "Cellular Office":
            own.append(Surface(f"{n} South Wall", "Wall", "Exterior Wall", n, "Outdoors", "",
                               wall("south", x0, x1, y0, y1)))
            add_window(room, f"{n} South Wall", "south", x0, x1, y0, 1.8)
            for face in ("west", "east"):
                neighbour = _neighbour(rooms, room, face) if individual_offices else None
                if neighbour is None:
                    own.append(Surface(f"{n} {face.title()} Wall", "Wall", "Partition", n,
                                       "Adiabatic", "", wall(face, x0, x1, y0, y1)))
                else:
                    own.append(Surface(f"{n} {face.title()} Wall", "Wall", "Partition", n,
                                       "Surface", f"{neighbour.name} {_opposite(face).title()} Wall",
                                       wall(face, x0, x1, y0, y1)))
            # The prototype office's corridor wall is a real partition, so its rooms lose
            # heat to the corridor; the corridor sees one office's share of it (the
            # multiplier scales the office's side only), its other walls to offices are adiabatic.
            own.append(Surface(f"{n} North Wall", "Wall", "Partition", n, "Surface",
                               f"{corridor.name} Wall To {n}", wall("north", x0, x1, y0, y1)))
            surfaces[corridor.name].append(Surface(
                f"{corridor.name} Wall To {n}", "Wall", "Partition", corridor.name, "Surface",
                f"{n} North Wall", wall("south", x0, x1, CORRIDOR_Y0, NORTH_Y0)))
        elif room.kind == "Stair Corridor":
            if not individual_offices:
                own.append(Surface(f"{n} South Wall", "Wall", "Partition", n, "Adiabatic", "",
                                   wall("south", OFFICE_WIDTH_M, x1, y0, y1)))
            for face in ("west", "east"):
                own.append(Surface(f"{n} {face.title()} Wall", "Wall", "Exterior Wall", n,
                                   "Outdoors", "", wall(face, x0, x1, y0, y1)))
        else:
            own.append(Surface(f"{n} North Wall", "Wall", "Exterior Wall", n, "Outdoors", "",
                               wall("north", x0, x1, y0, y1)))
            width = x1 - x0
            count = max(1, round(width / 4.5))
            for k in range(count):
                a = x0 + k * width / count
                b = a + width / count
                host = f"{n} North Wall {k + 1:02d}" if count > 1 else f"{n} North Wall"
                if count > 1:
                    if k == 0:
                        own.pop()
                    own.append(Surface(host, "Wall", "Exterior Wall", n, "Outdoors", "",
                                       wall("north", a, b, y0, y1)))
                add_window(room, host, "north", a, b, y1, min(2.4, 0.6 * (b - a)))
            own.append(Surface(f"{n} South Wall", "Wall", "Partition", n, "Surface",
                               f"{corridor.name} Wall To {n}", wall("south", x0, x1, y0, y1)))
            surfaces[corridor.name].append(Surface(
                f"{corridor.name} Wall To {n}", "Wall", "Partition", corridor.name, "Surface",
                f"{n} South Wall", wall("north", x0, x1, CORRIDOR_Y0, NORTH_Y0)))
            side = "west" if room.kind == "Meeting Room" else "east"
            own.append(Surface(f"{n} {side.title()} Wall", "Wall", "Exterior Wall", n, "Outdoors",
                               "", wall(side, x0, x1, y0, y1)))
            other = "east" if side == "west" else "west"
            own.append(Surface(f"{n} {other.title()} Wall", "Wall", "Partition", n, "Surface",
                               f"{_beside(rooms, room).name} {side.title()} Wall",
                               wall(other, x0, x1, y0, y1)))
    return surfaces, windows, windows_of


def _opposite(face: str) -> str:
    return {"west": "east", "east": "west"}[face]


def _neighbour(rooms: list[Room], room: Room, face: str) -> Room | None:
    x = room.x0 if face == "west" else room.x1
    for other in rooms:
        if other is room or other.kind != "Cellular Office":
            continue
        if (face == "west" and abs(other.x1 - x) < 1e-9) or (face == "east" and abs(other.x0 - x) < 1e-9):
            return other
    return None


def _beside(rooms: list[Room], room: Room) -> Room:
    kind = "Open Office" if room.kind == "Meeting Room" else "Meeting Room"
    return next(r for r in rooms if r.kind == kind)


def plant(rooms: list[Room]) -> list[str]:
    """The hot-water loop: pump, boiler, outdoor-reset supply, distribution pipe, one radiator branch per room."""
    radiators = [f"{r.name} Radiator" for r in rooms]
    design_flow = sum(RADIATOR_CAPACITY_W[r.kind] * (r.x1 - r.x0) / _width(r.kind) * r.multiplier
                      for r in rooms) / (WATER_CP * RATED_WATER_DELTA_K) * 1.5 / 1000.0
    out = [
        obj("PlantLoop", "Hot Water Loop", "Water", "", "Hot Water Loop Operation",
            "HW Supply Outlet Node", 90, 10, design_flow, 0, "autocalculate",
            "HW Supply Inlet Node", "HW Supply Outlet Node", "HW Supply Branches",
            "HW Supply Connectors", "HW Demand Inlet Node", "HW Demand Outlet Node",
            "HW Demand Branches", "HW Demand Connectors", "Optimal", "", "SingleSetpoint"),
        obj("PlantEquipmentOperationSchemes", "Hot Water Loop Operation",
            "PlantEquipmentOperation:HeatingLoad", "Boiler Operation", "Always On"),
        obj("PlantEquipmentOperation:HeatingLoad", "Boiler Operation", 0, 1e9, "Boiler Equipment"),
        obj("PlantEquipmentList", "Boiler Equipment", "Boiler:HotWater", "Boiler"),
        # Supply temperature: outdoor reset, 65 °C at -5 °C outdoors to 30 °C at 15 °C.
        obj("SetpointManager:OutdoorAirReset", "Supply Temperature Reset", "Temperature",
            65, -5, 30, 15, "HW Setpoint Nodes"),
        obj("NodeList", "HW Setpoint Nodes", "Boiler Outlet Node", "HW Supply Outlet Node"),
        obj("Pump:VariableSpeed", "HW Pump", "HW Supply Inlet Node", "HW Pump Outlet Node",
            design_flow, 20000, design_flow * 20000 / 0.6, 0.9, 0.0, 0, 1, 0, 0, 0, "Intermittent"),
        obj("Boiler:HotWater", "Boiler", "NaturalGas", 60000, 0.9, "", "", design_flow,
            0, 1, 1, "Boiler Inlet Node", "Boiler Outlet Node", 95, "LeavingSetpointModulated"),
        obj("Pipe:Adiabatic", "HW Supply Bypass Pipe", "HW Supply Bypass Inlet", "HW Supply Bypass Outlet"),
        obj("Pipe:Adiabatic", "HW Supply Outlet Pipe", "HW Supply Outlet Pipe Inlet", "HW Supply Outlet Node"),
        # The distribution pipe runs in the corridor's ceiling void: its loss is part of
        # the boiler's heating energy and a gain to the corridor.
        obj("Pipe:Indoor", "HW Distribution Pipe", "Insulated Pipe", "HW Demand Inlet Node",
            "HW Distribution Pipe Outlet", "Zone", "Stair Corridor", "", "", 0.025, 60),
        obj("Pipe:Adiabatic", "HW Demand Bypass Pipe", "HW Demand Bypass Inlet", "HW Demand Bypass Outlet"),
        obj("Pipe:Adiabatic", "HW Demand Outlet Pipe", "HW Demand Outlet Pipe Inlet", "HW Demand Outlet Node"),
        obj("Branch", "HW Supply Inlet Branch", "", "Pump:VariableSpeed", "HW Pump",
            "HW Supply Inlet Node", "HW Pump Outlet Node"),
        obj("Branch", "HW Boiler Branch", "", "Boiler:HotWater", "Boiler", "Boiler Inlet Node",
            "Boiler Outlet Node"),
        obj("Branch", "HW Supply Bypass Branch", "", "Pipe:Adiabatic", "HW Supply Bypass Pipe",
            "HW Supply Bypass Inlet", "HW Supply Bypass Outlet"),
        obj("Branch", "HW Supply Outlet Branch", "", "Pipe:Adiabatic", "HW Supply Outlet Pipe",
            "HW Supply Outlet Pipe Inlet", "HW Supply Outlet Node"),
        obj("BranchList", "HW Supply Branches", "HW Supply Inlet Branch", "HW Boiler Branch",
            "HW Supply Bypass Branch", "HW Supply Outlet Branch"),
        obj("Connector:Splitter", "HW Supply Splitter", "HW Supply Inlet Branch", "HW Boiler Branch",
            "HW Supply Bypass Branch"),
        obj("Connector:Mixer", "HW Supply Mixer", "HW Supply Outlet Branch", "HW Boiler Branch",
            "HW Supply Bypass Branch"),
        obj("ConnectorList", "HW Supply Connectors", "Connector:Splitter", "HW Supply Splitter",
            "Connector:Mixer", "HW Supply Mixer"),
        obj("Branch", "HW Demand Inlet Branch", "", "Pipe:Indoor", "HW Distribution Pipe",
            "HW Demand Inlet Node", "HW Distribution Pipe Outlet"),
        obj("Branch", "HW Demand Bypass Branch", "", "Pipe:Adiabatic", "HW Demand Bypass Pipe",
            "HW Demand Bypass Inlet", "HW Demand Bypass Outlet"),
        obj("Branch", "HW Demand Outlet Branch", "", "Pipe:Adiabatic", "HW Demand Outlet Pipe",
            "HW Demand Outlet Pipe Inlet", "HW Demand Outlet Node"),
    ]
    for radiator in radiators:
        out.append(obj("Branch", f"{radiator} Branch", "",
                       "ZoneHVAC:Baseboard:RadiantConvective:Water", radiator,
                       f"{radiator} Water Inlet", f"{radiator} Water Outlet"))
    demand = [f"{r} Branch" for r in radiators]
    out += [
        obj("BranchList", "HW Demand Branches", "HW Demand Inlet Branch", *demand,
            "HW Demand Bypass Branch", "HW Demand Outlet Branch"),
        obj("Connector:Splitter", "HW Demand Splitter", "HW Demand Inlet Branch", *demand,
            "HW Demand Bypass Branch"),
        obj("Connector:Mixer", "HW Demand Mixer", "HW Demand Outlet Branch", *demand,
            "HW Demand Bypass Branch"),
        obj("ConnectorList", "HW Demand Connectors", "Connector:Splitter", "HW Demand Splitter",
            "Connector:Mixer", "HW Demand Mixer"),
        # Convective only: EnergyPlus divides a multiplied zone's radiator output among the
        # copies for the air but sends the radiant part undivided to the one modelled room's
        # surfaces (a prototype office with a 30 % radiant radiator ran 0.3 K warmer on
        # 40 % less heat than its 16 rooms modelled one by one; with none, within 3 %).
        obj("ZoneHVAC:Baseboard:RadiantConvective:Water:Design", "Radiator Design",
            "HeatingDesignCapacity", "", "", 0.001, 0.0, 0.0),
    ]
    return out


def model(individual_offices: bool) -> str:
    rng = np.random.default_rng(BASELINE_SEED)
    rooms: list[Room] = []
    if individual_offices:
        for k in range(OFFICES):
            rooms.append(Room("Cellular Office", f"Cellular Office {k + 1:02d}",
                              k * OFFICE_WIDTH_M, (k + 1) * OFFICE_WIDTH_M, 0.0, SOUTH_DEPTH_M))
    else:
        rooms.append(Room("Cellular Office", "Cellular Office", 0.0, OFFICE_WIDTH_M, 0.0,
                          SOUTH_DEPTH_M, multiplier=OFFICES))
    rooms.append(Room("Stair Corridor", "Stair Corridor", 0.0, FLOOR_LENGTH_M, CORRIDOR_Y0, NORTH_Y0))
    rooms.append(Room("Meeting Room", "Meeting Room", 0.0, MEETING_WIDTH_M, NORTH_Y0,
                      NORTH_Y0 + NORTH_DEPTH_M))
    rooms.append(Room("Open Office", "Open Office", MEETING_WIDTH_M, FLOOR_LENGTH_M, NORTH_Y0,
                      NORTH_Y0 + NORTH_DEPTH_M))
    if individual_offices:
        for room in rooms:
            room.usage = float(1.0 + ROOM_SPREAD * rng.standard_normal())
            room.setpoint_offset_k = float(SETPOINT_SPREAD_K * rng.standard_normal())
    WINDOW_AREAS.clear()
    surfaces, windows, windows_of = envelope(rooms, individual_offices)
    kinds = list(dict.fromkeys(r.kind for r in rooms))
    title = ("every room modelled individually, per-room usage and setpoints varied"
             if individual_offices else "prototype rooms, one zone per room type")
    parts = [
        f"! Hydronic office floor (seed §4.1-4.2): {title}.\n"
        "! Written by sample_idf/make_hydronic_office.py; see sample_idf/README.md.\n\n",
        obj("Version", "25.2"),
        obj("Building", "Hydronic Office Floor", 0, "City", 0.04, 0.4, "FullExterior", 25, 6),
        obj("GlobalGeometryRules", "UpperLeftCorner", "Counterclockwise", "Relative"),
        obj("Timestep", 4),
        obj("SimulationControl", "No", "No", "No", "No", "Yes", "No", 1),
        obj("Site:Location", "Chicago Ohare Intl Ap", 41.98, -87.92, -6.0, 201.0),
        obj("HeatBalanceAlgorithm", "ConductionTransferFunction"),
        obj("SurfaceConvectionAlgorithm:Inside", "TARP"),
        obj("SurfaceConvectionAlgorithm:Outside", "DOE-2"),
        *constructions(),
        *schedules(kinds),
    ]
    for room in rooms:
        parts += room_objects(room, surfaces[room.name], windows_of[room.name])
    parts += windows
    parts += plant(rooms)
    parts.append(obj("Meter:Custom", "Office Electricity", "Electricity",
                     "", "InteriorLights:Electricity", "", "InteriorEquipment:Electricity"))
    return "\n".join(parts)


def main() -> None:
    (HERE / "hydronic_office.idf").write_text(model(individual_offices=False))
    (HERE / "hydronic_office_baseline.idf").write_text(model(individual_offices=True))


if __name__ == "__main__":
    main()
