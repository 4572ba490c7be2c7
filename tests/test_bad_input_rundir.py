"""Bad-input battery: run-directory safety, names and paths (issue 13).

Every case goes through the real CLI and asserts the exit code, a message
naming the file or key, no traceback, and that what the run directory held
before is byte-identical afterwards. The concurrency and kill cases start
real ``bpsflow`` processes.
"""

from __future__ import annotations

import ast
import copy
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import yaml
from battery import all_text, assert_clean_error, assert_ok, assert_unchanged, invoke, snapshot

from bpsflow.errors import BpsflowError
from bpsflow.files import inside
from bpsflow.simulation import rundir

from conftest import ROOT, short_raw, write_config

KEY = ["instance", "test", "output", "timestamp"]


def surrogate_raw(samples: int = 4) -> dict:
    raw = short_raw(samples=samples)
    raw["model"]["backend"] = "surrogate"
    raw["execution"] = {"jobs": 1}
    return raw


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> tuple[Path, dict]:
    """A finished surrogate run (config path) and its results, shared read-only."""
    folder = tmp_path_factory.mktemp("finished")
    config = write_config(folder, surrogate_raw())
    truth = folder / "truth.yaml"
    truth.write_text("seed: 1\nvalues: {}\n")
    assert_ok(invoke("run", config, "--no-progress"))
    assert_ok(invoke("synth", config, "--truth", truth))
    assert_ok(invoke("validate", config, "--measured", folder / "run" / "truth" / "measured.csv"))
    return config, snapshot(folder / "run")


def copy_run(finished, tmp_path: Path, **changes) -> Path:
    """A copy of the finished run in ``tmp_path`` (config rewritten, ``changes`` per section)."""
    import shutil

    config, _ = finished
    shutil.copytree(config.parent / "run", tmp_path / "run")
    raw = yaml.safe_load(config.read_text())
    for section, values in changes.items():
        raw[section] = {**raw.get(section, {}), **values}
    raw["execution"]["run_dir"] = str(tmp_path / "run")
    path = tmp_path / "case.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def sorted_results(run_dir: Path) -> pd.DataFrame:
    return pd.read_parquet(run_dir / "results.parquet").sort_values(KEY).reset_index(drop=True)


# 1. Options are validated before anything is touched; --force moves, never deletes ----------

@pytest.mark.parametrize("samples", ["0", "-3"])
def test_sample_with_a_bad_count_and_force_touches_nothing(finished, tmp_path, samples):
    config = copy_run(finished, tmp_path)
    before = snapshot(tmp_path / "run")
    result = invoke("sample", config, "--samples", samples, "--force")
    assert_clean_error(result, "design.samples", str(config))
    assert_unchanged(before, tmp_path / "run")
    assert snapshot(tmp_path / "run") == before          # nothing added either


def test_sample_force_moves_the_old_design_aside(finished, tmp_path):
    config = copy_run(finished, tmp_path)
    before = snapshot(tmp_path / "run")
    text = assert_ok(invoke("sample", config, "--samples", "5", "--force"))
    moved = sorted((tmp_path / "run" / "previous").iterdir())
    assert len(moved) == 1 and str(moved[0]) in "".join(text.split())   # says where
    kept = {name: digest for name, digest in before.items() if name.startswith("truth/")}
    assert kept                                          # measurements do not depend on the design
    assert_unchanged(kept, tmp_path / "run")
    assert_unchanged({name: digest for name, digest in before.items() if name not in kept},
                     moved[0])                           # every other old file, byte-identical
    assert len(pd.read_parquet(tmp_path / "run" / "samples.parquet")) == 5
    assert not (tmp_path / "run" / "results.parquet").exists()


# 2. A design change without --force is an error, never a mix -------------------------------

def test_resample_with_another_design_is_refused_naming_the_key(finished, tmp_path):
    config = copy_run(finished, tmp_path, design={"seed": 7})
    before = snapshot(tmp_path / "run")
    assert_clean_error(invoke("sample", config), "design.seed: 1 -> 7", "--force")
    assert_unchanged(before, tmp_path / "run")


@pytest.mark.parametrize("command", ["run", "validate"])
def test_commands_reading_results_refuse_a_changed_design(finished, tmp_path, command):
    config = copy_run(finished, tmp_path, design={"samples": 6})
    measured = tmp_path / "measured.csv"
    measured.write_text("timestamp,heating_power_w\n2025-12-06 01:00,100\n")
    before = snapshot(tmp_path / "run")
    args = ["--measured", measured] if command == "validate" else ["--no-progress"]
    result = invoke(command, config, *args)
    assert_clean_error(result, "design.samples: 4 -> 6", "--force", str(tmp_path / "run"))
    assert_unchanged(before, tmp_path / "run")


