"""Figures: ensemble uncertainty bands against measurements."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from bpsflow.config import Config, test_dates  # noqa: E402


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
            fig, ax = plt.subplots(figsize=(10, 3.6), constrained_layout=True)
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
            path = out_dir / f"band_{test.name}_{output}.png"
            fig.savefig(path, dpi=110)
            plt.close(fig)
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
