"""Simulating a batch of instances on the surrogate: tidy hourly outputs (vectorised)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.config import Config, WeatherTarget, test_dates
from bpsflow.simulation.idf import model_objects
from bpsflow.surrogate.cell import build_cell
from bpsflow.surrogate.forcing import period_forcing
from bpsflow.surrogate.network import build_network, simulate
from bpsflow.surrogate.outputs import (
    SUPPORTED_OUTPUTS,
    check_variables,
    face_probe,
    hourly_outputs,
    resolve_outputs,
    used_outputs,
)
from bpsflow.surrogate.params import field_values, sample_columns

#: Weather quantities the surrogate has no physics for.
WEATHER_IGNORED = {"wind_direction": "the exterior convection uses wind speed only"}

__all__ = ["SUPPORTED_OUTPUTS", "WEATHER_IGNORED", "simulate_instances", "ignored_targets",
           "announce_ignored"]


class _Extra:
    """Fields read only for reporting (thermostat temperature)."""

    def __init__(self, values, wanted: bool):
        gt = "ROOMAIR:TEMPERATUREPATTERN:CONSTANTGRADIENT"
        patterns = values.idf.of_type(gt)
        if wanted and patterns:
            self.thermostat_offset = values.get(gt, patterns[0].name, "Thermostat Offset")
        else:
            self.thermostat_offset = np.zeros(values.n)


def simulate_instances(config: Config, samples: pd.DataFrame, run_dir: Path | None = None,
                       ) -> tuple[pd.DataFrame, list[str]]:
    """Tidy hourly outputs of ``samples`` (index = instance labels) and the ignored targets.

    Rows: instance, test, output, timestamp (hour-ending), value, for each
    test's whole window like :func:`bpsflow.simulation.energyplus.tidy_outputs`.
    """
    check_variables(config)
    samples = sample_columns(config, samples)
    labels = list(samples.index)
    values = field_values(config, model_objects(config.model), samples)
    cell = build_cell(config, values)
    requests = resolve_outputs(config, cell)
    extra = _Extra(values, _wants_thermostat(config))
    network = build_network(cell)
    tph = config.model.timesteps_per_hour
    integer = all(isinstance(label, (int, np.integer)) for label in labels)
    label_array = np.asarray(labels, dtype=np.int64 if integer else object)
    frames = []
    for period in config.model.periods:
        tests = config.tests_in(period.name)
        if not tests:
            continue
        forcing = period_forcing(config, cell, period, samples, run_dir)
        hours = forcing.days * 24
        wanted = [requests[o] for o in sorted({o for t in tests for o in t.outputs})]
        probe = face_probe(wanted, hours, tph)
        result = simulate(cell, network, forcing, probe=probe)
        hourly = hourly_outputs(wanted, cell, forcing, result, probe, extra.thermostat_offset)
        stamps = pd.Timestamp(forcing.first) + pd.to_timedelta(np.arange(1, hours + 1), unit="h")
        for test in tests:
            first, _, last = test_dates(test, config.model.year)
            begin = (first - forcing.first).days * 24
            end = ((last - forcing.first).days + 1) * 24
            for output in test.outputs:
                data = hourly[output][:, begin:end] * config.outputs[output].scale
                count = end - begin
                frames.append(pd.DataFrame({
                    "instance": np.repeat(label_array, count),
                    "test": test.name, "output": output,
                    "timestamp": np.tile(stamps[begin:end].to_numpy(), len(labels)),
                    "value": data.reshape(-1)}))
    tidy = pd.concat(frames, ignore_index=True)
    return tidy, ignored_targets(config, values)


def _wants_thermostat(config: Config) -> bool:
    return any(config.outputs[o].variable.strip().upper() == "ZONE THERMOSTAT AIR TEMPERATURE"
               for o in used_outputs(config))


def ignored_targets(config: Config, values=None) -> list[str]:
    """Targets of the config the surrogate has no physics for (labels with parameters)."""
    if values is None:
        samples = sample_columns(config, pd.DataFrame(index=pd.Index([0], name="instance")))
        values = field_values(config, model_objects(config.model), samples)
        build_cell(config, values)
        _Extra(values, _wants_thermostat(config))
    out = values.ignored()
    for p in config.parameters:
        for t in p.targets:
            if isinstance(t, WeatherTarget) and t.weather in WEATHER_IGNORED:
                out.append(f"weather {t.weather} ({p.name})")
    return out


def announce_ignored(ignored: list[str], announce) -> None:
    if ignored:
        announce(f"[yellow]surrogate: no physics for {len(ignored)} targeted field(s); these "
                 f"parameters do not change its outputs: {'; '.join(ignored)}[/yellow]")
