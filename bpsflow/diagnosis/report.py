"""Writing a diagnosis: ``diagnosis.json`` (DESIGN.md §8), ``diagnosis.md``, figures, tables.

Figures (PNG, ``figures/``), after seed §1.1.1.1:

* ``signature_outdoor_temperature.png`` — the calibration signature
  (measured − predicted, in % of the mean measured value) against outdoor air
  temperature, hourly points and binned means;
* ``residual_heatmap.png`` — mean residual per hour of day × day of week;
* ``residual_vs_<driver>.png`` — residual against the strongest driver;
* ``residual_acf.png`` — the residuals' autocorrelation with the white-noise band;
* ``heldout.png`` — measured vs base and final model on the held-out block.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.diagnosis.drivers import DRIVER_UNITS
from bpsflow.diagnosis.workflow import Diagnosis, settings_of
from bpsflow.files import inside, save_figure, write_csv, write_text_atomic

JSON_FILE = "diagnosis.json"
MARKDOWN_FILE = "diagnosis.md"
RESIDUALS_FILE = "residuals.csv"
#: What a diagnosis writes in its folder (an earlier diagnosis's are moved aside first).
REPORT_FILES = (JSON_FILE, MARKDOWN_FILE, RESIDUALS_FILE, "figures")


def untried_reason(d: Diagnosis) -> str | None:
    """Why no candidate extension was tried for a ``model_form`` verdict (None if one was).

    Either the extensions are switched off (``diagnosis.extensions: []``) or
    none of the allowed ones answers the significant drivers (e.g. a measured
    column no extension stands for).
    """
    if d.verdict != "model_form" or d.extensions or d.cause.get("extension"):
        return None
    allowed = list(settings_of(d.base.config).extensions)
    if not allowed:
        return "the candidate extensions are switched off (diagnosis.extensions is empty)"
    return (f"none of diagnosis.extensions ({', '.join(allowed)}) answers the significant "
            f"drivers")


def _not_accepted(entry: dict) -> str:
    pruning = entry.get("pruning")
    if entry.get("pruned") and pruning:
        return (f"pruned (beside the later causes: p = {pruning['p_value']:.2g}, out-of-fold "
                f"CV(RMSE) {pruning['cvrmse_with']:.2%} with, {pruning['cvrmse_without']:.2%} "
                f"without)")
    return "no"


def cause_summary(d: Diagnosis) -> str:
    """The cause's one sentence.

    The workflow's sentence, except for a ``model_form`` verdict for which no
    candidate extension was tried: "no candidate extension improved the
    held-out accuracy" would claim a test that never ran, so it says that
    none was tried, and why (:func:`untried_reason`).
    """
    reason = untried_reason(d)
    if reason is None:
        return d.cause.get("summary", "")
    return (f"The residuals follow {d.cause.get('driver')} and no plausible change of an "
            f"existing parameter explains them; no candidate extension was tried: {reason}.")


def diagnosis_record(d: Diagnosis) -> dict:
    """The ``diagnosis.json`` content: the DESIGN.md §8 keys first, then details."""
    first = d.rounds[0] if d.rounds else {"drivers": []}
    return {
        "verdict": d.verdict,
        "cause": {**{k: d.cause.get(k) for k in ("driver", "parameter", "extension")},
                  "summary": cause_summary(d),
                  **{k: d.cause[k] for k in ("confidence", "runner_up", "unexplained")
                     if d.cause.get(k) is not None}},
        "drivers": first["drivers"],
        "extensions": [{"name": e["name"], "fitted": e["fitted"], "heldout": e["heldout"],
                        "accepted": bool(e.get("accepted", False)),
                        **{k: v for k, v in e.items()
                           if k not in ("name", "fitted", "heldout", "accepted")}}
                       for e in d.extensions],
        "gain": d.gain,
        "output": d.output,
        "backend": d.backend,
        "hours": {"calibration": int(d.calibration.sum()), "heldout": int((~d.calibration).sum()),
                  "first": str(d.timestamps[0]), "last": str(d.timestamps[-1]),
                  "heldout_first": str(d.timestamps[~d.calibration][0])
                  if (~d.calibration).any() else None},
        "scorecard": {"base": d.scorecard, "final": d.final_scores},
        "fitted_parameters": {"base": d.base.fit.named, "final": d.final.fit.named},
        "parameter_check": d.parameter_check,
        "parameter_fit": d.parameter_fit,
        "rounds": d.rounds,
        "round_limit_reached": d.round_limit_reached,
        "seconds": d.seconds,
        "seconds_per_step": d.timings,
        "notes": d.notes,
    }


def write_diagnosis(d: Diagnosis, out_dir: Path) -> dict[str, Path]:
    """Write JSON, residual table, figures and the markdown report; return their paths.

    ``d.cause["summary"]`` is set to :func:`cause_summary`, so that whoever
    prints it after this says what the files say.
    """
    out_dir = Path(out_dir)
    d.cause["summary"] = cause_summary(d)
    figures = out_dir / "figures"
    figures.mkdir(parents=True, exist_ok=True)
    record = diagnosis_record(d)
    paths = {"json": out_dir / JSON_FILE, "markdown": out_dir / MARKDOWN_FILE,
             "residuals": out_dir / RESIDUALS_FILE}
    write_text_atomic(paths["json"], _dumps(record))
    write_csv(residuals_table(d), paths["residuals"])
    try:
        paths.update(write_figures(d, figures))
    except Exception as exc:  # diagnosis.json is written; a figure never takes the report down
        d.notes.append(f"the figures could not all be drawn: {type(exc).__name__}: {exc}")
        write_text_atomic(paths["json"], _dumps(diagnosis_record(d)))
    write_text_atomic(paths["markdown"], markdown(d, record, {k: v.relative_to(out_dir)
                                                            for k, v in paths.items()
                                                            if v.suffix == ".png"}))
    return paths


def _dumps(record: dict) -> str:
    """Strict JSON: a non-finite number (the objective of a fit that did not run) is null."""
    def finite(value):
        if isinstance(value, dict):
            return {k: finite(v) for k, v in value.items()}
        if isinstance(value, np.ndarray):
            value = value.tolist()
        if isinstance(value, (list, tuple)):
            return [finite(v) for v in value]
        if isinstance(value, (float, np.floating)) and not np.isfinite(value):
            return None
        return value
    return json.dumps(finite(record), indent=2, default=_jsonable, allow_nan=False)


def _jsonable(value):
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def residuals_table(d: Diagnosis) -> pd.DataFrame:
    """Hourly measured, base and final predictions, residuals, the block and the drivers."""
    frame = pd.DataFrame({"measured": d.measured, "base_prediction": d.base.fit.prediction,
                          "final_prediction": d.final.fit.prediction,
                          "base_residual": d.measured - d.base.fit.prediction,
                          "final_residual": d.measured - d.final.fit.prediction,
                          "block": np.where(d.calibration, "calibration", "heldout")},
                         index=d.timestamps)
    frame.index.name = "timestamp"
    return frame.join(d.drivers)


def write_figures(d: Diagnosis, figures: Path) -> dict[str, Path]:
    """The diagnostic figures of the base model's calibration residuals (see module notes)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bpsflow.diagnosis.structure import autocorrelation

    cal = d.calibration
    residual = (d.measured - d.base.fit.prediction)[cal]
    stamps = d.timestamps[cal]
    drivers = d.drivers[cal]
    out: dict[str, Path] = {}

    mean = float(np.mean(d.measured[cal])) or 1.0
    signature = residual / mean * 100
    fig, ax = plt.subplots(figsize=(6, 4))
    outdoor = drivers["outdoor_air_temperature"].to_numpy()
    ax.scatter(outdoor, signature, s=4, alpha=0.35, color="tab:blue", label="hourly")
    _binned(ax, outdoor, signature)
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xlabel("outdoor air temperature (°C)")
    ax.set_ylabel(f"(measured − predicted) / mean {d.output} (%)")
    ax.set_title("calibration signature")
    ax.legend()
    out["signature"] = _save(fig, figures / "signature_outdoor_temperature.png")

    start = stamps - pd.Timedelta(hours=1)
    table = (pd.DataFrame({"r": residual, "day": start.day_of_week, "hour": start.hour})
             .pivot_table(index="day", columns="hour", values="r", aggfunc="mean")
             .reindex(index=range(7), columns=range(24)))
    fig, ax = plt.subplots(figsize=(9, 3.5))
    bound = float(np.nanmax(np.abs(table.to_numpy()))) or 1.0
    image = ax.imshow(table.to_numpy(), aspect="auto", cmap="RdBu_r", vmin=-bound, vmax=bound)
    ax.set_yticks(range(7), ["Mon", "Tue", "Wed", "Thu", "Fri", "Sat", "Sun"])
    ax.set_xticks(range(0, 24, 3))
    ax.set_xlabel("hour of day (start)")
    fig.colorbar(image, ax=ax, label=f"mean residual ({d.output})")
    ax.set_title("residual by hour and weekday (calibration hours)")
    out["heatmap"] = _save(fig, figures / "residual_heatmap.png")

    top = next((r["name"] for r in (d.rounds[0]["drivers"] if d.rounds else [])
                if r["name"] in drivers.columns), "outdoor_air_temperature")
    fig, ax = plt.subplots(figsize=(6, 4))
    values = drivers[top].to_numpy(dtype=float)
    ax.scatter(values, residual, s=4, alpha=0.35, color="tab:green", label="hourly")
    _binned(ax, values, residual)
    ax.axhline(0, color="k", lw=0.8)
    unit = DRIVER_UNITS.get(top, "")
    ax.set_xlabel(f"{top} ({unit})" if unit else top)
    ax.set_ylabel(f"residual ({d.output})")
    ax.set_title(f"residual vs the strongest driver ({top})")
    ax.legend()
    out["top_driver"] = _save(fig, inside(figures, f"residual_vs_{top}.png"))

    lags = min(72, len(residual) // 4)
    acf = autocorrelation(residual, lags)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.vlines(range(len(acf)), 0, acf, color="tab:blue")
    band = 1.96 / np.sqrt(len(residual))
    ax.axhspan(-band, band, color="0.85", label="white noise 95 %")
    ax.set_xlabel("lag (h)")
    ax.set_ylabel("autocorrelation")
    ax.set_title("residual autocorrelation")
    ax.legend()
    out["acf"] = _save(fig, figures / "residual_acf.png")

    held = ~d.calibration
    fig, ax = plt.subplots(figsize=(9, 3.5))
    ax.plot(d.timestamps[held], d.measured[held], color="k", lw=1, label="measured")
    ax.plot(d.timestamps[held], d.base.fit.prediction[held], color="tab:red", lw=1,
            label="base model (calibrated)")
    if d.final is not d.base:
        ax.plot(d.timestamps[held], d.final.fit.prediction[held], color="tab:blue", lw=1,
                label=f"final model ({d.final.label})")
    ax.set_ylabel(d.output)
    ax.set_title("held-out block (never fitted)")
    ax.legend()
    fig.autofmt_xdate()
    out["heldout"] = _save(fig, figures / "heldout.png")
    return out


def _binned(ax, x: np.ndarray, y: np.ndarray, bins: int = 12) -> None:
    edges = np.quantile(x, np.linspace(0, 1, bins + 1))
    which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, bins - 1)
    centres = [x[which == b].mean() for b in range(bins) if np.any(which == b)]
    means = [y[which == b].mean() for b in range(bins) if np.any(which == b)]
    ax.plot(centres, means, "o-", color="tab:red", label="binned mean")


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


