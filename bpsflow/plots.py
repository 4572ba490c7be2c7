"""Figures: ensemble uncertainty bands against measurements."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from bpsflow.config import Config, test_dates
from bpsflow.files import inside, save_figure

# Figures are bare ``Figure`` objects, not pyplot's: they render to PNG with Agg
# headless, leave the process's backend alone and need no closing.


def ensemble_band(results: pd.DataFrame, test: str, output: str,
                  coverage: float = 0.95) -> pd.DataFrame:
    """Ensemble mean and central ``coverage`` band per timestamp for one test and output."""
    rows = results[(results["test"] == test) & (results["output"] == output)]
    wide = rows.pivot(index="timestamp", columns="instance", values="value").sort_index()
    tail = (1 - coverage) / 2
    return pd.DataFrame({
        "mean": wide.mean(axis=1),
        "lower": wide.quantile(tail, axis=1),
        "upper": wide.quantile(1 - tail, axis=1),
        "members": wide.notna().sum(axis=1),
    })


def plot_bands(config: Config, results: pd.DataFrame, out_dir: Path,
               measured: pd.DataFrame | None = None, coverage: float = 0.95) -> list[Path]:
    """One PNG per test and output: ensemble mean, ``coverage`` band, measured values.

    The warm-up days are shaded; only the days after them are evaluated.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for test in config.model.tests:
        for output in test.outputs:
            band = ensemble_band(results, test.name, output, coverage)
            if band.empty:
                continue
            unit = config.outputs[output].unit
            # fixed margins: a constrained layout measured every tick label again, half the
            # figure's cost, for the same page at this size
            fig = Figure(figsize=(10, 3.6))
            fig.subplots_adjust(left=0.08, right=0.985, bottom=0.13, top=0.9)
            ax = fig.subplots()
            ax.fill_between(band.index, band["lower"], band["upper"], color="0.75",
                            label=f"{coverage:.0%} band ({int(band['members'].max())} instances)")
            ax.plot(band.index, band["mean"], color="black", lw=1.2, label="ensemble mean")
            if measured is not None and output in measured.columns:
                seen = measured.loc[measured.index.isin(band.index), output]
                ax.plot(seen.index, seen.to_numpy(), color="tab:blue", lw=1.2, label="measured")
            first, evaluated, _ = test_dates(test, config.model.year)
            ax.axvspan(pd.Timestamp(first), pd.Timestamp(evaluated), color="tab:orange",
                       alpha=0.08, label="warm-up (not evaluated)")
            ax.set_title(f"{test.name}: {output}")
            ax.set_ylabel(f"{output} [{unit}]" if unit else output)
            ax.legend(loc="upper left", fontsize=8, ncol=2)
            ax.grid(alpha=0.3)
            path = inside(out_dir, f"band_{test.name}_{output}.png")
            save_figure(fig, path, dpi=110)
            paths.append(path)
    return paths


def band_summary(config: Config, results: pd.DataFrame, coverage: float = 0.95) -> pd.DataFrame:
    """Per test and output over the evaluated days: mean prediction and mean band width."""
    rows = []
    for test in config.model.tests:
        _, evaluated, _ = test_dates(test, config.model.year)
        for output in test.outputs:
            band = ensemble_band(results, test.name, output, coverage)
            band = band[band.index > pd.Timestamp(evaluated)]
            if band.empty:
                continue
            rows.append({"test": test.name, "output": output, "unit": config.outputs[output].unit,
                         "instances": int(band["members"].max()),
                         "mean": float(band["mean"].mean()),
                         "band_width": float(np.mean(band["upper"] - band["lower"]))})
    return pd.DataFrame(rows)


def plot_mu_star_sigma(indices: pd.DataFrame, path: Path, title: str = "", unit: str = "",
                       label_top: int = 10, group_order: list[str] | None = None) -> Path:
    """Morris mu*–sigma plane of one response (seed Figure 3.3).

    Inputs on the right have large main effects, inputs high up large non-linear
    effects or interactions; the dashed line is sigma = mu*. Points are coloured
    by parameter group and the ``label_top`` inputs by mu* are named.

    Parameters
    ----------
    indices : DataFrame
        One response's rows of :func:`bpsflow.sensitivity.morris_indices`
        (parameter, group, mu_star, sigma, rank).
    path : Path
        The PNG to write.
    unit : str
        The response's unit; effects are in ``unit`` per normalised input range.
    group_order : list of str, optional
        Groups in colour order (keeps colours the same across responses).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    groups = list(dict.fromkeys((group_order or []) + list(indices["group"])))
    colours = matplotlib.colormaps["tab10" if len(groups) <= 10 else "tab20"]
    fig = Figure(figsize=(7.5, 5.5), layout="constrained")
    ax = fig.subplots()
    for g, group in enumerate(groups):
        rows = indices[indices["group"] == group]
        if len(rows):
            ax.scatter(rows["mu_star"], rows["sigma"], s=28, color=colours(g % colours.N),
                       label=group, alpha=0.85, edgecolor="none")
    mu_star_max = float(np.nanmax(np.r_[indices["mu_star"].to_numpy(), 0.0])) or 1.0
    sigma_max = float(np.nanmax(np.r_[indices["sigma"].to_numpy(), 0.0])) or mu_star_max
    largest = max(mu_star_max, sigma_max)
    ax.plot([0, largest * 1.2], [0, largest * 1.2], ls="--", lw=0.8, color="0.5",
            label="sigma = mu*")
    # staggered label offsets: neighbouring top inputs often sit close together
    for k, row in enumerate(indices.nsmallest(label_top, "rank").itertuples()):
        ax.annotate(row.parameter, (row.mu_star, row.sigma), fontsize=7,
                    xytext=(3, 3 + 7 * (k % 3)), textcoords="offset points")
    per = f" [{unit} per input range]" if unit else ""
    ax.set_xlabel(f"mu* (mean |elementary effect|){per}")
    ax.set_ylabel(f"sigma (std of elementary effects){per}")
    ax.set_xlim(0, mu_star_max * 1.25)
    ax.set_ylim(0, sigma_max * 1.25)
    ax.set_title(f"Morris screening: {title}" if title else "Morris screening")
    ax.legend(fontsize=7, loc="upper left")
    ax.grid(alpha=0.3)
    save_figure(fig, path, dpi=110)
    return path
