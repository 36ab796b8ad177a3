"""Each finished cell's final policy on held-out episodes (``itskill experiment held-out RUN``).

A run's curves are drawn on its evaluation episodes, the same at every evaluation, and the last
point of a curve is read off them. This measures each cell's final policy once more, on episodes
no run trains or evaluates on (:data:`itskill.tasks.evaluate.HELD_OUT_SEED`, the episodes of the
library's success rates and of ``itskill learn``'s figure), and writes ``held_out.json`` beside
the cell's ``result.json``; the report puts the two side by side. It takes minutes per cell, so
it is a step of its own: a cell already measured on as many episodes is not measured again, and
an interrupted call goes on where it stopped.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from itskill.executors import run_jobs
from itskill.experiments.runner import (
    CONFIG_FILE,
    Cell,
    ExperimentRunError,
    load_cell_results,
    read_run_config,
)
from itskill.files import CorruptFileError, read_json, write_json

HELD_OUT_FILE = "held_out.json"
HELD_OUT_ENVS = 25
"""Environments an evaluation steps together: the held-out episodes of a seed depend on it, and
``itskill learn`` and the library measure with 25."""


@dataclass
class HeldOutSummary:
    """What :func:`measure_held_out` did, cell by cell."""

    measured: list[Cell] = field(default_factory=list)
    skipped: list[Cell] = field(default_factory=list)
    """Already measured on as many episodes, at the same env-steps."""
    failed: dict[Cell, str] = field(default_factory=dict)


def read_held_out(cell_dir: Path, result: dict[str, Any]) -> dict[str, Any] | None:
    """The cell's ``held_out.json`` if it measured the policy ``result`` (its ``result.json``)
    describes: one written before the cell was resumed and trained on is out of date."""
    path = Path(cell_dir) / HELD_OUT_FILE
    if not path.is_file():
        return None
    try:
        data = read_json(path)
    except CorruptFileError:
        return None
    if not isinstance(data, dict) or data.get("num_timesteps") != result.get("num_timesteps"):
        return None
    return data


def measure_held_out(
    run_dir: str | Path,
    episodes: int = 200,
    workers: int | None = None,
    on_cell: Callable[[Cell, dict[str, Any] | None, str | None], None] | None = None,
) -> HeldOutSummary:
    """Measure the final policy of every finished cell of experiment run ``run_dir`` on
    ``episodes`` held-out episodes, ``workers`` cells at a time (one per core by default), and
    write each cell's ``held_out.json``. ``on_cell(cell, record, error)`` hears of each cell as
    it ends. A cell that fails (its weights missing, as in a report's copy of a run) is named in
    the summary and the others go on."""
    if episodes < 1:
        raise ValueError(f"episodes must be at least 1, got {episodes}")
    run_dir = Path(run_dir)
    if not (run_dir / CONFIG_FILE).is_file():
        raise ExperimentRunError(
            f"{run_dir}: not an experiment run directory (no {CONFIG_FILE}); give the directory "
            "`itskill experiment run` trained in"
        )
    config = read_run_config(run_dir)
    summary = HeldOutSummary()
    todo: list[tuple[Cell, dict[str, Any]]] = []
    for cell, result in load_cell_results(run_dir).items():
        if cell.task not in config.tasks:
            continue
        have = read_held_out(cell.dir(run_dir), result)
        if have is not None and have.get("episodes") == episodes:
            summary.skipped.append(cell)
        else:
            todo.append((cell, result))
    jobs = [(c.task, str(c.dir(run_dir)), episodes, r["num_timesteps"]) for c, r in todo]
    for job in run_jobs(_measure_cell, jobs, "local", workers):
        cell = todo[job.index][0]
        if job.ok:
            write_json(cell.dir(run_dir) / HELD_OUT_FILE, job.value)
            summary.measured.append(cell)
        else:
            summary.failed[cell] = f"{type(job.error).__name__}: {job.error}"
        if on_cell is not None:
            on_cell(cell, job.value if job.ok else None, summary.failed.get(cell))
    return summary


def _measure_cell(task: str, cell_dir: str, episodes: int, num_timesteps: int) -> dict[str, Any]:
    # Imported in the worker: the parent process needs no torch or simulator.
    from itskill.rl.checkpoint import as_policy
    from itskill.tasks import get_task
    from itskill.tasks.evaluate import HELD_OUT_SEED, evaluate

    res = evaluate(get_task(task), as_policy(cell_dir), episodes, HELD_OUT_SEED, HELD_OUT_ENVS)
    return {
        "policy": "final",
        "num_timesteps": num_timesteps,
        "episodes": episodes,
        "seed": HELD_OUT_SEED,
        "num_envs": HELD_OUT_ENVS,
        "success": res.success_rate,
        "ci_low": res.ci_low,
        "ci_high": res.ci_high,
        "stages_done": round(res.mean_stages_done / res.n_stages, 4),
        "wall_s": round(res.wall_s, 1),
        # Episode by episode, in the same order for every cell: two methods' policies can be
        # compared on the episodes only one of them succeeded in.
        "outcomes": [int(o) for o in res.outcomes],
    }
