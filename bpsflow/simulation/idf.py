"""A small IDF reader for the objects the surrogate needs (no IDD, no EnergyPlus).

The surrogate must run without EnergyPlus installed, so it cannot ask eppy
for field names. It reads the model's text itself and names the fields of
the few object types it uses from a built-in table (field order as in the
EnergyPlus 25.2 IDD). Objects of other types are kept as raw field lists so
that a config target on them can still be recognised (and reported as
ignored when the surrogate has no physics for it).

The model is ``model.idf`` followed by the snippets of ``model.idf_objects``;
:func:`model_objects` (parsed) and :func:`model_text` (IDF text, what the
EnergyPlus instances are written from) are the one place that assembles it,
so every reader of the model sees the same objects. A relative
``Schedule:File`` name is made absolute against the directory of the file
that declares it (EnergyPlus runs an instance's copy of the model in another
directory, where the relative name would not resolve).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

from bpsflow.errors import BpsflowError
from bpsflow.simulation.field_limits import normalise

if TYPE_CHECKING:
    from bpsflow.config import Model

_VERTICES = ("Vertex X", "Vertex Y", "Vertex Z")

#: Field names (after the object type) of the object types the surrogate reads.
FIELDS: dict[str, tuple[str, ...]] = {
    "MATERIAL": ("Name", "Roughness", "Thickness", "Conductivity", "Density", "Specific Heat",
                 "Thermal Absorptance", "Solar Absorptance", "Visible Absorptance"),
    "WINDOWMATERIAL:GLAZING": (
        "Name", "Optical Data Type", "Window Glass Spectral Data Set Name", "Thickness",
        "Solar Transmittance at Normal Incidence",
        "Front Side Solar Reflectance at Normal Incidence",
        "Back Side Solar Reflectance at Normal Incidence",
        "Visible Transmittance at Normal Incidence",
        "Front Side Visible Reflectance at Normal Incidence",
        "Back Side Visible Reflectance at Normal Incidence",
        "Infrared Transmittance at Normal Incidence",
        "Front Side Infrared Hemispherical Emissivity",
        "Back Side Infrared Hemispherical Emissivity", "Conductivity",
        "Dirt Correction Factor for Solar and Visible Transmittance", "Solar Diffusing"),
    "WINDOWMATERIAL:GAS": ("Name", "Gas Type", "Thickness"),
    "CONSTRUCTION": ("Name", "Outside Layer") + tuple(f"Layer {i}" for i in range(2, 11)),
    "CURVE:EXPONENT": ("Name", "Coefficient1 Constant", "Coefficient2 Constant",
                       "Coefficient3 Constant", "Minimum Value of x", "Maximum Value of x",
                       "Minimum Curve Output", "Maximum Curve Output", "Input Unit Type for X",
                       "Output Unit Type"),
    "CURVE:LINEAR": ("Name", "Coefficient1 Constant", "Coefficient2 x", "Minimum Value of x",
                     "Maximum Value of x", "Minimum Curve Output", "Maximum Curve Output",
                     "Input Unit Type for X", "Output Unit Type"),
    "SITE:GROUNDREFLECTANCE": tuple(f"{m} Ground Reflectance" for m in (
        "January", "February", "March", "April", "May", "June", "July", "August",
        "September", "October", "November", "December")),
    "ROOMAIR:TEMPERATUREPATTERN:CONSTANTGRADIENT": (
        "Room Air Temperature Pattern Constant Gradient Name",
        "Control Integer for Pattern Control Schedule Name", "Thermostat Offset",
        "Return Air Offset", "Exhaust Air Offset", "Temperature Gradient"),
    "ZONEVENTILATION:DESIGNFLOWRATE": (
        "Name", "Zone or ZoneList or Space or SpaceList Name", "Schedule Name",
        "Design Flow Rate Calculation Method", "Design Flow Rate", "Flow Rate per Floor Area",
        "Flow Rate per Person", "Air Changes per Hour", "Ventilation Type", "Fan Pressure Rise",
        "Fan Total Efficiency", "Constant Term Coefficient", "Temperature Term Coefficient",
        "Velocity Term Coefficient", "Velocity Squared Term Coefficient",
        "Minimum Indoor Temperature", "Minimum Indoor Temperature Schedule Name",
        "Maximum Indoor Temperature", "Maximum Indoor Temperature Schedule Name",
        "Delta Temperature", "Delta Temperature Schedule Name",
        "Minimum Outdoor Temperature", "Minimum Outdoor Temperature Schedule Name",
        "Maximum Outdoor Temperature", "Maximum Outdoor Temperature Schedule Name",
        "Maximum Wind Speed"),
    "BUILDINGSURFACE:DETAILED": (
        "Name", "Surface Type", "Construction Name", "Zone Name", "Space Name",
        "Outside Boundary Condition", "Outside Boundary Condition Object", "Sun Exposure",
        "Wind Exposure", "View Factor to Ground", "Number of Vertices"),
    "FENESTRATIONSURFACE:DETAILED": (
        "Name", "Surface Type", "Construction Name", "Building Surface Name",
        "Outside Boundary Condition Object", "View Factor to Ground",
        "Frame and Divider Name", "Multiplier", "Number of Vertices"),
    "SURFACEPROPERTY:OTHERSIDECOEFFICIENTS": (
        "Name", "Combined Convective/Radiative Film Coefficient", "Constant Temperature",
        "Constant Temperature Coefficient", "External Dry-Bulb Temperature Coefficient",
        "Ground Temperature Coefficient", "Wind Speed Coefficient",
        "Zone Air Temperature Coefficient", "Constant Temperature Schedule Name"),
    "SHADOWCALCULATION": ("Shading Calculation Method",
                          "Shading Calculation Update Frequency Method",
                          "Shading Calculation Update Frequency"),
    "BUILDING": ("Name", "North Axis", "Terrain", "Loads Convergence Tolerance Value",
                 "Temperature Convergence Tolerance Value", "Solar Distribution",
                 "Maximum Number of Warmup Days", "Minimum Number of Warmup Days"),
    "ZONEHVAC:IDEALLOADSAIRSYSTEM": (
        "Name", "Availability Schedule Name", "Zone Supply Air Node Name",
        "Zone Exhaust Air Node Name", "System Inlet Air Node Name",
        "Maximum Heating Supply Air Temperature", "Minimum Cooling Supply Air Temperature"),
    "SURFACECONVECTIONALGORITHM:INSIDE:USERCURVE": (
        "Name", "Reference Temperature for Convection Heat Transfer",
        "Hc Function of Temperature Difference Curve Name"),
    "SURFACECONVECTIONALGORITHM:OUTSIDE:USERCURVE": (
        "Name", "Wind Speed Type for Curve", "Hf Function of Wind Speed Curve Name",
        "Hn Function of Temperature Difference Curve Name"),
    "ZONEINFILTRATION:DESIGNFLOWRATE": (
        "Name", "Zone or ZoneList or Space or SpaceList Name", "Schedule Name",
        "Design Flow Rate Calculation Method", "Design Flow Rate", "Flow Rate per Floor Area",
        "Flow Rate per Exterior Surface Area", "Air Changes per Hour",
        "Constant Term Coefficient", "Temperature Term Coefficient",
        "Velocity Term Coefficient", "Velocity Squared Term Coefficient", "Density Basis"),
    "OTHEREQUIPMENT": (
        "Name", "Fuel Type", "Zone or ZoneList or Space or SpaceList Name", "Schedule Name",
        "Design Level Calculation Method", "Design Level", "Power per Floor Area",
        "Power per Person", "Fraction Latent", "Fraction Radiant", "Fraction Lost",
        "Carbon Dioxide Generation Rate", "End-Use Subcategory"),
    "INTERNALMASS": ("Name", "Construction Name", "Zone or ZoneList Name",
                     "Space or SpaceList Name", "Surface Area"),
    "SCHEDULE:CONSTANT": ("Name", "Schedule Type Limits Name", "Hourly Value"),
    "SCHEDULE:FILE": (
        "Name", "Schedule Type Limits Name", "File Name", "Column Number",
        "Rows to Skip at Top", "Number of Hours of Data", "Column Separator",
        "Interpolate to Timestep", "Minutes per Item", "Adjust Schedule for Daylight Savings"),
    "SURFACEPROPERTY:CONVECTIONCOEFFICIENTS": (
        "Surface Name", "Convection Coefficient 1 Location", "Convection Coefficient 1 Type",
        "Convection Coefficient 1", "Convection Coefficient 1 Schedule Name",
        "Convection Coefficient 1 User Curve Name", "Convection Coefficient 2 Location",
        "Convection Coefficient 2 Type", "Convection Coefficient 2",
        "Convection Coefficient 2 Schedule Name", "Convection Coefficient 2 User Curve Name"),
}

#: Types whose objects have no name field (a target's ``name`` must be ``*``).
UNNAMED = {"SITE:GROUNDREFLECTANCE", "SHADOWCALCULATION"}


@dataclass
class IdfObject:
    type: str            # upper case
    fields: list[str]    # raw text values after the type
    source: Path | None = None   # the file that declares the object
    spelling: str = ""           # the type as written

    @property
    def where(self) -> str:
        """``Type 'Name'`` for messages."""
        return f"{self.spelling or self.type} '{self.name}'"

    @property
    def name(self) -> str:
        if self.type in UNNAMED or not self.fields:
            return ""
        return self.fields[0]

    def field_index(self, field: str) -> int | None:
        names = FIELDS.get(self.type)
        if names is None:
            return None
        wanted = normalise(field)
        for i, name in enumerate(names):
            if normalise(name) == wanted:
                return i
        return None

    def get(self, field: str, default: str = "") -> str:
        i = self.field_index(field)
        if i is None:
            raise KeyError(f"{self.type} has no field '{field}' in the surrogate's table")
        return self.fields[i] if i < len(self.fields) else default

    def number(self, field: str, default: float | None = None) -> float:
        text = self.get(field).strip()
        if not text:
            if default is None:
                raise BpsflowError(f"{self.type} '{self.name}': field '{field}' is blank")
            return default
        try:
            return float(text)
        except ValueError:
            raise BpsflowError(f"{self.type} '{self.name}': field '{field}' holds '{text}', "
                               f"not a number") from None

    def vertices(self) -> list[tuple[float, float, float]]:
        """The vertex list of a surface (fields after 'Number of Vertices')."""
        start = len(FIELDS[self.type])
        values = [float(v) for v in self.fields[start:] if v.strip()]
        return [(values[i], values[i + 1], values[i + 2]) for i in range(0, len(values) - 2, 3)]


@dataclass
class IdfModel:
    path: Path
    objects: list[IdfObject]

    def of_type(self, object_type: str) -> list[IdfObject]:
        object_type = object_type.upper()
        return [o for o in self.objects if o.type == object_type]

    def find(self, object_type: str, name: str) -> IdfObject:
        for obj in self.of_type(object_type):
            if obj.name.upper() == name.upper():
                return obj
        raise BpsflowError(f"the model has no {object_type} named '{name}' (the surrogate "
                           f"needs it)", source=self.path)

    def one(self, object_type: str) -> IdfObject:
        found = self.of_type(object_type)
        if len(found) != 1:
            raise BpsflowError(f"expected exactly one {object_type} object, found {len(found)}",
                               source=self.path)
        return found[0]


def parse_idf_text(text: str, path: Path = Path("<text>")) -> IdfModel:
    """Split IDF text into objects: comments removed, fields split on commas."""
    body = "\n".join(line.split("!", 1)[0] for line in text.splitlines())
    objects = []
    for chunk in body.split(";"):
        parts = [p.strip() for p in chunk.split(",")]
        if not parts or not parts[0]:
            continue
        objects.append(IdfObject(type=parts[0].upper(), fields=parts[1:], source=path,
                                 spelling=parts[0]))
    return IdfModel(path=path, objects=objects)


@lru_cache(maxsize=4)
def read_idf(path: Path) -> IdfModel:
    """One IDF file, parsed (the model's base file alone; see :func:`model_objects`)."""
    path = Path(path)
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise BpsflowError(f"cannot read the IDF: {exc}", source=path) from None
    return parse_idf_text(text, path)


#: Object types a snippet may not add (the model has exactly one of each).
_SINGLETONS = {"VERSION", "BUILDING", "SIMULATIONCONTROL", "TIMESTEP", "GLOBALGEOMETRYRULES",
               "SITE:LOCATION", "SITE:GROUNDREFLECTANCE", "SHADOWCALCULATION"}
_SCHEDULE_FILE = "SCHEDULE:FILE"
_FILE_NAME = 2  # index of "File Name" among a Schedule:File's fields


def model_files(model: Model) -> list[Path]:
    """The files that make up the model: ``model.idf``, then ``model.idf_objects`` in order."""
    return [Path(model.idf), *[Path(p) for p in model.idf_objects]]


def describe_model(model: Model) -> str:
    """The model's files for messages: ``base.idf`` or ``base.idf + a.idf + b.idf``."""
    files = model_files(model)
    return str(files[0]) + "".join(f" + {p.name}" for p in files[1:])


def model_objects(model: Model) -> IdfModel:
    """Every object of the model: ``model.idf``'s, then each snippet's, in order.

    Each object knows the file that declares it (``IdfObject.source``); a
    relative ``Schedule:File`` name is made absolute against that file's
    directory. Parsed once per set of files and modification times.

    Raises
    ------
    BpsflowError
        When a snippet file is missing (naming ``model.idf_objects[i]``),
        declares an object of a type the model has once (``Version``,
        ``Building``, ...), or declares a schedule, infiltration, equipment or
        internal mass object whose name the model already uses.
    """
    stamps = []
    for i, path in enumerate(model_files(model)):
        path = Path(path).resolve()
        try:
            stat = path.stat()
        except OSError:
            key = "model.idf" if i == 0 else f"model.idf_objects[{i - 1}]"
            raise BpsflowError(f"{key}: IDF file not found: {path}") from None
        stamps.append((path, stat.st_mtime_ns, stat.st_size))
    return _assemble(tuple(stamps))


def model_text(model: Model) -> str:
    """The whole model as IDF text (what the EnergyPlus instances are written from).

    The objects of :func:`model_objects`, one field per line; comments are
    not kept.
    """
    return render_idf(model_objects(model).objects)


def render_idf(objects: list[IdfObject]) -> str:
    """IDF text of ``objects``."""
    parts = []
    for obj in objects:
        fields = [obj.spelling or obj.type, *obj.fields]
        parts.append(",\n    ".join(fields) + ";\n")
    return "\n".join(parts)


#: Types whose names must stay unique when a snippet adds objects.
_UNIQUE_NAMES = ("SCHEDULE:", "ZONEINFILTRATION:", "ZONEVENTILATION:", "OTHEREQUIPMENT",
                 "INTERNALMASS", "MATERIAL", "CONSTRUCTION")


#: Types whose names EnergyPlus also refuses twice (a second copy the surrogate would
#: silently take instead of the first), checked in the model file itself.
_UNIQUE_IN_MODEL = _UNIQUE_NAMES + ("WINDOWMATERIAL:", "BUILDINGSURFACE:", "FENESTRATIONSURFACE:",
                                    "LIGHTS", "ELECTRICEQUIPMENT", "PEOPLE")


def _check_model_names(objects: list[IdfObject], path: Path) -> None:
    seen: dict[tuple[str, str], IdfObject] = {}
    for obj in objects:
        if not obj.name or not (obj.type == "ZONE" or obj.type.startswith(_UNIQUE_IN_MODEL)):
            continue
        first = seen.setdefault((obj.type, obj.name.upper()), obj)
        if first is not obj:
            raise BpsflowError(f"{obj.where} is defined twice; EnergyPlus refuses a second "
                               f"object of one type and name (expected unique names: rename "
                               f"or delete one)", source=path)


@lru_cache(maxsize=8)
def _assemble(stamps: tuple[tuple[Path, int, int], ...]) -> IdfModel:
    objects: list[IdfObject] = []
    for i, (path, _, _) in enumerate(stamps):
        part = read_idf.__wrapped__(path) if i == 0 else _read_snippet(path)
        if i == 0:
            _check_model_names(part.objects, path)
        for obj in part.objects:
            if obj.type == _SCHEDULE_FILE and len(obj.fields) > _FILE_NAME:
                name = obj.fields[_FILE_NAME]
                if name and not Path(name).is_absolute():
                    obj.fields[_FILE_NAME] = str((path.parent / name).resolve())
            if i > 0:
                _check_snippet_object(obj, objects, path)
            objects.append(obj)
    return IdfModel(path=stamps[0][0], objects=objects)


def _read_snippet(path: Path) -> IdfModel:
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise BpsflowError(f"cannot read the IDF snippet: {exc}", source=path) from None
    return parse_idf_text(text, path)


def _check_snippet_object(obj: IdfObject, before: list[IdfObject], path: Path) -> None:
    if obj.type in _SINGLETONS:
        raise BpsflowError(f"a snippet may only add objects; {obj.spelling} is already in "
                           f"the model (once per model)", source=path)
    if obj.type.startswith(_UNIQUE_NAMES) and obj.name:
        for other in before:
            if other.type == obj.type and other.name.upper() == obj.name.upper():
                raise BpsflowError(f"{obj.where} is already defined in {other.source}; "
                                   f"names must be unique", source=path)


def polygon_area(vertices: list[tuple[float, float, float]]) -> float:
    """Area of a planar polygon in 3-D (Newell's method)."""
    nx = ny = nz = 0.0
    for (x1, y1, z1), (x2, y2, z2) in zip(vertices, vertices[1:] + vertices[:1]):
        nx += (y1 - y2) * (z1 + z2)
        ny += (z1 - z2) * (x1 + x2)
        nz += (x1 - x2) * (y1 + y2)
    return 0.5 * (nx * nx + ny * ny + nz * nz) ** 0.5


def centroid_height(vertices: list[tuple[float, float, float]]) -> float:
    return sum(v[2] for v in vertices) / len(vertices)


def surface_user_curves(idf: IdfModel, surface: str) -> tuple[str | None, str | None]:
    """(inside, outside) ``SurfaceConvectionAlgorithm:*:UserCurve`` names assigned to a surface.

    Read from the surface's ``SurfaceProperty:ConvectionCoefficients`` entries of
    type UserCurve; None where it has none.
    """
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


def inside_convection_curve(idf: IdfModel, surface: str) -> str:
    """The Hc curve of a surface's inside convection, following the IDF's chain.

    SurfaceProperty:ConvectionCoefficients (Inside, UserCurve) →
    SurfaceConvectionAlgorithm:Inside:UserCurve → its "Hc Function of
    Temperature Difference Curve Name".

    Raises
    ------
    BpsflowError
        When the surface has no inside UserCurve convection.
    """
    algorithm, _ = surface_user_curves(idf, surface)
    if algorithm is None:
        raise BpsflowError(f"surface '{surface}' has no inside UserCurve convection "
                           f"(SurfaceProperty:ConvectionCoefficients)", source=idf.path)
    return idf.find("SURFACECONVECTIONALGORITHM:INSIDE:USERCURVE", algorithm).get(
        "Hc Function of Temperature Difference Curve Name")


def missing_semicolon_hint(model: Model) -> str:
    """Where a missing ';' most likely is ("" if nowhere): an object with a type among its fields.

    Without the ';' that ends an object, the next object's type and fields run on as
    fields of the first; parsers then fail far from the cause, or a target finds no
    object of its name.
    """
    from bpsflow.simulation.field_limits import known_object_types

    types = known_object_types()
    try:
        objects = model_objects(model).objects
    except BpsflowError:
        return ""
    for obj in objects:
        for value in obj.fields[1:]:
            # 'Zone' is also a value of several choice fields
            if value.strip().upper() in types and value.strip().upper() != "ZONE":
                return (f"; {obj.where} in {obj.source or 'the model'} has the object type "
                        f"'{value.strip()}' among its fields: a missing ';' at the end of that "
                        f"object?")
    return ""
