"""Deterministic evaluation during training, for learning curves and steps-to-threshold figures.

Training success (from the exploring policy) understates what the policy can do; the figures users
compare (env-steps to 80% success, Table II-style success at budget fractions) come from the
deterministic policy on episodes it did not train on. For every multiple of ``every`` env-steps
this callback runs :func:`itskill.tasks.evaluate.evaluate` on the live policy between two
updates, at the last one at or before that step, and appends a row to ``eval.csv`` labelled
with the env-steps the policy learned from.

It also keeps the best policy so far in ``best/``, with the run's metadata: PPO can lose a level
it reached (docs/experiments.md), and a user wants the policy the run was best at, not only its
last one. "Best" is the highest success, then the most subtasks done, the later evaluation winning
a tie (it has trained longer at the same level). The choice is made on these evaluation episodes,
so its score is optimistic; a figure to report comes from other episodes (``itskill learn``
evaluates the chosen policy on a held-out seed).
"""

from __future__ import annotations

import csv
import json
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from itskill.curves import EVAL_COLUMNS, EVAL_FILE
from itskill.datafile import is_number
from itskill.rl.checkpoint import BEST_DIR, META_FILE, save_checkpoint
from itskill.rl.clock import WallClock
from itskill.rl.logger import drop_rows_after
from itskill.tasks.evaluate import PolicyActor, evaluate
from itskill.tasks.spec import TaskSpec

SELECTION_KEY = "selection"
"""``best/checkpoint.json`` field: the evaluation row that chose the policy, with its episodes."""


def last_evaluated(run_dir: str | Path) -> int | None:
    """The env-steps of the last row of ``run_dir/eval.csv``, or None if there is none."""
    path = Path(run_dir) / EVAL_FILE
    if not path.is_file():
        return None
    with open(path, newline="", encoding="utf-8-sig", errors="replace") as fh:
        steps = [row[0] for row in list(csv.reader(fh))[1:] if row]
    try:
        return int(float(steps[-1])) if steps else None
    except ValueError:
        return None


def truncate_evaluations(run_dir: str | Path, step: int) -> None:
    """Forget the evaluation rows after env-step ``step`` (a resumed run's checkpoint): they
    belong to training the resumed run does again, differently.

    ``best/`` stays, even if one of those evaluations chose it: it holds a policy this run
    trained and measured, with its record, and a later evaluation replaces it only by matching
    or beating that score.
    """
    drop_rows_after(Path(run_dir) / EVAL_FILE, step)


def read_selection(run_dir: str | Path) -> dict[str, Any] | None:
    """The ``selection`` record of ``run_dir/best``, or None if the run kept no best policy or
    its record lacks the env-steps and success that chose it (or holds no numbers there)."""
    path = Path(run_dir) / BEST_DIR / META_FILE
    if not path.is_file():
        return None
    try:
        selection = dict(json.loads(path.read_text())[SELECTION_KEY])
    except (json.JSONDecodeError, KeyError, TypeError, ValueError):
        # A damaged record must not stop training: the next evaluation writes a new one.
        return None
    numbers = ("env_steps", "success", *(("stages_done",) if "stages_done" in selection else ()))
    return selection if all(is_number(selection.get(k)) for k in numbers) else None


EVAL_ENVS = 25
"""Environments an evaluation steps together (the episodes drawn depend on it too)."""


