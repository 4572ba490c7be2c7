"""Hydronic office case (seed chapter 4): EnergyPlus seconds per run, and the whole demo.

* ``hydronic_energyplus_seconds_single_day`` / ``_whole_period``: one EnergyPlus run of the
  prototype model over one day plus its warm-up day (the source's single-day design) and
  over the whole period of ``configs/hydronic.yaml`` (6 weeks), median of 3, each the
  instance the tool writes (its run period, timestep, setpoints and output requests).
* with ``--demo``: ``make hydronic-demo`` timed (``hydronic_demo_minutes``, goal <= 30 on
  2 cores) and its results: pooled truth coverage of the 90 % intervals over the six
  scenarios, the hourly scenarios' coverage, and each scenario's decision risks.
* with ``--truths N`` (after the demo): N - 1 more truths drawn from the priors (the central
  90 % of each, seeds 2, 3, ...), each synthesised on the room-by-room floor and calibrated
  in all six scenarios on the demo's design runs; the coverage of the 90 % intervals pooled
  over the demo's truth and these (``hydronic_truth_coverage_90_pooled``, goal 0.80-0.98,
  hourly scenarios included).
* with ``--chain-groups`` (after the demo): NUTS seconds of D-BI and D-EI with the four chains
  one after another (one XLA device), in two groups of two and all four at once (one device
  per chain), the demo's design and data (``hydronic_nuts_chain_groups``: one after another
  over the faster grouping, per scenario).
* with ``--likelihood-gradient`` (after the demo): seconds per value and gradient of H-UI's
  NUTS potential with the hand-written Woodbury gradient over JAX's through the Cholesky
  factor (``hydronic_likelihood_gradient_ratio``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import time
from datetime import date
from pathlib import Path

import pandas as pd

from benchlib import record, scratch

ROOT = Path(__file__).resolve().parents[1]
HYDRONIC_MEASURED = Path("runs") / "hydronic_baseline" / "truth" / "measured.csv"


def energyplus_seconds(first: str, last: str, warmup_days: int | None = None,
                       repeats: int = 3) -> float:
    """Median seconds of one EnergyPlus run of the model as the tool writes it.

    The instance is what ``run`` simulates (:func:`write_instance`: the tool's own
    run period, timestep, setpoint schedules and output requests, every parameter at
    its prior median) for the days ``first``..``last`` (MM-DD) and the warm-up days the
    test puts before them (:func:`bpsflow.config.window_config`), or ``warmup_days``.
    """
    import numpy as np

    from bpsflow.config import load_config, window_config
    from bpsflow.simulation.energyplus.engine import find_energyplus, idd_path, run_energyplus
    from bpsflow.simulation.energyplus.instances import write_instance

    config = load_config(ROOT / "configs" / "hydronic.yaml")
    if warmup_days is not None:
        config.model.tests = [t.model_copy(update={"warmup_days": warmup_days})
                              for t in config.model.tests]
    year = config.model.year
    (m1, d1), (m2, d2) = (map(int, first.split("-")), map(int, last.split("-")))
    window = window_config(config, date(year, m1, d1), date(year, m2, d2))
    binary = find_energyplus()
    if binary is None:
        raise SystemExit("EnergyPlus is not installed (make install)")
    median = {p.name: float(p.distribution.ppf(np.array([0.5]))[0]) for p in window.parameters}
    work = scratch("hydronic-")
    files = write_instance(window, median, work / "instance", idd_path(binary))
    seconds = []
    for k in range(repeats):
        outcome = run_energyplus(binary, next(iter(files.idfs.values())), files.weather,
                                 work / f"run{k}")
        if not outcome.ok:
            raise SystemExit(f"EnergyPlus failed: {outcome.error}")
        seconds.append(outcome.seconds)
    return statistics.median(seconds)


def demo() -> None:
    started = time.perf_counter()
    subprocess.run(["make", "hydronic-demo"], cwd=ROOT, check=True)
    record_demo((time.perf_counter() - started) / 60)


def record_demo(minutes: float) -> None:
    """Record the demo's time and what its run directory holds."""
    out = ROOT / "runs" / "hydronic_screened" / "calibration"
    table = pd.read_csv(out / "scenarios.csv")
    truth = [c for c in table.columns if c.startswith("truth_in_90:")]
    covered = table[truth].sum(axis=1)
    hourly = table["resolution"] == "hourly"
    command = "python bench/hydronic_bench.py --demo"
    record("hydronic_demo_minutes", minutes, "min", "<= 30 on 2 cores", command)
    record("hydronic_truth_coverage_90", covered.sum() / (len(truth) * len(table)), "share",
           "0.80-0.98 pooled over >= 3 truths", command, truths=1,
           per_scenario=dict(zip(table["scenario"], covered.astype(int).tolist())),
           parameters=len(truth))
    record("hydronic_truth_coverage_90_hourly", covered[hourly].sum() / (len(truth) * hourly.sum()),
           "share", "0.80-0.98", command, truths=1)
    if "rhat_max" in table:
        record("hydronic_rhat_max", float(table["rhat_max"].max()), "R-hat", "<= 1.01",
               command, per_scenario=dict(zip(table["scenario"], table["rhat_max"].tolist())),
               min_ess_per_second=dict(zip(table["scenario"],
                                           table["min_ess_per_second"].tolist())),
               mcmc_seconds=dict(zip(table["scenario"], table["mcmc_seconds"].tolist())))
    risks = {}
    for folder in sorted((out / "scenarios").iterdir()):
        decision = folder / "decision" / "supply_minus_5K" / "decision.json"
        if decision.is_file():
            rules = json.loads(decision.read_text())["rules"]
            risks[folder.name] = {r["name"]: {"p": r["underperformance_probability"],
                                              "risk": r["decision_risk"]} for r in rules}
    record("hydronic_decision_risk_max", max(v["risk"] for s in risks.values() for v in s.values()),
           "probability", "reported", command, per_scenario=risks)


