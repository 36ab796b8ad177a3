"""Learnability check of the expert reward: PPO on one task, trained as the project trains.

    python benchmarks/expert_reward_check.py --task reach_nut_m12 --steps 50000
    python benchmarks/expert_reward_check.py --task pick_nut_m12 --steps 150000

The run is what :func:`itskill.rl.train.train` runs (:func:`~itskill.rl.train.check_training`,
then :func:`~itskill.rl.train.run_training`) with the expert reward and the task's packaged
hyper-parameters (its family's, with its own task table's changes): discount, minibatch,
learning-rate decay over ``--steps``, reward normalisation, the staged policy, training starts,
and a warm start from scripted demonstrations where the table asks for one. It trains in a
temporary directory, removed afterwards. ``--envs``, ``--n-steps``, ``--batch-size``, ``--epochs``
and ``--lr`` each override one packaged setting; the header prints the settings the run uses and
names those given.

While it trains, a progress bar on stderr shows the latest success rate. At the end it prints a
line per ``--report`` env-steps (rounded up to whole rollouts): the success rate of the episodes
that ended since the previous line (``is_success`` from the env at episode end; episodes begun
from a training start are left out, as in the trainer's ``metrics.csv``), their mean return
under the expert reward (raw, not normalised), and the wall time since learning started.
"""

from __future__ import annotations

import argparse
import tempfile
from typing import Any

from rich.console import Console

from itskill.rl.logger import LoggerConfig, read_metrics
from itskill.rl.train import EXPERT, check_training, run_training

ALGO = "ppo"
NEVER = 10**9
"""A checkpoint interval no run reaches: the run directory is thrown away, so checkpoints on the
way would only cost time (``checkpoint_every`` does not change what the run learns)."""


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The PPO settings given on the command line, by the packaged table's field names."""
    given = {
        "n_steps": args.n_steps,
        "batch_size": args.batch_size,
        "n_epochs": args.epochs,
        "learning_rate": args.lr,
    }
    return {key: value for key, value in given.items() if value is not None}


def _number(value: float | None, width: int) -> str:
    # metrics.jsonl holds null for the figures of a row in which no episode ended.
    return f"{'-':>{width}s}" if value is None else f"{value:{width}.2f}"


def main(argv: list[str] | None = None) -> None:
    """Train PPO with the expert reward on ``--task`` and print its success rate over steps."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="reach_nut_m12")
    parser.add_argument("--steps", type=int, default=50_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--envs", type=int, help="environments (default: packaged num_envs)")
    parser.add_argument("--report", type=int, default=5_000, help="env-steps per printed line")
    parser.add_argument("--threads", type=int, default=1, help="physics threads of the env")
    parser.add_argument(
        "--n-steps", type=int, help="PPO rollout length per env (default: packaged)"
    )
    parser.add_argument("--batch-size", type=int, help="PPO minibatch (default: packaged)")
    parser.add_argument("--epochs", type=int, help="PPO epochs per update (default: packaged)")
    parser.add_argument("--lr", type=float, help="initial learning rate (default: packaged)")
    args = parser.parse_args(argv)

    overrides = _overrides(args)
    with tempfile.TemporaryDirectory(prefix="expert_reward_check-") as out:
        setup = check_training(
            args.task,
            ALGO,
            args.steps,
            args.seed,
            EXPERT,
            out,
            num_envs=args.envs,
            overrides={**overrides, "checkpoint_every": NEVER},
        )
        hp, ppo = setup.hp, setup.hp.algo_config
        changed = [f"{k}={v}" for k, v in overrides.items()]
        if args.envs is not None:
            changed.append(f"num_envs={args.envs}")
        print(
            f"task {args.task}  steps {args.steps}  envs {hp.num_envs}  seed {args.seed}  "
            f"n_steps {ppo.n_steps}  batch {ppo.batch_size}  epochs {ppo.n_epochs}  "
            f"lr {ppo.learning_rate:g} ({ppo.lr_schedule})  gamma {ppo.gamma}  "
            f"reward norm {hp.normalize_reward}  demos {hp.demos.episodes}  "
            f"settings: {'packaged except ' + ', '.join(changed) if changed else 'packaged'}",
            flush=True,
        )
        run_training(
            setup,
            logger=LoggerConfig(min_steps_per_row=args.report, tensorboard=False),
            n_threads=args.threads,
            # The progress bar goes to stderr, so stdout holds only the header and the lines.
            console=Console(stderr=True),
        )
        for row in read_metrics(out):
            print(
                f"steps {row['step']:7d}  success {_number(row['success_rate'], 5)}  "
                f"({row['episodes']:4d} episodes)  return {_number(row['ep_return'], 7)}  "
                f"wall {row['wall_s']:6.0f}s"
            )


if __name__ == "__main__":
    main()