def test_a_changed_distribution_is_a_design_change(finished, tmp_path):
    config = copy_run(finished, tmp_path)
    raw = yaml.safe_load(config.read_text())
    raw["parameters"][0]["distribution"]["std"] = 0.07
    config.write_text(yaml.safe_dump(raw, sort_keys=False))
    before = snapshot(tmp_path / "run")
    name = raw["parameters"][0]["name"]
    assert_clean_error(invoke("run", config, "--no-progress"), f"parameters.{name}.distribution")
    assert_unchanged(before, tmp_path / "run")


def test_execution_settings_are_not_a_design_change(finished, tmp_path):
    config = copy_run(finished, tmp_path, execution={"jobs": 2})
    raw = yaml.safe_load(config.read_text())
    raw["parameters"][0]["description"] = "a new description"
    raw["parameters"][0]["group"] = "regrouped"
    config.write_text(yaml.safe_dump(raw, sort_keys=False))
    reference = sorted_results(tmp_path / "run")
    text = assert_ok(invoke("run", config, "--no-progress"))
    assert "ran 0, skipped 4 finished" in " ".join(text.split())
    pd.testing.assert_frame_equal(sorted_results(tmp_path / "run"), reference)


# 3. Concurrency: one command per run directory ---------------------------------------------

def _hold_lock(run_dir: Path) -> subprocess.Popen:
    holder = subprocess.Popen(
        [sys.executable, "-c", "import time; from bpsflow.simulation.rundir import RunLock\n"
         f"with RunLock({str(run_dir)!r}):\n print('held', flush=True); time.sleep(120)"],
        stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert holder.stdout.readline().strip() == "held"
    return holder


def test_every_writing_command_refuses_a_locked_run_dir(finished, tmp_path):
    config = copy_run(finished, tmp_path)
    measured = tmp_path / "measured.csv"
    measured.write_text("timestamp,heating_power_w\n2025-12-06 01:00,100\n")
    truth = tmp_path / "truth.yaml"
    truth.write_text("seed: 1\nvalues: {}\n")
    commands = {
        "sample": [], "run": ["--no-progress"], "instances": ["-i", "0"],
        "synth": ["--truth", truth], "validate": ["--measured", measured],
        "sensitivity": ["--response", "raw", "--no-progress"],
        "refine": ["--detailed", tmp_path / "detailed.csv"],
        "calibrate": ["--measured", measured, "--no-progress"],
        "diagnose": ["--measured", measured, "--no-progress"]}
    holder = _hold_lock(tmp_path / "run")
    try:
        before = snapshot(tmp_path / "run")
        for command, args in commands.items():
            result = invoke(command, config, *args)
            assert_clean_error(result, "in use by another bpsflow process", f"pid {holder.pid}",
                               str(tmp_path / "run"))
        assert_unchanged(before, tmp_path / "run")
        assert snapshot(tmp_path / "run") == before
    finally:
        holder.kill()
        holder.wait()


def test_a_stale_lock_of_a_dead_process_is_taken_over(finished, tmp_path):
    config = copy_run(finished, tmp_path)
    (tmp_path / "run" / rundir.LOCK_FILE).write_text(f"{os.uname().nodename} 999999999 then\n")
    assert_ok(invoke("run", config, "--no-progress"))
    assert not (tmp_path / "run" / rundir.LOCK_FILE).exists()


def _bpsflow(*args: object, cwd: Path) -> subprocess.Popen:
    """A real ``bpsflow`` process running this checkout's code."""
    return subprocess.Popen([sys.executable, "-c", "from bpsflow.cli import main; main()",
                             *[str(a) for a in args]], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "200"})


@pytest.mark.slow
def test_two_real_runs_on_one_directory(tmp_path):
    raw = surrogate_raw(samples=400)
    raw["execution"] = {"jobs": 2}
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    shared = write_config(tmp_path / "a", raw)
    alone = write_config(tmp_path / "b", raw)
    first = _bpsflow("run", shared, "--no-progress", cwd=tmp_path)
    # the second starts once the first holds the lock (a fixed wait raced the first's start-up)
    lock = tmp_path / "a" / "run" / rundir.LOCK_FILE
    deadline = time.monotonic() + 60
    while not lock.exists() and first.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    second = _bpsflow("run", shared, "--no-progress", cwd=tmp_path)
    second_out, _ = second.communicate(timeout=300)
    first_out, _ = first.communicate(timeout=300)
    assert first.returncode == 0, first_out
    assert second.returncode == 2, second_out
    flat = " ".join(second_out.split())
    assert "in use by another bpsflow process" in flat and f"pid {first.pid}" in flat, second_out
    assert "Traceback" not in second_out
    undisturbed = _bpsflow("run", alone, "--no-progress", cwd=tmp_path)
    assert undisturbed.wait(timeout=300) == 0
    pd.testing.assert_frame_equal(sorted_results(tmp_path / "a" / "run"),
                                  sorted_results(tmp_path / "b" / "run"))
    manifest = rundir.read_manifest(tmp_path / "a" / "run")
    assert len(manifest) == 400 and set(manifest["status"]) == {"ok"}


