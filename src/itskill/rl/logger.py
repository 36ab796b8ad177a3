"""Training metrics: one row per update to ``metrics.csv``, ``metrics.jsonl`` and TensorBoard.

A row holds the env-steps done, wall time, the success rate and mean return and length of the
episodes that ended since the previous row (those begun from the task's own start: training starts,
see ``BatchEnv``, are left out), the mean of every reward component over the steps
since the previous row, and end-to-end env-steps per second (rollouts and gradient updates, not
the deterministic evaluations).

A row is written as a rollout ends, before the update that learns from it, once at least
``LoggerConfig.min_steps_per_row`` env-steps were collected since the previous row: A2C's
rollouts are small (``n_steps * num_envs`` env-steps), and with PPO's default sizes that is every
rollout.

Resuming appends to the same files: :meth:`MetricsWriter.truncate_after` first drops rows logged
after the checkpoint the run resumes from, so the step column stays increasing and unique.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Logger, TensorBoardOutputFormat

from itskill.files import write_text
from itskill.reward_contract import LOG_COLUMNS
from itskill.rl.clock import WallClock
from itskill.sim.vec_env import BatchEnv


@dataclass(frozen=True)
class LoggerConfig:
    """Where and how often metrics go; ``progress`` shows a rich progress bar on the terminal."""

    min_steps_per_row: int = 1000
    tensorboard: bool = True
    progress: bool = True


TB_DIR = "tb"
"""The run directory's TensorBoard folder."""


class MetricsWriter:
    """Appends metric rows to ``metrics.csv`` and ``metrics.jsonl`` in ``run_dir``.

    The CSV header is fixed by the first row (fixed columns, then reward components sorted by name);
    a component that appears later is written to the JSONL file only.
    """

    def __init__(self, run_dir: Path) -> None:
        self.csv_path = run_dir / "metrics.csv"
        self.jsonl_path = run_dir / "metrics.jsonl"
        self._columns: list[str] | None = None
        if self.csv_path.exists():
            with open(self.csv_path, newline="", encoding="utf-8-sig", errors="replace") as fh:
                header = next(csv.reader(fh), None)
            self._columns = header or None

    def truncate_after(self, step: int) -> None:
        """Drop rows with ``step`` greater than ``step`` (logged after the last checkpoint).

        A ``metrics.csv`` that is gone or empty (deleted, or a full disk) is written again from
        ``metrics.jsonl``, which holds the same rows: otherwise the resumed run would start it
        afresh and the table would lose the rows before the checkpoint. One left with no rows
        is removed, so the next row writes its header.
        """
        kept: list[str] = []
        if self.jsonl_path.exists():
            for raw in self.jsonl_path.read_bytes().splitlines():
                try:
                    line = raw.decode("utf-8")  # a damaged byte drops its line, no other
                    if json.loads(line)["step"] <= step:
                        kept.append(line)
                except (UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError):
                    continue  # a line cut short by a crash
            write_text(self.jsonl_path, "".join(ln + "\n" for ln in kept))
        if self._columns is None and kept:
            rows = [json.loads(line) for line in kept]
            self._columns = _columns_for(rows[0])
            text = io.StringIO()
            csv.writer(text).writerows([self._columns, *(self._csv_row(r) for r in rows)])
            write_text(self.csv_path, text.getvalue())
            return
        if drop_rows_after(self.csv_path, step) == 0 and self._columns is not None:
            # Every row went (a run started again): the next row fixes the header anew, for
            # a reward whose components may differ from the abandoned run's.
            self.csv_path.unlink()
            self._columns = None

    def write(self, row: dict[str, Any]) -> None:
        with open(self.jsonl_path, "a") as fh:
            fh.write(json.dumps({k: _json_value(v) for k, v in row.items()}) + "\n")
        new_file = self._columns is None
        if new_file:
            self._columns = _columns_for(row)
        with open(self.csv_path, "a", newline="") as fh:
            writer = csv.writer(fh)
            if new_file:
                writer.writerow(self._columns)
            writer.writerow(self._csv_row(row))

    def _csv_row(self, row: dict[str, Any]) -> list[str]:
        return [_csv_value(row.get(c)) for c in self._columns or ()]


