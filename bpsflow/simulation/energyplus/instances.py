"""Writing perturbed EnergyPlus instances: IDF, weather file, boundary data.

One instance is one sample row. For each run period it gets an IDF (the
model with the sampled values written into the targeted fields, the period's
RunPeriod, the tests' setpoint schedules with the model's thermostats rewired
to them (:mod:`bpsflow.simulation.setpoints`), and the configured output
variables and meters), plus, when the sample needs them, its own weather file
with sensor errors and its own boundary-temperature ``Schedule:File`` data.

eppy parses the model once per process (the IDD is process-wide in eppy);
every instance then sets its fields on that parse, writes the text and puts
the nominal values back, which keeps writing to a few milliseconds.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

from bpsflow.boundary import SEQUENCES_FILE, period_hours, read_sequences, write_boundary_file
from bpsflow.config import (
    BoundaryTarget,
    Config,
    IdfTarget,
    Model,
    Parameter,
    Period,
    WeatherTarget,
    period_dates,
)
from bpsflow.errors import BpsflowError
from bpsflow.files import write_text_atomic
from bpsflow.simulation.idf import describe_model, missing_semicolon_hint, model_objects, model_text
from bpsflow.simulation.setpoints import (
    ThermostatPlan,
    control_objects_text,
    setpoint_schedules,
    thermostat_plan,
)
from bpsflow.simulation.targets import apply_mode, select_objects
from bpsflow.weather import perturb, read_epw, write_epw

IDF_NAME = "in.idf"
EPW_NAME = "in.epw"
BOUNDARY_NAME = "boundary.csv"


def _normalise(name: str) -> str:
    return re.sub(r"[^a-z0-9]", "", name.lower())


@lru_cache(maxsize=1)
def _set_idd(idd: str) -> None:
    from eppy.modeleditor import IDF

    try:
        IDF.setiddname(idd)
    except Exception:  # eppy refuses a second, different IDD in one process
        if _normalise(str(IDF.iddname)) != _normalise(idd):
            raise
    if getattr(IDF, "idd_info", None) is None:
        _load_parsed_idd(Path(idd))


def _parsed_idd_cache(idd: Path) -> Path:
    """Where eppy's parse of ``idd`` is kept between processes (per IDD file and eppy version)."""
    import hashlib
    from importlib.metadata import version

    from bpsflow.files import user_cache_dir

    stat = idd.stat()
    key = hashlib.sha256(f"{idd.resolve()}|{stat.st_size}|{stat.st_mtime_ns}|"
                         f"{version('eppy')}".encode()).hexdigest()[:20]
    return user_cache_dir() / f"eppy-idd-{key}.pickle"


def _load_parsed_idd(idd: Path) -> None:
    """Give eppy the IDD parsed by an earlier process (0.3 s instead of about 1 s), if kept."""
    import pickle

    from eppy.modeleditor import IDF

    try:
        with _parsed_idd_cache(idd).open("rb") as handle:
            idd_info, idd_index, block, idd_version = pickle.load(handle)
    except Exception:  # noqa: S110 - no cache, or an unreadable one: eppy parses the IDD itself
        return
    IDF.setidd(idd_info, idd_index, block, idd_version)


@lru_cache(maxsize=4)
def _keep_parsed_idd(idd: Path) -> None:
    """Keep eppy's parse of ``idd`` for later processes (checked once per process, written
    once, atomically); called after a parse, when eppy holds the IDD."""
    import pickle

    from eppy.modeleditor import IDF

    from bpsflow.files import write_bytes_atomic

    path = _parsed_idd_cache(idd)
    if path.is_file() or getattr(IDF, "idd_info", None) is None:
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(path, pickle.dumps(
            (IDF.idd_info, IDF.idd_index, IDF.block, IDF.idd_version),
            protocol=pickle.HIGHEST_PROTOCOL))
    except OSError:  # a read-only home: every process parses the IDD, as without the cache
        pass


def open_idf(path: Path, idd: Path):
    """Parse an IDF with eppy against ``idd``, with a clear error when it does not parse."""
    from eppy.modeleditor import IDF

    _set_idd(str(idd))
    try:
        idf = IDF(str(path))
    except Exception as exc:
        raise BpsflowError(f"eppy could not parse the IDF against {idd}: {exc}", source=path) from None
    _keep_parsed_idd(Path(idd))
    return idf