# 4. Corrupt or partial files count as unfinished ---------------------------------------------

@pytest.mark.parametrize("damage", ["truncated_outputs", "empty_manifest", "truncated_results",
                                    "empty_outputs"])
def test_corrupt_files_are_rerun_to_the_uninterrupted_results(finished, tmp_path, damage):
    config = copy_run(finished, tmp_path)
    run = tmp_path / "run"
    reference = sorted_results(run)
    outputs = rundir.instance_dir(run, 2) / rundir.INSTANCE_OUTPUTS
    if damage == "truncated_outputs":
        outputs.write_bytes(outputs.read_bytes()[:100])
    elif damage == "empty_outputs":
        outputs.write_bytes(b"")
    elif damage == "empty_manifest":
        (run / rundir.MANIFEST_FILE).write_bytes(b"")
    else:
        (run / rundir.RESULTS_FILE).write_bytes((run / rundir.RESULTS_FILE).read_bytes()[:200])
    text = assert_ok(invoke("run", config, "--no-progress"))
    rerun = 1 if "outputs" in damage else 0
    assert f"ran {rerun}, skipped {4 - rerun} finished" in " ".join(text.split())
    pd.testing.assert_frame_equal(sorted_results(run), reference)   # row by row
    assert set(rundir.read_manifest(run)["status"]) == {"ok"}


# 5. Every result file is written atomically --------------------------------------------------

_WRITERS = {"to_csv", "to_parquet", "savefig", "write_text", "write_bytes", "savez",
            "savez_compressed", "dump"}


def test_no_module_writes_a_file_except_through_the_atomic_helpers():
    """Every write in bpsflow/ goes through bpsflow.files (temporary file + rename)."""
    offenders = []
    for path in sorted((ROOT / "bpsflow").rglob("*.py")):
        if path.name == "files.py" and path.parent.name == "bpsflow":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) \
                    and node.func.attr in _WRITERS and not node.args[:0] \
                    and _writes_a_file(node):
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} .{node.func.attr}")
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                    and node.func.id == "open" and _mode(node) in {"w", "wb", "a", "x"}:
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} open(..., 'w')")
    assert not offenders, "non-atomic writes:\n" + "\n".join(offenders)


def _writes_a_file(node: ast.Call) -> bool:
    # frame.to_csv() with no target returns text; json.dumps is not json.dump
    if node.func.attr == "to_csv":
        return bool(node.args) or any(k.arg == "path_or_buf" for k in node.keywords)
    if node.func.attr == "dump":
        return isinstance(node.func.value, ast.Name) and node.func.value.id in {"json", "yaml",
                                                                               "pickle"} \
            and len(node.args) > 1
    return True


def _mode(node: ast.Call) -> str:
    mode = node.args[1] if len(node.args) > 1 else next(
        (k.value for k in node.keywords if k.arg == "mode"), None)
    return mode.value if isinstance(mode, ast.Constant) else "r"


def test_a_crash_while_writing_keeps_the_previous_results(finished, tmp_path, monkeypatch):
    """validate dies half-way through writing validation.csv (disk full): the previous
    validation files are still there, whole, and no temporary file is left."""
    config = copy_run(finished, tmp_path)
    run = tmp_path / "run"
    before = snapshot(run)
    assert "validation.csv" in before and "validation.json" in before
    real = pd.DataFrame.to_csv

    def disk_full(frame, path_or_buf=None, *args, **kwargs):
        if path_or_buf is None:
            return real(frame, None, *args, **kwargs)
        path_or_buf.write(real(frame, None, *args, **kwargs)[:20].encode())
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(pd.DataFrame, "to_csv", disk_full)
    result = invoke("validate", config, "--measured", run / "truth" / "measured.csv")
    assert_clean_error(result, "No space left on device")
    assert_unchanged(before, run)
    assert not [p for p in run.rglob(".*.tmp")]


# 7. The run directory is a file, or not writable ---------------------------------------------

def test_a_run_dir_that_is_a_file_is_refused(tmp_path):
    blocker = tmp_path / "run"
    blocker.write_text("not a folder\n")
    config = write_config(tmp_path, surrogate_raw())
    for command in ("sample", "run"):
        result = invoke(command, config, "--no-progress") if command == "run" else \
            invoke(command, config)
        assert_clean_error(result, "execution.run_dir", str(blocker), "is a file; expected a folder")
    assert blocker.read_text() == "not a folder\n"
    nested = invoke("run", config, "--run-dir", blocker / "below", "--no-progress")
    assert_clean_error(nested, str(blocker), "is a file; expected a folder")


