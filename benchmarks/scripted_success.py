"""Success rate of the scripted waypoint controller on each task.

Runs N episodes (default 100) per task on a batch of environments and prints the success rate with
a Wilson 95% interval and the wall time. By default it runs every Table I task; ``--check`` makes
it exit non-zero if any Table I task it ran is below 90%. ``--random`` adds the success of a
uniformly random policy over the same number of episodes: what a task gives away by chance.
``--noise SIGMA`` adds Gaussian noise to the controller's actions, as a learner exploring around
it would (the scripted insert of the rectangular peg succeeds in 2% at 0.3: docs/training.md).

    python benchmarks/scripted_success.py
    python benchmarks/scripted_success.py --tasks pick_nut_m12 screw_nut_m16 --episodes 50
    python benchmarks/scripted_success.py --tasks grasp_nut_m12_bolt --episodes 50 --random
    python benchmarks/scripted_success.py --tasks insert_peg_rect --noise 0.3
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from itskill.files import write_json
from itskill.stats import wilson_interval
from itskill.tasks import all_tasks, get_task
from itskill.tasks.evaluate import RandomPolicy, evaluate, noise_sigma
from itskill.tasks.scripted import run_episodes

THRESHOLD = 0.9


def main(argv: list[str] | None = None) -> int:
    """Run the scripted controller on each task and print its success; 1 if ``--check`` fails."""
    table_i = [name for name, spec in all_tasks().items() if spec.table_i]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=table_i, help="task ids (default: Table I)")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--num-envs", type=int, default=25)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, metavar="PATH", help="also write the results as JSON")
    parser.add_argument("--random", action="store_true", help="also run a random policy")
    parser.add_argument(
        "--noise",
        type=noise_sigma,
        default=0.0,
        metavar="SIGMA",
        help="standard deviation of Gaussian noise added to the controller's actions",
    )
    below = f"exit 1 if a Table I task is below {THRESHOLD * 100:.0f}%%"
    parser.add_argument("--check", action="store_true", help=below)
    args = parser.parse_args(argv)
    if args.episodes < 1 or args.num_envs < 1:
        parser.error("--episodes and --num-envs must be at least 1")

    results = []
    print(f"{'task':28s} {'success':>8s} {'95% CI':>15s} {'time':>7s}" + " random" * args.random)
    for name in args.tasks:
        start = time.perf_counter()
        outcomes = run_episodes(
            name, args.episodes, min(args.num_envs, args.episodes), args.seed, args.noise
        )
        wall = time.perf_counter() - start
        wins = sum(outcomes)
        low, high = wilson_interval(wins, len(outcomes))
        rate = wins / len(outcomes)
        line = f"{name:28s} {rate:8.0%} [{low:5.0%}, {high:5.0%}] {wall:6.1f}s"
        random = None
        if args.random:
            n = min(args.num_envs, args.episodes)
            random = evaluate(get_task(name), RandomPolicy(args.seed), args.episodes, args.seed, n)
            line += f" {random.successes:3d}/{random.episodes}"
        print(line, flush=True)
        results.append(
            {
                "task": name,
                "table_i": get_task(name).table_i,
                "episodes": len(outcomes),
                "successes": wins,
                "success_rate": rate,
                "wilson_95": [low, high],
                "wall_s": wall,
                "noise": args.noise,
                "random_success_rate": random.success_rate if random else None,
            }
        )
    if args.json:
        write_json(args.json, results)
    failing = [r["task"] for r in results if r["table_i"] and r["success_rate"] < THRESHOLD]
    if args.check and failing:
        print(f"below {THRESHOLD:.0%}: {', '.join(failing)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
