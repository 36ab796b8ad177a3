"""How a policy turns a threaded nut: the hand's sweeps against the nut's own turn.

For screwing and unscrewing policies: over N episodes from the held-out starts (one batch, each
environment one episode), the success rate (of the state each episode ends in, as
:func:`itskill.tasks.evaluate.evaluate` and the library count it), how often the hand grips again
after turning the open hand back (a new sweep), how far the gripping hand turned the task's way,
and how far the nut turned while engaged (its travel along the thread over the thread's lead). A
nut that turns further than the gripping hand was turned by something else, the fingers' contact;
``--contact`` measures that directly on a nut threaded on its bolt, over one episode of each of
``--episodes`` starts (default 8) without turning the hand: the open and the closed hand pushed
down, and the closed hand rubbed sideways across the nut. Its ``--task`` (default
grasp_nut_m12_bolt; grasp_nut_m16_bolt for the M16 nut) must start with the open hand around a
nut engaged on its bolt.

    python benchmarks/thread_turns.py --task screw_nut_m16 \
        --policy src/itskill/skills/library/screw_nut_m16
    python benchmarks/thread_turns.py --contact
    python benchmarks/thread_turns.py --contact --task grasp_nut_m16_bolt
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from itskill.files import write_json
from itskill.rl import load_policy
from itskill.skills.pretrain import PretrainConfig
from itskill.tasks import get_task, make_batch_env

POLICY_TASK, POLICY_EPISODES = "screw_nut_m12", 50
"""``--task`` and ``--episodes`` unless given, measuring a policy."""
CONTACT_TASK, CONTACT_EPISODES = "grasp_nut_m12_bolt", 8
"""``--task`` and ``--episodes`` unless given, with ``--contact``."""
WIND_MIN = 1.0
"""Radians the open hand must turn back between two grips for the second to count as a sweep."""
HAND_STILL = 0.01
"""Radians per step under which the hand counts as not turning."""


def thread_turn(before: dict, after: dict) -> np.ndarray:
    """Each environment's nut turn over one step, anticlockwise positive: its travel along the
    thread over the lead, counted only while engaged at both ends (a nut lifted off the bolt turns
    no more, and its yaw reading wraps at +-pi)."""
    engaged = (after["engaged"][:, 0] > 0.5) & (before["engaged"][:, 0] > 0.5)
    rise = after["obj_bottom_z"][:, 0] - before["obj_bottom_z"][:, 0]
    return np.where(engaged, rise / after["thread_lead"][:, 0], 0.0)


def policy_turns(task: str, policy_dir: Path, episodes: int, seed: int) -> dict:
    """Roll ``episodes`` deterministic episodes at once; measure the hand's sweeps and the nut's
    turn. Turns are in the task's direction (clockwise to screw, anticlockwise to unscrew)."""
    spec = get_task(task)
    way = -1.0 if "screw" in spec.actions else 1.0  # the sign of the hand's yaw rate that works
    policy = load_policy(policy_dir)
    env = make_batch_env(spec, num_envs=episodes, seed=seed)
    try:
        obs = env.reset()
        ctx = env.context()
        running = np.ones(episodes, bool)
        success = np.zeros(episodes, bool)
        sweeps = np.zeros(episodes)
        gripped_turn = np.zeros(episodes)
        nut_turn = np.zeros(episodes)
        nut_turn_hand_still = np.zeros(episodes)  # while the hand turns less than HAND_STILL
        wound = np.zeros(episodes)  # open-hand turn back since the last grip
        while running.any():
            actions, _ = policy.predict(obs, deterministic=True)
            # advance, not step: step would reset an ending episode to a new start before its
            # last state could be measured.
            res = env.advance(actions)
            obs, new = res.obs, res.context
            turn = way * (new["ee_yaw"] - ctx["ee_yaw"])
            closed, was_closed = new["grip_closed"] > 0.5, ctx["grip_closed"] > 0.5
            gripped_turn += np.where(running & closed & was_closed, turn, 0.0)
            wound = np.where(~closed, wound - turn, wound)
            sweeps += running & closed & ~was_closed & (wound >= WIND_MIN)
            wound = np.where(closed, 0.0, wound)
            step_turn = np.where(running, way * thread_turn(ctx, new), 0.0)
            nut_turn += step_turn
            nut_turn_hand_still += np.where(np.abs(turn) < HAND_STILL, step_turn, 0.0)
            # Success in the state the episode ends in, not at any step on the way: a nut seated
            # and turned off again has not been screwed on, and the library counts it the same.
            ended = running & (res.terminated | res.truncated)
            success[ended] = res.success[ended]
            running &= ~ended
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
        "nut_turn_while_hand_still_rad": float(nut_turn_hand_still.mean()),
    }