def draw_truth(seed: int, path: Path) -> Path:
    """A truth file: every parameter drawn from the central 90 % of its prior (seeded)."""
    import numpy as np
    import yaml

    from bpsflow.config import load_config

    config = load_config(ROOT / "configs" / "hydronic.yaml")
    rng = np.random.default_rng(seed)
    values = {p.name: float(p.distribution.ppf(np.array([rng.uniform(0.05, 0.95)]))[0])
              for p in config.parameters}
    noise = yaml.safe_load((ROOT / "configs" / "hydronic_truth.yaml").read_text())["noise"]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump({"seed": 2017 + seed, "values": values, "noise": noise}))
    return path


def calibrate_truth(seed: int) -> Path:
    """Synthesise truth ``seed`` and calibrate the six scenarios on the demo's design runs."""
    bps = [str(ROOT / ".venv" / "bin" / "bpsflow")]
    work = ROOT / "runs" / "hydronic_truths" / f"seed{seed}"
    truth = draw_truth(seed, work / "truth.yaml")
    subprocess.run(bps + ["synth", "configs/hydronic_baseline.yaml", "--truth", str(truth),
                          "--equivalent-for", "configs/hydronic.yaml", "--out",
                          str(work / "data"), "--no-progress"], cwd=ROOT, check=True)
    out = work / "calibration"
    design = ROOT / "runs" / "hydronic_screened" / "calibration" / "design"
    if not (out / "design").exists():
        out.mkdir(parents=True, exist_ok=True)
        # hard links: the same design runs, no copy of their files
        subprocess.run(["cp", "-al", str(design), str(out / "design")], check=True)
    subprocess.run(bps + ["calibrate", "runs/hydronic_screened.yaml", "--measured",
                          str(work / "data" / "measured.csv"), "--truth",
                          str(work / "data" / "truth_equivalent.json"), "--scenarios",
                          "--out", str(out), "--no-progress", "--allow-unconverged"],
                   cwd=ROOT, check=True)
    return out


