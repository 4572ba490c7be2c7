"""Figures of ``bpsflow decide``: the risks of each rule (Figure 4.10) and accuracy vs risk (Figure 4.11)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bpsflow.files import save_figure


def plot_risks(record: dict, path: Path) -> Path:
    """Per rule: the probability of each event, the underperformance probability and the decision risk."""
    import matplotlib.pyplot as plt

    rules = record["rules"]
    fig, axes = plt.subplots(1, len(rules), figsize=(3.2 * len(rules) + 1, 3.2), squeeze=False)
    for ax, rule in zip(axes[0], rules):
        labels = [f"P({e['outcome']})" for e in rule["events"]] + ["p", "risk"]
        values = [e["probability"] for e in rule["events"]] + [
            rule["underperformance_probability"], rule["decision_risk"]]
        colours = ["#9ecae1"] * len(rule["events"]) + ["#3182bd", "#de2d26"]
        ax.bar(range(len(values)), values, color=colours)
        ax.axhline(rule["threshold"], color="k", lw=0.8, ls="--")
        ax.set_xticks(range(len(values)), labels, rotation=30, ha="right", fontsize=7)
        ax.set_ylim(0, 1)
        verdict = "implement" if rule["implement"] else "do not implement"
        ax.set_title(f"{rule['name']}: {verdict}", fontsize=9)
    axes[0][0].set_ylabel("probability")
    fig.suptitle(f"{record['intervention']} ({record['scenario']}): "
                 f"{record['outcomes_sampled']} outcomes", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    return path


def plot_correlation(table: dict[str, dict[str, float | None]], path: Path) -> Path:
    """Pearson correlation across scenarios between accuracy metrics (rows) and risks (columns)."""
    import matplotlib.pyplot as plt

    metrics = list(table)
    risks = sorted({r for row in table.values() for r in row})
    values = np.array([[np.nan if table[m].get(r) is None else table[m][r] for r in risks]
                       for m in metrics], dtype=float).reshape(len(metrics), len(risks))
    fig, ax = plt.subplots(figsize=(1.2 * max(len(risks), 2) + 2, 0.5 * max(len(metrics), 2) + 1.5))
    image = ax.imshow(values, vmin=-1, vmax=1, cmap="RdBu_r", aspect="auto")
    ax.set_xticks(range(len(risks)), risks, rotation=30, ha="right", fontsize=7)
    ax.set_yticks(range(len(metrics)), metrics, fontsize=7)
    for i in range(len(metrics)):
        for j in range(len(risks)):
            text = "n/a" if np.isnan(values[i, j]) else f"{values[i, j]:.2f}"
            ax.text(j, i, text, ha="center", va="center", fontsize=7)
    fig.colorbar(image, ax=ax, label="Pearson r across scenarios")
    ax.set_title("held-out accuracy vs decision risk", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    return path
