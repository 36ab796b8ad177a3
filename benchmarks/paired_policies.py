"""Two policies of one task on the same held-out episodes: each one's success and the paired test.

The comparison `itskill skills pretrain --refine` makes before a refined skill replaces the
library's (:func:`itskill.skills.pretrain.measure_skill` on both, then the one-sided exact
McNemar test over the episodes only one of them succeeded in), for any two policies: a skill
retrained another way, or one from a run directory. By default on the library's held-out
episodes (400 of seed 10,000). ``--noise SIGMA`` adds Gaussian noise to both policies' actions,
as the exploration of a learner acting through them does: a policy trained with noise may be
better with it and worse without.

    python benchmarks/paired_policies.py insert_peg_rect \\
        src/itskill/skills/library/insert_peg_rect runs/pretrain/insert_peg_rect/seed0/best
    python benchmarks/paired_policies.py pickplaceinsert_peg_rect RUN/best RUN --noise 0.135
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from itskill.files import write_json
from itskill.skills.pretrain import PretrainConfig, measure_skill
from itskill.stats import paired_gain_p, paired_wins
from itskill.tasks import get_task
from itskill.tasks.evaluate import noise_sigma


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("task")
    parser.add_argument("before", type=Path, help="policy directory (a skill's or a run's)")
    parser.add_argument("after", type=Path, help="policy directory compared with BEFORE")
    parser.add_argument("--episodes", type=int, default=PretrainConfig.eval_episodes)
    parser.add_argument("--seed", type=int, default=PretrainConfig.eval_seed)
    parser.add_argument("--json", type=Path, help="also write the result as JSON")
    parser.add_argument(
        "--noise",
        type=noise_sigma,
        default=0.0,
        metavar="SIGMA",
        help="standard deviation of Gaussian noise added to both policies' actions",
    )
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error("--episodes must be at least 1")
    for policy in (args.before, args.after):
        if not policy.is_dir():
            parser.error(f"{policy}: no such policy directory")
    config = PretrainConfig(eval_episodes=args.episodes, eval_seed=args.seed)
    spec = get_task(args.task)

    before, after = (measure_skill(spec, p, config, args.noise) for p in (args.before, args.after))
    won, lost = paired_wins(after.outcomes, before.outcomes)
    p = paired_gain_p(won, lost)
    noise = f", action noise {args.noise:g}" if args.noise else ""
    print(f"{args.task}, {args.episodes} episodes of seed {args.seed}{noise}")
    for label, ev in (("before", before), ("after", after)):
        print(f"  {label:6s} {ev.success_rate:6.2%} [{ev.ci_low:.1%}, {ev.ci_high:.1%}]")
    print(f"  after won {won} episodes and lost {lost}; one-sided exact McNemar p = {p:.2g}")
    if args.json:
        write_json(
            args.json,
            {
                "task": args.task,
                "episodes": args.episodes,
                "seed": args.seed,
                "noise": args.noise,
                "before": {"policy": str(args.before), "success": before.success_rate},
                "after": {"policy": str(args.after), "success": after.success_rate},
                "episodes_won": won,
                "episodes_lost": lost,
                "p": p,
            },
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
