"""A training run's wall clock, counted across the sessions of a resumed run.

A run's checkpoint records the wall time spent up to it, and the part of it spent evaluating, so a
resumed run goes on counting where it stopped: learning curves (``eval.csv``) give the training
time, without the evaluations, at each point, and a run resumed after Ctrl-C keeps the time of the
training it kept.
"""

from __future__ import annotations

import time

TRAIN_WALL_KEY = "train_wall_s"
"""Checkpoint metadata field: the run's wall seconds up to that checkpoint, evaluations included."""
EVAL_WALL_KEY = "eval_wall_s"
"""Checkpoint metadata field: the seconds of those spent in deterministic evaluations."""


class WallClock:
    """A run's wall time: what its checkpoint recorded, plus this session's."""

    def __init__(self, prior_s: float = 0.0, prior_eval_s: float = 0.0) -> None:
        self.prior_s = prior_s
        self.eval_s = prior_eval_s
        self._start = time.perf_counter()

    def session_s(self) -> float:
        return time.perf_counter() - self._start

    def total_s(self) -> float:
        """Wall seconds of the run so far, evaluations included."""
        return self.prior_s + self.session_s()

    def training_s(self) -> float:
        """Wall seconds of the run so far spent training (the evaluations left out)."""
        return self.total_s() - self.eval_s

    def add_eval(self, seconds: float) -> None:
        """Count ``seconds`` as spent evaluating."""
        self.eval_s += seconds

    def checkpoint_fields(self) -> dict[str, float]:
        """What a checkpoint records of this clock (see :func:`from_checkpoint`)."""
        return {TRAIN_WALL_KEY: round(self.total_s(), 2), EVAL_WALL_KEY: round(self.eval_s, 2)}

    @classmethod
    def from_checkpoint(cls, meta: dict) -> WallClock:
        """Go on from a checkpoint's record (a checkpoint of an older release has no evaluation
        time: its evaluations then count as training)."""
        return cls(float(meta.get(TRAIN_WALL_KEY, 0.0)), float(meta.get(EVAL_WALL_KEY, 0.0)))
