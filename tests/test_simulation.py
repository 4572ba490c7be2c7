"""The simulation layer: the ensemble loop on a toy backend, thermostats, architecture rules."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from toy_backend import ToyBackend, toy_value

from bpsflow.config import load_config
from bpsflow.errors import BpsflowError
from bpsflow.simulation import rundir
from bpsflow.simulation.backend import Backend, get_backend, register_backend
from bpsflow.simulation.ensemble import run_ensemble, simulate_samples
from bpsflow.simulation.executor import LocalExecutor
from bpsflow.simulation.idf import parse_idf_text
from bpsflow.simulation.setpoints import thermostat_plan

from conftest import ROOT, short_raw, write_config


def toy_config(tmp_path: Path, samples: int = 6):
    tmp_path.mkdir(parents=True, exist_ok=True)
    raw = short_raw(samples=samples)
    raw["model"]["boundary"] = None
    raw["parameters"] = [
        {"name": "a", "distribution": {"type": "uniform", "lower": -1.0, "upper": 1.0},
         "targets": [{"object": "Material", "name": "*", "field": "Conductivity"}]},
        {"name": "b", "distribution": {"type": "uniform", "lower": 0.0, "upper": 1.0},
         "targets": [{"object": "Material", "name": "*", "field": "Density"}]},
    ]
    return load_config(write_config(tmp_path, raw))


def design(n: int, first: float = 0.5) -> pd.DataFrame:
    return pd.DataFrame({"a": np.linspace(first, 1.0, n), "b": np.linspace(0.0, 1.0, n)},
                        index=pd.Index(range(n), name="instance"))


def test_toy_backend_meets_the_protocol():
    assert isinstance(ToyBackend(), Backend)
    register_backend(ToyBackend("toy-registered", vectorised=True))
    assert get_backend("toy-registered").vectorised
    with pytest.raises(BpsflowError, match="expected one of"):
        get_backend("no-such-backend")


@pytest.mark.parametrize("vectorised", [False, True])
def test_ensemble_outputs_equal_the_closed_form(tmp_path, vectorised):
    config = toy_config(tmp_path)
    samples = design(6)
    summary = run_ensemble(config, samples, ToyBackend(vectorised=vectorised), jobs=1,
                           show_progress=False)
    assert (summary.total, summary.ran, summary.ok, summary.failed) == (6, 6, 6, 0)
    results = rundir.read_results(config.run_dir)
    for label, row in samples.iterrows():
        mine = results[results["instance"] == label]
        expected = toy_value(row.to_numpy(), pd.DatetimeIndex(mine["timestamp"]).hour.to_numpy())
        np.testing.assert_allclose(mine["value"].to_numpy(), expected)
    manifest = rundir.read_manifest(config.run_dir)
    assert set(manifest["status"]) == {"ok"} and set(manifest["backend"]) == {"toy"}


def test_ensemble_resumes_and_isolates_failures(tmp_path):
    config = toy_config(tmp_path)
    samples = design(5, first=-0.5)     # instances 0 and 1 have a < 0: they crash
    toy = ToyBackend()
    summary = run_ensemble(config, samples, toy, jobs=1, show_progress=False)
    assert (summary.ok, summary.failed) == (3, 2)
    assert "toy crash" in summary.first_error
    manifest = rundir.read_manifest(config.run_dir).set_index("instance")
    assert manifest.loc[[0, 1], "status"].tolist() == ["failed", "failed"]
    assert set(rundir.read_results(config.run_dir)["instance"]) == {2, 3, 4}
    before = rundir.read_results(config.run_dir)
    # Resume: nothing finished runs again, failures only when asked.
    summary = run_ensemble(config, samples, toy, jobs=1, show_progress=False)
    assert (summary.ran, summary.skipped) == (0, 5)
    pd.testing.assert_frame_equal(rundir.read_results(config.run_dir), before)
    fixed = samples.copy()
    fixed.loc[[0, 1], "a"] = 0.25
    summary = run_ensemble(config, fixed, toy, jobs=1, retry_failed=True, show_progress=False)
    assert (summary.ran, summary.ok, summary.failed) == (2, 5, 0)


def test_corrupt_instance_files_are_rerun_to_the_same_results(tmp_path):
    config = toy_config(tmp_path)
    samples = design(4)
    run_ensemble(config, samples, ToyBackend(), jobs=1, show_progress=False)
    reference = rundir.read_results(config.run_dir)
    outputs = rundir.instance_dir(config.run_dir, 2) / rundir.INSTANCE_OUTPUTS
    outputs.write_bytes(outputs.read_bytes()[:40])              # truncated
    (config.run_dir / rundir.MANIFEST_FILE).write_bytes(b"")     # 0-byte manifest
    summary = run_ensemble(config, samples, ToyBackend(), jobs=1, show_progress=False)
    assert (summary.ran, summary.ok) == (1, 4)
    pd.testing.assert_frame_equal(rundir.read_results(config.run_dir), reference)


def test_a_second_run_on_a_locked_directory_refuses(tmp_path):
    config = toy_config(tmp_path)
    rundir.prepare_run_dir(config.run_dir)
    # Another process holds the lock (the same process may nest it: a command and its loop).
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from bpsflow.simulation.rundir import RunLock\n"
         f"with RunLock({str(config.run_dir)!r}):\n print('held', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(BpsflowError, match=f"in use by another bpsflow process.*pid {holder.pid}"):
            run_ensemble(config, design(2), ToyBackend(), jobs=1, show_progress=False)
    finally:
        holder.kill()
        holder.wait()
    # The kernel released the killed holder's lock: its left-over file is taken over.
    assert (config.run_dir / rundir.LOCK_FILE).exists()
    summary = run_ensemble(config, design(2), ToyBackend(), jobs=1, show_progress=False)
    assert summary.ok == 2 and not (config.run_dir / rundir.LOCK_FILE).exists()
    # So is a lock file naming a process that no longer exists.
    (config.run_dir / rundir.LOCK_FILE).write_text(f"{os.uname().nodename} 999999999 then\n")
    summary = run_ensemble(config, design(2), ToyBackend(), jobs=1, show_progress=False)
    assert summary.ok == 2 and not (config.run_dir / rundir.LOCK_FILE).exists()


def test_parallel_executor_gives_the_serial_results(tmp_path):
    serial_cfg = toy_config(tmp_path / "serial")
    parallel_cfg = toy_config(tmp_path / "parallel")
    samples = design(6)
    run_ensemble(serial_cfg, samples, ToyBackend(), jobs=1, show_progress=False)
    run_ensemble(parallel_cfg, samples, ToyBackend(), executor=LocalExecutor(2),
                 show_progress=False)
    key = ["instance", "test", "output", "timestamp"]
    a = rundir.read_results(serial_cfg.run_dir).sort_values(key).reset_index(drop=True)
    b = rundir.read_results(parallel_cfg.run_dir).sort_values(key).reset_index(drop=True)
    pd.testing.assert_frame_equal(a, b)


def test_simulate_samples_raises_naming_the_failed_instance(tmp_path):
    config = toy_config(tmp_path)
    for vectorised in (False, True):
        with pytest.raises(BpsflowError, match="instance 0.*toy crash|toy crash"):
            simulate_samples(config, design(3, first=-1.0), tmp_path / f"w{vectorised}",
                             ToyBackend(vectorised=vectorised))


# Thermostats ---------------------------------------------------------------

TWO_ZONES = """
Zone, East; Zone, West; Zone, Store;
ZoneList, Offices, East, West;
ZoneHVAC:EquipmentConnections, East, East Equipment, EastIn, , EastAir, EastOut;
ZoneHVAC:EquipmentList, East Equipment, SequentialLoad, ZoneHVAC:IdealLoadsAirSystem, East Ideal, 1, 1, , ;
ZoneHVAC:EquipmentConnections, West, West Equipment, WestIn, , WestAir, WestOut;
ZoneHVAC:EquipmentList, West Equipment, SequentialLoad, ZoneHVAC:IdealLoadsAirSystem, West Ideal, 1, 1, , ;
ZoneControl:Thermostat, Office Thermostat, Offices, Office Control, ThermostatSetpoint:SingleHeating, Office Heat;
"""


def plan_for(tmp_path, idf_text: str, **model_keys):
    raw = short_raw()
    raw["model"].update(model_keys)
    config = load_config(write_config(tmp_path, raw))
    return config, thermostat_plan(config, parse_idf_text(idf_text))


def test_thermostats_of_a_zone_list_are_found_with_their_equipment(tmp_path):
    _, plan = plan_for(tmp_path, TWO_ZONES)
    assert plan.thermostats == ["Office Thermostat"]
    assert plan.zones == {"East": ["ZoneHVAC:IdealLoadsAirSystem 'East Ideal'"],
                          "West": ["ZoneHVAC:IdealLoadsAirSystem 'West Ideal'"]}
    _, plan = plan_for(tmp_path, TWO_ZONES, thermostat_zones=["west"])
    assert list(plan.zones) == ["West"]


def test_setpoints_that_cannot_take_effect_are_errors(tmp_path):
    no_thermostat = TWO_ZONES.replace("ZoneControl:Thermostat", "! ZoneControl:Thermostat")
    with pytest.raises(BpsflowError, match="no ZoneControl:Thermostat.*could not take effect"):
        plan_for(tmp_path, no_thermostat)
    with pytest.raises(BpsflowError, match="Store have no ZoneControl:Thermostat"):
        plan_for(tmp_path, TWO_ZONES, thermostat_zones=["East", "Store"])
    with pytest.raises(BpsflowError, match=r"thermostat_zones\[0\]: 'Attic' is not a zone"):
        plan_for(tmp_path, TWO_ZONES, thermostat_zones=["Attic"])
    unequipped = TWO_ZONES + "ZoneControl:Thermostat, Store Thermostat, Store, C, " \
                             "ThermostatSetpoint:SingleHeating, H;"
    with pytest.raises(BpsflowError, match="Store have no conditioning equipment"):
        plan_for(tmp_path, unequipped)


def test_free_floating_tests_need_no_thermostat(tmp_path):
    raw = short_raw()
    for test in raw["model"]["tests"]:
        test.update(mode="free_floating", setpoint_c=None, setback_c=None)
    config = load_config(write_config(tmp_path, raw))
    plan = thermostat_plan(config, parse_idf_text("Zone, Lonely;"))
    assert plan.thermostats == []


# Architecture --------------------------------------------------------------

PACKAGE = ROOT / "bpsflow"


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """Every bpsflow module a file imports, at module level or inside functions.

    ``from package import submodule`` is an edge to the submodule (the package
    itself is already being imported by then); ``from module import name`` an
    edge to the module.
    """
    modules = {_module_name(p) for p in PACKAGE.rglob("*.py")}
    tree = ast.parse(path.read_text())
    module = _module_name(path)
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names if alias.name.startswith("bpsflow")}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                name = f"{base}.{node.module}" if node.module else base
            else:
                name = node.module or ""
            if name.startswith("bpsflow"):
                submodules = {f"{name}.{alias.name}" for alias in node.names} & modules
                found |= submodules
                if len(submodules) < len(node.names):
                    found.add(name)
    return found


def test_the_import_graph_has_no_cycle_counting_imports_inside_functions():
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph = {name: {m for m in _imports(path) if m in modules and m != name}
             for name, path in modules.items()}
    state: dict[str, int] = {}
    cycles: list[str] = []

    def visit(node: str, trail: list[str]) -> None:
        state[node] = 1
        for child in sorted(graph[node]):
            if state.get(child) == 1:
                cycle = trail[trail.index(child):] + [child] if child in trail else [node, child]
                cycles.append(" -> ".join(cycle))
            if child not in state:
                visit(child, trail + [child])
        state[node] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [name])
    assert cycles == []
    # every module was visited, and the graph really holds edges (the parser read imports)
    assert set(state) == set(modules) and all(v == 2 for v in state.values())
    assert any(m.startswith("bpsflow.simulation") for m in graph["bpsflow.diagnosis.workflow"])


def test_callers_never_import_a_concrete_backend_and_backends_never_import_the_loop():
    concrete = ("bpsflow.simulation.energyplus", "bpsflow.simulation.surrogate")
    for path in PACKAGE.rglob("*.py"):
        name = _module_name(path)
        imports = _imports(path)
        if not name.startswith("bpsflow.simulation"):
            assert not {m for m in imports if m.startswith(concrete)} - {
                "bpsflow.simulation.energyplus.engine"} or name == "bpsflow.cli", name
        if name.startswith(concrete) or name.startswith("bpsflow.surrogate"):
            assert "bpsflow.simulation.ensemble" not in imports, name
    cli_backends = {m for m in _imports(PACKAGE / "cli.py") if m.startswith(concrete)}
    # The CLI's `instances` command writes EnergyPlus inputs for inspection, nothing else.
    assert cli_backends <= {"bpsflow.simulation.energyplus.engine",
                            "bpsflow.simulation.energyplus.instances"}


def test_no_backend_branches_outside_the_simulation_layer():
    pattern = re.compile(r"backend\s*[!=]=")
    offenders = [f"{p}:{i}" for p in PACKAGE.rglob("*.py")
                 if "simulation" not in p.parts
                 for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert offenders == []


SHIPPED_NAMES = re.compile(r"\b(Cell|SouthWall|EastWall|SouthWindow|AlwaysOn|"
                           r"HeatingSetpointSchedule|CoolingSetpointSchedule|CellIdealLoads)\b")


def _code_strings(path: Path) -> list[tuple[int, str]]:
    """String constants of a module that are not docstrings."""
    tree = ast.parse(path.read_text())
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                docstrings.add(id(body[0].value))
    return [(node.lineno, node.value) for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str)
            and id(node) not in docstrings]


def test_no_code_path_or_package_data_names_a_shipped_models_objects():
    offenders = [f"{p.relative_to(ROOT)}:{line}: {text!r}"
                 for p in PACKAGE.rglob("*.py") for line, text in _code_strings(p)
                 if SHIPPED_NAMES.search(text)]
    offenders += [f"{p.relative_to(ROOT)}: {m.group(0)}" for p in PACKAGE.rglob("*.idf")
                  for m in [SHIPPED_NAMES.search(p.read_text())] if m]
    assert offenders == []


# The test seam: a workflow above the layer on the toy backend ---------------


def test_morris_on_the_toy_backend_recovers_the_closed_form_effects(tmp_path):
    """The toy output is ``a + 2 b + sin(hour)``: each elementary effect is its weight times
    the value step per unit step of the design, the same in every trajectory (sigma 0)."""
    from bpsflow import sensitivity as morris

    config = toy_config(tmp_path)
    config.parameters[0].distribution = config.parameters[0].distribution.model_copy(
        update={"lower": 0.0, "upper": 2.0})
    config.parameters[1].distribution = config.parameters[1].distribution.model_copy(
        update={"upper": 3.0})
    toy = ToyBackend("toy-morris")
    register_backend(toy)
    mcfg = morris.morris_config(config, trajectories=4, levels=4)
    samples = morris.prepare_morris(mcfg, toy.name, announce=lambda _: None)
    summary = run_ensemble(mcfg, samples, get_backend(toy.name), jobs=1, show_progress=False)
    assert summary.ok == len(samples) == 4 * 3
    results = rundir.read_results(mcfg.run_dir)
    responses = morris.window_responses(mcfg, results, None, "raw")
    unit = morris.read_unit_design(mcfg.run_dir)
    varied = morris.varied_parameters(mcfg)
    indices = morris.morris_indices(varied, unit[[p.name for p in varied]].to_numpy(),
                                    responses.reindex(unit.index), mcfg.design.levels)
    mu_star = indices.set_index(["response", "parameter"])["mu_star"]
    delta = mcfg.design.levels / (2 * (mcfg.design.levels - 1))      # SALib's unit step
    for weight, name in ((1.0, "a"), (2.0, "b")):
        # one Morris step moves a uniform input by the same amount everywhere
        trajectories = samples[name].to_numpy().reshape(mcfg.design.trajectories, -1)
        steps = np.abs(np.diff(trajectories, axis=1)).ravel()
        value_step = steps[steps > 0]
        assert np.ptp(value_step) < 1e-12
        for response in responses.columns:
            assert mu_star[(response, name)] == pytest.approx(
                weight * value_step[0] / delta, rel=1e-9)
    np.testing.assert_allclose(indices["sigma"].to_numpy(), 0.0, atol=1e-9)


def test_every_module_imports():
    import importlib
    import pkgutil

    import bpsflow

    names = [module.name for module in pkgutil.walk_packages(bpsflow.__path__, "bpsflow.")]
    imported = [importlib.import_module(name) for name in names]
    assert [module.__name__ for module in imported] == names
    # the walk found the whole package, not an empty or partial path
    assert {"bpsflow.cli", "bpsflow.diagnosis.workflow", "bpsflow.simulation.ensemble"} <= set(names)
