"""End-to-end training throughput (A2C, PPO) next to the bare ``BatchEnv`` rate, in one run.

(a) bare: ``BatchEnv`` stepped with uniform random actions through the VecEnv API;
(b) a2c / ppo: ``itskill.rl.train`` for a fixed number of env-steps (rollouts, gradient updates,
    metrics), with the same task, ``num_envs`` and the packaged hyper-parameters. The rate is read
    off the trainer's own clock in ``metrics.csv`` between its first row (after about 1,000
    env-steps) and its last, so building the environments and the model, the first checkpoint,
    the first rollouts' one-time start-up and the final checkpoint are not in it, as they are not
    in (a); a large ``checkpoint_every`` keeps checkpoints out of the loop.

    python benchmarks/train_throughput.py [--json] [--task reach_nut_m12] [--num-envs 16]
                                          [--steps N]

Target: training env-steps/s >= 0.5 x the bare rate.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from itskill.rl.logger import LoggerConfig
from itskill.rl.train import train
from itskill.tasks import make_batch_env

REWARD = """
import numpy as np

def compute_reward(ctx):
    d = np.linalg.norm(ctx["obj_to_ee"][:, 0], axis=-1)
    return -d, {"distance": -d}
"""


def bare_rate(task: str, num_envs: int, steps: int, reward_fn) -> float:
    env = make_batch_env(task, num_envs, seed=0, reward_fn=reward_fn)
    rng = np.random.default_rng(0)
    env.reset()
    n_batches = max(1, steps // num_envs)
    start = time.perf_counter()
    for _ in range(n_batches):
        env.step(rng.uniform(-1, 1, (num_envs, 5)))
    rate = n_batches * num_envs / (time.perf_counter() - start)
    env.close()
    return rate


def train_rate(task: str, algo: str, num_envs: int, steps: int, reward: Path, tmp: Path) -> float:
    result = train(
        task, algo, steps, seed=0, reward=reward, out=tmp / algo, num_envs=num_envs,
        overrides={"checkpoint_every": 10**9},
        logger=LoggerConfig(progress=False, tensorboard=True),
    )  # fmt: skip
    with open(result.run_dir / "metrics.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    if len(rows) < 2:
        raise SystemExit(f"--steps {steps}: too few to time the training between two metrics rows")
    first, last = rows[0], rows[-1]
    return (int(last["step"]) - int(first["step"])) / (
        float(last["wall_s"]) - float(first["wall_s"])
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--task", default="reach_nut_m12")
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--steps", type=int, default=8192)
    args = parser.parse_args()
    if args.steps < 1 or args.num_envs < 1:
        parser.error("--steps and --num-envs must be at least 1")
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        reward = tmp / "reward.py"
        reward.write_text(REWARD)
        namespace: dict = {}
        exec(REWARD, namespace)
        bare = bare_rate(args.task, args.num_envs, args.steps, namespace["compute_reward"])
        rates = {
            a: train_rate(args.task, a, args.num_envs, args.steps, reward, tmp)
            for a in ("a2c", "ppo")
        }
    result = {
        "task": args.task,
        "num_envs": args.num_envs,
        "steps": args.steps,
        "cpus": os.cpu_count(),
        "bare_env_steps_per_s": round(bare, 1),
        **{f"{a}_env_steps_per_s": round(r, 1) for a, r in rates.items()},
        **{f"{a}_ratio": round(r / bare, 3) for a, r in rates.items()},
        "target_ratio": 0.5,
    }
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        for key, value in result.items():
            print(f"{key:>24}: {value}")


if __name__ == "__main__":
    main()