def open_model(model: Model, idd: Path):
    """Parse the whole model (``model.idf`` and its ``idf_objects`` snippets) with eppy.

    The text is :func:`bpsflow.simulation.idf.model_text`, the one assembly of
    the model both backends read.
    """
    from io import StringIO

    from eppy.modeleditor import IDF

    text = model_text(model)
    _set_idd(str(idd))
    try:
        idf = IDF(StringIO(text))
    except Exception as exc:
        raise BpsflowError(f"eppy could not parse the model ({describe_model(model)}) against "
                           f"{idd}: {exc}{missing_semicolon_hint(model)}") from None
    _keep_parsed_idd(Path(idd))
    return idf


@dataclass(frozen=True)
class FieldRef:
    """A resolved IDF field: object type (upper case), index among its type, field name."""

    object_type: str
    index: int
    object_name: str
    field: str


@dataclass
class ResolvedTargets:
    """Every parameter's targets, resolved against one IDF."""

    idf_fields: dict[str, list[FieldRef]] = field(default_factory=dict)
    weather: dict[str, list[str]] = field(default_factory=dict)
    boundary: dict[str, list[str]] = field(default_factory=dict)


def resolve_targets(config: Config, idf) -> ResolvedTargets:
    """Check every target against the model and resolve it to concrete fields.

    Raises
    ------
    BpsflowError
        Naming the parameter, target, IDF object and field when one does not
        exist, or when a relative/additive target is not a number.
    """
    resolved = ResolvedTargets()
    source = config.source
    for i, parameter in enumerate(config.parameters):
        for j, target in enumerate(parameter.targets):
            where = f"parameters[{i}] ({parameter.name}).targets[{j}]"
            if isinstance(target, WeatherTarget):
                resolved.weather.setdefault(parameter.name, []).append(target.weather)
            elif isinstance(target, BoundaryTarget):
                resolved.boundary.setdefault(parameter.name, []).append(target.boundary)
            else:
                refs = _resolve_idf_target(target, idf, parameter, where, source,
                                           _model_files(config))
                resolved.idf_fields.setdefault(parameter.name, []).extend(refs)
    return resolved


def _model_files(config: Config) -> str:
    return describe_model(config.model)


def _resolve_idf_target(target: IdfTarget, idf, parameter: Parameter, where: str,
                        source, idf_path: Path | str) -> list[FieldRef]:
    object_type = target.object.upper()
    if object_type not in idf.idfobjects:
        raise BpsflowError(f"{where}.object: '{target.object}' is not an EnergyPlus object type "
                           f"in the IDD", source=source)
    objects = idf.idfobjects[object_type]
    chosen = select_objects(list(range(len(objects))), target.name,
                            lambda k: object_name(objects[k]))
    if not chosen:
        names = sorted({object_name(o) for o in objects})
        raise BpsflowError(
            f"{where}: no {target.object} object named '{target.name}' in {idf_path} "
            f"(objects of that type: {names or 'none'})", source=source)
    wanted = _normalise(target.field)
    refs: list[FieldRef] = []
    for k in chosen:
        obj = objects[k]
        match = [f for f in obj.fieldnames if _normalise(f) == wanted]
        if not match:
            raise BpsflowError(
                f"{where}.field: {target.object} '{object_name(obj) or k}' has no field "
                f"'{target.field}' (its fields: {', '.join(obj.fieldnames[1:])})", source=source)
        value = obj[match[0]]
        if parameter.mode in ("relative", "additive") and field_number(value) is None:
            raise BpsflowError(
                f"{where}: field '{match[0]}' of {target.object} '{object_name(obj) or k}' "
                f"holds '{value}', not a number, so {_article(parameter.mode)} "
                f"{parameter.mode} change cannot apply", source=source)
        refs.append(FieldRef(object_type, k, object_name(obj), match[0]))
    return refs


def field_number(value) -> float | None:
    """A field's value as a number: numbers, and numbers written in a text field (a
    Schedule:Compact value such as '15.6'); None for other text."""
    if isinstance(value, (int, float)):
        return float(value)
    try:
        number = float(str(value).strip())
    except ValueError:
        return None
    return number if math.isfinite(number) else None


def _article(word: str) -> str:
    return "an" if word[:1].lower() in "aeiou" else "a"


def object_name(obj) -> str:
    """An eppy object's name: its ``Name`` field, or the first field when that is a name."""
    if "Name" in obj.fieldnames:
        return str(obj.Name)
    if len(obj.fieldnames) > 1 and obj.fieldnames[1].lower().endswith("name"):
        return str(obj[obj.fieldnames[1]])
    return ""