def test_a_blank_run_dir_option_is_refused_not_read_as_the_current_folder(tmp_path,
                                                                          monkeypatch):
    config = write_config(tmp_path, surrogate_raw())
    work = tmp_path / "cwd"
    work.mkdir()
    monkeypatch.chdir(work)
    for blank in ("", "  "):
        for command in ("sample", "run"):
            arguments = ("--run-dir", blank, "--no-progress") if command == "run" \
                else ("--run-dir", blank)
            assert_clean_error(invoke(command, config, *arguments), "--run-dir",
                               "expected a folder")
    assert not list(work.iterdir())          # nothing written into the current folder


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_run_dir_is_refused(finished, tmp_path):
    config = copy_run(finished, tmp_path)
    before = snapshot(tmp_path / "run")
    os.chmod(tmp_path / "run", 0o555)
    try:
        assert_clean_error(invoke("run", config, "--no-progress"), str(tmp_path / "run"),
                           "not writable")
    finally:
        os.chmod(tmp_path / "run", 0o755)
    assert_unchanged(before, tmp_path / "run")


def test_a_run_dir_without_write_permission_is_refused(finished, tmp_path, monkeypatch):
    """As root (CI containers) permissions are not enforced: the check is what is tested."""
    config = copy_run(finished, tmp_path)
    before = snapshot(tmp_path / "run")
    real = os.access
    monkeypatch.setattr(rundir.os, "access", lambda path, mode, **kw: False
                        if Path(path) == tmp_path / "run" else real(path, mode, **kw))
    for command in ("run", "sample", "validate"):
        args = {"run": ["--no-progress"], "sample": ["--force"],
                "validate": ["--measured", tmp_path / "run" / "truth" / "measured.csv"]}[command]
        assert_clean_error(invoke(command, config, *args), "execution.run_dir",
                           str(tmp_path / "run"), "is not writable; expected a folder")
    assert snapshot(tmp_path / "run") == before


# 8. Names and paths ---------------------------------------------------------------------------

HOSTILE = ["../x", "a/b", "/abs", "..", ".", "-x", "a\\b", "a\x00b", "a\nb", "x\n", ""]


def _renamed(raw: dict, where: str, name: str) -> tuple[dict, str]:
    raw = copy.deepcopy(raw)
    if where == "output":
        raw["outputs"][name] = raw["outputs"].pop("heating_power_w")
        raw["model"]["tests"][0]["outputs"] = [name]
        return raw, "outputs"
    if where == "test":
        raw["model"]["tests"][0]["name"] = name
        return raw, "model.tests[0]"
    if where == "period":
        raw["model"]["periods"][0]["name"] = name
        for test in raw["model"]["tests"]:
            test["period"] = name
        return raw, "model.periods[0]"
    if where == "parameter":
        raw["parameters"][0]["name"] = name
        return raw, "parameters[0]"
    raw["calibration"] = {"scenarios": [{"name": name, "outputs": ["heating_power_w"]}]}
    return raw, "calibration.scenarios[0]"


@pytest.mark.parametrize("where", ["output", "test", "period", "parameter", "scenario"])
def test_hostile_names_are_refused_naming_the_key(tmp_path, where):
    for i, name in enumerate(HOSTILE):
        raw, key = _renamed(surrogate_raw(), where, name)
        folder = tmp_path / f"case{i}"
        folder.mkdir()
        config = write_config(folder, raw)
        result = invoke("check", config)
        assert_clean_error(result, key, str(config))
        assert "expected letters, digits" in " ".join(all_text(result).split()), (name, where)


def test_inside_refuses_any_escape(tmp_path):
    root = tmp_path / "run"
    root.mkdir()
    assert inside(root, "figures", "band_a_b.png") == root / "figures" / "band_a_b.png"
    for name in ["../../x.png", "/abs.png", "a/../../../b", "x\n.png", "a\x00b"]:
        with pytest.raises(BpsflowError, match="refusing to write"):
            inside(root, "figures", "..", name) if name.startswith("../") else \
                inside(root, name)
    (root / "link").symlink_to(tmp_path)
    with pytest.raises(BpsflowError, match="outside"):
        inside(root, "link", "escaped.png")


