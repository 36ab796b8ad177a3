"""`itskill train`: train one task with A2C or PPO into a resumable run directory."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from itskill.cli.common import (
    SKILL_PREFIX,
    EvalEpisodesOpt,
    EvalEveryOpt,
    HyperparamsOpt,
    TaskArg,
    console,
    print_trained,
    run_dir_option,
    seed_option,
    skill_checkpoint,
    steps_option,
    user_errors,
)
from itskill.limits import EPISODES_MAX, NUM_ENVS_MAX


def train_cmd(
    task: TaskArg,
    algo: Annotated[str, typer.Option(help="a2c (the paper's algorithm) or ppo.")] = "ppo",
    steps: Annotated[int, steps_option("Total env-steps (a rerun resumes).")] = 100_000,
    seed: Annotated[int, seed_option("Seed of the run.")] = 0,
    reward: Annotated[
        str, typer.Option(help="'expert' or a .py file defining compute_reward(ctx).")
    ] = "expert",
    out: Annotated[Path, run_dir_option("Run directory (checkpoints, metrics).")] = Path(
        "runs/train"
    ),
    num_envs: Annotated[
        int | None, typer.Option(min=1, max=NUM_ENVS_MAX, help="Environments stepped together.")
    ] = None,
    hyperparams: HyperparamsOpt = None,
    eval_every: EvalEveryOpt = None,
    eval_episodes: EvalEpisodesOpt = 50,
    demos: Annotated[
        int | None,
        typer.Option(
            min=0,
            max=EPISODES_MAX,
            help="Warm start: clone the task's scripted controller over this many episodes "
            "before RL (0: off; default: the hyper-parameters' demos.episodes).",
        ),
    ] = None,
    init: Annotated[
        str | None,
        typer.Option(
            help="Start from this trained policy (skill:NAME, or a run or skill directory or "
            "its policy.safetensors, with the same network shape) instead of random weights, "
            "with the hyper-parameters' init table's action noise and learning rate.",
        ),
    ] = None,
) -> None:
    """Train a policy with A2C or PPO; rerun the same command to resume from the last checkpoint."""
    from itskill.rl.config import ALGOS
    from itskill.rl.train import train

    if algo not in ALGOS:
        raise typer.BadParameter(f"expected one of {', '.join(ALGOS)}", param_hint="--algo")
    try:
        with user_errors():
            result = train(
                task,
                algo,
                steps,
                seed,
                reward,
                out,
                num_envs,
                hyperparams,
                overrides=None if demos is None else {"demos": {"episodes": demos}},
                console=console,
                eval_every=eval_every,
                eval_episodes=eval_episodes,
                init=None if init is None else _init_source(init),
            )
    except KeyboardInterrupt:
        raise typer.Exit(130) from None
    print_trained(f"{task} with {algo}", result, steps)


def _init_source(init: str) -> Path:
    """What ``--init`` names, as :func:`~itskill.rl.init_policy.describe_init` takes it: a
    skill's own weights file, or the path given. A weights file stays a file: its directory
    would mean the best policy of the run it lies in."""
    if init.startswith(SKILL_PREFIX):
        return skill_checkpoint(init[len(SKILL_PREFIX) :])
    return Path(init)