CONTACT_MODES = {
    "open hand pressed down": (-1.0, 0.0),
    "closed hand pressed down": (1.0, 0.0),
    "closed hand rubbed sideways": (1.0, 1.0),
}
"""Mode -> (grip action, sideways action amplitude). Rubbing moves the hand along x, four steps
each way; every mode also pushes down, and none turns the hand."""
RUB_PERIOD = 4


def hand_around_engaged_nut(ctx: dict) -> np.ndarray:
    """Per environment, whether the open hand's grip point is within the nut, which is engaged
    on its bolt: the start :func:`contact_turns` measures from."""
    near = np.linalg.norm(ctx["obj_to_ee"][:, 0], axis=-1) < ctx["obj_width"][:, 0] / 2
    return (ctx["engaged"][:, 0] > 0.5) & (ctx["grip_closed"] < 0.5) & near


def contact_turns(task: str, seed: int, envs: int = CONTACT_EPISODES) -> dict:
    """How far the hand's contact alone turns a threaded nut in each of :data:`CONTACT_MODES`,
    over one episode of ``task`` from each of ``envs`` starts. A task whose starts do not all put
    the open hand around the engaged nut (:func:`hand_around_engaged_nut`) is a ValueError: the
    hand would spend the episode reaching the nut, or push on nothing."""
    spec = get_task(task)
    # One step short of the episode's end: the next step would reset to a new start.
    steps = spec.max_steps - 1
    result: dict = {"task": task, "steps": steps, "episodes": envs, "turn_rad": {}}
    for mode, (grip, rub) in CONTACT_MODES.items():
        env = make_batch_env(spec, num_envs=envs, seed=seed)
        try:
            env.reset()
            ctx = env.context()
            if not hand_around_engaged_nut(ctx).all():
                raise ValueError(
                    f"{task}: not every start puts the open hand around a nut engaged on its "
                    f"bolt, as --contact needs (e.g. {CONTACT_TASK})"
                )
            turn = np.zeros(envs)
            for t in range(steps):
                action = np.zeros((envs, 5))
                action[:, 2], action[:, 4] = -1.0, grip
                action[:, 0] = rub * (1.0 if (t // RUB_PERIOD) % 2 == 0 else -1.0)
                env.step(action)
                new = env.context()
                turn += thread_turn(ctx, new)
                ctx = new
        finally:
            env.close()
        result["turn_rad"][mode] = [round(float(t), 3) for t in turn]
    return result


def main(argv: list[str] | None = None) -> int:
    """Measure a policy's turns (``--policy``) or the contact's (``--contact``); print them."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", help=f"default: {POLICY_TASK}, with --contact {CONTACT_TASK}")
    parser.add_argument("--policy", type=Path, help="a policy directory (a skill's or best/)")
    parser.add_argument(
        "--episodes",
        type=int,
        help=f"default: {POLICY_EPISODES}, with --contact {CONTACT_EPISODES}",
    )
    parser.add_argument("--seed", type=int, default=PretrainConfig.eval_seed)
    parser.add_argument(
        "--contact", action="store_true", help="push and rub on a threaded nut instead"
    )
    parser.add_argument("--json", type=Path, help="also write the result as JSON")
    args = parser.parse_args(argv)
    if args.episodes is not None and args.episodes < 1:
        parser.error(f"--episodes must be at least 1, got {args.episodes}")
    if args.contact and args.policy is not None:
        parser.error("--contact moves the hand itself and measures no policy: drop --policy")
    if args.contact:
        task = args.task or CONTACT_TASK
        try:
            result = contact_turns(task, args.seed, args.episodes or CONTACT_EPISODES)
        except ValueError as err:  # a task whose start does not suit, named by the error
            parser.error(str(err))
        for mode, turns in result["turn_rad"].items():
            print(f"{mode}, {result['steps']} steps: the nut turned {turns} rad")
    elif args.policy is None:
        parser.error("give --policy DIR (or --contact)")
    else:
        task, episodes = args.task or POLICY_TASK, args.episodes or POLICY_EPISODES
        result = policy_turns(task, args.policy, episodes, args.seed)
        print(
            f"{task}: success {result['success']:.0%} of {episodes} episodes; "
            f"{result['sweeps_after_turning_back']:.1f} grips after turning the open hand back "
            f"per episode ({result['episodes_with_such_a_sweep']:.0%} of episodes have one)"
        )
        print(
            f"the nut turned {result['nut_turn_rad']:.2f} rad while engaged; the gripping hand "
            f"turned {result['hand_turn_gripped_rad']:.2f} rad; the nut turned "
            f"{result['nut_turn_while_hand_still_rad']:.2f} rad while the hand did not turn"
        )
    if args.json:
        write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
