"""Task suite: the paper's Table I and the wider skill set as TOML data, scripted controllers."""

from __future__ import annotations

from typing import TYPE_CHECKING

from itskill.sim.task import RewardFn
from itskill.tasks.spec import (
    TaskFileError,
    TaskSpec,
    UnknownTaskError,
    all_tasks,
    get_task,
)

if TYPE_CHECKING:
    from itskill.sim.env import TaskEnv
    from itskill.sim.vec_env import BatchEnv


def make_env(name: str, reward_fn: RewardFn | None = None, **kwargs) -> TaskEnv:
    """A single Gymnasium environment for task ``name``."""
    # Imported here: the environments bring Stable-Baselines3 and torch, which reading tasks
    # (the skill space's commands, the planner) does not need.
    from itskill.sim.env import TaskEnv

    return TaskEnv(get_task(name).to_sim_task(), reward_fn=reward_fn, **kwargs)


def make_batch_env(
    task: str | TaskSpec,
    num_envs: int = 8,
    seed: int | None = None,
    reward_fn: RewardFn | None = None,
    n_threads: int | None = None,
    training: bool = False,
) -> BatchEnv:
    """``num_envs`` copies of ``task`` (a task id or a spec) stepped together (an SB3
    ``VecEnv``); ``training`` turns on the task's training starts."""
    from itskill.sim.vec_env import BatchEnv

    spec = get_task(task) if isinstance(task, str) else task
    return BatchEnv(
        spec.to_sim_task(),
        num_envs=num_envs,
        seed=seed,
        reward_fn=reward_fn,
        n_threads=n_threads,
        training=training,
    )


__all__ = [
    "TaskFileError",
    "TaskSpec",
    "UnknownTaskError",
    "all_tasks",
    "get_task",
    "make_batch_env",
    "make_env",
]