def _period_text(config: Config, period: Period, plan: ThermostatPlan) -> str:
    """The objects every instance of ``period`` appends: run period, setpoints, outputs."""
    first, last = period_dates(period, config.model.year)
    heating, cooling = setpoint_schedules(config, period)
    controls = [control_objects_text()] if plan.thermostats else []
    parts = [
        f"Timestep, {config.model.timesteps_per_hour};\n",
        "RunPeriod,\n  " + ",\n  ".join([
            period.name, str(first.month), str(first.day), str(first.year),
            str(last.month), str(last.day), str(last.year), "", "No", "No", "No", "Yes", "Yes",
        ]) + ";\n",
        heating, cooling, *controls,
        "Output:SQLite, Simple;\n",
    ]
    frequency = {"hourly": "Hourly", "timestep": "Timestep"}
    variables = {(o.key, o.variable, frequency[o.frequency]) for o in config.outputs.values()
                 if o.variable is not None}
    meters = {(o.meter, frequency[o.frequency]) for o in config.outputs.values()
              if o.meter is not None}
    parts += [f"Output:Variable, {key}, {variable}, {every};\n"
              for key, variable, every in sorted(variables)]
    parts += [f"Output:Meter, {meter}, {every};\n" for meter, every in sorted(meters)]
    return "\n".join(parts)


#: Objects the tool writes itself for every instance; the model's own copies are removed.
_REPLACED_TYPES = ("RUNPERIOD", "TIMESTEP", "OUTPUT:VARIABLE", "OUTPUT:METER",
                   "OUTPUT:SQLITE", "OUTPUT:TABLE:SUMMARYREPORTS", "OUTPUT:TABLE:MONTHLY")


@dataclass
class FieldSlot:
    """A field whose text each instance fills in: its nominal value and the parameters on it."""

    nominal: float | None
    parameters: list[str]


@dataclass
class Template:
    """One period's model text, cut at every field an instance fills in.

    ``pieces`` interleave with the slots: the text of an instance is
    ``pieces[0] + text[order[0]] + pieces[1] + ... + pieces[-1]``, where the
    texts are the parameter fields (``slots``) followed by the Schedule:File
    names.
    """

    pieces: list[str]
    order: list[int]
    slots: list[FieldSlot]
    schedule_slots: int
    targets: ResolvedTargets
    thermostats: ThermostatPlan


_TEMPLATES: dict[tuple[str, str, str], Template] = {}


def _template(config: Config, period_name: str, idd: str, config_key: str) -> Template:
    """The per-process template of a period (the model parsed once per process).

    ``config_key`` identifies the config (its JSON); computed once per instance.
    A miss builds every period's template from one parse of the model.
    """
    key = (config_key, period_name, idd)
    if key not in _TEMPLATES:
        if len(_TEMPLATES) > 8:
            _TEMPLATES.clear()
        for name, template in build_templates(config, Path(idd)).items():
            _TEMPLATES[(config_key, name, idd)] = template
    return _TEMPLATES[key]


def template_key(config: Config) -> str:
    """What a template depends on: the config, and the identity of the model's files."""
    stamps = []
    for path in (config.model.idf, *config.model.idf_objects):
        try:
            stat = Path(path).stat()
            stamps.append(f"{stat.st_mtime_ns}:{stat.st_size}")
        except OSError:
            stamps.append("missing")
    return config.model_dump_json() + "|" + ",".join(stamps)


def prepared_templates(config: Config, idd: Path) -> dict[str, Template]:
    """Every period's template of ``config`` (built once in this process, then cached)."""
    key = template_key(config)
    return {period.name: _template(config, period.name, str(idd), key)
            for period in config.model.periods}


def install_templates(config: Config, idd: Path, templates: dict[str, Template]) -> None:
    """Give this process templates built elsewhere, so it does not parse the model again."""
    key = template_key(config)
    for name, template in templates.items():
        _TEMPLATES.setdefault((key, name, str(idd)), template)


_SLOT = "@@bpsflow-slot-{}@@"
_SLOT_PATTERN = re.compile(r"@@bpsflow-slot-(\d+)@@")