def record_pooled(folders: list[Path]) -> None:
    """Coverage of the 90 % intervals pooled over the calibrations in ``folders``."""
    tables = []
    for k, folder in enumerate(folders):
        table = pd.read_csv(folder / "scenarios.csv")
        truth = [c for c in table.columns if c.startswith("truth_in_90:")]
        tables.append(pd.DataFrame({"truth": k, "scenario": table["scenario"],
                                    "resolution": table["resolution"],
                                    "covered": table[truth].sum(axis=1),
                                    "parameters": len(truth)}))
    pooled = pd.concat(tables)
    hourly = pooled["resolution"] == "hourly"
    by_scenario = pooled.groupby("scenario")[["covered", "parameters"]].sum()
    command = f"python bench/hydronic_bench.py --truths {len(folders)}"
    record("hydronic_truth_coverage_90_pooled",
           pooled["covered"].sum() / pooled["parameters"].sum(), "share",
           "0.80-0.98 pooled over >= 3 truths", command, truths=len(folders),
           hourly=float(pooled.loc[hourly, "covered"].sum()
                        / pooled.loc[hourly, "parameters"].sum()),
           per_scenario={s: f"{int(r.covered)}/{int(r.parameters)}"
                         for s, r in by_scenario.iterrows()})


def posterior_runs(names: list[str], overrides: dict, measured_path: Path,
                   truth_path: Path | None = None):
    """Calibrate the demo's scenarios ``names`` on its design, posterior only (no re-runs).

    ``overrides`` replace ``calibration.bayes`` settings (``SECTION.KEY``: one of
    another ``calibration`` section, e.g. ``emulator.points`` or ``refinement.runs``);
    yields each scenario's run.
    """
    from bpsflow.calibration import bayes, workflow
    from bpsflow.config import load_config
    from bpsflow.measured import read_measured

    config = load_config(ROOT / "runs" / "hydronic_screened.yaml")
    settings = workflow.settings_of(config)
    sections: dict[str, dict] = {}
    for key, value in overrides.items():
        section, name = key.split(".", 1) if "." in key else ("bayes", key)
        sections.setdefault(section, {})[name] = value
    for section, update in sections.items():
        setattr(settings, section, getattr(settings, section).model_copy(update=update))
    bayes.configure_jax(settings.bayes.chains)
    measured = read_measured(measured_path, config).frame
    design = workflow.prepare_design(config, settings, ROOT / "runs" / "hydronic_screened"
                                     / "calibration" / "design", "energyplus", 2, False)
    truth = workflow.read_truth(truth_path, design.parameters) if truth_path else None
    for scenario in [s for s in settings.scenarios if s.name in names]:
        yield workflow.calibrate_scenario(config, settings, scenario, design, measured,
                                          measured_path, "bayes", scratch("posterior-"), 2,
                                          truth, show_progress=False, physical_check=False)


def nuts_seconds(scenario_name: str, parallel_chains: int) -> tuple[float, float]:
    """NUTS seconds and steps per iteration of one demo scenario with chains grouped so."""
    run = next(posterior_runs([scenario_name], {"parallel_chains": parallel_chains},
                              ROOT / HYDRONIC_MEASURED))
    return run.timings["mcmc_seconds"], float(run.posterior.num_steps.mean())


