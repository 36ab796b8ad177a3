"""The trainer's evaluation file (``eval.csv``) and the learning curve read from it.

Torch-free, below every package that reads a run's evaluations: the trainer writes the file
(:mod:`itskill.rl.eval_callback`), the reward search and the experiment reports read it.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from itskill.datafile import NotUTF8Error, utf8_text
from itskill.errors import PicklableError

EVAL_FILE = "eval.csv"
EVAL_COLUMNS = (
    "env_steps", "wall_s", "success", "ci_low", "ci_high", "mean_length", "stages_done"
)  # fmt: skip
"""``stages_done``: subtasks finished at the end of an episode, as a fraction of the task's."""
EVAL_SEED = 20_000
"""Seed of the evaluation episodes of a run with training seed 0 (see :func:`eval_seed`)."""


def eval_seed(train_seed: int) -> int:
    """The seed of the evaluation episodes of a run with training seed ``train_seed``.

    A run evaluates on the same episodes every time, so its curve compares its policies on
    equal terms, and runs of one training seed (other methods, other rewards) share them, so
    they compare episode by episode. Across training seeds the episodes differ: a mean over
    seeds then averages over as many episode samples as seeds. When every seed shared one
    sample (releases before 2026-12-06, 15:25 UTC), the sample's own luck moved every seed alike
    and the interval over seeds could not show it: the final policies of the five ITN peg runs at
    log-std -3.0 scored 3.5 to 15.5 points higher on their 40 shared episodes than on 200
    held-out ones (docs/experiments.md).
    """
    return EVAL_SEED + train_seed


def evaluation_seed(meta: Mapping[str, Any]) -> int:
    """The seed of the evaluation episodes a run with checkpoint metadata ``meta`` uses: the
    one it recorded, or, for a run from before the seed was recorded, :data:`EVAL_SEED` (what
    every run used then, kept so that a resumed run's curve stays on one set of episodes)."""
    return int((meta.get("evaluation") or {}).get("seed", EVAL_SEED))


class CurveError(PicklableError, ValueError):
    """An evaluation file that cannot be read as a learning curve: names the file and problem."""

    def __init__(self, path: str | Path, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path, self.problem = str(path), problem


class NoEvaluationsError(CurveError):
    """A run with no evaluation to read: no evaluation file, or one stopped before its first row
    (any other :class:`CurveError` is a damaged file)."""


@dataclass(frozen=True)
class Curve:
    """One run's deterministic success against env-steps, with cumulative training wall time.

    ``budget`` is the env-step count the run was asked to reach; a run that never reaches a
    threshold is censored there.
    """

    steps: np.ndarray
    success: np.ndarray
    wall_s: np.ndarray
    budget: float

    def __post_init__(self) -> None:
        if not (len(self.steps) == len(self.success) == len(self.wall_s)):
            raise ValueError("steps, success and wall_s must have the same length")
        if len(self.steps) and np.any(np.diff(self.steps) <= 0):
            raise ValueError("steps must be strictly increasing")


def read_curve(run_dir: str | Path, budget: float, column: str = "success") -> Curve:
    """The learning curve in ``run_dir/eval.csv`` (written by the trainer's evaluation callback).

    ``column`` picks what the curve's ``success`` values hold: the success rate, or
    ``stages_done`` (the fraction of the task's subtasks finished at the end of an episode).

    A run resumed after a crash appends a new session to the file, whose first rows may repeat
    env-steps the crashed session had evaluated after its last checkpoint: those superseded rows
    are dropped. ``wall_s`` is the run's training time from its first session on (the trainer
    resumes its clock from the checkpoint); in files of older releases each session's clock
    restarted from zero, and such a session is offset by the time of the previous session's
    last kept row (the time between that row and the interruption is then not counted).
    """
    path = Path(run_dir) / EVAL_FILE
    if not path.is_file():
        raise NoEvaluationsError(
            path, "missing: the run was not trained with evaluations (eval_every)"
        )
    try:
        # Decoded whole, so a damaged byte's offset is the file's, not one of a read buffer's.
        reader = csv.DictReader(io.StringIO(utf8_text(path.read_bytes()), newline=""))
        rows, lines = [], []  # each row with the line it ends on (blank lines are skipped)
        for row in reader:
            rows.append(row)
            lines.append(reader.line_num)
    except OSError as err:
        raise CurveError(path, f"cannot be read: {(err.strerror or str(err)).lower()}") from err
    except NotUTF8Error as err:
        raise CurveError(path, str(err)) from err
    except csv.Error as err:
        raise CurveError(path, f"not a CSV file: {err}") from err
    missing = {"env_steps", "wall_s", column} - set(reader.fieldnames or ())
    if missing:
        raise CurveError(path, f"missing column(s) {', '.join(sorted(missing))}")
    try:
        raw = [(float(r["env_steps"]), float(r["wall_s"]), float(r[column])) for r in rows]
    except (TypeError, ValueError) as err:
        raise CurveError(path, f"not a number: {err}") from err
    if not raw:
        # A run stopped before its first evaluation: no curve to plot or reach a threshold on.
        raise NoEvaluationsError(path, "no evaluations")
    for row, (step, wall, value) in zip(lines, raw, strict=True):
        # A value no evaluation writes (an edit, a damaged cell) reached the report as a
        # success of 150%.
        if not (math.isfinite(step) and step >= 0 and math.isfinite(wall) and wall >= 0):
            raise CurveError(path, f"line {row}: env_steps and wall_s must be numbers >= 0")
        if not 0.0 <= value <= 1.0:
            raise CurveError(path, f"line {row}: {column} {value:g} is not a fraction in [0, 1]")
    kept: list[list[float]] = []  # [step, wall over the run, success]
    offset = 0.0
    for step, wall, success in raw:
        while kept and kept[-1][0] >= step:
            kept.pop()  # re-evaluated by a resumed session: that trajectory was thrown away
        if kept and wall + offset < kept[-1][1]:
            offset = kept[-1][1]  # a session of an older release, its clock restarted at zero
        kept.append([step, wall + offset, success])
    data = np.asarray(kept, dtype=float)
    return Curve(data[:, 0], data[:, 2], data[:, 1], float(budget))
