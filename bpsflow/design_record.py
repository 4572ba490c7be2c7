"""What determined a run directory's design, recorded beside it and compared before use.

``samples.parquet`` and ``boundary_sequences.npz`` are drawn from part of the
config only: the parameters (distributions, modes, targets), the ``design``
section and the boundary-temperature settings. ``design.json`` records those
inputs, flattened to key paths, when the design is drawn. A command that
would use the run directory's samples or results compares the record with
the config in hand: a difference means finished instances were drawn (and
run) for another design, and mixing them with new ones would be a silently
wrong answer, so it is an error naming the changed key.

Not part of the design (they may change freely between commands): the
execution settings (``jobs``, ``run_dir``, ``keep_files``), the backend, the
outputs and tests, validation, calibration and diagnosis settings, and a
parameter's ``group``, ``description`` and ``provenance``.

What the instances *simulate* is recorded apart, in ``simulation.json``,
when they first run (:func:`simulation_inputs`): the model section (the
IDF, snippet and weather files by content; the tests, periods, year, time
step, thermostat zones, boundary settings), the outputs and the backend.
Finished instances of another model are never resumed, validated or mixed
with new ones: ``run`` and ``validate`` compare the record and name what
changed (:func:`require_same_simulation`).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bpsflow.errors import BpsflowError
from bpsflow.files import jsonable, read_parquet, write_json

if TYPE_CHECKING:
    from bpsflow.config import Config

DESIGN_FILE = "design.json"

#: Parameter keys that describe a parameter without changing what is drawn or simulated.
_COSMETIC = ("group", "description", "provenance")


def _digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def design_inputs(config: Config) -> dict[str, Any]:
    """The config's design inputs as ``{key path: JSON value}``.

    File paths are replaced by their content's SHA-256, so that moving a
    project folder is not a design change but editing a data file is.

    Parameters
    ----------
    config : Config

    Returns
    -------
    dict
        Key paths (``design.samples``, ``parameters.<name>.distribution``,
        ``model.boundary.file`` ...) to plain JSON values.
    """
    from bpsflow.distributions import Empirical

    design = config.design
    inputs: dict[str, Any] = {"design.method": design.method, "design.seed": design.seed}
    if design.method == "lhs":
        inputs["design.samples"] = design.samples
    else:
        inputs["design.levels"] = design.levels
        inputs["design.trajectories"] = design.trajectories
    inputs["parameters (names, in order)"] = [p.name for p in config.parameters]
    for parameter in config.parameters:
        where = f"parameters.{parameter.name}"
        distribution = parameter.distribution.model_dump(mode="json")
        if isinstance(parameter.distribution, Empirical):
            distribution.pop("file", None)
            values = np.asarray(parameter.distribution.values_, dtype=float)
            distribution["values (sha256)"] = hashlib.sha256(values.tobytes()).hexdigest()
        inputs[f"{where}.distribution"] = distribution
        inputs[f"{where}.mode"] = parameter.mode
        inputs[f"{where}.targets"] = [t.model_dump(mode="json") for t in parameter.targets]
    boundary = config.model.boundary
    if boundary is not None:
        dumped = boundary.model_dump(mode="json", exclude={"file"})
        for key, value in dumped.items():
            inputs[f"model.boundary.{key}"] = value
        inputs["model.boundary.file (sha256)"] = _digest(boundary.file)
        # The sequences cover the run periods' hours of the model year.
        inputs["model.year"] = config.model.year
        inputs["model.periods"] = [p.model_dump(mode="json") for p in config.model.periods]
    return jsonable(inputs)


def write_design_record(config: Config, run_dir: Path,
                        overrides: dict[str, Any] | None = None) -> Path:
    """Write ``design.json`` (the config's :func:`design_inputs`) into ``run_dir``.

    ``overrides`` are the design keys the command line set (``sample --samples
    8``: ``{"design.samples": 8}``); later commands take them as the run
    directory's own, so the samples drawn with them stay usable.
    """
    record: dict[str, Any] = {"inputs": design_inputs(config)}
    if overrides:
        record["overrides"] = jsonable(overrides)
    return write_json(Path(run_dir) / DESIGN_FILE, record)


def recorded_overrides(run_dir: Path) -> dict[str, Any]:
    """The design keys the command line set when the run directory's samples were drawn."""
    record = read_design_file(run_dir)
    overrides = record.get("overrides") if record is not None else None
    return overrides if isinstance(overrides, dict) else {}


def read_design_file(run_dir: Path) -> dict[str, Any] | None:
    """``design.json`` as written (``inputs`` and any ``overrides``), or None when unreadable."""
    try:
        record = json.loads((Path(run_dir) / DESIGN_FILE).read_text())
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def changed_keys(recorded: dict[str, Any], current: dict[str, Any]) -> list[str]:
    """``key: old -> new`` for every key path whose value differs (missing shown as ``-``)."""
    changes = []
    for key in list(recorded) + [k for k in current if k not in recorded]:
        old, new = recorded.get(key, "-"), current.get(key, "-")
        if old != new:
            changes += _leaf_changes(key, old, new)
    return changes


def _leaf_changes(key: str, old: Any, new: Any) -> list[str]:
    """The innermost keys that differ (``model.tests[0].setpoint_c: 30 -> 28``)."""
    if isinstance(old, dict) and isinstance(new, dict):
        return [change for k in list(old) + [k for k in new if k not in old]
                if old.get(k, "-") != new.get(k, "-")
                for change in _leaf_changes(f"{key}.{k}", old.get(k, "-"), new.get(k, "-"))]
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new) and \
            any(isinstance(v, (dict, list)) for v in old):
        return [change for i, (a, b) in enumerate(zip(old, new)) if a != b
                for change in _leaf_changes(f"{key}[{i}]", a, b)]
    return [f"{key}: {_short(old)} -> {_short(new)}"]


