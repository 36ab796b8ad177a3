"""How a policy turns a threaded nut: the hand's sweeps against the nut's own turn.

For screwing and unscrewing policies: over N episodes from the held-out starts (one batch, each
environment one episode), the success rate, the share of episodes whose hand reached the wrist's
limit and of those that then turned the open hand back for another sweep, and how far the nut
turned (its travel along the thread over the thread's lead) by the time the hand first reached
the limit and by the end. A nut that turns further than the hand did was turned by something
other than the grip, such as pressing on it; ``--press`` measures that directly: the open and
the closed hand pushed down onto a nut threaded on its bolt for 40 steps, without turning.

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
from itskill.sim.controller import ControllerConfig
from itskill.skills.pretrain import PretrainConfig
from itskill.tasks import get_task, make_batch_env

LIMIT_MARGIN = 0.2
"""The hand counts as at its wrist limit within this many radians of it."""


def policy_turns(task: str, policy_dir: Path, episodes: int, seed: int) -> dict:
    """Roll ``episodes`` deterministic episodes at once and measure the hand's and nut's turns."""
    spec = get_task(task)
    screw = "screw" in spec.actions
    low, high = ControllerConfig().yaw_limits
    policy = load_policy(policy_dir)
    env = make_batch_env(spec, num_envs=episodes, seed=seed)
    try:
        obs = env.reset()
        ctx = env.context()
        start = ctx["obj_bottom_z"][:, 0].copy()
        lead = ctx["thread_lead"][:, 0]
        reached = np.zeros(episodes, bool)
        back = np.zeros(episodes, bool)
        success = np.zeros(episodes, bool)
        first = np.full(episodes, np.nan)
        for _ in range(spec.max_steps - 1):
            actions, _ = policy.predict(obs, deterministic=True)
            obs, _, _, _ = env.step(actions)
            ctx = env.context()
            yaw, opened = ctx["ee_yaw"], ctx["grip_closed"] < 0.5
            at_limit = yaw < low + LIMIT_MARGIN if screw else yaw > high - LIMIT_MARGIN
            newly = ~reached & at_limit
            first[newly] = np.abs(start - ctx["obj_bottom_z"][:, 0])[newly] / lead[newly]
            reached |= newly
            # Another sweep: the open hand back past the middle of the wrist's range.
            middle = (low + high) / 2
            back |= reached & opened & ((yaw > middle) if screw else (yaw < middle))
            success |= np.asarray(spec.success(ctx), bool)
        total = np.abs(start - ctx["obj_bottom_z"][:, 0]) / lead
    finally:
        env.close()
    return {
        "task": task,
        "policy": str(policy_dir),
        "episodes": episodes,
        "success": float(success.mean()),
        "reached_wrist_limit": float(reached.mean()),
        "turned_back_for_another_sweep": float(back.mean()),
        "nut_turn_at_first_limit_rad": float(np.nanmean(first)) if reached.any() else None,
        "nut_turn_by_the_end_rad": float(total.mean()),
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
            f"{args.task}: success {result['success']:.0%}, wrist limit reached in "
            f"{result['reached_wrist_limit']:.0%}, another sweep in "
            f"{result['turned_back_for_another_sweep']:.0%} of {args.episodes} episodes"
        )
        first = result["nut_turn_at_first_limit_rad"]
        print(
            f"nut turned {first if first is None else round(first, 2)} rad when the hand first "
            f"reached its limit, {result['nut_turn_by_the_end_rad']:.2f} rad by the end"
        )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