def _columns_for(row: dict[str, Any]) -> list[str]:
    """The CSV header a first row fixes: the fixed columns, then its reward components by name."""
    return [*LOG_COLUMNS, *sorted(k for k in row if k not in LOG_COLUMNS)]


def drop_rows_after(path: Path, step: int) -> int:
    """Rewrite the CSV file at ``path`` (env-steps in its first column) without the rows past
    ``step``, atomically; the number of rows kept (0 where there is no file). A row cut short by
    a crash goes too."""
    if not path.exists():
        return 0
    # A damaged byte is carried through as it is, for the reports to name: the rows around it
    # still say where the run was.
    with open(path, newline="", encoding="utf-8-sig", errors="surrogateescape") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        return 0
    header, body = rows[0], rows[1:]
    kept = [r for r in body if len(r) == len(header) and _row_step(r[0]) <= step]
    if len(kept) < len(body):
        text = io.StringIO()
        csv.writer(text).writerows([header, *kept])
        write_text(path, text.getvalue(), errors="surrogateescape")
    return len(kept)


def _row_step(value: str) -> float:
    try:
        return float(value)
    except ValueError:
        return math.inf


def _json_value(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def _csv_value(v: Any) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def read_metrics(run_dir: str | Path) -> list[dict[str, Any]]:
    """The rows of ``metrics.jsonl`` in ``run_dir`` (empty if there are none yet)."""
    path = Path(run_dir) / "metrics.jsonl"
    if not path.exists():
        return []
    return [json.loads(ln) for ln in path.read_text().splitlines() if ln.strip()]


class MetricsCallback(BaseCallback):
    """Collects episode outcomes and reward components each step; writes a row as a rollout
    ends, once ``min_steps_per_row`` env-steps were collected since the previous one.

    ``env`` is the unwrapped :class:`BatchEnv` being trained on (its ``last_components`` attribute
    holds the reward components of the step just taken; an ending episode's info its raw
    ``episode_return``). ``total_steps`` is the step count training will stop at, for the
    progress bar.
    """

    def __init__(
        self,
        env: BatchEnv,
        run_dir: Path,
        total_steps: int,
        config: LoggerConfig | None = None,
        console: Console | None = None,
        clock: WallClock | None = None,
    ) -> None:
        super().__init__()
        self.env = env
        self.clock = clock or WallClock()
        self.config = config or LoggerConfig()
        self.writer = MetricsWriter(run_dir)
        self.run_dir = run_dir
        self.total_steps = total_steps
        self.console = console
        self._tb: Logger | None = None
        self._progress: Progress | None = None
        self._task_id: Any = None
        self._len = np.zeros(env.num_envs, dtype=np.int64)
        self._reset_window(None)

    def _reset_window(self, step0: int | None) -> None:
        self._successes: list[bool] = []
        self._returns: list[float] = []
        self._lengths: list[int] = []
        self._comp_sums: dict[str, float] = {}
        self._comp_count = 0
        self._updates = 0
        # The window's training seconds: an evaluation run at a rollout's start is not training.
        self._train0 = self.clock.training_s()
        self._step0 = step0

    # ------------------------------------------------------------------ SB3 hooks
    def _on_training_start(self) -> None:
        self._reset_window(self.num_timesteps)
        if self.config.tensorboard:
            tb_dir = self.run_dir / TB_DIR
            tb_dir.mkdir(parents=True, exist_ok=True)
            self._tb = Logger(str(tb_dir), [TensorBoardOutputFormat(str(tb_dir))])
            # SB3's own training statistics (losses, entropy, ...) go to the same event file.
            self.model.set_logger(self._tb)
        if self.config.progress:
            self._progress = Progress(
                TextColumn("[bold]{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("{task.fields[stats]}"),
                TimeRemainingColumn(),
                console=self.console,
                transient=False,
            )
            self._progress.start()
            self._task_id = self._progress.add_task(
                "training", total=self.total_steps, completed=self.num_timesteps, stats=""
            )

    def _on_step(self) -> bool:
        dones = self.locals["dones"]
        infos = self.locals["infos"]
        self._len += 1
        for key, value in self.env.last_components.items():
            self._comp_sums[key] = self._comp_sums.get(key, 0.0) + float(np.sum(value))
        self._comp_count += self.env.num_envs
        for e in np.flatnonzero(dones):
            # Episodes begun from a training start (the part already grasped, say) would flatter
            # the task's success rate, return and length: only the task's own starts count.
            if not infos[e].get("training_start", False):
                self._successes.append(bool(infos[e].get("is_success", False)))
                # Not a sum of self.locals["rewards"]: reward normalisation rescales those.
                self._returns.append(float(infos[e]["episode_return"]))
                self._lengths.append(int(self._len[e]))
            self._len[e] = 0
        return True

    def _on_rollout_start(self) -> None:
        self._dump_update()

    def _dump_update(self) -> None:
        """Write to TensorBoard what Stable-Baselines3 recorded of the update just done (losses,
        entropy, learning rate), labelled with the env-steps it learned from. It records them as
        the update runs, after the row of its rollout was written: left for the next row, each
        was labelled a rollout late and the last update's never written."""
        if self._tb is not None:
            self._tb.dump(self.num_timesteps)

    def _on_rollout_end(self) -> None:
        self._updates += 1
        if self.num_timesteps - self._step0 >= self.config.min_steps_per_row:
            self.flush()

    def _on_training_end(self) -> None:
        self._dump_update()
        if self._step0 is not None and self.num_timesteps > self._step0 and self._updates:
            self.flush()
        self.close()

    # ------------------------------------------------------------------ rows
    def flush(self) -> dict[str, Any]:
        """Write a row for the steps since the previous one."""
        steps = self.num_timesteps - (self._step0 or 0)
        n_ep = len(self._successes)
        row: dict[str, Any] = {
            "step": int(self.num_timesteps),
            "wall_s": round(self.clock.training_s(), 3),
            "updates": self._updates,
            "episodes": n_ep,
            "success_rate": float(np.mean(self._successes)) if n_ep else float("nan"),
            "ep_return": float(np.mean(self._returns)) if n_ep else float("nan"),
            "ep_length": float(np.mean(self._lengths)) if n_ep else float("nan"),
            "steps_per_s": steps / max(self.clock.training_s() - self._train0, 1e-9),
        }
        for key in sorted(self._comp_sums):
            row[key] = self._comp_sums[key] / max(self._comp_count, 1)
        self.writer.write(row)
        if self._tb is not None:
            for key, value in row.items():
                if key in ("step",) or (isinstance(value, float) and not math.isfinite(value)):
                    continue
                prefix = "rollout" if key in LOG_COLUMNS else "reward"
                self._tb.record(f"{prefix}/{key}", value)
            self._tb.dump(self.num_timesteps)
        if self._progress is not None:
            sr = row["success_rate"]
            stats = f"success {sr:.0%}" if math.isfinite(sr) else "success -"
            stats += f"  {row['steps_per_s']:.0f} steps/s"
            self._progress.update(self._task_id, completed=self.num_timesteps, stats=stats)
        self._reset_window(self.num_timesteps)
        return row

    def close(self) -> None:
        """Stop the progress bar and close the TensorBoard file; safe to call again."""
        if self._progress is not None:
            self._progress.update(self._task_id, completed=self.num_timesteps)
            self._progress.stop()
            self._progress = None
        if self._tb is not None:
            self._tb.close()
            self._tb = None