def _listed(changes: list[str]) -> str:
    """The first three changes, and how many more."""
    return "; ".join(changes[:3]) + (f"; and {len(changes) - 3} more" if len(changes) > 3 else "")


def _short(value: Any, limit: int = 80) -> str:
    text = json.dumps(value) if not isinstance(value, str) else value
    return text if len(text) <= limit else text[:limit - 3] + "..."


def design_changes(config: Config, run_dir: Path,
                   given: frozenset[str] = frozenset()) -> list[str] | None:
    """How the config's design differs from the one ``run_dir``'s samples were drawn with.

    A design key the command line set when the samples were drawn
    (:func:`recorded_overrides`) stands for the config's value, unless it is
    in ``given`` (set on this command line too: ``config`` already holds it).

    Returns
    -------
    list of str or None
        ``[]`` when they agree, the changed keys when they differ, None when
        the run directory holds no samples. A run directory drawn before
        ``design.json`` existed is compared by drawing the design again; when
        it matches the record is written.
    """
    from bpsflow.sampling import SAMPLES_FILE

    run_dir = Path(run_dir)
    samples_path = run_dir / SAMPLES_FILE
    if not samples_path.is_file():
        return None
    record = read_design_file(run_dir) or {}
    recorded = record.get("inputs")
    if isinstance(recorded, dict):
        # what the command line set when sampling stands for the config's value
        overrides = record.get("overrides")
        kept = {key: value for key, value in (overrides or {}).items() if key not in given} \
            if isinstance(overrides, dict) else {}
        return changed_keys(recorded, {**design_inputs(config), **kept})
    if _same_as_redrawn(config, samples_path):
        write_design_record(config, run_dir)
        return []
    return [f"{SAMPLES_FILE} differs from the design the config draws (no {DESIGN_FILE} "
            f"records what drew it)"]


def _same_as_redrawn(config: Config, samples_path: Path) -> bool:
    from bpsflow.sampling import sample

    try:
        stored = read_parquet(samples_path).set_index("instance")
        drawn = sample(config).values
    except Exception:  # unreadable samples or a design that no longer draws: not the same
        return False
    return (list(stored.columns) == list(drawn.columns) and stored.shape == drawn.shape
            and np.allclose(stored.to_numpy(dtype=float), drawn.to_numpy(dtype=float),
                            rtol=1e-12, atol=0, equal_nan=True))


def require_same_design(config: Config, run_dir: Path, command: str) -> None:
    """Raise when ``run_dir`` holds samples of another design than the config's.

    Parameters
    ----------
    config : Config
    run_dir : Path
    command : str
        The command that would use them (named in the message).

    Raises
    ------
    BpsflowError
        Naming the run directory, the changed key(s) and the two ways out.
    """
    changes = design_changes(config, run_dir)
    if not changes:
        return
    shown = _listed(changes)
    raise BpsflowError(
        f"the config's design changed since the samples in {run_dir} were drawn ({shown}); "
        f"'{command}' would mix results of the old and the new design. Draw the new design "
        f"with 'bpsflow sample CONFIG --force' (the old results are moved to "
        f"{Path(run_dir) / 'previous'}/<timestamp>), or use another --run-dir",
        source=config.source)


SIMULATION_FILE = "simulation.json"

#: Output keys that say how a value is named, read or judged, not what is simulated.
_OUTPUT_COSMETIC = ("plausible", "unit", "label", "description")


