"""Learnability check of the expert reward: PPO (Stable-Baselines3) on one task, success vs steps.

    python benchmarks/expert_reward_check.py --task reach_nut_m12 --steps 50000
    python benchmarks/expert_reward_check.py --task pick_nut_m12 --steps 150000

Prints, every ``--report`` env-steps, the success rate of the episodes that ended since the last
line (``is_success`` from the env at episode end), the mean episode return, and wall time.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecNormalize

from itskill.tasks import get_task, make_batch_env
from itskill.tasks.rewards import expert_reward


class SuccessLog(BaseCallback):
    """Collect episode outcomes from the VecEnv's infos; print a line every ``every`` steps."""

    def __init__(self, every: int, last_stage: np.ndarray) -> None:
        super().__init__()
        self.last_stage = last_stage
        self.final_stages: list[int] = []
        self.every, self.next_report = every, every
        self.successes: list[bool] = []
        self.returns: list[float] = []
        self.ret: np.ndarray | None = None
        self.start = time.perf_counter()
        self.rows: list[tuple[int, float, float]] = []

    def _on_step(self) -> bool:
        rewards, dones = self.locals["rewards"], self.locals["dones"]
        if self.ret is None:
            self.ret = np.zeros(len(rewards))
        self.ret += rewards
        for e in np.flatnonzero(dones):
            self.successes.append(bool(self.locals["infos"][e].get("is_success", False)))
            self.returns.append(float(self.ret[e]))
            self.final_stages.append(int(self.last_stage[e]))
            self.ret[e] = 0.0
        if self.num_timesteps >= self.next_report:
            self.next_report += self.every
            rate = float(np.mean(self.successes)) if self.successes else float("nan")
            ret = float(np.mean(self.returns)) if self.returns else float("nan")
            self.rows.append((self.num_timesteps, rate, ret))
            hist = np.bincount(self.final_stages, minlength=int(self.last_stage.max()) + 1)
            print(
                f"steps {self.num_timesteps:7d}  success {rate:5.2f}  "
                f"({len(self.successes):4d} episodes)  return {ret:7.2f}  "
                f"final stages {hist.tolist()}  wall {time.perf_counter() - self.start:6.0f}s",
                flush=True,
            )
            self.successes, self.returns, self.final_stages = [], [], []
        return True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="reach_nut_m12")
    parser.add_argument("--steps", type=int, default=50_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--envs", type=int, default=16)
    parser.add_argument("--report", type=int, default=5_000)
    parser.add_argument("--threads", type=int, default=1, help="physics threads of the env")
    parser.add_argument("--n-steps", type=int, default=64, help="PPO rollout length per env")
    parser.add_argument("--batch-size", type=int, default=512)
    parser.add_argument("--epochs", type=int, default=5)
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument(
        "--norm-obs", action="store_true", help="normalise observations (SB3 VecNormalize)"
    )
    args = parser.parse_args()

    torch.set_num_threads(1)
    spec = get_task(args.task)
    reward = expert_reward(spec)
    last_stage = np.zeros(args.envs, dtype=np.int64)

    def logged_reward(ctx):
        # The env computes the reward on the terminal state before it resets, so this holds each
        # environment's stage at the end of its episode when the callback sees ``dones``.
        last_stage[:] = ctx["stage"]
        return reward(ctx)

    env = make_batch_env(
        args.task,
        num_envs=args.envs,
        seed=args.seed,
        reward_fn=logged_reward,
        n_threads=args.threads,
    )
    venv = VecNormalize(env, norm_obs=True, norm_reward=False) if args.norm_obs else env
    # The project's PPO settings (itskill/rl/data/hyperparams.toml), except a shorter rollout so
    # that a 50k-step budget still gets ~50 updates.
    model = PPO(
        "MlpPolicy",
        venv,
        n_steps=args.n_steps,
        batch_size=args.batch_size,
        n_epochs=args.epochs,
        learning_rate=args.lr,
        gamma=0.99,
        gae_lambda=0.95,
        clip_range=0.2,
        ent_coef=0.0,
        policy_kwargs={
            "net_arch": {"pi": [256, 256, 128], "vf": [256, 256, 128]},
            "activation_fn": torch.nn.Tanh,
            "log_std_init": -0.5,
        },
        seed=args.seed,
        device="cpu",
        verbose=0,
    )
    log = SuccessLog(args.report, last_stage)
    print(
        f"task {args.task}  steps {args.steps}  envs {args.envs}  seed {args.seed}  "
        f"norm_obs {args.norm_obs}  batch {args.batch_size}  epochs {args.epochs}",
        flush=True,
    )
    model.learn(total_timesteps=args.steps, callback=log)
    env.close()


if __name__ == "__main__":
    main()
