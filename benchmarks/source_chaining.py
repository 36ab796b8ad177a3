"""How far skills from the skill space get on a complex task when simply run one after another.

Each stage of the target task is handed to one skill (``--chain``, one skill name per stage). On
every step each environment acts with the skill of the stage it is in, deterministically. Nothing
is trained: the figure says whether the skills' end and start states meet, what reusing them
without learning can reach, and whether a library is ready to be a transfer network's sources.

By default each skill sees the stage its own task would be in (its task's stage predicates
applied to the state), so it meets observations like those it was trained on; with
``--target-stage`` it sees the target's stage instead, as the transfer network's sources do.

    python benchmarks/source_chaining.py pickplace_nut_m12 \\
        --chain pick_nut_m12 pick_nut_m12 pick_nut_m12 place_nut_m12 place_nut_m12
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from itskill.rl.checkpoint import TrainedPolicy
from itskill.tasks import get_task
from itskill.tasks.evaluate import evaluate
from itskill.tasks.spec import TaskSpec
from itskill.transfer import resolve_sources


class StageChain:
    """Acts with the skill assigned to each environment's current stage of ``target``."""

    def __init__(self, target: TaskSpec, chain: list[str], own_stage: bool) -> None:
        # Resolved as transfer sources are: from the skill space, checkpoints checked.
        skills = resolve_sources(target.id, list(dict.fromkeys(chain)), exclude_target=False)
        self.names = [s.name for s in skills]
        self.actors = [TrainedPolicy(s.run_dir) for s in skills]
        self.tasks = [get_task(s.task_id) for s in skills]
        self.stage_skill = np.array([self.names.index(name) for name in chain])
        self.own_stage = own_stage

    def reset(self, env_ids: np.ndarray | None = None) -> None:
        """Nothing to reset: the skills are feed-forward policies."""

    def __call__(self, ctx: dict[str, np.ndarray]) -> np.ndarray:
        which = self.stage_skill[ctx["stage"]]
        actions = np.zeros((len(which), 5))
        for k, (actor, task) in enumerate(zip(self.actors, self.tasks, strict=True)):
            rows = which == k
            if not rows.any():
                continue
            view = dict(ctx)
            if self.own_stage:
                view["stage"] = task.stage_index(ctx)
            actions[rows] = actor(view)[rows]
        return actions


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("task", help="the complex target task")
    parser.add_argument("--chain", nargs="+", required=True, help="one skill name per stage")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=10_000, help="held-out episodes by default")
    parser.add_argument("--target-stage", action="store_true", help="skills see the target's stage")
    parser.add_argument("--json", type=Path, help="also write the result as JSON")
    args = parser.parse_args(argv)

    spec = get_task(args.task)
    if len(args.chain) != len(spec.stages):
        stages = ", ".join(s.name for s in spec.stages)
        parser.error(
            f"{spec.id} has {len(spec.stages)} stages ({stages}), --chain names {len(args.chain)}"
        )
    policy = StageChain(spec, args.chain, own_stage=not args.target_stage)
    res = evaluate(spec, policy, args.episodes, args.seed, num_envs=25)
    print(
        f"{spec.id}: chain {' -> '.join(args.chain)} "
        f"({'target' if args.target_stage else 'own'} stage)\n"
        f"success {res.success_rate:.0%} [{res.ci_low:.0%}, {res.ci_high:.0%}] over "
        f"{res.episodes} episodes; subtasks finished {res.mean_stages_done / res.n_stages:.0%}"
    )
    if args.json:
        record = {"chain": args.chain, "own_stage": not args.target_stage, **res.to_dict()}
        args.json.write_text(json.dumps(record, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
