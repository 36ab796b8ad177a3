"""Figures a report embeds are written whole."""

from __future__ import annotations

from pathlib import Path

import matplotlib.figure
import numpy as np
import pytest

from itskill.experiments.analysis import Band
from itskill.experiments.plots import plot_learning_curves


def _band() -> Band:
    grid = np.array([0.0, 1000.0, 2000.0])
    return Band(grid, np.array([0.1, 0.5, 0.8]), np.zeros(3), np.ones(3), np.full(3, 3))


def test_an_interrupted_figure_leaves_the_previous_one(tmp_path: Path, monkeypatch) -> None:
    out = tmp_path / "curves.png"
    plot_learning_curves({"itn": _band()}, "first", out)
    first = out.read_bytes()
    assert first.startswith(b"\x89PNG")

    def cut_short(self, fname, **kw):
        Path(fname).write_bytes(first[:100])
        raise KeyboardInterrupt

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", cut_short)
    with pytest.raises(KeyboardInterrupt):
        plot_learning_curves({"itn": _band()}, "second", out)
    assert out.read_bytes() == first
    assert [p.name for p in tmp_path.iterdir()] == ["curves.png"]
