"""Figures of the reports: learning curves with confidence bands (Fig. 7), attention weights over
an episode (Fig. 8). Matplotlib with the Agg backend: no display is needed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # before pyplot is imported: no display is needed
import matplotlib.pyplot as plt
import numpy as np

from itskill.experiments.analysis import Band
from itskill.files import replaced_whole

# One colour per method, fixed so a method looks the same in every figure.
METHOD_COLOURS = {
    "itn": "tab:red",
    "nia": "tab:orange",
    "dfs": "tab:green",
    "pst": "tab:purple",
    "no_transfer": "tab:blue",
}
METHOD_LABELS = {
    "itn": "ITN",
    "nia": "NIA",
    "dfs": "DFS",
    "pst": "PST",
    "no_transfer": "No_Transfer",
}


def method_label(method: str) -> str:
    """The paper's name of a method."""
    return METHOD_LABELS.get(method, method)


def plot_learning_curves(
    bands: Mapping[str, Band],
    title: str,
    out: Path,
    threshold: float | None = None,
    ylabel: str = "success (deterministic)",
) -> Path:
    """Mean success (or another fraction, named by ``ylabel``) against env-steps, one line per
    method, its 95% interval shaded."""
    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=120)
    for i, (method, band) in enumerate(bands.items()):
        colour = METHOD_COLOURS.get(method, f"C{i}")
        n = int(band.n.max()) if band.n.size else 0
        ax.plot(band.grid, band.mean, color=colour, label=f"{method_label(method)} (n={n})")
        if n > 1:
            ax.fill_between(band.grid, band.low, band.high, color=colour, alpha=0.2, linewidth=0)
    if threshold is not None:
        ax.axhline(threshold, color="grey", linestyle=":", linewidth=1)
    ax.set(title=title, xlabel="env-steps", ylabel=ylabel, ylim=(-0.02, 1.02))
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    return _save(fig, out)


def plot_attention(
    weights: np.ndarray,
    stages: Sequence[int],
    sources: Sequence[str],
    title: str,
    out: Path,
    stage_names: Sequence[str] = (),
    raw: np.ndarray | None = None,
) -> Path:
    """Each source's weight at every step of one episode (``raw`` dashed); stage changes marked."""
    weights = np.asarray(weights, dtype=float)
    stages = np.asarray(stages)
    steps = np.arange(len(weights))
    fig, ax = plt.subplots(figsize=(6.4, 3.8), dpi=120)
    for j, name in enumerate(sources):
        (line,) = ax.plot(steps, weights[:, j], label=name)
        if raw is not None:
            ax.plot(steps, raw[:, j], color=line.get_color(), linestyle="--", linewidth=0.8)
    starts = [0, *(np.flatnonzero(np.diff(stages)) + 1)] if len(stages) else []
    for start in starts:
        if start:
            ax.axvline(start, color="grey", linestyle=":", linewidth=0.8)
        stage = int(stages[start])
        name = stage_names[stage] if stage < len(stage_names) else f"stage {stage}"
        ax.text(start + 0.5, 1.01, name, fontsize=7, va="bottom")
    ax.set(title=title, xlabel="step of the episode", ylabel="weight", ylim=(0, 1.1))
    ax.grid(alpha=0.3)
    ax.legend(loc="center right", fontsize=8)
    return _save(fig, out)


def _save(fig: plt.Figure, out: Path) -> Path:
    out = Path(out)
    fig.tight_layout()
    # Whole or not at all: a report must not embed a figure an interruption cut short.
    with replaced_whole(out) as tmp:
        fig.savefig(tmp, format=out.suffix.lstrip(".") or "png")
    plt.close(fig)
    return out
