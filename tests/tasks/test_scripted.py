"""The scripted waypoint controller: grasps, screwing, script parsing and Table I success rates."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from itskill.sim.context import wrap_angle
from itskill.tasks import all_tasks, get_task, make_batch_env
from itskill.tasks.scripted import (
    YAW_HIGH,
    YAW_LOW,
    ScriptedPolicy,
    ScriptError,
    _fixture_yaw_goal,
    _Part,
    run_episodes,
)


def _run(task: str, num_envs: int, steps: int | None = None, seed: int = 0):
    """Run the task's script for ``steps`` (default: one episode); return the last context."""
    spec = get_task(task)
    env = make_batch_env(task, num_envs=num_envs, seed=seed, n_threads=1)
    policy = ScriptedPolicy(spec, num_envs)
    env.reset()
    policy.reset()
    try:
        for _ in range(steps or spec.max_steps - 1):
            env.step(policy(env.context()))
        return env.context()
    finally:
        env.close()


@pytest.mark.parametrize(
    ("task", "steps"),
    [("pick_nut_m12", 45), ("pick_nut_m16", 45), ("pick_peg_round", 55), ("pick_peg_rect", 55)],
)
def test_scripted_grasp_lifts_part(task: str, steps: int) -> None:
    ctx = _run(task, num_envs=4, steps=steps)
    assert (ctx["grasped"][:, 0] > 0.5).all()
    assert (ctx["obj_bottom_z"][:, 0] > ctx["obj_height"][:, 0]).all()


def test_scripted_screw_seats_nut() -> None:
    ctx = _run("screw_nut_m16", num_envs=4)
    assert (ctx["engaged"][:, 0] > 0.5).all()
    assert (ctx["seat_gap"][:, 0] <= 0.002).all()


def test_scripted_push_brings_nut_to_its_target() -> None:
    # 97% of 200 held-out episodes (docs/skills.md): 14 of these 16 leaves room for the misses.
    outcomes = run_episodes("push_nut_m12", episodes=16, num_envs=16, seed=0)
    assert sum(outcomes) >= 14, outcomes


@pytest.mark.parametrize("task", ["lift_nut_m12_bolt", "lift_nut_m16_bolt"])
def test_lift_off_the_bolt_starts_where_unscrewing_ends(task: str) -> None:
    # The nut starts held just above the top of the thread, off it, as the unscrew skills leave
    # it (5.2 +- 1.9 mm up); the scripted lift takes it 3 cm up, still held. Starts within 1 mm
    # of the tip began engaged (about 1 in 75): every one of 400 is clear of it.
    env = make_batch_env(task, num_envs=100, seed=0, n_threads=1)
    try:
        starts = []
        for seed in range(4):
            env.seed(seed)
            env.reset()
            starts.append(env.context())
    finally:
        env.close()
    for start in starts:
        assert (start["grasped"][:, 0] > 0.5).all()
        assert (start["engaged"][:, 0] < 0.5).all()
        height = -start["obj_to_fix"][:, 0, 2]
        assert ((height > 0.0015) & (height < 0.011)).all(), height
    end = _run(task, num_envs=4)
    assert (end["grasped"][:, 0] > 0.5).all()
    assert (-end["obj_to_fix"][:, 0, 2] >= 0.03).all()


def test_every_task_script_compiles() -> None:
    for spec in all_tasks().values():
        assert spec.script, f"{spec.id} has no script"
        ScriptedPolicy(spec, num_envs=1)


def test_unknown_primitive_is_a_clear_error() -> None:
    spec = dataclasses.replace(get_task("pick_nut_m12"), script=("pick 0", "juggle 0"))
    with pytest.raises(ScriptError, match="unknown primitive 'juggle'"):
        ScriptedPolicy(spec, num_envs=1)


def test_bad_object_slot_is_a_clear_error() -> None:
    spec = dataclasses.replace(get_task("pick_nut_m12"), script=("pick 3",))
    with pytest.raises(ScriptError, match="object slot"):
        ScriptedPolicy(spec, num_envs=1)


@pytest.mark.slow
@pytest.mark.parametrize("task", [n for n, s in all_tasks().items() if s.table_i])
def test_table_i_success_rate(task: str) -> None:
    outcomes = run_episodes(task, episodes=100, num_envs=25, seed=0)
    assert len(outcomes) == 100
    assert np.mean(outcomes) >= 0.9, f"{task}: {np.mean(outcomes):.0%} success"


def test_the_scripted_hand_lines_a_peg_up_with_a_turned_hole_within_the_wrists_range():
    # With the hole turned 1 rad, every hand yaw below about -0.57 rad aimed at -2.14 rad, past
    # the wrist's limit, and the peg stayed 8 degrees off: the goal a half turn away is reachable
    # and the rectangular peg looks the same there.
    part = _Part(0, get_task("insert_peg_rect").objects[0])
    hole_yaw = 1.0
    hand = np.linspace(-np.pi / 2, np.pi / 2, 13)
    error = wrap_angle(hand - hole_yaw, np.pi)
    ctx = {"ee_yaw": hand, "yaw_error": np.stack([error, np.zeros_like(hand)], -1)}
    goal = _fixture_yaw_goal(part, ctx, np.arange(len(hand)))
    assert ((goal >= YAW_LOW) & (goal <= YAW_HIGH)).all()
    np.testing.assert_allclose(wrap_angle(goal - hole_yaw, np.pi), 0.0, atol=1e-9)