def test_run_and_sensitivity_write_nothing_outside_the_run_dir(tmp_path):
    raw = surrogate_raw()
    raw["design"].update(levels=4, trajectories=2)
    (tmp_path / "project").mkdir()
    config = write_config(tmp_path / "project", raw)
    before = snapshot(tmp_path)
    assert_ok(invoke("run", config, "--no-progress"))
    assert_ok(invoke("sensitivity", config, "--response", "raw", "--no-progress"))
    after = snapshot(tmp_path)
    new = [name for name in after if name not in before]
    outside = [name for name in new if not name.startswith("project/run/")]
    assert not outside, outside
    assert any(name.startswith("project/run/morris/figures/") for name in new)
    assert all(before[name] == after[name] for name in before)


# 9. Every instance fails: the failure summary, never a traceback -----------------------------

#: Every instance fails on the surrogate: a conductivity 1e200 times too high gives
#: non-finite temperatures.
FAILING_PARAMETER = {
    "name": "south_wall_insulation_conductivity", "mode": "relative",
    "distribution": {"type": "uniform", "lower": 1e200, "upper": 1e201},
    "targets": [{"object": "Material", "name": "SouthWallInsulation", "field": "Conductivity"}]}


@pytest.fixture(scope="module")
def all_failing(tmp_path_factory) -> tuple[Path, Path, Path]:
    """A config every instance of which fails, measured data of a healthy twin, a truth file.

    Twelve days of the shipped calibration example (enough for calibrate and diagnose to
    reach their runs), small designs.
    """
    folder = tmp_path_factory.mktemp("all_failing")
    raw = {"extends": str(ROOT / "configs" / "calibration.yaml"),
           "model": {"periods": [{"name": "cal", "start": "11-08", "end": "11-19"}],
                     "tests": [{"name": "H", "period": "cal", "start": "11-08", "days": 12,
                                "warmup_days": 2, "mode": "heating", "setpoint_c": 30.0,
                                "outputs": ["heating_power_w", "zone_air_temperature_c"]}]},
           "design": {"method": "lhs", "samples": 4, "seed": 1, "levels": 4, "trajectories": 2},
           "calibration": {"outputs": ["heating_power_w"], "resolution": "daily",
                           "holdout_days": 3, "design": {"runs": 20, "seed": 1},
                           "emulator": {"points": 100}, "bayes": {"chains": 1, "warmup": 20,
                                                                  "samples": 20},
                           "deterministic": {"starts": 1}, "posterior_runs": 4,
                           "scenarios": []}}
    truth = folder / "truth.yaml"
    truth.write_text("seed: 1\nvalues: {}\n")
    healthy = write_config(folder, raw, "healthy.yaml")
    assert_ok(invoke("synth", healthy, "--truth", truth))
    measured = folder / "measured.csv"
    measured.write_bytes((folder / "run" / "truth" / "measured.csv").read_bytes())
    (folder / "failing").mkdir()
    failing = write_config(folder / "failing", {**raw, "parameters": [FAILING_PARAMETER]})
    return failing, measured, truth


@pytest.mark.parametrize("command", ["run", "synth", "sensitivity", "calibrate", "diagnose",
                                     "validate"])
def test_a_run_where_every_instance_fails_ends_with_the_failure_summary(all_failing, command):
    config, measured, truth = all_failing
    args = {"run": ["--no-progress"], "synth": ["--truth", truth],
            "sensitivity": ["--response", "raw", "--no-progress"],
            "calibrate": ["--measured", measured, "--no-progress"],
            "diagnose": ["--measured", measured, "--no-progress"],
            "validate": ["--measured", measured]}[command]
    if command == "validate":
        # the failed run first, here: xdist may give the "run" case to another worker
        invoke("run", config, "--no-progress")
    result = invoke(command, config, *args)
    text = all_text(result)
    assert "no types given" not in text and "internal error" not in text, text
    if command == "validate":    # after the failed run: no results to validate
        assert_clean_error(result, "heating_power_w")
    elif command == "run":
        assert_clean_error(result, "all 4 instances failed", "non-finite outputs",
                           "manifest.parquet", code=1)
    else:
        assert_clean_error(result, "failed", "non-finite outputs")


# 6. Worker processes die with their parent (EnergyPlus) --------------------------------------

def _process_table() -> dict[int, int]:
    """pid -> parent pid of every process (Linux /proc)."""
    table = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            fields = stat.rsplit(")", 1)[1].split()
            if fields[0] != "Z":                     # a zombie no longer runs
                table[int(entry.name)] = int(fields[1])
    return table


def _descendants(pid: int) -> set[int]:
    table, found, frontier = _process_table(), set(), {pid}
    while frontier:
        frontier = {child for child, parent in table.items() if parent in frontier} - found
        found |= frontier
    return found


def _mtimes(folder: Path) -> dict[str, int]:
    return {str(p): p.stat().st_mtime_ns for p in folder.rglob("*") if p.exists()}