def likelihood_gradient(scenario_name: str = "H-UI") -> None:
    """Seconds per value and gradient of one hourly scenario's NUTS potential, at its start.

    The low-rank likelihood's Woodbury terms with their hand-written gradient
    (:func:`bpsflow.calibration.bayes.woodbury_terms`) against JAX differentiating
    through the Cholesky factor, on the demo's design and data, in one run.
    """
    import jax
    import jax.numpy as jnp
    import numpy as np
    import numpyro
    from jax.scipy.linalg import solve_triangular
    from numpyro.infer.util import initialize_model

    from bpsflow.calibration import bayes

    captured: dict = {}

    class Captured(Exception):
        pass

    def capture(data, settings, init=None, **_):
        captured.update(data=data, init={k: np.asarray(v)[0] for k, v in init.items()})
        raise Captured

    sample_posterior, hand = bayes.sample_posterior, bayes.woodbury_terms
    bayes.sample_posterior = capture
    try:
        next(posterior_runs([scenario_name], {}, ROOT / HYDRONIC_MEASURED))
    except Captured:
        pass
    finally:
        bayes.sample_posterior = sample_posterior
    data = captured["data"]
    arrays = bayes.model_arrays(data)

    def through_cholesky(w, scaled):
        chol = jnp.linalg.cholesky(jnp.eye(w.shape[0]) + w @ w.T)
        proj = solve_triangular(chol, w @ scaled, lower=True)
        return 2.0 * jnp.sum(jnp.log(jnp.diag(chol))) - proj @ proj

    def seconds(terms) -> tuple[float, list]:
        bayes.woodbury_terms = terms
        try:
            model = bayes.make_model(data.ard, dict(data.priors), data.lowrank, data.n_noise,
                                     data.n_discrepancy)
            info = initialize_model(jax.random.PRNGKey(0), model, model_args=(arrays,),
                                    init_strategy=numpyro.infer.init_to_value(
                                        values=captured["init"]))
            step = jax.jit(jax.value_and_grad(info.potential_fn))
            jax.block_until_ready(step(info.param_info.z))
            best = float("inf")
            for _ in range(5):
                started = time.perf_counter()
                for _ in range(100):
                    out = step(info.param_info.z)
                jax.block_until_ready(out)
                best = min(best, (time.perf_counter() - started) / 100)
            return best, jax.tree.leaves(out[1])
        finally:
            bayes.woodbury_terms = hand

    autodiff, autodiff_grad = seconds(through_cholesky)
    written, written_grad = seconds(hand)
    difference = max(float(np.max(np.abs(np.asarray(a) - np.asarray(b))))
                     for a, b in zip(autodiff_grad, written_grad))
    record("hydronic_likelihood_gradient_ratio", written / autodiff, "ratio", "< 1",
           "python bench/hydronic_bench.py --likelihood-gradient --skip-timing",
           scenario=scenario_name, hand_written_ms=written * 1e3,
           through_cholesky_ms=autodiff * 1e3, gradient_max_abs_difference=difference,
           woodbury_rows=int(data.x_inducing.shape[0] + arrays["extra_factor"].shape[1]),
           note="seconds per value and gradient of the NUTS potential at the chains' start, "
           "best of 5 x 100, the demo's design and data (after make hydronic-demo)")


def chain_groups() -> None:
    layouts = {"one_after_another_s": 1, "one_group_per_core_s": 2, "all_chains_at_once_s": 4}
    ratios, seconds = {}, {}
    for name in ("D-BI", "D-EI"):
        timed = {label: nuts_seconds(name, chains) for label, chains in layouts.items()}
        seconds[name] = {label: s for label, (s, _) in timed.items()}
        seconds[name]["steps_per_iteration"] = [steps for _, steps in timed.values()]
        ratios[name] = timed["one_after_another_s"][0] / min(
            timed["one_group_per_core_s"][0], timed["all_chains_at_once_s"][0])
    record("hydronic_nuts_chain_groups", ratios["D-BI"], "ratio",
           "< 1 above 30 observations (D-BI, 76), > 1 below (D-EI, 20)",
           "python bench/hydronic_bench.py --chain-groups --skip-timing", per_scenario=ratios,
           seconds=seconds, note="NUTS seconds with the four chains one after another / the "
           "faster of two groups of two and four at once (one XLA device per chain), 2 cores, "
           "the demo's design and data")