def simulation_inputs(config: Config) -> dict[str, Any]:
    """What decides the instances' outputs besides their parameter values, as key paths.

    Files (the IDF, its snippets, the weather file, the boundary data and the
    files beside the IDF that it may read, such as a ``Schedule:File``) are
    given by their content's SHA-256; ``model.backend`` and the EnergyPlus
    path are left to :func:`require_same_simulation`'s caller.
    """
    model = config.model.model_dump(mode="json", exclude={"backend", "energyplus", "idf",
                                                          "idf_objects", "weather"})
    inputs: dict[str, Any] = {f"model.{key}": value for key, value in model.items()
                              if key != "boundary"}
    if config.model.boundary is not None:
        inputs["model.boundary"] = config.model.boundary.model_dump(mode="json",
                                                                    exclude={"file"})
        inputs["model.boundary.file (sha256)"] = _digest(config.model.boundary.file)
    inputs["model.idf (sha256)"] = _digest(config.model.idf)
    inputs["model.idf_objects (sha256)"] = [_digest(p) for p in config.model.idf_objects]
    inputs["model.weather (sha256)"] = _digest(config.model.weather)
    read = _schedule_files(config)
    if read:
        inputs["Schedule:File files (sha256)"] = {p.name: _digest(p) for p in read}
    for name, output in config.outputs.items():
        inputs[f"outputs.{name}"] = output.model_dump(mode="json", exclude=set(_OUTPUT_COSMETIC))
    return jsonable(inputs)


def _schedule_files(config: Config) -> list[Path]:
    """The files the model's ``Schedule:File`` objects read (relative to the file naming them)."""
    from bpsflow.simulation.idf import model_objects

    found = set()
    for schedule in model_objects(config.model).of_type("SCHEDULE:FILE"):
        name = schedule.fields[2].strip() if len(schedule.fields) > 2 else ""
        if not name:
            continue
        base = Path(schedule.source or config.model.idf).parent
        path = Path(name) if Path(name).is_absolute() else base / name
        if path.is_file():
            found.add(path.resolve())
    return sorted(found)


def read_simulation_record(run_dir: Path) -> dict[str, Any] | None:
    """``simulation.json``'s record (``inputs``, ``backend``), or None when missing or unreadable."""
    try:
        record = json.loads((Path(run_dir) / SIMULATION_FILE).read_text())
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) and isinstance(record.get("inputs"), dict) \
        else None


def write_simulation_record(config: Config, run_dir: Path, backend: str,
                            inputs: dict[str, Any] | None = None) -> Path:
    """Record what the instances of ``run_dir`` simulate (written when the first ones run).

    ``inputs``: :func:`simulation_inputs` of ``config`` when the caller has them already.
    """
    return write_json(Path(run_dir) / SIMULATION_FILE,
                      {"inputs": inputs or simulation_inputs(config), "backend": backend})


def require_same_simulation(config: Config, run_dir: Path, command: str,
                            backend: str | None = None,
                            inputs: dict[str, Any] | None = None) -> None:
    """Raise when ``run_dir``'s finished instances simulated another model than the config's.

    Parameters
    ----------
    config : Config
    run_dir : Path
    command : str
        The command that would use them (named in the message).
    backend : str, optional
        The backend that would run more instances (``run``): instances of
        two backends are never mixed. ``validate`` passes None.

    Raises
    ------
    BpsflowError
        Naming the run directory, the changed keys and the ways out.
    """
    record = read_simulation_record(run_dir)
    if record is None:
        from bpsflow.simulation.rundir import INSTANCE_OUTPUTS

        if not any(path.is_file() for path in
                   (Path(run_dir) / "instances").glob(f"*/{INSTANCE_OUTPUTS}")):
            return
        # finished instances without a record of their model: whether they match the
        # config cannot be told, and mixing two models' results would go unseen
        state = "is damaged" if (Path(run_dir) / SIMULATION_FILE).exists() else "is missing"
        raise BpsflowError(
            f"{Path(run_dir) / SIMULATION_FILE} {state}: it records the model the finished "
            f"instances in {run_dir} simulated, so '{command}' cannot tell whether they "
            f"simulated the config's model. Run them again with 'bpsflow sample CONFIG "
            f"--force' then 'bpsflow run' (the old results are moved to "
            f"{Path(run_dir) / 'previous'}/<timestamp>), or use another --run-dir",
            source=config.source)
    changes = changed_keys(record["inputs"], inputs or simulation_inputs(config))
    if backend is not None and record.get("backend") not in (None, backend):
        changes.insert(0, f"backend: {record['backend']} -> {backend}")
    if not changes:
        return
    shown = _listed(changes)
    raise BpsflowError(
        f"the instances in {run_dir} simulated another model than the config's ({shown}); "
        f"'{command}' would "
        + ("mix their results with new ones" if command == "run"
           else "score results of the old model")
        + f". Run the new model with 'bpsflow sample CONFIG --force' then 'bpsflow run' (the "
        f"old results are moved to {Path(run_dir) / 'previous'}/<timestamp>), or use another "
        f"--run-dir", source=config.source)