@pytest.mark.energyplus
@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="parent-death signal is Linux")
def test_sigkill_leaves_no_orphan_and_resumes_to_the_same_results(tmp_path):
    raw = short_raw(samples=6)
    raw["execution"] = {"jobs": 2}
    (tmp_path / "killed").mkdir()
    (tmp_path / "alone").mkdir()
    killed = write_config(tmp_path / "killed", raw)
    alone = write_config(tmp_path / "alone", raw)
    run = tmp_path / "killed" / "run"
    process = _bpsflow("run", killed, "--jobs", "2", "--no-progress", cwd=tmp_path)
    family: set[int] = set()
    deadline = time.time() + 600
    while time.time() < deadline:
        family |= _descendants(process.pid)
        if len(list(run.glob("instances/*/outputs.parquet"))) >= 2 or process.poll() is not None:
            break
        time.sleep(0.1)
    assert process.poll() is None, "the run finished before it could be killed"
    family |= _descendants(process.pid)
    assert len(family) >= 2, "no worker processes seen"
    os.kill(process.pid, signal.SIGKILL)             # the process, not its group
    process.wait()
    survivors = family
    for _ in range(50):
        survivors = family & set(_process_table())
        if not survivors:
            break
        time.sleep(0.1)
    for orphan in survivors:                         # do not leave them to other tests
        os.kill(orphan, signal.SIGKILL)
    assert not survivors, f"orphaned processes still run: {sorted(survivors)}"
    frozen = _mtimes(run)
    time.sleep(3)
    assert _mtimes(run) == frozen, "something still writes into the run directory"
    resumed = _bpsflow("run", killed, "--jobs", "2", "--no-progress", cwd=tmp_path)
    out, _ = resumed.communicate(timeout=900)
    assert resumed.returncode == 0, out
    assert "skipped" in out and "Traceback" not in out
    reference = _bpsflow("run", alone, "--jobs", "2", "--no-progress", cwd=tmp_path)
    assert reference.wait(timeout=900) == 0
    pd.testing.assert_frame_equal(sorted_results(run), sorted_results(tmp_path / "alone" / "run"))


def test_a_damaged_result_file_is_named_and_nothing_else_changes(tmp_path):
    """A samples.parquet overwritten after bpsflow wrote it is bad input, not a defect:
    the message names the file and says what to do; the other files stay as they were."""
    config = write_config(tmp_path, surrogate_raw())
    assert_ok(invoke("sample", config))
    run_dir = tmp_path / "run"
    (run_dir / "samples.parquet").write_text("garbage\n")
    before = snapshot(run_dir)
    assert_clean_error(invoke("run", config, "--no-progress"), "samples.parquet",
                       "not a readable parquet file")
    assert_unchanged(before, run_dir)


def test_scores_over_a_partial_ensemble_come_with_a_note(tmp_path):
    """A failed instance never stops the others, but validate must say the ensemble is
    smaller than designed (it once scored 5 of 6 without a word)."""
    records = {i: rundir.InstanceRecord(instance=i, status="ok" if i != 3 else "failed",
                                        seconds=1.0) for i in range(6)}
    rundir.write_manifest(tmp_path, records)
    results = pd.DataFrame({"instance": [0, 1, 2, 4, 5], "test": "t", "output": "o",
                            "timestamp": pd.Timestamp("2025-01-01"), "value": 1.0})
    note = rundir.ensemble_gap_note(tmp_path, results)
    assert note is not None and "5 of 6" in note and "instance(s) 3" in note
    assert rundir.ensemble_gap_note(tmp_path, pd.concat(
        [results, results.assign(instance=3)])) is not None      # 3 is still a failure
    records[3] = rundir.InstanceRecord(instance=3, status="ok", seconds=1.0)
    rundir.write_manifest(tmp_path, records)
    assert rundir.ensemble_gap_note(tmp_path, pd.concat(
        [results, results.assign(instance=3)])) is None
    # an interrupted run: the manifest holds what finished, the design drew more
    pd.DataFrame({"instance": range(10), "x": 0.0}).to_parquet(tmp_path / "samples.parquet")
    note = rundir.ensemble_gap_note(tmp_path, pd.concat([results, results.assign(instance=3)]))
    assert note is not None and "6 of 10" in note and "4 not run" in note
    rundir.write_manifest(tmp_path, {})
    assert "6 of 10" in rundir.ensemble_gap_note(tmp_path, pd.concat(
        [results, results.assign(instance=3)]))


