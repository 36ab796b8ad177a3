"""How fast basic skills are learned from scratch with the expert reward.

For each task x algorithm x seed, train with periodic deterministic evaluation
(:class:`itskill.rl.eval_callback.DeterministicEvalCallback`), then report per task and algorithm:
env-steps and wall-minutes to 80% and 90% deterministic success (mean over the seeds that got
there, and how many did), the final success, and a learning-curve plot with a 95% band across
seeds. Runs are resumable: rerunning the same command continues unfinished trainings.

Targets (the task-suite issue): Pick (nut M12) at 80% within 200k env-steps and 5 wall-minutes
with PPO; A2C within 2x PPO's steps; every basic skill >= 95% final success.

``--reward FILE.py`` trains with another reward than the expert's (a generated one, say, to set
it against the expert's at a budget that learns the task: the reward search's own budget is too
short to tell the two apart, docs/reward.md). The file is run as trusted Python, as by
``itskill train --reward``. ``--hyperparams FILE.toml`` trains with a hyper-parameter file of the
packaged file's shape instead of the packaged one, to screen settings on several seeds.

    python benchmarks/learn_basic.py --tasks pick_nut_m12 --algos ppo a2c --seeds 0 1 2 \
        --steps 200000 --a2c-steps 300000
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from itskill.executors import EXECUTORS, run_jobs
from itskill.experiments.analysis import read_curve
from itskill.rl.train import train
from itskill.stats import mean_interval, steps_to_threshold

THRESHOLDS = (0.8, 0.9)


def run_one(
    task: str,
    algo: str,
    seed: int,
    steps: int,
    every: int,
    episodes: int,
    out: str,
    reward: str,
    hyperparams: str | None,
):
    """One training run with evaluations; returns its eval curve (picklable)."""
    run_dir = Path(out) / "runs" / task / algo / f"seed{seed}"
    train(
        task,
        algo=algo,
        steps=steps,
        seed=seed,
        reward=reward,
        out=run_dir,
        hyperparams=hyperparams,
        n_threads=1,
        eval_every=every,
        eval_episodes=episodes,
    )
    # read_curve drops rows a crashed session evaluated after its last checkpoint and adds up the
    # wall time of resumed sessions.
    curve = read_curve(run_dir, steps)
    return {
        "seed": seed,
        "budget": steps,
        "steps": [int(x) for x in curve.steps],
        "wall_s": [float(x) for x in curve.wall_s],
        "success": [float(x) for x in curve.success],
    }


def summarise(curves: list[dict]) -> dict:
    """Steps and minutes to each threshold (over the seeds that reached it) and final success."""
    out: dict = {"seeds": len(curves)}
    for thr in THRESHOLDS:
        hits = [
            (
                steps_to_threshold(c["steps"], c["success"], thr),
                steps_to_threshold(c["wall_s"], c["success"], thr),
                c["budget"],
            )
            for c in curves
        ]
        # Training ends one rollout past its budget: a crossing at that last evaluation is not
        # within the budget.
        reached = [(s, w) for s, w, budget in hits if s is not None and s <= budget]
        key = f"to_{round(thr * 100)}"
        out[key] = {
            "reached": len(reached),
            "env_steps_mean": mean_interval([s for s, _ in reached])[0] if reached else None,
            "wall_min_mean": mean_interval([w for _, w in reached])[0] / 60 if reached else None,
        }
    curves = sorted(curves, key=lambda c: c["seed"])
    finals = [c["success"][-1] for c in curves]
    mean, low, high = mean_interval(finals)
    # A rate's interval is clipped to [0, 1]; with 3 seeds the t-interval easily runs past it.
    out["final_success"] = {
        "mean": mean,
        "ci": [max(low, 0.0), min(high, 1.0)],
        "per_seed": finals,
        "seeds": [c["seed"] for c in curves],
    }
    out["final_steps"] = max(c["steps"][-1] for c in curves)
    return out


def _cell(s: dict, key: str) -> str:
    c, seeds = s[key], s["seeds"]
    if not c["reached"]:
        return f"not reached (0/{seeds})"
    return f"{c['env_steps_mean']:,.0f} / {c['wall_min_mean']:.1f} ({c['reached']}/{seeds})"


def plot(task: str, curves_by_algo: dict[str, list[dict]], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(6, 4))
    for algo, curves in curves_by_algo.items():
        n = min(len(c["steps"]) for c in curves)
        x = np.asarray(curves[0]["steps"][:n])
        ys = np.asarray([c["success"][:n] for c in curves])
        bands = np.asarray([mean_interval(ys[:, k]) for k in range(n)])
        (line,) = ax.plot(x, bands[:, 0], lw=2, label=f"{algo}: mean of {len(curves)} seeds")
        ax.fill_between(
            x,
            np.clip(bands[:, 1], 0, 1),
            np.clip(bands[:, 2], 0, 1),
            alpha=0.15,
            color=line.get_color(),
        )
        for y in ys:  # each seed, so a wide band can be read as spread, not noise
            ax.plot(x, y, lw=0.7, alpha=0.5, color=line.get_color())
    for thr in THRESHOLDS:
        ax.axhline(thr, color="grey", lw=0.6, ls=":")
    ax.set(xlabel="env-steps", ylabel="deterministic success", title=task, ylim=(0, 1.02))
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", nargs="+", default=["pick_nut_m12"])
    parser.add_argument("--algos", nargs="+", default=["ppo", "a2c"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--steps", type=int, default=200_000)
    parser.add_argument(
        "--a2c-steps",
        type=int,
        default=None,
        help="A2C's budget (default: --steps); twice PPO's shows whether A2C is within 2x",
    )
    parser.add_argument("--eval-every", type=int, default=10_000)
    parser.add_argument("--eval-episodes", type=int, default=50)
    parser.add_argument("--reward", default="expert", help="expert, or a reward file (.py)")
    parser.add_argument(
        "--hyperparams",
        type=Path,
        default=None,
        help="a hyper-parameter TOML file instead of the packaged one (to screen settings)",
    )
    parser.add_argument("--executor", choices=EXECUTORS, default="local")
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--out", type=Path, default=Path("results/learn_basic"))
    args = parser.parse_args()

    args.out.mkdir(parents=True, exist_ok=True)
    cells = [(t, a, s) for t in args.tasks for a in args.algos for s in args.seeds]
    budget = {"a2c": args.a2c_steps or args.steps}
    hyperparams = str(args.hyperparams) if args.hyperparams else None
    common = (args.eval_every, args.eval_episodes, str(args.out), args.reward, hyperparams)
    jobs = [(t, a, s, budget.get(a, args.steps), *common) for t, a, s in cells]
    curves: dict[tuple[str, str], list[dict]] = {}
    for res in run_jobs(run_one, jobs, args.executor, args.workers):
        task, algo, seed = cells[res.index]
        if not res.ok:
            print(f"{task} {algo} seed {seed}: FAILED {type(res.error).__name__}: {res.error}")
            continue
        curves.setdefault((task, algo), []).append(res.value)
        print(f"{task} {algo} seed {seed}: final success {res.value['success'][-1]:.0%}")

    summary = {
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
        "settings": {
            k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items() if k != "out"
        },
        "results": {},
    }
    print(f"\n{'task':24s} {'algo':5s} {'to 80%: steps / min (seeds)':32s} {'to 90%':28s} final")
    for task in args.tasks:
        by_algo = {a: curves[(task, a)] for a in args.algos if (task, a) in curves}
        if not by_algo:
            continue
        plot(task, by_algo, args.out / f"{task}.png")
        for algo, cs in by_algo.items():
            s = summarise(cs)
            summary["results"][f"{task}/{algo}"] = s
            final = s["final_success"]
            print(
                f"{task:24s} {algo:5s} {_cell(s, 'to_80'):32s} {_cell(s, 'to_90'):28s} "
                f"{final['mean']:.0%} [{final['ci'][0]:.0%}, {final['ci'][1]:.0%}]"
            )
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"\nplots and summary.json in {args.out}")


if __name__ == "__main__":
    main()