def build_templates(config: Config, idd: Path) -> dict[str, Template]:
    """Parse the model, check the targets and cut each period's text at the instance fields.

    eppy does the parsing and the writing once for every period (they differ
    only in the objects :func:`_period_text` appends); each instance then only
    joins strings, so writing an instance costs well under a millisecond.
    """
    idf = open_model(config.model, idd)
    targets = resolve_targets(config, idf)
    plan = thermostat_plan(config, model_objects(config.model))
    for object_type in _REPLACED_TYPES:
        for obj in list(idf.idfobjects.get(object_type, [])):
            idf.removeidfobject(obj)
    # the tool's RunPeriod is the simulation: a model that ran design days only (common in
    # example files) would otherwise report nothing for it
    for control in idf.idfobjects.get("SIMULATIONCONTROL", []):
        control.Run_Simulation_for_Weather_File_Run_Periods = "Yes"
    _rewire_thermostats(idf, plan)
    slots: dict[tuple[str, int, str], FieldSlot] = {}
    for name, refs in targets.idf_fields.items():
        for ref in refs:
            obj = idf.idfobjects[ref.object_type][ref.index]
            key = (ref.object_type, ref.index, ref.field)
            if key not in slots:
                value = obj[ref.field]
                slots[key] = FieldSlot(field_number(value), [])
            slots[key].parameters.append(name)
    ordered = list(slots.items())
    for k, ((object_type, index, field_name), _) in enumerate(ordered):
        idf.idfobjects[object_type][index][field_name] = _SLOT.format(k)
    schedule_files = {o.Name.upper(): o for o in idf.idfobjects["SCHEDULE:FILE"]}
    schedule_slots = 0
    filled: set[str] = set()
    if config.model.boundary is not None:
        for surface, spec in config.model.boundary.surfaces.items():
            if spec.schedule.upper() not in schedule_files:
                raise BpsflowError(
                    f"model.boundary.surfaces.{surface}.schedule: no Schedule:File named "
                    f"'{spec.schedule}' in {_model_files(config)}", source=config.source)
            schedule_files[spec.schedule.upper()].File_Name = _SLOT.format(len(ordered) + schedule_slots)
            filled.add(spec.schedule.upper())
            schedule_slots += 1
    _check_schedule_files(config, filled)
    pieces = _SLOT_PATTERN.split(idf_text(idf) + "\n")
    templates = {}
    for period in config.model.periods:
        texts = pieces[0::2]
        texts = [*texts[:-1], texts[-1] + _period_text(config, period, plan)]
        templates[period.name] = Template(
            pieces=texts, order=[int(n) for n in pieces[1::2]],
            slots=[slot for _, slot in ordered], schedule_slots=schedule_slots,
            targets=targets, thermostats=plan)
    return templates


def idf_text(idf) -> str:
    """The IDF text of an eppy model: its values as eppy writes them, without comments.

    eppy's own ``idfstr`` looks up every field's units to write them in a
    comment, which costs seconds on a multi-zone model (quadratic in the
    fields of long objects); the values, and so the simulation, are the same.
    """
    from eppy.bunchhelpers import scientificnotation

    objects = []
    for object_type in idf.model.dtls:
        for obj in idf.idfobjects[object_type]:
            values = []
            for value in obj.obj:
                try:
                    number = int(value)
                    value = number if number == value else value
                except (TypeError, ValueError):
                    pass
                values.append(value)
            fields = [str(scientificnotation(v, width=18)) for v in values[1:]]
            objects.append(f"{values[0]},\n    " + ",\n    ".join(fields) + ";\n")
    return "\n".join(objects)


def _rewire_thermostats(idf, plan: ThermostatPlan) -> None:
    """Point the planned ``ZoneControl:Thermostat`` objects at the tool's dual setpoint.

    The model's own setpoint objects and schedules stay in the model (other
    objects may use them); only the thermostats' references change.
    """
    from bpsflow.simulation.setpoints import CONTROL_TYPE_SCHEDULE, DUAL_SETPOINT

    chosen = {name.upper() for name in plan.thermostats}
    for thermostat in idf.idfobjects["ZONECONTROL:THERMOSTAT"]:
        if thermostat.Name.upper() not in chosen:
            continue
        names = thermostat.fieldnames
        thermostat[names[3]] = CONTROL_TYPE_SCHEDULE
        thermostat[names[4]] = "ThermostatSetpoint:DualSetpoint"
        thermostat[names[5]] = DUAL_SETPOINT
        for extra in names[6:12]:
            if extra.startswith("Control_"):
                thermostat[extra] = ""


def _check_schedule_files(config: Config, filled: set[str]) -> None:
    """Every Schedule:File the instances keep must name a file that exists.

    EnergyPlus would stop with a fatal error in every instance; this names
    the schedule and the file that declares it before anything runs.
    """
    for obj in model_objects(config.model).of_type("SCHEDULE:FILE"):
        file_name = obj.get("File Name").strip()
        if obj.name.upper() not in filled and not Path(file_name).is_file():
            raise BpsflowError(f"Schedule:File '{obj.name}' (in {obj.source}): its file "
                               f"'{file_name}' does not exist", source=config.source)


