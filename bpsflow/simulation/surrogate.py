"""The surrogate backend: the bundled reduced-order model, vectorised over a chunk of instances."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from bpsflow.errors import BpsflowError
from bpsflow.simulation.backend import Batch, CheckReport
from bpsflow.simulation.model_inputs import check_model_inputs
from bpsflow.simulation.rundir import RESULT_COLUMNS, InstanceRecord
from bpsflow.simulation.target_bounds import check_sample_values
from bpsflow.surrogate.run import ignored_targets, simulate_instances
from bpsflow.surrogate.support import unsupported_features

if TYPE_CHECKING:
    from bpsflow.config import Config


class SurrogateBackend:
    """The bundled RC-network model (no EnergyPlus needed)."""

    name = "surrogate"
    vectorised = True

    def available(self, config: Config) -> bool:
        return True

    def unsupported(self, config: Config) -> list[str]:
        return unsupported_features(config)

    def check(self, config: Config) -> CheckReport:
        check_model_inputs(config)
        lacking = unsupported_features(config)
        if lacking:
            raise BpsflowError("the surrogate cannot represent this model: " + "; ".join(lacking)
                               + ". Use EnergyPlus (backend energyplus; 'make install' gets it "
                               "when it is not installed)", source=config.source)
        from bpsflow.config import BoundaryTarget, IdfTarget, WeatherTarget

        targets = [t for p in config.parameters for t in p.targets]
        ignored = ignored_targets(config)
        return CheckReport(
            backend=self.name,
            idf_fields=sum(isinstance(t, IdfTarget) for t in targets),
            weather_targets=sum(isinstance(t, WeatherTarget) for t in targets),
            boundary_targets=sum(isinstance(t, BoundaryTarget) for t in targets),
            notes=([f"the surrogate has no physics for {len(ignored)} targeted field(s): "
                    + "; ".join(ignored)] if ignored else []) + _version_notes(config))

    def check_samples(self, config: Config, samples: pd.DataFrame) -> None:
        """Refuse samples that set a field outside the IDD's bounds (before anything runs)."""
        check_sample_values(config, samples)

    def simulate(self, config: Config, samples: pd.DataFrame, workdir: Path, *,
                 keep_inputs: bool = False) -> Batch:
        started = time.perf_counter()
        tidy, _ = simulate_instances(config, samples, Path(workdir))
        per = (time.perf_counter() - started) / max(len(samples), 1)
        bad = set(tidy.loc[~np.isfinite(tidy["value"].to_numpy(dtype=float)), "instance"])
        records = [InstanceRecord(instance=int(i) if not isinstance(i, str) else -1,
                                  status="failed" if i in bad else "ok", seconds=per,
                                  simulate_seconds=per,
                                  error="non-finite outputs" if i in bad else "",
                                  backend=self.name)
                   for i in samples.index]
        if bad:
            tidy = tidy[~tidy["instance"].isin(bad)]
        return Batch(tidy=tidy[RESULT_COLUMNS], records=records)

    def write_inputs(self, config: Config, sample: dict[str, float], directory: Path
                     ) -> list[Path]:
        raise BpsflowError("the surrogate reads the model and the samples directly; it writes "
                           "no instance input files (EnergyPlus does: --backend energyplus)")


BACKEND = SurrogateBackend()


def _version_notes(config: Config) -> list[str]:
    """The IDF's EnergyPlus version when it is not 25.2: the surrogate reads any, the engine
    would not, so a later run on EnergyPlus meets it."""
    from bpsflow.simulation.energyplus import version_mismatch

    mismatch = version_mismatch(config.model)
    return [f"the surrogate reads the model as it is, but on EnergyPlus: {mismatch}"] \
        if mismatch else []
