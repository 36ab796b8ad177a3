"""The expert reward: values on hand-built states, along scripted rollouts, and on every task."""

from __future__ import annotations

import numpy as np
import pytest

from itskill.sim.context import MAX_FIXTURES, MAX_OBJECTS
from itskill.tasks import all_tasks, get_task, make_batch_env
from itskill.tasks.rewards import PROGRESS_WEIGHT, SUCCESS_BONUS, TEMPERATURES, expert_reward
from itskill.tasks.scripted import ScriptedPolicy

N = 3
NUT_HEIGHT = 0.01
NUT_WIDTH = 0.018
M12_LEAD = 0.00175 / (2 * np.pi)


def _ctx(**overrides) -> dict[str, np.ndarray]:
    """A context of N = 3 environments: an M12-sized nut on the table at (0.5, 0, 0), its bolt
    tip at (0.55, 0.12, 0.04), the open hand 10 cm above the nut. ``overrides`` replace keys."""
    nut = np.array([0.5, 0.0, NUT_HEIGHT / 2])
    fix = np.array([0.55, 0.12, 0.04])
    ctx = {
        "ee_pos": np.tile(nut + np.array([0.0, 0.0, 0.1]), (N, 1)),
        "ee_vel": np.zeros((N, 3)),
        "ee_yaw": np.zeros(N),
        "gripper_width": np.full(N, 0.08),
        "grip_closed": np.zeros(N),
        "action": np.zeros((N, 5)),
        "obj_mask": np.tile([1.0, 0.0], (N, 1)),
        "obj_pos": np.zeros((N, MAX_OBJECTS, 3)),
        "obj_vel": np.zeros((N, MAX_OBJECTS, 3)),
        "obj_yaw": np.zeros((N, MAX_OBJECTS)),
        "obj_tilt": np.zeros((N, MAX_OBJECTS)),
        "obj_height": np.tile([NUT_HEIGHT, 0.0], (N, 1)),
        "obj_width": np.tile([NUT_WIDTH, 0.0], (N, 1)),
        "obj_bottom_z": np.zeros((N, MAX_OBJECTS)),
        "grasped": np.zeros((N, MAX_OBJECTS)),
        "fix_mask": np.tile([1.0, 0.0], (N, 1)),
        "fix_pos": np.zeros((N, MAX_FIXTURES, 3)),
        "fix_yaw": np.zeros((N, MAX_FIXTURES)),
        "seat_z": np.zeros((N, MAX_FIXTURES)),
        "obj_fixture": np.zeros((N, MAX_OBJECTS)),
        "yaw_error": np.zeros((N, MAX_OBJECTS)),
        "engaged": np.zeros((N, MAX_OBJECTS)),
        "insertion_depth": np.zeros((N, MAX_OBJECTS)),
        "thread_lead": np.tile([M12_LEAD, 0.0], (N, 1)),
        "stage": np.zeros(N, dtype=np.int64),
        "n_stages": np.full(N, 3.0),
        "time_frac": np.zeros(N),
    }
    ctx["obj_pos"][:, 0] = nut
    ctx["fix_pos"][:, 0] = fix
    ctx["seat_z"][:, 0] = 0.005
    ctx.update({k: np.asarray(v, dtype=np.float64) for k, v in overrides.items()})
    _derive(ctx)
    return ctx


def _derive(ctx: dict[str, np.ndarray]) -> None:
    """Fill the keys that follow from positions, as the simulator does."""
    pos = ctx["obj_pos"]
    ctx["obj_bottom_z"] = (pos[..., 2] - ctx["obj_height"] / 2) * ctx["obj_mask"]
    ctx["obj_to_ee"] = (ctx["ee_pos"][:, None] - pos) * ctx["obj_mask"][..., None]
    bottom = pos.copy()
    bottom[..., 2] = ctx["obj_bottom_z"]
    ctx["obj_to_fix"] = (ctx["fix_pos"][:, :1] - bottom) * ctx["obj_mask"][..., None]
    ctx["seat_gap"] = (ctx["obj_bottom_z"] - ctx["seat_z"][:, :1]) * ctx["obj_mask"]