@dataclass
class InstanceFiles:
    """Where an instance's inputs were written."""

    directory: Path
    idfs: dict[str, Path]
    weather: Path
    boundary: Path | None


def write_instance(config: Config, sample: dict[str, float], directory: Path,
                   idd: Path) -> InstanceFiles:
    """Write one instance's IDF per run period, plus its weather and boundary files.

    Parameters
    ----------
    config : Config
    sample : dict
        Parameter name -> sampled value (one row of ``samples.parquet``).
    directory : Path
        The instance directory (created); period IDFs go in sub-directories.
    idd : Path
        The Energy+.idd matching the model's version.
    """
    directory.mkdir(parents=True, exist_ok=True)
    config_key = template_key(config)
    first = _template(config, config.model.periods[0].name, str(idd), config_key)
    weather_errors = {
        quantity: (config.parameter(name).mode, float(sample[name]))
        for name, quantities in first.targets.weather.items() for quantity in quantities
    }
    if weather_errors:
        epw = read_epw(config.model.weather)
        weather = write_epw(epw, perturb(epw, weather_errors), directory / EPW_NAME,
                            rows=period_hours(config, n_rows=epw.n_hours))
    else:
        weather = config.model.weather
    boundary_path = None
    if config.model.boundary is not None:
        selection = {surface: int(sample[name])
                     for name, surfaces in first.targets.boundary.items() for surface in surfaces}
        sequences = read_sequences(config.run_dir.resolve() / SEQUENCES_FILE) if selection else None
        boundary_path = write_boundary_file(config.model.boundary, sequences, selection,
                                            directory / BOUNDARY_NAME)
    idfs = {}
    for period in config.model.periods:
        template = _template(config, period.name, str(idd), config_key)
        period_dir = directory / period.name
        period_dir.mkdir(exist_ok=True)
        idfs[period.name] = _write_period_idf(config, template, sample, boundary_path,
                                              period_dir / IDF_NAME)
    return InstanceFiles(directory=directory, idfs=idfs, weather=weather, boundary=boundary_path)


def load_inputs(config: Config) -> None:
    """Read (and cache in this process) the files every instance reads: weather, boundary data.

    A worker does this once while the caller still checks the model, so its
    first instance starts from cached inputs like the others.
    """
    from bpsflow.boundary import read_boundary_file

    read_epw(config.model.weather)
    boundary = config.model.boundary
    if boundary is not None:
        read_boundary_file(boundary.file, tuple(boundary.surfaces[s].column
                                                for s in boundary.surfaces))
        sequences = config.run_dir.resolve() / SEQUENCES_FILE
        if sequences.is_file():
            read_sequences(sequences)


def field_value(config: Config, slot: FieldSlot, sample: dict[str, float]) -> float:
    """The value of one field for a sample: each parameter on it applied in config order."""
    value = slot.nominal
    for name in slot.parameters:
        mode = config.parameter(name).mode
        if value is None and mode != "absolute":
            raise BpsflowError(f"parameters ({name}): its field holds no number, so a {mode} "
                               f"change cannot apply", source=config.source)
        value = apply_mode(mode, value if value is not None else 0.0, float(sample[name]))
    if value is None:
        raise BpsflowError(f"parameters ({', '.join(slot.parameters)}): no value for a field",
                           source=config.source)
    return value


def _write_period_idf(config: Config, template: Template, sample: dict[str, float],
                      boundary_path: Path | None, path: Path) -> Path:
    texts = [f"{field_value(config, slot, sample):.10g}" for slot in template.slots]
    if template.schedule_slots:
        if boundary_path is None:
            raise BpsflowError("the model's boundary Schedule:File objects need model.boundary "
                               "data, and none was written", source=config.source)
        texts += [str(boundary_path.resolve())] * template.schedule_slots
    parts = [template.pieces[0]]
    for number, piece in zip(template.order, template.pieces[1:]):
        parts += [texts[number], piece]
    return write_text_atomic(path, "".join(parts))


def check_model(config: Config, idd: Path) -> Template:
    """Parse the model and check every target and thermostat before anything runs.

    The templates stay cached in this process (:func:`prepared_templates`).
    """
    return prepared_templates(config, idd)[config.model.periods[0].name]
