"""Each finished cell's final or best policy on held-out episodes (``itskill experiment held-out
RUN [--policy best]``).

A run's curves are drawn on its evaluation episodes, the same at every evaluation: the last
point of a curve is read off them, and the best policy (``best/``) is the one that scored most
on them, so its score there flatters it. This measures a cell's policy once
more, on episodes no run trains or evaluates on (:data:`itskill.tasks.evaluate.HELD_OUT_SEED`,
the episodes of the library's success rates and of ``itskill learn``'s figure), and writes
``held_out.json`` beside the policy's checkpoint (the cell's own, or ``best/``'s); the report
puts each beside the evaluation it was chosen or drawn at. It takes seconds per cell
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
from itskill.experiments.runner import Cell, cells, load_cell_results, read_run_config
from itskill.files import read_json_or_none, write_json
from itskill.rl.checkpoint import BEST_DIR, META_FILE

HELD_OUT_FILE = "held_out.json"


class TaskChangedError(ValueError):
    """A cell's policy was trained on its task as the task file defined it then, not now."""


POLICY_DIRS = {"final": ".", "best": BEST_DIR}
"""Which of a cell's policies, and where it lies in the cell's directory."""


def policy_dir(cell_dir: Path, policy: str) -> Path:
    """Where a cell's ``policy`` (a key of :data:`POLICY_DIRS`) lies; ``ValueError`` naming the
    known ones for another."""
    if policy not in POLICY_DIRS:
        raise ValueError(f"unknown policy {policy!r}; expected one of {', '.join(POLICY_DIRS)}")
    return Path(cell_dir) / POLICY_DIRS[policy]


@dataclass
class HeldOutSummary:
    """What :func:`measure_held_out` did, cell by cell."""

    measured: list[Cell] = field(default_factory=list)
    skipped: list[Cell] = field(default_factory=list)
    """Already measured on as many episodes, at the same env-steps."""
    failed: dict[Cell, str] = field(default_factory=dict)
    unfinished: list[Cell] = field(default_factory=list)
    """Cells of the run without a readable ``result.json``: not trained to the end (or the
    record damaged), so there is no final policy to measure; ``experiment run --resume``
    finishes them."""


def read_held_out(cell_dir: Path, policy: str = "final") -> dict[str, Any] | None:
    """The ``held_out.json`` of the cell's ``policy`` if it measured the policy the cell holds
    now: one written before the cell was trained on (or chose another best), damaged, or
    missing a figure is None."""
    where = policy_dir(cell_dir, policy)
    data = read_json_or_none(where / HELD_OUT_FILE)
    if (
        not isinstance(data, dict)
        or not is_count(data.get("num_timesteps"))
        or data.get("num_timesteps") != _trained_steps(where)
        or not is_number(data.get("success"))
        or not is_count(data.get("episodes"))
    ):
        return None
    return data


def _trained_steps(where: Path) -> int | None:
    """The env-steps of the policy in ``where``, as its checkpoint records them."""
    meta = read_json_or_none(where / META_FILE)
    return meta.get("num_timesteps") if isinstance(meta, dict) else None


def measure_held_out(
    run_dir: str | Path,
    episodes: int = 200,
    workers: int | None = None,
    on_cell: Callable[[Cell, dict[str, Any] | None, str | None], None] | None = None,
    policy: str = "final",
) -> HeldOutSummary:
    """Measure the ``policy`` (``final`` or ``best``) of every finished cell of experiment run
    ``run_dir`` on ``episodes`` held-out episodes, ``workers`` cells at a time (one per core by
    default), and write its ``held_out.json``. ``on_cell(cell, record, error)`` hears of each
    cell as it ends. A cell that fails (its weights missing, as in a report's copy of a run, or
    no best policy kept) is named in the summary and the others go on."""
    if episodes < 1:
        raise ValueError(f"episodes must be at least 1, got {episodes}")
    policy_dir(Path(), policy)  # an unknown one is refused before any cell
    run_dir = Path(run_dir)
    config = read_run_config(run_dir)
    summary = HeldOutSummary()
    todo: list[Cell] = []
    finished = load_cell_results(run_dir)
    for cell in cells(config):
        if cell not in finished:
            summary.unfinished.append(cell)
            continue
        have = read_held_out(cell.dir(run_dir), policy)
        if have is not None and have["episodes"] == episodes:
            summary.skipped.append(cell)
        else:
            todo.append(cell)
    jobs = [(c.task, str(c.dir(run_dir)), episodes, policy) for c in todo]
    for job in run_jobs(_measure_cell, jobs, "local", workers):
        cell = todo[job.index]
        if job.ok:
            write_json(policy_dir(cell.dir(run_dir), policy) / HELD_OUT_FILE, job.value)
            summary.measured.append(cell)
        else:
            summary.failed[cell] = f"{type(job.error).__name__}: {job.error}"
        if on_cell is not None:
            on_cell(cell, job.value if job.ok else None, summary.failed.get(cell))
    return summary


def _measure_cell(task: str, cell_dir: str, episodes: int, policy: str) -> dict[str, Any]:
    # Imported in the worker, which alone runs the simulator.
    import torch

    from itskill.rl.checkpoint import (
        TASK_CHANGED,
        as_policy,
        read_meta,
        trained_on_another_version,
    )
    from itskill.tasks import get_task
    from itskill.tasks.evaluate import HELD_OUT_ENVS, HELD_OUT_SEED, evaluate

    # One core a worker, as a training cell has. With PyTorch's default (a thread per core),
    # beside two training jobs on 2 cores, a peg cell took 145-310 s; alone, with one thread, 16 s.
    torch.set_num_threads(1)

    where = policy_dir(Path(cell_dir), policy)
    if not (where / META_FILE).is_file():
        raise FileNotFoundError(f"{where}: no {policy} policy kept (no {META_FILE})")
    spec, meta = get_task(task), read_meta(where)
    if trained_on_another_version(meta, spec.fingerprint):
        raise TaskChangedError(
            f"{where}: trained on {task} as the task was then; {TASK_CHANGED}, so a held-out "
            "figure now would measure another task: train the cell again, or measure it on a "
            "checkout of the task file it trained on"
        )
    res = evaluate(spec, as_policy(where), episodes, HELD_OUT_SEED, HELD_OUT_ENVS)
    return {
        "policy": policy,
        "num_timesteps": meta["num_timesteps"],
        "task_sha256": spec.fingerprint,  # the version of the task it was measured on
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
