"""Does keeping the best evaluated policy pay off on held-out episodes?

PPO can lose a level it reached: on the peg task ITN seeds 1 and 3 reached 80% and ended at 0%
(docs/experiments.md). A run evaluated while it trains keeps the policy of its best evaluation in
``best/`` (:mod:`itskill.rl.eval_callback`). That choice is made on the training-time evaluation
episodes, so their score flatters it; this benchmark trains transfer runs (resumable: a rerun
continues them), then evaluates both the last checkpoint and ``best/`` on held-out episodes (the
seed ``itskill learn`` reports on) and prints the two side by side.

    python benchmarks/best_policy.py                        # ITN on the peg, seeds 1 and 3
    python benchmarks/best_policy.py --seeds 0 2 4 --json runs/best_policy_seeds_0_2_4.json

It trains with the task's packaged hyper-parameters of the day; ``--hyperparams FILE.toml`` (the
packaged file's shape) trains with others: the runs in ``results/best_policy/`` (2026-12-02) were
at the peg task's packaged settings then, log-std -0.5 and a PPO learning rate of 3e-5.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from itskill.curves import read_curve
from itskill.executors import run_jobs
from itskill.files import write_json
from itskill.rl.checkpoint import BEST_DIR, as_policy, read_meta
from itskill.rl.config import HyperparamError, check_hyperparams_file
from itskill.rl.eval_callback import read_selection
from itskill.tasks import UnknownTaskError, get_task
from itskill.tasks.evaluate import HELD_OUT_ENVS, HELD_OUT_SEED, evaluate
from itskill.transfer import train_transfer


def train_one(
    task: str, method: str, seed: int, steps: int, every: int, episodes: int, out: str,
    hyperparams: str | None,
):  # fmt: skip
    """One transfer run into ``out`` (resumed if it is there), PPO with the packaged settings
    or those of ``hyperparams``."""
    train_transfer(
        task, method, "auto", seed=seed, steps=steps, algo="ppo", out=Path(out),
        hyperparams=hyperparams, eval_every=every, eval_episodes=episodes, n_threads=1,
        progress=False,
    )  # fmt: skip
    return seed


def measure(task: str, run_dir: Path, episodes: int) -> dict[str, Any]:
    """Held-out success of the last checkpoint and of ``best/``, with what chose the latter."""
    spec = get_task(task)
    row: dict[str, Any] = {"run_dir": str(run_dir), "steps": read_meta(run_dir)["num_timesteps"]}
    for name, where in (("last", run_dir), ("best", run_dir / BEST_DIR)):
        res = evaluate(spec, as_policy(where), episodes, seed=HELD_OUT_SEED, num_envs=HELD_OUT_ENVS)
        row[name] = {"success": res.success_rate, "ci": [res.ci_low, res.ci_high]}
    row["selection"] = read_selection(run_dir)
    row["last_training_eval"] = float(read_curve(run_dir, row["steps"]).success[-1])
    return row


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="pickplaceinsert_peg_rect")
    parser.add_argument("--method", default="itn")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 3])
    parser.add_argument("--steps", type=int, default=500_000)
    parser.add_argument("--eval-every", type=int, default=50_000)
    parser.add_argument("--eval-episodes", type=int, default=40)
    parser.add_argument("--held-out", type=int, default=100, help="held-out episodes per policy")
    parser.add_argument(
        "--hyperparams", type=Path, default=None, help="a hyper-parameter TOML file instead of "
        "the packaged one",
    )  # fmt: skip
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("runs/bench_best_policy"))
    parser.add_argument("--json", type=Path, help="also write the results as JSON")
    args = parser.parse_args(argv)
    if args.hyperparams is not None:
        try:  # before every job fails
            check_hyperparams_file(args.hyperparams, [(args.task, "ppo")])
        except (HyperparamError, UnknownTaskError) as err:
            parser.error(str(err))

    runs = {s: args.out / args.task / args.method / f"seed_{s}" for s in args.seeds}
    t0 = time.perf_counter()
    jobs = [
        (
            args.task,
            args.method,
            s,
            args.steps,
            args.eval_every,
            args.eval_episodes,
            str(d),
            None if args.hyperparams is None else str(args.hyperparams),
        )
        for s, d in runs.items()
    ]
    failed = False
    for job in run_jobs(train_one, jobs, workers=args.workers):
        if not job.ok:
            print(f"seed {args.seeds[job.index]} failed: {job.error}", file=sys.stderr)
            failed = True
    if failed:
        return 1
    train_s = time.perf_counter() - t0

    rows = {s: measure(args.task, d, args.held_out) for s, d in runs.items()}
    print(
        f"{args.task}, {args.method}, {args.steps:,} env-steps, held-out success over "
        f"{args.held_out} episodes (seed {HELD_OUT_SEED})"
    )
    print(f"{'seed':>4}  {'best chosen at':>24}  {'last eval':>9}  {'last':>17}  {'best/':>17}")
    for s, r in rows.items():
        sel = r["selection"]
        chosen = f"{sel['success']:.0%} at {int(sel['env_steps']):,}"
        last, best = r["last"], r["best"]
        print(
            f"{s:>4}  {chosen:>24}  {r['last_training_eval']:>9.0%}  "
            f"{last['success']:>5.0%} [{last['ci'][0]:.0%}, {last['ci'][1]:.0%}]  "
            f"{best['success']:>5.0%} [{best['ci'][0]:.0%}, {best['ci'][1]:.0%}]"
        )
    mean_last = float(np.mean([r["last"]["success"] for r in rows.values()]))
    mean_best = float(np.mean([r["best"]["success"] for r in rows.values()]))
    print(f"mean held-out success: last checkpoint {mean_last:.1%}, best/ {mean_best:.1%}")
    print(f"training {train_s / 60:.1f} min this call on {platform.node()}")
    if args.json:
        write_json(
            args.json,
            {
                "task": args.task,
                "method": args.method,
                "steps": args.steps,
                "eval_every": args.eval_every,
                "eval_episodes": args.eval_episodes,
                "held_out_episodes": args.held_out,
                "held_out_seed": HELD_OUT_SEED,
                "seeds": {str(s): r for s, r in rows.items()},
                "mean_last": mean_last,
                "mean_best": mean_best,
            },
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
