"""Re-measure every skill of a library on the current simulator.

A skill's success in ``manifest.json`` was measured when it was trained. After a change to the
simulator or a task (control limits, step limits, success predicates) those figures may no longer
hold; this evaluates each skill's deterministic policy over the same held-out episodes that
pretraining measured it on (:func:`itskill.skills.pretrain.measure_skill`), prints the old
and new success side by side, and with ``--update`` writes the new figures into the manifest
(budget and everything else unchanged). Skills that fall below ``--min-success`` are listed, and
kept in the manifest with their new figure: removing one is a decision for a person.

    python benchmarks/library_success.py                      # the shipped library
    python benchmarks/library_success.py --update --json results/library_success_400.json
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import sys
import time
from pathlib import Path

from itskill.files import write_json
from itskill.skills import SHIPPED_LIBRARY
from itskill.skills.manifest import read_manifest, write_manifest
from itskill.skills.pretrain import PretrainConfig, measure_skill
from itskill.tasks import get_task


def main(argv: list[str] | None = None) -> int:
    """Re-measure the chosen skills, print old and new success, and optionally record them."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--library", type=Path, default=SHIPPED_LIBRARY)
    parser.add_argument("--skills", nargs="+", help="skill names (default: all)")
    parser.add_argument("--episodes", type=int, default=PretrainConfig.eval_episodes)
    parser.add_argument("--seed", type=int, default=PretrainConfig.eval_seed)
    parser.add_argument("--min-success", type=float, default=0.5)
    parser.add_argument(
        "--update",
        action="store_true",
        help="write the figures to the manifest (only with the default --episodes and --seed)",
    )
    parser.add_argument("--json", type=Path, help="also write the results as JSON")
    args = parser.parse_args(argv)
    # The manifest records no episode count or seed: its success is by definition the figure over
    # pretraining's held-out episodes, so a figure over any others must not be written there.
    if args.update and (args.episodes, args.seed) != (
        PretrainConfig.eval_episodes,
        PretrainConfig.eval_seed,
    ):
        parser.error(
            f"--update writes the manifest's success, which is measured over "
            f"{PretrainConfig.eval_episodes} episodes from seed {PretrainConfig.eval_seed}; "
            f"drop --update or --episodes/--seed (got {args.episodes} episodes, seed {args.seed})"
        )
    config = PretrainConfig(eval_episodes=args.episodes, eval_seed=args.seed)

    entries = read_manifest(args.library)
    unknown = sorted(set(args.skills or ()) - {e.name for e in entries})
    if unknown:
        # Left out silently, they measured nothing and --update rewrote the manifest.
        parser.error(f"not in {args.library}'s manifest: {', '.join(unknown)}")
    chosen = [e for e in entries if not args.skills or e.name in args.skills]
    print(f"{'skill':22s} {'before':>7s} {'now':>6s} {'95% CI':>15s} {'time':>6s}")
    results, updated = [], {}
    for entry in chosen:
        start = time.perf_counter()
        ev = measure_skill(get_task(entry.task), (args.library / entry.checkpoint).parent, config)
        before = "-" if entry.success is None else f"{entry.success:.1%}"
        print(
            f"{entry.name:22s} {before:>7s} {ev.success_rate:6.1%} "
            f"[{ev.ci_low:5.1%}, {ev.ci_high:5.1%}] {time.perf_counter() - start:5.1f}s",
            flush=True,
        )
        results.append(
            {
                "skill": entry.name,
                "before": entry.success,
                "success": ev.success_rate,
                "ci": [ev.ci_low, ev.ci_high],
                "episodes": ev.episodes,
            }
        )
        updated[entry.name] = dataclasses.replace(
            entry, success=ev.success_rate, success_ci=(ev.ci_low, ev.ci_high)
        )
    low = [r["skill"] for r in results if r["success"] < args.min_success]
    if low:
        print(f"below {args.min_success:.0%}: {', '.join(low)}")
    if args.update:
        write_manifest(args.library, [updated.get(e.name, e) for e in entries])
        print(f"updated {args.library / 'manifest.json'}")
    if args.json:
        machine = {"platform": platform.platform(), "python": sys.version.split()[0]}
        write_json(args.json, {"machine": machine, "episodes": args.episodes, "skills": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
