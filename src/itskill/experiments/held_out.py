"""Each finished cell's final policy on held-out episodes (``itskill experiment held-out RUN``).

A run's curves are drawn on its evaluation episodes, the same at every evaluation, and the last
point of a curve is read off them. This measures each cell's final policy once more, on episodes
no run trains or evaluates on (:data:`itskill.tasks.evaluate.HELD_OUT_SEED`, the episodes of the
library's success rates and of ``itskill learn``'s figure), and writes ``held_out.json`` beside
the cell's ``result.json``; the report puts the two side by side. It takes seconds per cell
alone and minutes beside training, so it is a step of its own: a cell already measured on as
many episodes is not measured again, and an interrupted call goes on where it stopped.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from itskill.datafile import is_count, is_number
from itskill.executors import run_jobs
from itskill.experiments.runner import Cell, load_cell_results, read_run_config
from itskill.files import read_json_or_none, write_json

HELD_OUT_FILE = "held_out.json"
CHECKPOINT_META = "checkpoint.json"
"""The cell's checkpoint record (:data:`itskill.rl.checkpoint.META_FILE`, spelled out: importing
the rl layer would load torch for every report)."""


@dataclass
class HeldOutSummary:
    """What :func:`measure_held_out` did, cell by cell."""

    measured: list[Cell] = field(default_factory=list)
    skipped: list[Cell] = field(default_factory=list)
    """Already measured on as many episodes, at the same env-steps."""
    failed: dict[Cell, str] = field(default_factory=dict)


def read_held_out(cell_dir: Path) -> dict[str, Any] | None:
    """The cell's ``held_out.json`` if it measured the policy the cell holds now: one written
    before the cell was trained on, damaged, or missing a figure is None."""
    data = read_json_or_none(Path(cell_dir) / HELD_OUT_FILE)
    if (
        not isinstance(data, dict)
        or data.get("num_timesteps") != _trained_steps(Path(cell_dir))
        or not is_number(data.get("success"))
        or not is_count(data.get("episodes"))
    ):
        return None
    return data


def _trained_steps(cell_dir: Path) -> int | None:
    """The env-steps of the policy in ``cell_dir``, as its checkpoint records them."""
    meta = read_json_or_none(cell_dir / CHECKPOINT_META)
    return meta.get("num_timesteps") if isinstance(meta, dict) else None


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
    config = read_run_config(run_dir)
    summary = HeldOutSummary()
    todo: list[Cell] = []
    for cell in load_cell_results(run_dir):
        if cell.task not in config.tasks:
            continue
        have = read_held_out(cell.dir(run_dir))
        if have is not None and have["episodes"] == episodes:
            summary.skipped.append(cell)
        else:
            todo.append(cell)
    jobs = [(c.task, str(c.dir(run_dir)), episodes) for c in todo]
    for job in run_jobs(_measure_cell, jobs, "local", workers):
        cell = todo[job.index]
        if job.ok:
            write_json(cell.dir(run_dir) / HELD_OUT_FILE, job.value)
            summary.measured.append(cell)
        else:
            summary.failed[cell] = f"{type(job.error).__name__}: {job.error}"
        if on_cell is not None:
            on_cell(cell, job.value if job.ok else None, summary.failed.get(cell))
    return summary


def _measure_cell(task: str, cell_dir: str, episodes: int) -> dict[str, Any]:
    # Imported in the worker: the parent process needs no torch or simulator.
    import torch

    from itskill.rl.checkpoint import as_policy, read_meta
    from itskill.tasks import get_task
    from itskill.tasks.evaluate import HELD_OUT_ENVS, HELD_OUT_SEED, evaluate

    # One core a worker, as a training cell has. With PyTorch's default (a thread per core),
    # beside two training jobs on 2 cores, a peg cell took 145-310 s; alone, with one thread, 16 s.
    torch.set_num_threads(1)

    policy = as_policy(cell_dir)
    res = evaluate(get_task(task), policy, episodes, HELD_OUT_SEED, HELD_OUT_ENVS)
    return {
        "policy": "final",
        "num_timesteps": read_meta(cell_dir)["num_timesteps"],
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
