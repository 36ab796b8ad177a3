"""A generated reward against the expert's, both trained where the network learns the task.

The reward search judges its candidates at a short budget; on a complex task the transfer network
has barely left its sources' level there, so the search's own final comparison says little. This
benchmark trains the chosen reward and the expert reward on the same transfer network for the
same budget and seeds (PPO, the ``itskill learn`` default training: 300,000 env-steps), keeps each
run's best evaluated policy (``best/``) and evaluates it on 100 held-out episodes. It prints, per
reward, the final training evaluation and the held-out success per seed, their means with 95%
intervals and the env-steps to 80%; it writes ``summary.json``, ``curves.png`` and each run's
``eval.csv`` and held-out result to ``--results``. Runs go to ``--out`` (rerunning resumes them).
``--hyperparams FILE.toml`` trains both rewards with a hyper-parameter file of the packaged
file's shape instead (to compare rewards at another learning rate, say). ``--with-earlier``
pools the seeds whose runs earlier calls of the same settings kept in ``--results`` with this
call's (``--seeds`` may then be empty, to summarise the kept seeds again).

Target (issue 4): generated reward success >= the expert's.

    python benchmarks/reward_at_budget.py \\
        --reward results/reward_search/pickplace_nut_m12_itn/best_reward.py \\
        --results results/reward_search/pickplace_nut_m12_itn/at_300k
"""

from __future__ import annotations

import argparse
import hashlib
import os
import platform
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from itskill.curves import EVAL_FILE, read_curve
from itskill.executors import run_jobs
from itskill.experiments.analysis import (
    Estimate,
    common_grid,
    estimate,
    mean_band,
    time_to_threshold,
)
from itskill.experiments.plots import plot_learning_curves
from itskill.experiments.sandboxed import train_transfer_on
from itskill.files import read_json, replaced_whole, write_json
from itskill.reward_contract import EXPERT
from itskill.rl.checkpoint import BEST_DIR, as_policy
from itskill.rl.config import HyperparamError, check_hyperparams_file
from itskill.tasks import UnknownTaskError, get_task
from itskill.tasks.evaluate import HELD_OUT_ENVS, HELD_OUT_SEED, evaluate

THRESHOLD = 0.8
HELDOUT_FILE = "heldout_eval.json"


def train_one(task: str, method: str, reward: str, seed: int, steps: int, every: int,
              episodes: int, out: str, hyperparams: str | None) -> int:  # fmt: skip
    """One transfer run into ``out`` (resumed if it is there), PPO with the packaged settings
    or those of the ``hyperparams`` file. The generated reward trains only in the sandbox."""
    train_transfer_on(
        reward, "file", f"the training of seed {seed}", target=task, method=method,
        sources="auto", seed=seed, steps=steps, algo="ppo", out=Path(out), eval_every=every,
        eval_episodes=episodes, n_threads=1, progress=False, hyperparams=hyperparams,
    )  # fmt: skip
    return seed


def _band(values: list[float]) -> dict[str, float]:
    est = estimate(values)
    return {"mean": est.mean, "ci_low": est.low, "ci_high": est.high, "seeds": est.n}


def _format_band(band: dict[str, float]) -> str:
    # Seeds that all measured one rate say so, rather than a zero-width "interval".
    return Estimate(band["mean"], band["ci_low"], band["ci_high"], band["seeds"]).format(0)


REWARDS = ("generated", "expert")
REWARD_HASH = "reward_sha256"