def _with_stage(spec, ctx: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    ctx["stage"] = spec.stage_index(ctx)
    return ctx


def _reward(task: str, ctx: dict[str, np.ndarray]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    spec = get_task(task)
    return expert_reward(spec)(_with_stage(spec, ctx))


def test_approach_term_is_higher_at_the_nut() -> None:
    far = _ctx()
    at = _ctx(ee_pos=np.tile([0.5, 0.0, 0.012], (N, 1)))
    r_far, c_far = _reward("reach_nut_m12", far)
    r_at, c_at = _reward("reach_nut_m12", at)
    assert (c_at["0.approach/reach"] > c_far["0.approach/reach"]).all()
    assert (r_at > r_far).all()
    # At the nut the reach task has succeeded and pays the success bonus.
    np.testing.assert_allclose(c_at["success"], SUCCESS_BONUS)
    np.testing.assert_allclose(c_far["success"], 0.0)


def test_approach_comes_down_over_the_nut_not_beside_it() -> None:
    # 3 cm to the side of the nut: lowering the open fingers to the table there would push the
    # nut away, so hovering over the table at that distance pays more than being on it.
    beside = _ctx(ee_pos=np.tile([0.5, 0.03, 0.012], (N, 1)))
    above_beside = _ctx(ee_pos=np.tile([0.5, 0.03, 0.035], (N, 1)))
    centred_low = _ctx(ee_pos=np.tile([0.5, 0.0, 0.012], (N, 1)))
    _, c_beside = _reward("reach_nut_m12", beside)
    _, c_above = _reward("reach_nut_m12", above_beside)
    _, c_centred = _reward("reach_nut_m12", centred_low)
    reach = "0.approach/reach"
    assert (c_beside[reach] < c_above[reach]).all() and (c_above[reach] < c_centred[reach]).all()


def test_hover_term_and_success_are_at_the_point_over_the_bolt() -> None:
    over_bolt = np.tile([0.55, 0.12, 0.04 + 0.05], (N, 1))
    at_nut = _ctx(ee_pos=np.tile([0.5, 0.0, 0.012], (N, 1)))
    r_nut, c_nut = _reward("hover_bolt_m12", at_nut)
    r_bolt, c_bolt = _reward("hover_bolt_m12", _ctx(ee_pos=over_bolt))
    np.testing.assert_allclose(c_bolt["0.approach/reach"], 2 / 3)  # reach weighs 1, fine 0.5
    assert (c_bolt["0.approach/reach"] > c_nut["0.approach/reach"]).all() and (r_bolt > r_nut).all()
    np.testing.assert_allclose(c_bolt["success"], SUCCESS_BONUS)
    np.testing.assert_allclose(c_nut["success"], 0.0)


def test_lifted_beats_grasped_on_table_and_success_pays_bonus() -> None:
    grip = dict(grip_closed=np.ones(N), grasped=np.tile([1.0, 0.0], (N, 1)))
    on_table = _ctx(ee_pos=np.tile([0.5, 0.0, 0.012], (N, 1)), **grip)
    lifted_pos = np.zeros((N, MAX_OBJECTS, 3))
    lifted_pos[:, 0] = [0.5, 0.0, 0.02 + NUT_HEIGHT / 2]  # bottom 2 heights up: not yet success
    half = _ctx(ee_pos=np.tile([0.5, 0.0, 0.027], (N, 1)), obj_pos=lifted_pos, **grip)
    done_pos = lifted_pos.copy()
    done_pos[:, 0, 2] = 0.04 + NUT_HEIGHT / 2  # 4 heights: success (3 needed)
    done = _ctx(ee_pos=np.tile([0.5, 0.0, 0.047], (N, 1)), obj_pos=done_pos, **grip)
    r_table, _ = _reward("pick_nut_m12", on_table)
    r_half, c_half = _reward("pick_nut_m12", half)
    r_done, c_done = _reward("pick_nut_m12", done)
    assert (r_table < r_half).all() and (r_half < r_done).all()
    np.testing.assert_allclose(c_half["success"], 0.0)
    np.testing.assert_allclose(c_done["success"], SUCCESS_BONUS)
    assert (c_half["2.lift/lift"] > 0).all()


def test_a_peg_let_go_into_its_hole_earns_neither_depth_nor_success() -> None:
    # Three pegs 2 cm into the hole (past half its 3.5 cm depth), the first and last still held.
    inside = np.zeros((N, MAX_OBJECTS, 3))
    inside[:, 0] = [0.55, 0.12, 0.04 - 0.02 + NUT_HEIGHT / 2]
    held = np.tile([1.0, 0.0], (N, 1))
    held[1] = 0.0
    depth = np.zeros((N, MAX_OBJECTS))
    depth[:, 0] = 0.02
    ctx = _ctx(
        ee_pos=inside[:, 0] + np.array([0.0, 0.0, 0.01]),
        obj_pos=inside,
        grasped=held,
        grip_closed=held[:, 0],
        engaged=np.tile([1.0, 0.0], (N, 1)),
        insertion_depth=depth,
    )
    total, comps = _reward("insert_peg_round", ctx)
    np.testing.assert_allclose(comps["0.insert/depth"][2], comps["0.insert/depth"][0])
    assert comps["0.insert/depth"][0] > 0.0 and comps["0.insert/depth"][1] == 0.0
    np.testing.assert_allclose(comps["success"], [SUCCESS_BONUS, 0.0, SUCCESS_BONUS])
    assert total[1] < total[0]


def test_a_millimetre_tolerance_is_shaped_at_the_millimetre_scale() -> None:
    # The held part's bottom 5 mm over the fixture point (mid-window), 0.5, 1 and 3 mm off axis.
    over = np.zeros((N, MAX_OBJECTS, 3))
    over[:, 0] = [[0.55 + dx, 0.12, 0.04 + 0.005 + NUT_HEIGHT / 2] for dx in (0.0005, 0.001, 0.003)]
    held = dict(grasped=np.tile([1.0, 0.0], (N, 1)), grip_closed=np.ones(N))
    ctx = _ctx(ee_pos=over[:, 0], obj_pos=over, **held)
    _, place = _reward("place_peg_round", ctx)  # within 1.5 mm of the axis
    axis = place["1.place/over_axis"]
    assert axis[0] > axis[1] > axis[2] and axis[1] - axis[2] > 0.5 * axis[1]
    _, carry = _reward("carry_nut_m12", ctx)  # within 4 mm: the fine term is enough
    assert not any(name.endswith("over_axis") for name in carry)


def test_grasping_beats_hovering_and_empty_fingers_are_worse() -> None:
    centred = np.tile([0.5, 0.0, 0.012], (N, 1))
    open_ = _ctx(ee_pos=centred)
    shut = _ctx(ee_pos=centred, grip_closed=np.ones(N), gripper_width=np.zeros(N))
    held = _ctx(
        ee_pos=centred,
        grip_closed=np.ones(N),
        gripper_width=np.full(N, NUT_WIDTH),
        grasped=np.tile([1.0, 0.0], (N, 1)),
    )
    r_open, _ = _reward("pick_nut_m12", open_)
    r_shut, _ = _reward("pick_nut_m12", shut)
    r_held, _ = _reward("pick_nut_m12", held)
    assert (r_shut < r_open).all() and (r_open < r_held).all()


def test_a_nut_held_tipped_on_its_side_neither_finishes_the_grasp_nor_pays_as_much() -> None:
    # The fingers hold a tipped nut too; it can never go onto the bolt, so a pick must not count.
    lifted_pos = np.zeros((N, MAX_OBJECTS, 3))
    lifted_pos[:, 0] = [0.5, 0.0, 0.04 + NUT_HEIGHT / 2]
    held = dict(
        ee_pos=np.tile([0.5, 0.0, 0.047], (N, 1)),
        obj_pos=lifted_pos,
        grip_closed=np.ones(N),
        grasped=np.tile([1.0, 0.0], (N, 1)),
    )
    tilt = np.zeros((N, MAX_OBJECTS))
    tilt[:, 0] = [np.radians(90), np.radians(30), np.radians(5)]
    spec = get_task("pick_nut_m12")
    tipped = _with_stage(spec, _ctx(obj_tilt=tilt, **held))
    upright = _with_stage(spec, _ctx(**held))
    np.testing.assert_array_equal(tipped["stage"], [1, 1, 2])
    np.testing.assert_array_equal(upright["stage"], [2, 2, 2])
    r_tipped, c_tipped = expert_reward(spec)(tipped)
    r_upright, _ = expert_reward(spec)(upright)
    np.testing.assert_allclose(c_tipped["success"], [0.0, 0.0, SUCCESS_BONUS])
    assert r_tipped[0] < r_tipped[1] < r_upright[1]
    # Held but tipped pays the grasp term in full and little of the upright term.
    assert c_tipped["1.grasp/grasp"][0] == c_tipped["1.grasp/grasp"][1] > 0
    assert c_tipped["1.grasp/upright"][0] < 0.01 < c_tipped["1.grasp/upright"][1]


# ``down`` is 1 where turning the nut clockwise (seen from above) is the task, -1 anticlockwise.
@pytest.mark.parametrize(("task", "down"), [("screw_nut_m12", 1), ("unscrew_nut_m12", -1)])
def test_both_halves_of_a_regrasp_cycle_pay(task: str, down: int) -> None:
    # The hand holds a nut engaged on its bolt, 2 mm above the seat gap the task accepts.
    def state(yaw: float, nut_z: float) -> dict[str, np.ndarray]:
        nut = np.array([0.55, 0.12, nut_z])
        obj_pos = np.zeros((N, MAX_OBJECTS, 3))
        obj_pos[:, 0] = nut
        return _ctx(
            obj_pos=obj_pos,
            ee_pos=np.tile(nut, (N, 1)),
            ee_yaw=np.full(N, yaw),
            engaged=np.tile([1.0, 0.0], (N, 1)),
            fix_pos=np.tile([[0.55, 0.12, 0.03], [0.0, 0.0, 0.0]], (N, 1, 1)),
        )

    def terms(yaw: float, nut_z: float) -> dict[str, float]:
        _, comps = _reward(task, state(yaw, nut_z))
        return {k.split("/")[1]: float(v[0]) for k, v in comps.items() if "/" in k}

    z = 0.005 + 0.00175 + 0.002 + NUT_HEIGHT / 2
    progress = "screw" if down > 0 else "raise"
    start = terms(0.0, z)
    # Turning the held nut one radian the task's way moves it one lead along the thread: the
    # progress term pays, and what the rest of the turn could still do (wind) stays.
    turned = terms(-down * 1.0, z - down * M12_LEAD)
    assert turned[progress] > start[progress]
    assert turned["wind"] == pytest.approx(start["wind"], abs=1e-9)
    # Turning the open hand back one radian leaves the nut where it is: wind pays.
    back = terms(0.0, z - down * M12_LEAD)
    assert back[progress] == pytest.approx(turned[progress], abs=1e-9)
    assert back["wind"] > turned["wind"]


def test_components_sum_to_total_and_stages_only_pay_their_own_terms() -> None:
    ctx = _ctx(ee_pos=np.array([[0.5, 0.0, 0.2], [0.5, 0.0, 0.02], [0.5, 0.0, 0.012]]))
    total, comps = _reward("pickplace_nut_m12", ctx)
    np.testing.assert_allclose(sum(comps.values()), total)
    stage = ctx["stage"]
    for name, value in comps.items():
        if "/" in name:
            k = int(name.split(".", 1)[0])
            assert (value[stage != k] == 0).all(), name


def test_temperatures_can_be_overridden_and_typos_are_caught() -> None:
    spec = get_task("reach_nut_m12")
    ctx = _with_stage(spec, _ctx())
    sharp = expert_reward(spec, {"reach": TEMPERATURES["reach"] / 4})(ctx)[1]["0.approach/reach"]
    default = expert_reward(spec)(ctx)[1]["0.approach/reach"]
    assert (sharp < default).all()
    with pytest.raises(KeyError, match="unknown temperature"):
        expert_reward(spec, {"reech": 0.1})


def _scripted_rollout(task: str, num_envs: int = 4):
    """Rewards, stages and success of one scripted episode: arrays (T, num_envs)."""
    spec = get_task(task)
    reward_fn = expert_reward(spec)
    env = make_batch_env(task, num_envs=num_envs, seed=1, n_threads=1)
    policy = ScriptedPolicy(spec, num_envs)
    env.reset()
    policy.reset()
    rewards, stages, successes = [], [], []
    try:
        for _ in range(spec.max_steps - 1):
            ctx = env.context()
            total, comps = reward_fn(ctx)
            np.testing.assert_allclose(sum(comps.values()), total)
            rewards.append(total)
            stages.append(ctx["stage"].copy())
            successes.append(spec.success(ctx))
            env.step(policy(ctx))
    finally:
        env.close()
    return np.array(rewards), np.array(stages), np.array(successes)


@pytest.mark.parametrize("task", ["pick_nut_m12", "place_nut_m12", "insert_peg_round"])
def test_reward_rises_along_a_scripted_episode_and_jumps_when_it_succeeds(task: str) -> None:
    rewards, _, successes = _scripted_rollout(task)
    assert successes[-1].all(), "the script should solve the task"
    assert (rewards[-1] > rewards[0]).all()
    # The success bonus is paid from the step the task is solved on, so the per-step reward jumps
    # there by more than the shaping could give up. A single-stage task has no stage bonus: this
    # is its one step up.
    solved = successes[1:] & ~successes[:-1]
    assert solved.any(axis=0).all()
    assert (rewards[1:][solved] - rewards[:-1][solved] > SUCCESS_BONUS - PROGRESS_WEIGHT).all()


@pytest.mark.parametrize("task", ["pick_nut_m12", "place_nut_m12"])
def test_reward_rises_as_a_scripted_episode_finishes_each_stage(task: str) -> None:
    n_stages = len(get_task(task).stages)
    rewards, stages, _ = _scripted_rollout(task)
    assert (stages[-1] == n_stages - 1).all(), "the script should go through every stage"
    # At stage transitions upward the per-step reward rises (the stage bonus covers the shaping
    # the finished stage paid), apart from the odd physics wobble.
    up = stages[1:] > stages[:-1]
    assert up.any(axis=0).all()
    rises = rewards[1:][up] > rewards[:-1][up]
    assert rises.mean() >= 0.9


@pytest.mark.parametrize("task", list(all_tasks()))
def test_every_task_has_a_finite_expert_reward(task: str) -> None:
    spec = get_task(task)
    env = make_batch_env(task, num_envs=2, seed=0, n_threads=1)
    try:
        env.reset()
        total, comps = expert_reward(spec)(env.context())
    finally:
        env.close()
    assert total.shape == (2,) and np.isfinite(total).all()
    assert {"stage_bonus", "success"} <= set(comps)
    for value in comps.values():
        assert value.shape == (2,) and np.isfinite(value).all()
