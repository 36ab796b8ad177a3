"""Pulling a held peg out of its hole while the hand also moves sideways: when does it jam?

Two starts per peg: the Remove task's, with the scripted controller grasping the peg in its hole
(the grip a learner makes for itself), and the Extract task's (the peg held at its middle, as
placed there). Once the peg has been held for a few steps, every environment sends one constant
action: up at ``dz`` and sideways along x at ``dx`` (action units, fingers closed). For each pair
the table gives the share of episodes in which the peg came out of the hole while held (the
task's success at any step) and the share in which the fingers lost it while it was still in
the hole. A policy exploring with sideways noise meets those losses, which is how Remove learned
to hold the peg still (docs/skills.md, "Fifteenth pretraining").

    python benchmarks/pull_jam.py --json results/pull_jam/pull_jam.json
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from itskill.files import write_json
from itskill.skills.pretrain import PretrainConfig
from itskill.tasks import get_task, make_batch_env
from itskill.tasks.scripted import ScriptedPolicy

SIDEWAYS = (0.0, -0.1, -0.2, -0.3, -0.5, -1.0)
UPWARD = (1.0, 0.5, 0.2)
HELD_STEPS = 3
"""Steps the peg must have been held before the pull starts."""
STARTS = {
    "round": {"grasp": "remove_peg_round", "held": "extract_peg_round"},
    "rect": {"grasp": "remove_peg_rect", "held": "extract_peg_rect"},
}
"""Peg -> start -> the task whose start it is (``grasp``: its script grasps the peg first)."""


def pull(task: str, dx: float, dz: float, envs: int, seed: int) -> dict:
    """One constant pull ``(dx, dz)`` in ``envs`` episodes of ``task``, each begun by the task's
    script until the peg is held, then held still for :data:`HELD_STEPS` steps."""
    spec = get_task(task)
    env = make_batch_env(spec, num_envs=envs, seed=seed)
    script = ScriptedPolicy(spec, envs)
    try:
        env.reset()
        script.reset()
        ctx = env.context()
        held_for = np.zeros(envs, int)
        out = np.zeros(envs, bool)
        lost_in_hole = np.zeros(envs, bool)
        # One step short of the episode's end: the next step would reset to a new start.
        for _ in range(spec.max_steps - 1):
            action = script(ctx)
            # Held: keep still with the fingers closed (not the script's lift) until the pull.
            action[held_for > 0] = [0.0, 0.0, 0.0, 0.0, 1.0]
            pulling = held_for >= HELD_STEPS
            action[pulling] = [dx, 0.0, dz, 0.0, 1.0]
            env.step(action)
            ctx = env.context()
            held = ctx["grasped"][:, 0] > 0.5
            # Its bottom below the hole's entrance: the figures in docs/skills.md. ``engaged``
            # also asks for the hole's footprint and counts a few dragged pegs as out already.
            in_hole = ctx["obj_bottom_z"][:, 0] < ctx["fix_pos"][:, 0, 2]
            lost_in_hole |= pulling & ~held & in_hole & ~out
            out |= pulling & np.asarray(spec.success(ctx), bool)
            held_for = np.where(held | pulling, held_for + 1, 0)
        return {
            "dx": dx,
            "dz": dz,
            "pulling": float(np.mean(held_for >= HELD_STEPS)),
            "out_held": float(out.mean()),
            "lost_in_hole": float(lost_in_hole.mean()),
        }
    finally:
        env.close()


def table(rows: list[dict]) -> str:
    """The pulls as a text table, one line each."""
    lines = ["   dz    dx  pulled  out, held  lost in the hole"]
    lines += [
        f"{r['dz']:5.1f} {r['dx']:5.1f}  {r['pulling']:6.0%}  {r['out_held']:9.0%}"
        f"  {r['lost_in_hole']:16.0%}"
        for r in rows
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pegs", nargs="+", choices=list(STARTS), default=list(STARTS))
    parser.add_argument("--envs", type=int, default=16)
    parser.add_argument("--seed", type=int, default=PretrainConfig.eval_seed)
    parser.add_argument("--json", type=Path, help="also write the result as JSON")
    args = parser.parse_args(argv)
    if args.envs < 1:
        parser.error("--envs must be at least 1")
    result: dict = {"episodes": args.envs, "seed": args.seed, "pulls": {}}
    for peg in args.pegs:
        for start, task in STARTS[peg].items():
            rows = [pull(task, dx, dz, args.envs, args.seed) for dz in UPWARD for dx in SIDEWAYS]
            result["pulls"][f"{peg}/{start}"] = {"task": task, "rows": rows}
            print(f"{peg} peg, {start} start ({task}), {args.envs} episodes per pull")
            print(table(rows))
    if args.json:
        write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
