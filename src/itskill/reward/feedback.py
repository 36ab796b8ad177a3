"""What a candidate's training says about its reward: the numbers fed back to the language model.

The paper's strategy-optimisation stage records the maximum success rate and every subtask's and
the total reward through training; the model then retunes each subtask's temperature. Here they
come from the training run's ``metrics.csv`` (one row per update, the mean of every reward
component over its steps, the episode return); the success rates from its deterministic
evaluations, which :func:`itskill.curves.read_curve` reads.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable
from pathlib import Path

from itskill.curves import CurveError
from itskill.datafile import NotUTF8Error, utf8_text
from itskill.reward_contract import EPISODE_RETURN, LOG_COLUMNS


def _float(path: Path, column: str | None, text: str | list[str] | None) -> float | None:
    """A finite cell's value, None for an empty or non-finite one; a cell that is no number, or
    one past the header's columns, raises :class:`CurveError` naming the file."""
    if column is None:
        raise CurveError(path, f"a row has more cells than the header ({text!r})")
    if text is None or text == "":
        return None
    try:
        value = float(text)
    except ValueError as err:
        raise CurveError(path, f"column {column!r}: not a number: {text!r}") from err
    return value if math.isfinite(value) else None


def _rows(path: Path) -> list[dict[str, str]]:
    if not path.is_file():
        return []
    try:
        return list(csv.DictReader(io.StringIO(utf8_text(path.read_bytes()), newline="")))
    except NotUTF8Error as err:  # the candidate fails, naming the file
        raise CurveError(path, str(err)) from err


def component_stats(run_dirs: Iterable[Path]) -> dict[str, dict[str, float]]:
    """Max, mean and min of every reward component, and of the episode return, through training.

    Each ``metrics.csv`` row holds a component's mean per step over one logging window; the
    statistics are over the windows of every run in ``run_dirs`` (one per seed). A component with
    no finite value is left out.
    """
    series: dict[str, list[float]] = {}
    for run_dir in run_dirs:
        path = Path(run_dir) / "metrics.csv"
        for row in _rows(path):
            for column, text in row.items():
                name = EPISODE_RETURN if column == "ep_return" else column
                if column in LOG_COLUMNS and column != "ep_return":
                    continue
                value = _float(path, column, text)
                if value is not None:
                    series.setdefault(name, []).append(value)
    return {
        name: {"max": max(v), "mean": sum(v) / len(v), "min": min(v)}
        for name, v in sorted(series.items())
    }


def peak_success(curve: list[tuple[int, float]]) -> float:
    """The best deterministic success through training (0 if never evaluated)."""
    return max((s for _, s in curve), default=0.0)