def _earlier_seeds(results: Path, settings: dict[str, Any], seeds: list[int]) -> list[int]:
    """The seeds besides ``seeds`` whose runs an earlier call kept in ``results`` (each
    reward's ``seed_N/`` with its curve and held-out result), if ``results/summary.json`` says
    they were made with the same ``settings``: runs of other settings cannot be pooled."""
    path = results / "summary.json"
    if not path.is_file():
        return []
    before = read_json(path)
    # The reward is compared by its bytes too (a search rewrites best_reward.py in place);
    # summaries from before that was recorded are taken at their path's word.
    changed = [
        k
        for k, v in settings.items()
        if before.get(k) != v and not (k == REWARD_HASH and k not in before)
    ]
    if changed:
        raise SystemExit(
            f"{path}: made with other settings ({', '.join(changed)}); --with-earlier pools "
            "only runs of the same settings"
        )

    def kept(seed_dir: Path) -> bool:
        return (seed_dir / EVAL_FILE).is_file() and (seed_dir / HELDOUT_FILE).is_file()

    # Only the seeds this summary counted: a call that replaced an earlier summary left that
    # call's seed folders behind, made with whatever settings it had.
    counted = [set(before.get("rewards", {}).get(r, {}).get("seeds", [])) for r in REWARDS]
    return sorted(
        s
        for s in set.intersection(*counted) - set(seeds)
        if all(kept(results / r / f"seed_{s}") for r in REWARDS)
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="pickplace_nut_m12")
    parser.add_argument("--reward", type=Path, required=True, help="the generated reward (.py)")
    parser.add_argument("--method", default="itn")
    parser.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3])
    parser.add_argument("--steps", type=int, default=300_000)
    parser.add_argument("--eval-every", type=int, default=20_000)
    parser.add_argument("--eval-episodes", type=int, default=50)
    parser.add_argument("--held-out", type=int, default=100, help="held-out episodes per policy")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("runs/reward_at_budget"))
    parser.add_argument("--results", type=Path, required=True)
    parser.add_argument(
        "--hyperparams", type=Path, help="a hyper-parameter file instead of the packaged one"
    )
    parser.add_argument(
        "--with-earlier",
        action="store_true",
        help="also count the seeds whose runs earlier calls of the same settings kept in --results "
        "(their eval.csv and held-out result), so seeds added later join one summary",
    )
    args = parser.parse_args(argv)
    if not args.reward.is_file():
        parser.error(f"no reward file {args.reward}")
    if args.hyperparams is not None:
        try:  # before every job fails
            check_hyperparams_file(args.hyperparams, [(args.task, "ppo")])
        except (HyperparamError, UnknownTaskError) as err:
            parser.error(str(err))

    settings: dict[str, Any] = {
        "task": args.task,
        "method": args.method,
        "reward": str(args.reward),
        REWARD_HASH: hashlib.sha256(args.reward.read_bytes()).hexdigest(),
        "algo": "ppo",
        "hyperparams": str(args.hyperparams) if args.hyperparams else "packaged",
        "steps": args.steps,
        "eval_every": args.eval_every,
        "eval_episodes": args.eval_episodes,
        "heldout_episodes": args.held_out,
        "heldout_seed": HELD_OUT_SEED,
    }
    # Checked before training: a summary that cannot be pooled is known now, not hours later.
    earlier = _earlier_seeds(args.results, settings, args.seeds) if args.with_earlier else []
    seeds = sorted([*earlier, *args.seeds])
    if not seeds:
        parser.error("no seeds: give --seeds, or --with-earlier where a summary is kept")

    rewards = dict(zip(REWARDS, (str(args.reward), EXPERT), strict=True))
    runs = {(r, s): args.out / f"{r}_seed{s}" for r in rewards for s in args.seeds}
    t0 = time.perf_counter()
    jobs = [
        (args.task, args.method, rewards[r], s, args.steps, args.eval_every, args.eval_episodes,
         str(d), str(args.hyperparams) if args.hyperparams else None)
        for (r, s), d in runs.items()
    ]  # fmt: skip
    failed = False
    for job in run_jobs(train_one, jobs, workers=args.workers):
        if not job.ok:
            print(f"run {list(runs.values())[job.index]} failed: {job.error}", file=sys.stderr)
            failed = True
    if failed:
        return 1
    train_s = time.perf_counter() - t0
    spec = get_task(args.task)

    summary: dict[str, Any] = {
        **settings,
        "machine": f"{os.cpu_count()} CPUs ({platform.machine()}), {args.workers} runs at a time",
        "earlier_seeds": earlier,
        "rewards": {},
    }
    bands = {}
    print(f"{args.task} on {args.method}, {args.steps:,} env-steps, best/ on {args.held_out} "
          f"held-out episodes (seed {HELD_OUT_SEED})")  # fmt: skip
    for name in rewards:
        curves, heldout, stage_steps = [], [], []
        for s in seeds:
            keep = args.results / name / f"seed_{s}"
            if s in earlier:
                curves.append(read_curve(keep, args.steps))
                kept = read_json(keep / HELDOUT_FILE)
                heldout.append(kept["success_rate"])
                stage_steps.append(kept["stage_steps"])
                continue
            run_dir = runs[name, s]
            curves.append(read_curve(run_dir, args.steps))
            res = evaluate(spec, as_policy(run_dir / BEST_DIR), args.held_out,
                           seed=HELD_OUT_SEED, num_envs=HELD_OUT_ENVS)  # fmt: skip
            heldout.append(res.success_rate)
            stage_steps.append(res.stage_steps)
            # Copied to a temporary file replacing the target whole: an interrupted copy must not
            # leave a truncated curve that a later analysis would read as a short run.
            with replaced_whole(keep / EVAL_FILE) as tmp:
                shutil.copyfile(run_dir / EVAL_FILE, tmp)
            write_json(keep / HELDOUT_FILE, res.to_dict())
        reached = time_to_threshold(curves, THRESHOLD)
        final = [float(c.success[-1]) for c in curves]
        bands[name] = mean_band(curves, common_grid(curves))
        summary["rewards"][name] = {
            "seeds": seeds,
            "final": final,
            "best": [float(np.max(c.success)) for c in curves],
            "heldout": heldout,
            "reached_80": [
                int(v) if ok else None for v, ok in zip(reached.steps, reached.reached, strict=True)
            ],
            "stage_steps": np.mean(stage_steps, axis=0).tolist(),
            "final_band": _band(final),
            "heldout_band": _band(heldout),
        }
        result = summary["rewards"][name]
        print(
            f"{name:>9}: final {', '.join(f'{v:.0%}' for v in final)}, "
            f"mean {_format_band(result['final_band'])}; held-out "
            f"{', '.join(f'{v:.0%}' for v in heldout)}, "
            f"mean {_format_band(result['heldout_band'])}; "
            f"80% reached: {reached.format_steps()}"
        )
    plot_learning_curves(bands, f"{args.task}: generated vs expert reward ({args.method})",
                         args.results / "curves.png", threshold=THRESHOLD)  # fmt: skip
    write_json(args.results / "summary.json", summary)
    print(f"training {train_s / 60:.1f} min this call; results in {args.results}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
