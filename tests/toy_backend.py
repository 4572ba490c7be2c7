"""A cheap backend implementing the simulation protocol, for fast tests of the layers above it.

Its model is a closed form: every output of every test is, at each hour-ending
timestamp ``t`` of the test's window, ``sum_k value_k * (1 + k) + sin(hour(t))``
over the sample's parameter values in config order. A sample whose first
parameter is negative "crashes" (a failed instance with an error), so failure
handling can be checked.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.config import Config, test_dates
from bpsflow.simulation.backend import Batch, CheckReport
from bpsflow.simulation.rundir import RESULT_COLUMNS, InstanceRecord


def toy_value(values: np.ndarray, hours: np.ndarray) -> np.ndarray:
    """The toy model's output at the given hours of day for one sample's values."""
    weights = 1.0 + np.arange(len(values))
    return float(np.dot(values, weights)) + np.sin(hours.astype(float))


class ToyBackend:
    """Closed-form outputs; vectorised or one instance per task."""

    def __init__(self, name: str = "toy", vectorised: bool = False):
        self.name = name
        self.vectorised = vectorised
        self.calls = 0

    def available(self, config: Config) -> bool:
        return True

    def unsupported(self, config: Config) -> list[str]:
        return []

    def check(self, config: Config) -> CheckReport:
        return CheckReport(backend=self.name)

    def write_inputs(self, config: Config, sample: dict[str, float], directory: Path
                     ) -> list[Path]:
        return []

    def simulate(self, config: Config, samples: pd.DataFrame, workdir: Path, *,
                 keep_inputs: bool = False) -> Batch:
        self.calls += 1
        names = [p.name for p in config.parameters]
        frames, records = [], []
        for label, row in samples.iterrows():
            values = np.array([float(row[n]) for n in names])
            if len(values) and values[0] < 0:
                records.append(InstanceRecord(instance=int(label), status="failed", seconds=0.0,
                                              error=f"toy crash: {names[0]} = {values[0]:g} < 0"))
                continue
            for test in config.model.tests:
                first, _, last = test_dates(test, config.model.year)
                stamps = pd.date_range(pd.Timestamp(first) + pd.Timedelta(hours=1),
                                       pd.Timestamp(last) + pd.Timedelta(days=1), freq="h")
                for output in test.outputs:
                    frames.append(pd.DataFrame({
                        "instance": int(label), "test": test.name, "output": output,
                        "timestamp": stamps, "value": toy_value(values, stamps.hour.to_numpy())}))
            records.append(InstanceRecord(instance=int(label), status="ok", seconds=0.0))
        tidy = pd.concat(frames, ignore_index=True)[RESULT_COLUMNS] if frames else \
            pd.DataFrame(columns=RESULT_COLUMNS)
        return Batch(tidy=tidy, records=records)
