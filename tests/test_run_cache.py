"""Finished simulations are kept by content: the same call again runs nothing, a changed input runs."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bpsflow.simulation.run_cache import RunCache, model_digest

sys.path.insert(0, str(Path(__file__).parent))


def _samples(values: list[float], config=None) -> pd.DataFrame:
    """Rows at the config's nominal values, the glazing's dirt correction set to ``values``."""
    nominal = {p.name: float(p.distribution.nominal) for p in config.parameters} if config else {}
    return pd.DataFrame([{**nominal, "glazing_dirt_correction": v} for v in values],
                        index=pd.RangeIndex(len(values), name="instance"))


def test_keys_follow_every_value_and_a_stored_output_comes_back(tmp_path):
    hours = pd.date_range("2025-11-01 01:00", periods=5, freq="h")
    keys = RunCache.keys("d", "heating_power_w", hours, _samples([0.9, 0.9, 0.9000001]))
    assert keys[0] == keys[1] and keys[2] != keys[0]
    assert RunCache.keys("e", "heating_power_w", hours, _samples([0.9]))[0] != keys[0]
    assert RunCache.keys("d", "other_w", hours, _samples([0.9]))[0] != keys[0]
    assert RunCache.keys("d", "heating_power_w", hours[1:], _samples([0.9]))[0] != keys[0]
    cache = RunCache(tmp_path / "cache")
    assert cache.get(keys[0], 5) is None
    cache.put(keys[0], np.arange(5.0))
    np.testing.assert_array_equal(cache.get(keys[0], 5), np.arange(5.0))
    assert cache.get(keys[0], 6) is None                 # other hours: not this output
    (tmp_path / "cache" / f"{keys[2]}.npy").write_bytes(b"\x93NUMPY half")
    assert cache.get(keys[2], 5) is None                 # a damaged file runs again
    assert not list((tmp_path / "cache").glob("*.partial.npy"))


@pytest.mark.energyplus
def test_energyplus_outputs_are_reused_on_a_rerun_and_rerun_when_the_model_changes(
        tmp_path, monkeypatch):
    from test_diagnosis import base_config

    from bpsflow.config import load_config
    from bpsflow.diagnosis.fitting import output_simulator
    from bpsflow.simulation import ensemble

    config = load_config(base_config(tmp_path / "base", days=4, backend="energyplus"))
    hours = pd.date_range("2025-11-04 01:00", "2025-11-05 00:00", freq="h")

    def simulator():
        return output_simulator(config, "heating_power_w", hours, backend="energyplus",
                                work_dir=tmp_path / "runs" / "fit", jobs=2,
                                sequences_dir=tmp_path / "runs", on_failure="record")

    first = simulator()(_samples([0.8, 1.0], config))
    assert np.isfinite(first).all() and not np.allclose(first[0], first[1])
    assert len(list((tmp_path / "runs" / "cache").glob("*.npy"))) == 2

    ran = []
    real = ensemble.simulate_batch

    def counting(config, samples, *args, **kwargs):
        ran.append(len(samples))
        return real(config, samples, *args, **kwargs)

    monkeypatch.setattr(ensemble, "simulate_batch", counting)
    again = simulator()(_samples([1.0, 0.8, 0.9], config))
    assert ran == [1]                                    # only the new value ran
    np.testing.assert_array_equal(again[[1, 0]], first)

    digest = model_digest(config, "energyplus", tmp_path / "runs")
    edited = tmp_path / "model.idf"
    edited.write_text(Path(config.model.idf).read_text() + "\n! edited\n")
    config.model.idf = edited
    assert model_digest(config, "energyplus", tmp_path / "runs") != digest
    simulator()(_samples([0.8], config))
    assert ran == [1, 1]                                 # a changed model runs again


def test_a_file_rewritten_within_one_clock_tick_is_read_again(tmp_path):
    """Same path, same size, same modification time, other bytes: a new digest."""
    import os

    from bpsflow.simulation.run_cache import file_digest

    path = tmp_path / "schedule.csv"
    path.write_text("1,0\n")
    first = file_digest(path)
    stamp = path.stat().st_mtime_ns
    path.write_text("0,1\n")
    os.utime(path, ns=(stamp, stamp))
    assert file_digest(path) != first