def emulator_fit(names: tuple[str, ...] = ("H-BI", "D-BI")) -> None:
    """Hold-out error of the emulator fitted on the whole grid (row term) vs scattered points.

    Both fits on the demo's design and data, the same training and test runs, one run;
    records each output's hold-out RMSE (standardised) and the fit seconds.
    """
    from bpsflow.calibration import workflow
    from bpsflow.config import load_config
    from bpsflow.measured import read_measured

    config = load_config(ROOT / "runs" / "hydronic_screened.yaml")
    measured_path = ROOT / HYDRONIC_MEASURED
    measured = read_measured(measured_path, config).frame
    per_scenario: dict = {}
    for fit in ("points", "grid"):
        settings = workflow.settings_of(config)
        settings.emulator = settings.emulator.model_copy(update={"fit": fit})
        design = workflow.prepare_design(config, settings, ROOT / "runs" / "hydronic_screened"
                                         / "calibration" / "design", "energyplus", 2, False)
        for scenario in [s for s in settings.scenarios if s.name in names]:
            started = time.perf_counter()
            run = workflow.calibrate_scenario(config, settings, scenario, design, measured,
                                              measured_path, "deterministic",
                                              scratch("emulator-"), 2, None,
                                              show_progress=False, physical_check=False)
            test = run.emulator.test
            per_scenario.setdefault(scenario.name, {})[fit] = {
                "heldout_rmse_standardised": {o: v["mse_standardised"] ** 0.5
                                              for o, v in test.per_output.items()},
                "fit_seconds": sum(h.fit_seconds for h in run.emulator.hypers),
                "scenario_seconds": time.perf_counter() - started}
    ratios = {name: {o: fits["grid"]["heldout_rmse_standardised"][o]
                     / fits["points"]["heldout_rmse_standardised"][o]
                     for o in fits["grid"]["heldout_rmse_standardised"]}
              for name, fits in per_scenario.items()}
    hourly = next(name for name in names if name.startswith("H"))
    record("hydronic_emulator_grid_fit_error_ratio", ratios[hourly]["heating_kwh"], "ratio",
           "< 1", "python bench/hydronic_bench.py --emulator-fit --skip-timing",
           per_scenario=per_scenario, ratios=ratios,
           note="hold-out RMSE of the emulator fitted on the whole runs x rows grid with a "
                "row term (calibration.emulator.fit: grid) / fitted on scattered points "
                f"(points), {hourly} heating; same design, data and test runs, one run")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--demo", action="store_true", help="also time make hydronic-demo")
    parser.add_argument("--truths", type=int, default=0,
                        help="pool truth coverage over this many truths (after the demo)")
    parser.add_argument("--chain-groups", action="store_true",
                        help="time NUTS with chains grouped per core vs all at once")
    parser.add_argument("--likelihood-gradient", action="store_true",
                        help="time the hourly NUTS potential's gradient (after the demo)")
    parser.add_argument("--emulator-fit", action="store_true",
                        help="emulator hold-out error, grid fit vs scattered points")
    parser.add_argument("--skip-timing", action="store_true", help="no EnergyPlus timings")
    args = parser.parse_args()
    command = "python bench/hydronic_bench.py"
    if not args.skip_timing:
        record("hydronic_energyplus_seconds_single_day",
               energyplus_seconds("03-20", "03-20", warmup_days=1), "s", "reported", command,
               note="one day plus one warm-up day (the source's single-day design), the "
                    "instance as the tool writes it")
        record("hydronic_energyplus_seconds_whole_period", energyplus_seconds("02-13", "03-26"),
               "s", "reported", command, note="the 6 weeks of configs/hydronic.yaml (42 days with the warm-up week), "
                    "the instance as the tool writes it")
    if args.demo:
        demo()
    if args.truths > 1:
        extra = [calibrate_truth(seed) for seed in range(2, args.truths + 1)]
        record_pooled([ROOT / "runs" / "hydronic_screened" / "calibration"] + extra)
    if args.chain_groups:
        chain_groups()
    if args.likelihood_gradient:
        likelihood_gradient()
    if args.emulator_fit:
        emulator_fit()


if __name__ == "__main__":
    main()