def markdown(d: Diagnosis, record: dict, figures: dict[str, Path]) -> str:
    """The short human report."""
    base, final = d.scorecard, d.final_scores
    lines = [f"# Diagnosis of {d.output}", "",
             f"**Verdict: {d.verdict}.** {record['cause']['summary']}", "",
             f"Backend {d.backend}; hours {record['hours']['first']} – "
             f"{record['hours']['last']}: {record['hours']['calibration']} calibration hours, "
             f"{record['hours']['heldout']} held-out hours (from "
             f"{record['hours']['heldout_first']}); {d.seconds:.0f} s.", "",
             "## Scorecard", "",
             "| model | block | NMBE | CV(RMSE) | nMCRPS | Guideline 14 |",
             "|---|---|---|---|---|---|"]
    for label, card in (("base (calibrated)", base), ("final", final)):
        for block in ("calibration", "heldout"):
            s = card[block]
            lines.append(f"| {label} | {block} | {s['nmbe']:+.2%} | {s['cvrmse']:.2%} | "
                         f"{s['nmcrps']:.2%} | {'pass' if s['guideline14'] else 'fail'} |")
    lines += ["", "## Drivers of the residuals (round 1)", "",
              "| driver | share of residual variance | effect | p (Holm) | stable sign | "
              "significant |", "|---|---|---|---|---|---|"]
    for r in record["drivers"]:
        lines.append(f"| {r['name']} | {r['share']:.1%} | {r['effect']:.3g} | "
                     f"{r['p_adjusted']:.2g} | {'yes' if r['sign_consistent'] else 'no'} | "
                     f"{'**yes**' if r['significant'] else 'no'} |")
    if d.rounds:
        white = d.rounds[0]["whiteness"]
        lines += ["", f"Ljung–Box (24 lags): p = {white['p_value']:.2g} — residuals "
                      f"{'look white' if white['white'] else 'are autocorrelated'}."]
    if d.parameter_check:
        lines += ["", "## Existing parameters (characteristic signatures)", "",
                  "| parameter | change that explains most (linear) | plausible | share | "
                  "refitted | structure left after refit |", "|---|---|---|---|---|---|"]
        for p in d.parameter_check:
            refit = f"{p['refitted']:.4g}" if "refitted" in p else "-"
            left = ", ".join(p["structure_left"]) or "none" if "structure_left" in p else "-"
            lines.append(f"| {p['name']} | {p['change']:+.4g} (→ {p['value']:.4g}) | "
                         f"{'yes' if p['plausible'] else 'no'} | {p['share']:.1%} | {refit} | "
                         f"{left} |")
    if d.extensions:
        lines += ["", "## Candidate extensions", "",
                  "Ranked per round by BIC on the calibration hours; the best "
                  f"{settings_of(d.base.config).cv_candidates} are cross-validated over "
                  "whole-week folds (out-of-fold CV(RMSE); encompassing p, which decides; "
                  "loss-difference p, reported).", "",
                  "| round | rank | cause | driver | fitted | out-of-fold CV(RMSE) before → after "
                  "| held-out CV(RMSE) before → after | encompassing p (loss-difference p) "
                  "| BIC before → after "
                  "| accepted |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for e in d.extensions:
            h, cv, test = e["heldout"], e.get("cross_validation"), e.get("encompassing")
            loss = e.get("loss_difference")
            fitted = e.get("law") or ", ".join(f"{k} = {v:.4g}" for k, v in e["fitted"].items())
            lines.append(
                f"| {e['round']} | {'-' if e.get('rank') is None else e['rank']} | "
                f"{_extension_label(e)} | {e['driver']} "
                f"| {fitted} | "
                + (f"{cv['cvrmse_before']:.2%} → {cv['cvrmse_after']:.2%}" if cv else "-")
                + f" | {h['before']['cvrmse']:.2%} → {h['after']['cvrmse']:.2%} | "
                + (f"{test['p_value']:.2g}" if test else "-")
                + (f" ({loss['p_value']:.2g})" if loss else "")
                + f" | {e['bic']['before']:.0f} → "
                + (f"{e['bic']['after']:.0f}" if e["bic"]["after"] is not None
                   else f"(screen {e.get('screen_bic', float('nan')):.0f})")
                + f" | {'**yes**' if e.get('accepted') else _not_accepted(e)} |")
        for e in d.extensions:
            if e.get("accepted") and e.get("runner_up"):
                r = e["runner_up"]
                effective = r.get("delta_bic_effective", r["delta_bic"])
                lines += ["", f"Round {e['round']}: {e.get('cause', e['name'])} over the "
                              f"runner-up {r['cause']}: "
                              + (f"chosen by {e['chosen_by']}" if e.get("chosen_by") else
                                 f"ΔBIC = {r['delta_bic']:.1f}, {effective:.1f} counting the "
                                 f"residuals' independent hours")
                              + f" ({r['evidence']}; BIC weight {e['confidence']:.2f})."]
            if e.get("accepted") and e.get("term_selection"):
                terms = "; ".join(f"{' + '.join(t['terms'])}: {t['bic']:.0f}"
                                  for t in e["term_selection"][:4])
                lines += ["", f"Law terms chosen by BIC (best first): {terms}."]
        if d.unexplained:
            lines += ["", ("Structure left when the rounds ran out (diagnosis.max_rounds): "
                           if d.round_limit_reached else
                           "Structure no candidate explains: ") + ", ".join(d.unexplained)
                      + " (see the residual heatmap and the autocorrelation plot)."]
    elif untried_reason(d) is not None:
        lines += ["", "## Candidate extensions", "", f"None tried: {untried_reason(d)}."]
    if d.notes:
        lines += ["", "## Notes", ""] + [f"- {note}" for note in d.notes]
    lines += ["", "## Figures", ""]
    for name, path in figures.items():
        lines.append(f"![{name}]({path.as_posix()})")
    return "\n".join(lines) + "\n"


def _extension_label(entry: dict) -> str:
    """``name (zone Z)``, with the facade and its surfaces for a solar aperture."""
    where = [f"zone {entry['zone']}"] if entry.get("zone") else []
    block = entry.get("schedule")
    if isinstance(block, dict) and "day_type" in block:
        where.append(f"{block['day_type']} {block['start_hour']}–{block['end_hour']} h")
    if entry.get("facade") == "sky_diffuse":
        where.append("the sky's diffuse irradiance")
    elif entry.get("facade"):
        surfaces = ", ".join(entry.get("surfaces") or []) or (
            f"the zone has no outdoor surface facing {entry['facade']}: the {entry['facade']} "
            "compass plane's irradiance, whatever would carry it")
        where.append(f"{entry['facade']} facade: {surfaces}")
    name = entry.get("cause", entry["name"])
    return f"{name} ({'; '.join(where)})" if where else name
