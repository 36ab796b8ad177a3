"""The paper's Fig. 6 for one search: success per iteration of the generated rewards against the
expert reward's with the same training budget. Matplotlib with the Agg backend (no display).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # before pyplot is imported: no display is needed
import matplotlib.pyplot as plt
import numpy as np

from itskill.files import replaced_whole
from itskill.llm.offline.backend import BACKEND

_BANDS = (
    ("generated", "tab:blue", "chosen generated reward"),
    ("expert", "tab:red", "expert reward"),
)


def plot_fig6(summary: dict[str, Any], out: Path) -> Path:
    """Draw ``summary`` (a search's ``summary.json``) into ``out`` (PNG, written atomically).

    Every trained candidate is a grey dot at its iteration; the line joins each iteration's best;
    a star marks the chosen reward's mean over the search's and the selection's seeds.
    The horizontal bands are the final retraining over fresh seeds (mean and 95% interval) of the
    best generated reward and of the expert reward; a retraining on one seed is its line alone.
    """
    iterations = summary["iterations"]
    x = np.arange(1, len(iterations) + 1)
    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=120)
    for it, xi in zip(iterations, x, strict=True):
        values = [s["success"] for s in it["samples"] if s.get("status") == "ok"]
        if not values:
            continue  # nothing of the iteration trained (a scalar x with no y failed to draw)
        jitter = np.linspace(-0.12, 0.12, len(values)) if len(values) > 1 else 0.0
        ax.scatter(xi + jitter, values, s=12, color="0.6", zorder=2)
    best = np.array(
        [np.nan if it["best_success"] is None else it["best_success"] for it in iterations]
    )
    ax.plot(x, best, "o-", color="tab:blue", label="generated: best of the iteration", zorder=3)
    chosen = (summary.get("best") or {}).get("selected_success")
    if chosen is not None:
        selection = summary.get("selection") or {}
        seeds = len(selection.get("search_seeds", [])) + len(selection.get("seeds", []))
        ax.scatter(summary["best"]["iteration"] + 1, chosen, marker="*", s=120, color="tab:green",
                   zorder=4, label=f"chosen reward, mean of {seeds} seeds")  # fmt: skip
    final = summary.get("final") or {}
    for key, colour, label in _BANDS:
        band = final.get(key)
        if not band or band.get("mean") is None:
            continue
        n = len(band["success"])
        # One seed has no spread to estimate: neither a band nor a legend that promises one.
        spread = f"mean of {n} seeds, 95% CI" if n > 1 else "1 seed, no interval"
        ax.axhline(band["mean"], color=colour, linestyle="--", linewidth=1.2,
                   label=f"{label}, retrained ({spread})")  # fmt: skip
        if n > 1:
            ax.axhspan(band["ci_low"], band["ci_high"], color=colour, alpha=0.12, linewidth=0)
    llm = summary.get("llm", "")
    source = BACKEND if summary.get("offline") else llm
    steps = final.get("steps")
    network = summary.get("network")
    runs = f"every run: {steps:,} env-steps" if steps else ""
    if network:
        runs = ", ".join(filter(None, [runs, network["label"]]))
    ax.set(
        title=f"{summary['task']}: generated ({source}) vs expert reward",
        xlabel="iteration" + (f" ({runs})" if runs else ""),
        ylabel="success (deterministic, best through training)",
        ylim=(-0.02, 1.02),
        xlim=(0.5, len(iterations) + 0.5),
        xticks=x,
    )
    ax.title.set_fontsize(9)
    ax.yaxis.set_major_formatter(matplotlib.ticker.PercentFormatter(1.0))
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=7)
    out = Path(out)
    fig.tight_layout()
    with replaced_whole(out) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return out
