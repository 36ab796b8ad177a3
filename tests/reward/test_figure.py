"""The Fig. 6 of a search (reward/figure.py): what its final-retraining bands claim."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import pytest

from itskill.reward import figure


def _band(success: list[float], low: float, high: float) -> dict[str, Any]:
    return {
        "seeds": list(range(len(success))),
        "success": success,
        "mean": sum(success) / len(success),
        "ci_low": low,
        "ci_high": high,
    }


def _summary(generated: dict[str, Any], expert: dict[str, Any]) -> dict[str, Any]:
    """The parts of a search's summary.json that the figure reads."""
    return {
        "task": "pick_nut_m12",
        "llm": "offline",
        "offline": True,
        "iterations": [{"samples": [{"status": "ok", "success": 0.5}], "best_success": 0.5}],
        "best": {"iteration": 0, "sample": 0, "success": 0.5},
        "final": {"steps": 128, "generated": generated, "expert": expert},
    }


def test_a_band_of_one_seed_claims_no_interval(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The legend said "mean of 1 seeds, 95% CI" over a line with no interval drawn.
    axes: list[Any] = []
    subplots = plt.subplots

    def kept(*args: Any, **kwargs: Any) -> Any:
        fig, ax = subplots(*args, **kwargs)
        axes.append(ax)
        return fig, ax

    monkeypatch.setattr(figure.plt, "subplots", kept)
    summary = _summary(_band([0.4], 0.4, 0.4), _band([0.6, 0.8, 1.0], 0.55, 1.05))
    out = figure.plot_fig6(summary, tmp_path / "fig6.png")
    assert out.stat().st_size > 0
    (ax,) = axes
    labels = ax.get_legend_handles_labels()[1]
    assert "chosen generated reward, retrained (1 seed, no interval)" in labels
    assert "expert reward, retrained (mean of 3 seeds, 95% CI)" in labels
    assert len(ax.patches) == 1  # the expert's interval band only


def test_an_iteration_where_nothing_trained_is_drawn_without_dots(tmp_path: Path) -> None:
    # Every sample of the first iteration rejected or failed: the figure raised "x and y must be
    # the same size" at the end of the search, and again on every --resume.
    summary = _summary(_band([0.5, 0.7], 0.3, 0.9), _band([0.6, 0.6], 0.6, 0.6))
    failed = {"samples": [{"status": "failed", "error": "raised"}], "best_success": None}
    summary["iterations"] = [failed, *summary["iterations"]]
    summary["best"]["iteration"] = 1
    out = figure.plot_fig6(summary, tmp_path / "fig6.png")
    assert out.stat().st_size > 0