class DeterministicEvalCallback(BaseCallback):
    """Evaluate the deterministic policy over ``episodes`` episodes for every ``every``
    env-steps (between updates, at the last one at or before each multiple), and at the end.

    The best policy so far is written to ``run_dir/best`` with ``meta`` (the run's checkpoint
    metadata) after each evaluation that matches or beats it. With ``at_start``, a run that
    starts from step 0 is evaluated before its first update too (a warm-started policy, which
    reinforcement learning may make worse before it makes it better). A row's ``wall_s`` is the
    training time of ``clock`` (the run's, counted across the sessions of a resumed run), the
    evaluations left out. A resumed run first makes up an evaluation that was due and never
    written (interrupted mid-evaluation), and one at the end.
    """

    def __init__(
        self,
        spec: TaskSpec,
        run_dir: Path,
        every: int,
        episodes: int,
        seed: int,
        meta: Mapping[str, Any],
        clock: WallClock,
        at_start: bool = False,
    ) -> None:
        super().__init__()
        self.at_start = at_start
        self.spec, self.run_dir, self.path = spec, Path(run_dir), Path(run_dir) / EVAL_FILE
        self.every, self.episodes, self.seed = every, episodes, seed
        self.meta = dict(meta)
        self._next = every
        self.clock = clock
        self._last_evaluated = -1
        self._best: tuple[float, float] | None = None

    def _on_training_start(self) -> None:
        kept = read_selection(self.run_dir)
        if kept is not None:
            self._best = (float(kept["success"]), float(kept.get("stages_done", 0.0)))
        if not self.path.exists() or self.path.stat().st_size == 0:  # an emptied file too
            with open(self.path, "w", newline="") as fh:
                csv.writer(fh).writerow(EVAL_COLUMNS)
        with open(self.path, newline="", encoding="utf-8-sig", errors="replace") as fh:
            # A run resumed from an older release keeps its file's columns (a damaged byte in
            # a later row is the reports' to name, not a reason to stop training).
            self._columns = next(csv.reader(fh))
        self._rollout = getattr(self.model, "n_steps", 1) * self.model.n_envs
        last = last_evaluated(self.run_dir)
        if self.at_start and self.num_timesteps == 0 and last is None:
            # A warm-started run, unless a session stopped before its first update evaluated
            # it already.
            self.evaluate()
            last = 0
        # The steps a row covers are those up to the end of the rollout after it; the first due
        # step past them is the next to evaluate for. One a Ctrl-C or crash cut short (the
        # checkpoint was saved past its row) is due at once. A row off the rollouts' boundaries
        # was written in the middle of a rollout, as releases before 2026-12-06 did: it covers
        # its own due step only. (Such a row that fell on a boundary, with `every` shorter than
        # a rollout, is read as a new one and can leave one due step unevaluated.)
        if last is not None and last % self._rollout:
            self._next = max(self.every, (last // self.every + 1) * self.every)
        else:
            self._next = self._due_from(last)

    def _due_from(self, evaluated: int | None) -> int:
        """The first multiple of ``every`` (from ``every`` on) that an evaluation at env-step
        ``evaluated`` (None: none yet) leaves to a later one: those before the end of the next
        rollout it covers."""
        covered = 0 if evaluated is None else evaluated + self._rollout
        return max(self.every, -(-covered // self.every) * self.every)

    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        # Between updates, so a row's env_steps are exactly those its policy learned from; at
        # the last update at or before the due step, so a curve has a row by each multiple of
        # `every` (Table II reads the success at such fractions of the budget).
        if self._next < self.num_timesteps + self._rollout:
            self.evaluate()
            self._next = self._due_from(self.num_timesteps)

    def _on_training_end(self) -> None:
        if self._last_evaluated != self.num_timesteps:
            self.evaluate()

    def evaluate(self) -> None:
        """Evaluate now and append the row."""
        self._last_evaluated = self.num_timesteps
        t0 = time.perf_counter()
        res = evaluate(
            self.spec, PolicyActor(self.model.policy), self.episodes, self.seed, num_envs=EVAL_ENVS
        )
        self.clock.add_eval(time.perf_counter() - t0)
        row = {
            "env_steps": self.num_timesteps,
            # Training only, over every session of the run: steps-to-threshold times are not
            # inflated by the evaluations themselves, nor cut by a resume.
            "wall_s": round(self.clock.training_s(), 2),
            "success": res.success_rate,
            "ci_low": res.ci_low,
            "ci_high": res.ci_high,
            "mean_length": res.mean_length,
            "stages_done": round(res.mean_stages_done / res.n_stages, 4),
        }
        with open(self.path, "a", newline="") as fh:
            csv.writer(fh).writerow([row[c] for c in self._columns])
        score = (row["success"], row["stages_done"])
        if self._best is None or score >= self._best:
            self._best = score
            selection = {**row, "episodes": self.episodes, "seed": self.seed}
            save_checkpoint(
                self.model,
                self.run_dir / BEST_DIR,
                {**self.meta, SELECTION_KEY: selection},
                resumable=False,
            )