@pytest.mark.parametrize("script, needle", [
    ("echo 'engine: out of licences'\nexit 3\n", "exit code 3"),
    ("kill -9 $$\n", "killed by signal SIGKILL"),
])
def test_an_engine_that_dies_is_recorded_with_how_it_ended(tmp_path, script, needle):
    """An EnergyPlus that dies before writing eplusout.err leaves its exit status, signal
    and last output in the failure record, not only 'no eplusout.err was written'."""
    from bpsflow.simulation.energyplus.engine import run_energyplus

    binary = tmp_path / "energyplus"
    binary.write_text("#!/bin/sh\n" + script)
    binary.chmod(0o755)
    outcome = run_energyplus(binary, tmp_path / "in.idf", tmp_path / "w.epw", tmp_path / "out")
    assert not outcome.ok
    assert needle in outcome.error and "wrote no eplusout.err" in outcome.error
    if "licences" in script:
        assert "out of licences" in outcome.error


def test_refine_never_writes_its_config_over_the_one_given(tmp_path):
    """--refined-config naming the config (or a base) is refused before anything is read."""
    config = write_config(tmp_path, short_raw())
    before = config.read_text()
    result = invoke("refine", config, "--detailed", tmp_path / "nowhere.csv",
                    "--refined-config", config)
    assert_clean_error(result, "--refined-config", "is the config given")
    assert config.read_text() == before
    mine = tmp_path / "mine.yaml"
    mine.write_text("a: 1\n")
    result = invoke("refine", config, "--detailed", tmp_path / "nowhere.csv",
                    "--refined-config", mine)
    assert_clean_error(result, "--refined-config", "not a refined config bpsflow wrote")
    assert mine.read_text() == "a: 1\n"


def test_finished_instances_of_another_model_are_never_resumed_or_scored(tmp_path):
    """An edited IDF or test setpoint after a run: run and validate refuse (exit 2, naming
    the change) instead of skipping or scoring the old model's results; sample --force
    moves them aside and the new model runs."""
    idf = tmp_path / "model.idf"
    shutil.copy(ROOT / "sample_idf" / "flexlab_x3b.idf", idf)
    raw = short_raw()
    raw["model"]["backend"] = "surrogate"
    raw["model"]["idf"] = str(idf)
    config = write_config(tmp_path, raw)
    assert_ok(invoke("run", config, "--no-progress"))
    truth = tmp_path / "truth.yaml"
    truth.write_text("seed: 3\nvalues: {}\n")
    assert_ok(invoke("synth", config, "--truth", truth))
    measured = tmp_path / "run" / "truth" / "measured.csv"
    before = snapshot(tmp_path / "run")

    changed = copy.deepcopy(raw)
    changed["model"]["tests"][0]["setpoint_c"] = 22.0
    (tmp_path / "setpoint").mkdir()
    setpoint = write_config(tmp_path / "setpoint", changed)
    run_dir = tmp_path / "run"
    for command in (["run", setpoint, "--run-dir", run_dir, "--no-progress"],
                    ["validate", setpoint, "--run-dir", run_dir, "--measured", measured]):
        assert_clean_error(invoke(*command), "simulated another model", "model.tests",
                           "sample CONFIG --force")
    assert_unchanged(before, run_dir)
    # without a readable record of the model, finished instances are never mixed with new ones
    record = run_dir / "simulation.json"
    saved = record.read_bytes()
    for state, damage in (("is missing", None), ("is damaged", b"{")):
        record.unlink(missing_ok=True)
        if damage is not None:
            record.write_bytes(damage)
        assert_clean_error(invoke("run", setpoint, "--run-dir", run_dir, "--no-progress"),
                           f"simulation.json {state}", "sample CONFIG --force")
    record.write_bytes(saved)
    assert_unchanged(before, run_dir)

    idf.write_text(idf.read_text() + "\n! edited after the run\n")
    assert_clean_error(invoke("run", config, "--no-progress"), "model.idf (sha256)")
    assert_ok(invoke("sample", config, "--force"))
    text = assert_ok(invoke("run", config, "--no-progress"))
    assert "ran 3, skipped 0" in " ".join(text.split())
    assert list((run_dir / "previous").glob("*/simulation.json"))


def test_synth_again_keeps_the_earlier_synthetic_data(tmp_path):
    raw = short_raw()
    raw["model"]["backend"] = "surrogate"
    config = write_config(tmp_path, raw)
    truths = []
    for seed in (3, 4):
        truth = tmp_path / f"truth{seed}.yaml"
        truth.write_text(f"seed: {seed}\nvalues: {{}}\n")
        truths.append(truth)
    assert_ok(invoke("synth", config, "--truth", truths[0]))
    folder = tmp_path / "run" / "truth"
    first = (folder / "measured.csv").read_text()
    text = assert_ok(invoke("synth", config, "--truth", truths[1]))
    assert "moved to" in " ".join(text.split())
    kept = list((folder / "previous").glob("*/measured.csv"))
    assert len(kept) == 1 and kept[0].read_text() == first
    assert (folder / "measured.csv").read_text() != first


