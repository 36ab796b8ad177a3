"""Deterministic evaluation during training, for learning curves and steps-to-threshold figures.

Training success (from the exploring policy) understates what the policy can do; the figures users
compare (env-steps to 80% success, Table II-style success at budget fractions) come from the
deterministic policy on episodes it did not train on. Every ``every`` env-steps this callback runs
:func:`itskill.tasks.evaluate.evaluate` on the live policy and appends a row to ``eval.csv``.
"""

from __future__ import annotations

import csv
import time
from pathlib import Path

from stable_baselines3.common.callbacks import BaseCallback

from itskill.tasks.evaluate import PolicyActor, evaluate
from itskill.tasks.spec import TaskSpec

EVAL_FILE = "eval.csv"
EVAL_COLUMNS = (
    "env_steps", "wall_s", "success", "ci_low", "ci_high", "mean_length", "stages_done"
)  # fmt: skip
"""``stages_done``: subtasks finished at the end of an episode, as a fraction of the task's."""


class DeterministicEvalCallback(BaseCallback):
    """Evaluate the deterministic policy every ``every`` env-steps over ``episodes`` episodes."""

    def __init__(
        self, spec: TaskSpec, run_dir: Path, every: int, episodes: int = 50, seed: int = 20_000
    ) -> None:
        super().__init__()
        self.spec, self.path = spec, Path(run_dir) / EVAL_FILE
        self.every, self.episodes, self.seed = every, episodes, seed
        self._next = every
        self._start = time.perf_counter()
        self._eval_time = 0.0
        self._last_evaluated = -1

    def _on_training_start(self) -> None:
        self._next = (self.num_timesteps // self.every + 1) * self.every
        if not self.path.exists():
            with open(self.path, "w", newline="") as fh:
                csv.writer(fh).writerow(EVAL_COLUMNS)
        with open(self.path, newline="") as fh:
            # A run resumed from an older release keeps its file's columns.
            self._columns = next(csv.reader(fh))

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next:
            self._next += self.every
            self.evaluate()
        return True

    def _on_training_end(self) -> None:
        if self._last_evaluated != self.num_timesteps:
            self.evaluate()

    def evaluate(self) -> None:
        """Evaluate now and append the row."""
        self._last_evaluated = self.num_timesteps
        t0 = time.perf_counter()
        res = evaluate(
            self.spec, PolicyActor(self.model.policy), self.episodes, self.seed, num_envs=25
        )
        self._eval_time += time.perf_counter() - t0
        # Wall time counts training only, so steps-to-threshold times are not inflated by
        # the evaluations themselves.
        wall = time.perf_counter() - self._start - self._eval_time
        row = {
            "env_steps": self.num_timesteps,
            "wall_s": round(wall, 2),
            "success": res.success_rate,
            "ci_low": res.ci_low,
            "ci_high": res.ci_high,
            "mean_length": res.mean_length,
            "stages_done": round(res.mean_stages_done / res.n_stages, 4),
        }
        with open(self.path, "a", newline="") as fh:
            csv.writer(fh).writerow([row[c] for c in self._columns])
