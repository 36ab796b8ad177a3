"""How a policy turns a threaded nut: the hand's sweeps against the nut's own turn.

For screwing and unscrewing policies: over N episodes from the held-out starts (one batch, each
environment one episode), the success rate, how often the hand grips again after turning the
open hand back (a new sweep), how far the gripping hand turned the task's way, and how far the
nut turned while engaged (its travel along the thread over the thread's lead). A nut that turns
further than the gripping hand was turned by something else, the fingers' contact; ``--press``
measures that directly: the open and the closed hand pushed down beside a nut threaded on its
bolt for 40 steps, without turning.

    python benchmarks/thread_turns.py --task screw_nut_m16 \
        --policy src/itskill/skills/library/screw_nut_m16
    python benchmarks/thread_turns.py --press
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from itskill.rl import load_policy
from itskill.skills.pretrain import PretrainConfig
from itskill.tasks import get_task, make_batch_env

WIND_MIN = 1.0
"""Radians the open hand must turn back between two grips for the second to count as a sweep."""


def policy_turns(task: str, policy_dir: Path, episodes: int, seed: int) -> dict:
    """Roll ``episodes`` deterministic episodes at once; measure the hand's sweeps and the nut's
    turn. Turns are in the task's direction (clockwise to screw, anticlockwise to unscrew), the
    nut's counted only while its thread is engaged (a nut lifted off the bolt turns no more)."""
    spec = get_task(task)
    way = -1.0 if "screw" in spec.actions else 1.0  # the sign of the hand's yaw rate that works
    policy = load_policy(policy_dir)
    env = make_batch_env(spec, num_envs=episodes, seed=seed)
    try:
        obs = env.reset()
        ctx = env.context()
        lead = ctx["thread_lead"][:, 0]
        success = np.zeros(episodes, bool)
        sweeps = np.zeros(episodes)
        gripped_turn = np.zeros(episodes)
        nut_turn = np.zeros(episodes)
        wound = np.zeros(episodes)  # open-hand turn back since the last grip
        for _ in range(spec.max_steps - 1):
            actions, _ = policy.predict(obs, deterministic=True)
            obs, _, _, _ = env.step(actions)
            new = env.context()
            turn = way * (new["ee_yaw"] - ctx["ee_yaw"])
            closed, was_closed = new["grip_closed"] > 0.5, ctx["grip_closed"] > 0.5
            gripped_turn += np.where(closed & was_closed, turn, 0.0)
            wound = np.where(~closed, wound - turn, wound)
            sweeps += closed & ~was_closed & (wound >= WIND_MIN)
            wound = np.where(closed, 0.0, wound)
            engaged = (new["engaged"][:, 0] > 0.5) & (ctx["engaged"][:, 0] > 0.5)
            rise = new["obj_bottom_z"][:, 0] - ctx["obj_bottom_z"][:, 0]
            nut_turn += np.where(engaged, way * rise / lead, 0.0)
            success |= np.asarray(spec.success(new), bool)
            ctx = new
    finally:
        env.close()
    return {
        "task": task,
        "policy": str(policy_dir),
        "episodes": episodes,
        "success": float(success.mean()),
        "sweeps_after_turning_back": float(sweeps.mean()),
        "episodes_with_such_a_sweep": float((sweeps > 0).mean()),
        "hand_turn_gripped_rad": float(gripped_turn.mean()),
        "nut_turn_rad": float(nut_turn.mean()),
    }


def press_turns(task: str, seed: int, steps: int = 40, envs: int = 8) -> dict:
    """How far pushing the open or the closed hand down onto the threaded nut turns it."""
    result = {"task": task, "steps": steps, "episodes": envs}
    for name, grip in (("open", -1.0), ("closed", 1.0)):
        env = make_batch_env(task, num_envs=envs, seed=seed)
        try:
            env.reset()
            yaw0 = env.context()["obj_yaw"][:, 0].copy()
            push = np.zeros((envs, 5))
            push[:, 2], push[:, 4] = -1.0, grip
            for _ in range(steps):
                env.step(push)
            turn = env.context()["obj_yaw"][:, 0] - yaw0
        finally:
            env.close()
        result[f"{name}_hand_turn_rad"] = [round(float(t), 3) for t in turn]
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="screw_nut_m12")
    parser.add_argument("--policy", type=Path, help="a policy directory (a skill's or best/)")
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--seed", type=int, default=PretrainConfig.eval_seed)
    parser.add_argument("--press", action="store_true", help="push on a threaded nut instead")
    parser.add_argument("--json", type=Path, help="also write the result as JSON")
    args = parser.parse_args(argv)
    if args.press:
        # The open hand starts around the nut, one to two turns up the thread.
        result = press_turns("grasp_nut_m12_bolt", args.seed)
        for name in ("open", "closed"):
            turns = result[f"{name}_hand_turn_rad"]
            print(f"{name} hand pressed {result['steps']} steps: nut turned {turns} rad")
    elif args.policy is None:
        parser.error("give --policy DIR (or --press)")
    else:
        result = policy_turns(args.task, args.policy, args.episodes, args.seed)
        print(
            f"{args.task}: success {result['success']:.0%} of {args.episodes} episodes; "
            f"{result['sweeps_after_turning_back']:.1f} grips after turning the open hand back "
            f"per episode ({result['episodes_with_such_a_sweep']:.0%} of episodes have one)"
        )
        print(
            f"the nut turned {result['nut_turn_rad']:.2f} rad while engaged; the gripping hand "
            f"turned {result['hand_turn_gripped_rad']:.2f} rad"
        )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