def test_refusals_of_instances_and_validate_leave_no_folder_or_file_behind(finished, tmp_path):
    """An unknown --instance used to leave an empty inspect/ folder, and validate wrote
    validation.json before finding that its figures folder was a file."""
    config = copy_run(finished, tmp_path)
    run = tmp_path / "run"
    assert_clean_error(invoke("instances", config, "-i", "0", "-i", "-1"), "--instance -1")
    assert not (run / "inspect").exists()
    import shutil

    figures = run / "figures"
    shutil.rmtree(figures)
    figures.write_text("not a folder")
    (run / "validation.json").unlink()
    assert_clean_error(invoke("validate", config, "--measured", run / "truth" / "measured.csv"),
                       "is a file")
    assert not (run / "validation.json").exists()


def test_a_blank_outputs_option_is_refused(finished, tmp_path):
    config = copy_run(finished, tmp_path)
    result = invoke("calibrate", config, "--measured", tmp_path / "run" / "truth" / "measured.csv",
                    "--outputs", "")
    assert_clean_error(result, "--outputs ''", "comma-separated output names")


@pytest.mark.energyplus
def test_a_hung_engine_is_stopped_and_the_others_still_run(tmp_path):
    """An engine that never returns held run forever; execution.run_timeout_s stops it and
    records the instance as failed with the key to change, the others being recorded too."""
    from bpsflow.simulation.energyplus.engine import find_energyplus, idd_path

    real = find_energyplus()
    assert real is not None
    (tmp_path / "Energy+.idd").symlink_to(idd_path(real))
    binary = tmp_path / "energyplus"
    binary.write_text('#!/bin/sh\ncase "$PWD" in\n  *000000*) exec sleep 600 ;;\n'
                      '  *) echo "engine: failing on purpose"; exit 3 ;;\nesac\n')
    binary.chmod(0o755)
    raw = short_raw(samples=3)
    raw["model"]["backend"] = "energyplus"
    raw["model"]["energyplus"] = str(binary)
    raw["execution"] = {"jobs": 2, "run_timeout_s": 3}
    config = write_config(tmp_path, raw)
    started = time.monotonic()
    result = invoke("run", config, "--no-progress")
    assert time.monotonic() - started < 120
    assert result.exit_code != 0 and "Traceback" not in result.output
    assert (tmp_path / "run" / "manifest.parquet").is_file(), result.output
    manifest = pd.read_parquet(tmp_path / "run" / "manifest.parquet").set_index("instance")
    assert "stopped after 3 s (execution.run_timeout_s)" in manifest.loc[0, "error"]
    assert manifest.loc[[1, 2], "error"].str.contains("exit code 3").all()


def test_a_design_drawn_with_command_line_options_is_the_run_dirs_own(tmp_path):
    """'sample --samples 3' then 'run' was refused (design.samples: 3 -> 4, and run has no
    --samples): the options are recorded and stand for the config's value later."""
    config = write_config(tmp_path, surrogate_raw(samples=4))
    assert_ok(invoke("sample", config, "--samples", "3"))
    assert_ok(invoke("run", config, "--no-progress"))
    assert pd.read_parquet(tmp_path / "run" / "results.parquet")["instance"].nunique() == 3
    kept = invoke("sample", config)
    assert_ok(kept)
    assert "design.samples 3" in " ".join(kept.output.split())
    assert_clean_error(invoke("sample", config, "--samples", "5"), "design.samples: 3 -> 5")


def test_an_invalid_ensemble_of_other_definitions_or_designs_is_refused(finished, tmp_path):
    """An invalid ensemble with outputs scaled 0.001, or a Morris folder, was scored as
    invalid predictions (type II risk 0, reduced risk 0.9) without a word."""
    import json

    config = copy_run(finished, tmp_path)
    run = tmp_path / "run"
    measured = run / "truth" / "measured.csv"
    scaled = tmp_path / "scaled"
    shutil.copytree(run, scaled)
    record = json.loads((scaled / "simulation.json").read_text())
    output = next(k for k in record["inputs"] if k.startswith("outputs."))
    record["inputs"][output]["scale"] = 0.001
    (scaled / "simulation.json").write_text(json.dumps(record))
    before = snapshot(run)
    assert_clean_error(invoke("validate", config, "--measured", measured, "--invalid", scaled),
                       "--invalid", f"{output}.scale: 0.001 -> 1")
    morris = tmp_path / "morris"
    shutil.copytree(run, morris)
    (morris / "morris_design.json").write_text("{}")
    assert_clean_error(invoke("validate", config, "--measured", measured, "--invalid", morris),
                       "--invalid", "its design is morris")
    assert_unchanged(before, run)
    same = shutil.copytree(run, tmp_path / "same")   # the same definitions: accepted
    assert_ok(invoke("validate", config, "--measured", measured, "--invalid", same))
