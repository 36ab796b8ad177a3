"""The reward search with the offline backend, next to the expert reward with the same budget.

For each task, run the full loop (:func:`itskill.reward.generate_reward`, default 5 iterations x
10 samples, the packaged candidate budget), then report the wall time on this machine and the
chosen reward's success on the final seeds beside the expert reward's (same env-steps, same
seeds): each seed's best evaluation through training (what the search ranks by, optimistic as a
maximum of noisy evaluations) and its last evaluation, at the budget, each as a mean over the
seeds with its 95% t-interval. Results go to ``results/reward_search/<task>/`` (the
search's ``summary.json``, ``fig6.png`` and the chosen ``best_reward.py``); the run directories
to ``--runs`` (resumable: rerunning the same command continues an interrupted search). A
search of another size than the one whose results are there is refused unless ``--force`` (the
quick example below would replace the committed full search's results); give it its own
``--results`` directory.

Targets (issue 4): the basic-skill loop under 60 minutes on 2 cores; generated reward success >=
the expert's.

    python benchmarks/reward_search.py                       # pick_nut_m12 and pickplace_nut_m12
    python benchmarks/reward_search.py --tasks pick_nut_m12 --iterations 1 --samples 2 \
        --steps 2048 --results runs/reward_search_trial
    python benchmarks/reward_search.py --tasks pickplace_nut_m12 --transfer itn

``--transfer METHOD`` trains every candidate (and the final runs of both rewards) with that
transfer network over the skills retrieved for the task, as ``itskill learn`` does; its results go
to ``results/reward_search/<task>_<method>/``.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import time
from pathlib import Path

from rich.console import Console

from itskill.executors import EXECUTORS
from itskill.experiments.analysis import estimate
from itskill.files import read_json, read_json_or_none, replaced_whole, write_json
from itskill.reward import generate_reward, load_search_config, search_client
from itskill.reward.search import BEST_FILE, CONFIG_FILE, FIGURE_FILE, NETWORK_DIR, SUMMARY_FILE
from itskill.transfer import search_network

DEFAULT_TASKS = ("pick_nut_m12", "pickplace_nut_m12")


def _interval(band: dict | None, key: str) -> str:
    """Mean over the final seeds of ``band[key]`` (their best or last evaluations) with its 95%
    t-interval; ``-`` where no seed finished, or the expert reward was not compared."""
    if not band or not band.get(key):
        return "-"
    return estimate(band[key]).format(0)  # "(all n seeds)" where they agree, not [x, x]


def _name(task: str, transfer: str | None) -> str:
    """The directory of a task's search under --runs and --results."""
    return f"{task}_{transfer}" if transfer else task


def _search_size(summary: dict) -> tuple[int, int] | None:
    """(iterations, samples per iteration) of the search a summary records; None if unreadable."""
    iterations = summary.get("iterations")
    if not isinstance(iterations, list) or not iterations:
        return None
    samples = iterations[0].get("samples") if isinstance(iterations[0], dict) else None
    return (len(iterations), len(samples)) if isinstance(samples, list) else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--tasks", nargs="+", default=list(DEFAULT_TASKS))
    parser.add_argument("--iterations", type=int)
    parser.add_argument("--samples", type=int)
    parser.add_argument("--steps", type=int, help="env-steps per candidate and final run")
    parser.add_argument("--select-top", type=int, help="best rewards retrained on more seeds")
    parser.add_argument("--final-seeds", type=int)
    parser.add_argument("--workers", type=int, help="parallel candidates (default one per core)")
    parser.add_argument("--executor", choices=EXECUTORS)
    parser.add_argument(
        "--transfer", metavar="METHOD", help="train candidates with this transfer method (itn, ...)"
    )
    parser.add_argument("--runs", type=Path, default=Path("runs/reward_search"))
    parser.add_argument("--results", type=Path, default=Path("results/reward_search"))
    parser.add_argument(
        "--force", action="store_true", help="replace results of a search of another size"
    )
    args = parser.parse_args()
    config = load_search_config(
        overrides={
            "iterations": args.iterations,
            "samples": args.samples,
            "steps": args.steps,
            "select_top": args.select_top,
            "final_seeds": args.final_seeds,
            "workers": args.workers,
            "executor": args.executor,
        }
    )
    for task in args.tasks:
        # The defaults write into the committed results: a quick trial (the second example
        # above) replaced the full search's figure and the reward other benchmarks read.
        target = args.results / _name(task, args.transfer)
        kept = read_json_or_none(target / SUMMARY_FILE)
        size = _search_size(kept) if isinstance(kept, dict) else None
        if size not in (None, (config.iterations, config.samples)) and not args.force:
            parser.error(
                f"{target} holds the results of a "
                f"{size[0]} x {size[1]} search, this one is {config.iterations} x "
                f"{config.samples}: give another --results directory, or --force to replace them"
            )
    console = Console(stderr=True)
    rows = []
    for task in args.tasks:
        name = _name(task, args.transfer)
        run_dir = args.runs / name
        client = search_client(run_dir, "offline")
        network = None
        if args.transfer:
            network = search_network(
                task, args.transfer, run_dir / NETWORK_DIR, algo=config.algo, client=client
            )
        start = time.perf_counter()
        result = generate_reward(
            task,
            client,
            run_dir,
            config,
            resume=(run_dir / CONFIG_FILE).is_file(),
            console=console,
            network=network,
        )
        wall = time.perf_counter() - start
        target = args.results / name
        summary = read_json(run_dir / SUMMARY_FILE)
        summary["benchmark"] = {
            "wall_s_this_call": round(wall, 1),
            "cpus": os.cpu_count(),
            "machine": platform.machine(),
            "python": platform.python_version(),
        }
        write_json(target / SUMMARY_FILE, summary)
        for file in (FIGURE_FILE, BEST_FILE):
            # Copied to a temporary file replacing the target whole: an interrupted copy must not
            # leave a truncated figure or reward beside a summary that looks complete.
            with replaced_whole(target / file) as tmp:
                shutil.copyfile(run_dir / file, tmp)
        rows.append((name, summary, result))
    print(
        f"\n{config.iterations} iterations x {config.samples} samples, {config.steps} env-steps "
        f"per candidate, best {config.select_top} retrained on {config.select_seeds} more seeds, "
        f"{config.final_seeds} final seeds, {os.cpu_count()} cores"
    )
    print(
        "success on the final seeds, mean [95% t-interval]: each seed's best evaluation through "
        "training (optimistic: the maximum of its evaluations) and its last evaluation"
    )
    columns = ("generated best eval", "generated last eval", "expert best eval", "expert last eval")
    print(f"{'task':<26} {'wall min':>9}  " + " ".join(f"{c:<19}" for c in columns))
    for name, summary, _ in rows:
        final = summary["final"]
        minutes = summary["usage"]["wall_s"] / 60
        # The search's "success" per seed is its peak evaluation, "final_success" its last.
        cells = [
            _interval(final[reward], key)
            for reward in ("generated", "expert")
            for key in ("success", "final_success")
        ]
        print(f"{name:<26} {minutes:>9.1f}  " + " ".join(f"{c:<19}" for c in cells))


if __name__ == "__main__":
    main()
