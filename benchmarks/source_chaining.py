"""How far skills from the skill space get on a complex task when simply run one after another.

Each stage of the target task is handed to one skill (``--chain``, one skill name per stage). On
every step each environment acts with the skill of the stage it is in, deterministically. Nothing
is trained: the figure says whether the skills' end and start states meet, what reusing them
without learning can reach, and whether a library is ready to be a transfer network's sources.

By default each skill sees the stage its own task would be in (its task's stage predicates
applied to the state), so it meets observations like those it was trained on; with
``--target-stage`` it sees the target's stage mapped onto its own task's stages by their names,
as the transfer network shows its sources (``itskill.transfer.stages.stage_map``). The two differ
where the tasks' stage predicates do: a place skill whose approach ends 2 mm from the bolt's axis,
in a target whose approach ended at 4 mm, saw its place stage 2-4 mm off the axis.

    python benchmarks/source_chaining.py pickplace_nut_m12 \\
        --chain pick_nut_m12 pick_nut_m12 pick_nut_m12 place_nut_m12 place_nut_m12

``--handovers N`` also says where a chain breaks, over N more episodes run as one batch: how many
succeed; per stage, how many got there and the part's offsets from the grip point and from its
fixture when the stage began; and of the failed episodes, how many end holding their part, how
many never held it, and per stage how many last lost it there, with the fingers still commanded
closed (a grasp that slipped) or opened short of the goal, and the part's offsets then. (Records
written before 2026-12-06 hold the per-stage rows alone, as a list.)

``--noise SIGMA`` adds Gaussian noise of that standard deviation to every action, as a transfer
target exploring around its sources' actions does (its policy's ``exp(log_std_init)``): a chain
that finishes only without noise gives the target's rollouts nothing to learn from. A chain of one
skill on its own task measures the skill alone.

    python benchmarks/source_chaining.py insert_peg_rect --chain insert_peg_rect --noise 0.135
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from itskill.files import write_json
from itskill.rl.checkpoint import TrainedPolicy
from itskill.sim.layout import MAX_STAGES, OBSERVATION_LAYOUT
from itskill.tasks import get_task, make_batch_env
from itskill.tasks.evaluate import (
    HELD_OUT_ENVS,
    HELD_OUT_SEED,
    Policy,
    evaluate,
    make_policy,
    noise_sigma,
    with_noise,
)
from itskill.tasks.spec import TaskSpec
from itskill.transfer import resolve_sources
from itskill.transfer.sources import SourceError
from itskill.transfer.stages import pad_stages, stage_map


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
        target_names = [st.name for st in target.stages]
        self.stage_maps = [
            np.array(pad_stages(stage_map(target_names, [st.name for st in task.stages])))
            for task in self.tasks
        ]

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
            else:
                view["stage"] = self.stage_maps[k][np.minimum(ctx["stage"], MAX_STAGES - 1)]
            actions[rows] = actor(view)[rows]
        return actions


def trace_handovers(spec: TaskSpec, policy: Policy, episodes: int, seed: int) -> dict:
    """Where a chain breaks, over ``episodes`` run as one batch, one episode each.

    Returns ``episodes``, ``successes``, the failed episodes that end holding their part
    (``failed_held``) or never held it (``failed_never_held``), and ``stages``, a row per stage:
    how many episodes got that far (``reached``); the grip point's offset from the part
    (``obj_to_ee``, m) and the part bottom's offset from its fixture point (``obj_to_fix``, m)
    when an episode first entered it, the state that stage's skill starts from, to compare with
    the starts it was trained on; and how many failed episodes, not holding the part at the end,
    last lost it there (the furthest stage they had reached), with the fingers still commanded
    closed (``slipped``) or open (``let_go``), and the offsets at that moment. A part dropped and
    grasped again counts where it was last dropped; successful episodes, which may let go at
    their goal, are not counted.
    """
    env = make_batch_env(spec.id, num_envs=episodes, seed=seed)
    n = len(spec.stages)
    handed: list[dict[int, np.ndarray]] = [{} for _ in range(n)]
    last_loss: dict[int, tuple[int, bool, np.ndarray]] = {}
    furthest = np.zeros(episodes, dtype=np.int64)
    success = np.zeros(episodes, dtype=bool)
    held_at_end = np.zeros(episodes, dtype=bool)
    running = np.ones(episodes, dtype=bool)
    held = np.zeros(episodes, dtype=bool)

    def note_loss(e: int, grasped: bool, closed: bool, offsets: np.ndarray) -> None:
        if held[e] and not grasped:
            last_loss[e] = (int(furthest[e]), closed, offsets)

    try:
        env.reset()
        policy.reset()
        while running.any():
            ctx = env.context()
            # One part per chained task: slot 0.
            offsets = np.concatenate([ctx["obj_to_ee"][:, 0], ctx["obj_to_fix"][:, 0]], axis=1)
            grasped = ctx["grasped"][:, 0] > 0.5
            for e in np.flatnonzero(running):
                k = int(ctx["stage"][e])
                furthest[e] = max(furthest[e], k)
                handed[k].setdefault(e, offsets[e])
                note_loss(e, grasped[e], bool(ctx["grip_closed"][e]), offsets[e])
            held = grasped
            _, _, dones, infos = env.step(policy(ctx))
            for e in np.flatnonzero(running & dones):
                # The environment is reset at once: its last state is seen only in its end's
                # record. A stage entered on the last step counts; on success every stage was
                # reached.
                furthest[e] = max(furthest[e], min(int(infos[e]["stages_done"]), n - 1))
                success[e] = bool(infos[e]["is_success"])
                last = infos[e]["terminal_observation"]
                held_at_end[e] = last[OBSERVATION_LAYOUT["obj0_grasped"]][0] > 0.5
                end_offsets = np.concatenate(
                    [
                        last[OBSERVATION_LAYOUT["obj0_to_ee"]],
                        last[OBSERVATION_LAYOUT["obj0_to_fix"]],
                    ]
                )
                closed = bool(last[OBSERVATION_LAYOUT["grip_closed"]][0] > 0.5)
                note_loss(e, held_at_end[e], closed, end_offsets)
            running &= ~dones
    finally:
        env.close()
    failed = ~success
    losses = [last_loss[e] for e in np.flatnonzero(failed & ~held_at_end) if e in last_loss]
    rows = []
    for k, stage in enumerate(spec.stages):
        row: dict = {"stage": k, "name": stage.name, "reached": int((furthest >= k).sum())}
        if k and handed[k]:
            row.update(_offset_stats(list(handed[k].values())))
        for kind, closed in (("slipped", True), ("let_go", False)):
            states = [s for stage_k, c, s in losses if stage_k == k and c == closed]
            row[kind] = len(states)
            if states:
                row.update(_offset_stats(states, prefix=f"{kind}_"))
        rows.append(row)
    never_held = [e for e in np.flatnonzero(failed & ~held_at_end) if e not in last_loss]
    return {
        "episodes": episodes,
        "successes": int(success.sum()),
        "failed_held": int((failed & held_at_end).sum()),
        "failed_never_held": len(never_held),
        "stages": rows,
    }


def _offset_stats(states: list[np.ndarray], prefix: str = "") -> dict[str, list[float]]:
    """Mean and standard deviation of ``obj_to_ee`` and ``obj_to_fix`` over recorded states."""
    arr = np.array(states)
    stats = {}
    for name, cols in (("obj_to_ee", slice(0, 3)), ("obj_to_fix", slice(3, 6))):
        stats[f"{prefix}{name}_mean"] = arr[:, cols].mean(axis=0).round(4).tolist()
        stats[f"{prefix}{name}_std"] = arr[:, cols].std(axis=0).round(4).tolist()
    return stats


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("task", help="the complex target task")
    parser.add_argument("--chain", nargs="+", required=True, help="one skill name per stage")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument(
        "--seed", type=int, default=HELD_OUT_SEED, help="held-out episodes by default"
    )
    parser.add_argument(
        "--target-stage",
        action="store_true",
        help="skills see the target's stage mapped onto theirs, as the transfer network's sources",
    )
    parser.add_argument("--json", type=Path, help="also write the result as JSON")
    parser.add_argument(
        "--noise",
        type=noise_sigma,
        default=0.0,
        metavar="SIGMA",
        help="standard deviation of Gaussian noise added to every action (a target's "
        "exp(log_std_init))",
    )
    parser.add_argument(
        "--handovers",
        type=int,
        metavar="N",
        help="also run N episodes in one batch and report how many succeed and, per stage, how "
        "many got there, the part's offsets (mean, std) when it began, and how many failed "
        "episodes last lost the part there",
    )
    args = parser.parse_args(argv)
    if args.episodes < 1 or (args.handovers is not None and args.handovers < 1):
        parser.error("--episodes and --handovers must be at least 1")

    spec = get_task(args.task)
    if len(args.chain) != len(spec.stages):
        stages = ", ".join(s.name for s in spec.stages)
        parser.error(
            f"{spec.id} has {len(spec.stages)} stages ({stages}), --chain names {len(args.chain)}"
        )
    try:
        chain = StageChain(spec, args.chain, own_stage=not args.target_stage)
    except SourceError as err:  # a skill misspelled, or one without its checkpoint
        parser.error(str(err))

    # Each run draws its noise afresh from the seed: the trace does not depend on --episodes.
    policy = with_noise(chain, args.noise, args.seed)
    res = evaluate(spec, policy, args.episodes, args.seed, num_envs=HELD_OUT_ENVS)
    print(
        f"{spec.id}: chain {' -> '.join(args.chain)} "
        f"({'target' if args.target_stage else 'own'} stage"
        + (f", action noise {args.noise:g}" if args.noise else "")
        + ")\n"
        f"success {res.success_rate:.0%} [{res.ci_low:.0%}, {res.ci_high:.0%}] over "
        f"{res.episodes} episodes; subtasks finished {res.mean_stages_done / res.n_stages:.0%}"
    )
    handovers = None
    if args.handovers:
        handovers = trace_handovers(
            spec, make_policy(policy, spec, args.handovers), args.handovers, args.seed
        )
        failed = args.handovers - handovers["successes"]
        print(f"hand-overs over {args.handovers} episodes, {handovers['successes']} of them "
              f"successful; of the {failed} failed, {handovers['failed_held']} end holding the "
              f"part and {handovers['failed_never_held']} never held it (obj_to_ee = grip point "
              "- part centre, obj_to_fix = fixture point - part bottom; mean ± std):")  # fmt: skip
        for row in handovers["stages"]:
            print(f"  stage {row['stage']} {row['name']}: reached by {row['reached']}"
                  + _offsets_text(row))  # fmt: skip
            for kind, what in (("slipped", "last slipped from the closed fingers"),
                               ("let_go", "was last let go short of the goal")):  # fmt: skip
                if row[kind]:
                    print(f"    failed episodes whose part {what} here: {row[kind]}"
                          + _offsets_text(row, f"{kind}_"))  # fmt: skip
    if args.json:
        record = {
            "chain": args.chain,
            "own_stage": not args.target_stage,
            "noise": args.noise,
            **res.to_dict(),
        }
        if handovers is not None:
            record["handovers"] = handovers
        write_json(args.json, record)
    return 0


def _offsets_text(row: dict, prefix: str = "") -> str:
    """``; obj_to_ee (mean) ± (std); obj_to_fix ...`` in mm, or nothing if not recorded."""
    if f"{prefix}obj_to_ee_mean" not in row:
        return ""
    return "".join(
        f"; {name} {_vec(row[prefix + name + '_mean'])} ± {_vec(row[prefix + name + '_std'], '')}"
        for name in ("obj_to_ee", "obj_to_fix")
    )


def _vec(values: list[float], sign: str = "+") -> str:
    return "(" + ", ".join(f"{1000 * v:{sign}.1f}" for v in values) + ") mm"


if __name__ == "__main__":
    sys.exit(main())
