"""The environments a user drives: Gymnasium's checker, seeding, episodes, control, layout."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from itskill.sim.controller import ControllerConfig
from itskill.sim.layout import OBSERVATION_LAYOUT as L
from itskill.sim.task import Range, TrainingStart
from itskill.sim.vec_env import BatchEnv
from itskill.tasks import get_task, make_batch_env, make_env

FREE = np.array([0.0, 0.0, 0.0, 0.0, -1.0])
"""Hold still with the fingers open."""


def actions_sequence(n: int, seed: int = 123) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.uniform(-1, 1, 5).astype(np.float32) for _ in range(n)]


# ---------------------------------------------------------------------- Gymnasium API
def test_task_env_passes_gymnasium_env_checker():
    env = make_env("pick_nut_m12")
    with warnings.catch_warnings():
        # An unbounded Box observation space is intended (positions, velocities); the checker
        # only warns about it.
        warnings.filterwarnings("ignore", message=".*infinity.*")
        check_env(env, skip_render_check=True)
    env.close()


def test_task_env_refuses_a_render_mode_it_cannot_render_and_says_when_physics_diverged():
    with pytest.raises(ValueError, match=r"render_mode must be one of \['rgb_array'\]"):
        make_env("pick_nut_m12", render_mode="human")  # it rendered nothing, silently
    env = make_env("pick_nut_m12")
    env.reset(seed=0)
    *_, info = env.step(np.zeros(5))
    assert info["unstable"] is False
    env.data.qvel[env.batch.sim.scene.obj_dof[0][0]] = 1e20
    _, _, terminated, truncated, info = env.step(np.zeros(5))
    # A Gymnasium user could not tell a diverged episode from one that ran out of time.
    assert truncated and not terminated and info["unstable"] is True
    env.close()


# ---------------------------------------------------------------------- seeding
def test_task_env_reset_is_deterministic_by_seed():
    a, b = make_env("pick_nut_m12"), make_env("pick_nut_m12")
    obs_a, _ = a.reset(seed=7)
    obs_b, _ = b.reset(seed=7)
    np.testing.assert_array_equal(obs_a, obs_b)
    for action in actions_sequence(10):
        obs_a = a.step(action)[0]
        obs_b = b.step(action)[0]
    np.testing.assert_array_equal(obs_a, obs_b)

    # Reseeding the same instance replays the same start.
    again, _ = a.reset(seed=7)
    first = make_env("pick_nut_m12").reset(seed=7)[0]
    np.testing.assert_array_equal(again, first)

    # Another seed: another initial part position.
    other, _ = b.reset(seed=8)
    pos = L["obj0_pos"]
    assert np.linalg.norm(other[pos] - first[pos]) > 1e-3
    a.close()
    b.close()


def test_batch_env_reset_is_deterministic_by_seed():
    name = "pick_nut_m12"
    a = make_batch_env(name, num_envs=4, seed=11)
    b = make_batch_env(name, num_envs=4, seed=11)
    c = make_batch_env(name, num_envs=4, seed=12)
    obs_a, obs_b, obs_c = a.reset(), b.reset(), c.reset()
    assert obs_a.shape == (4, L.size)
    np.testing.assert_array_equal(obs_a, obs_b)
    pos = L["obj0_pos"]
    # The copies in a batch start differently, and so do batches with different seeds.
    starts = obs_a[:, pos]
    for i in range(4):
        for j in range(i + 1, 4):
            assert np.linalg.norm(starts[i] - starts[j]) > 1e-3
    assert np.all(np.linalg.norm(obs_c[:, pos] - starts, axis=1) > 1e-3)

    for action in actions_sequence(10):
        batch_action = np.tile(action, (4, 1))
        obs_a = a.step(batch_action)[0]
        obs_b = b.step(batch_action)[0]
    np.testing.assert_array_equal(obs_a, obs_b)
    for env in (a, b, c):
        env.close()


def test_single_env_matches_first_env_of_a_batch_with_the_same_seed():
    single = make_env("pick_nut_m12")
    batch = make_batch_env("pick_nut_m12", num_envs=3, seed=5)
    obs = single.reset(seed=5)[0]
    batch_obs = batch.reset()
    np.testing.assert_array_equal(obs, batch_obs[0])
    for action in actions_sequence(10):
        obs = single.step(action)[0]
        batch_obs = batch.step(np.tile(action, (3, 1)))[0]
    np.testing.assert_array_equal(obs, batch_obs[0])
    single.close()
    batch.close()


# ---------------------------------------------------------------------- episodes
def test_an_ending_episode_reports_the_reward_functions_sum():
    # Metrics read it there: what a wrapper (reward normalisation) hands the learner is rescaled.
    name = "reach_nut_m12"
    n = 2

    def half(ctx):
        r = np.full(n, 0.5)
        return r, {"half": r}

    env = make_batch_env(name, num_envs=n, seed=3, reward_fn=half)
    env.reset()
    still = np.tile(FREE, (n, 1))
    total, dones = np.zeros(n), np.zeros(n, dtype=bool)
    while not dones.any():
        _, rewards, dones, infos = env.step(still)
        total += rewards
    for e in np.flatnonzero(dones):
        assert infos[e]["episode_return"] == pytest.approx(total[e])
        assert infos[e]["episode_return"] == pytest.approx(0.5 * get_task(name).max_steps)


def test_batch_env_truncates_at_max_steps_and_resets():
    name = "reach_nut_m12"
    max_steps = get_task(name).max_steps
    n = 4
    env = make_batch_env(name, num_envs=n, seed=3)
    # A twin stepped without automatic resets gives the true final observation.
    twin = make_batch_env(name, num_envs=n, seed=3)
    env.reset()
    twin.reset()
    still = np.tile(FREE, (n, 1))
    for k in range(max_steps - 1):
        obs, _, dones, infos = env.step(still)
        twin.advance(still)
        assert not dones.any(), f"done early at step {k + 1}"
        assert all("terminal_observation" not in info for info in infos)
    obs, _, dones, infos = env.step(still)
    final = twin.advance(still).obs

    assert dones.dtype == bool and dones.all()
    t = L["time_frac"]
    for e, info in enumerate(infos):
        terminal = info["terminal_observation"]
        np.testing.assert_array_equal(terminal, final[e])
        assert terminal[t][0] == pytest.approx(1.0)
        assert info["TimeLimit.truncated"] is True
        assert isinstance(info["is_success"], bool)
        # The returned observation is the new episode's first.
        assert obs[e][t][0] == 0.0
        assert not np.array_equal(obs[e], terminal)
    np.testing.assert_array_equal(env.steps, np.zeros(n))

    # The step counter restarted: the next episode is again max_steps long.
    for k in range(max_steps - 1):
        obs, _, dones, _ = env.step(still)
        assert not dones.any(), f"second episode done early at step {k + 1}"
        assert obs[0][t][0] == pytest.approx((k + 1) / max_steps)
    dones = env.step(still)[2]
    assert dones.all()
    env.close()
    twin.close()


# ---------------------------------------------------------------------- control
def test_end_effector_moves_about_1_5_cm_per_unit_action():
    for axis in range(3):
        for sign in (1.0, -1.0):
            env = make_env("reach_nut_m12")
            env.reset(seed=0)
            start = env.context()["ee_pos"][0].copy()
            action = FREE.copy()
            action[axis] = sign
            for _ in range(5):
                env.step(action)
            moving = env.context()["ee_pos"][0] - start
            for _ in range(5):  # let the arm catch up with the command
                env.step(FREE)
            moved = env.context()["ee_pos"][0] - start
            env.close()
            # Commanded 5 x 1.5 cm = 7.5 cm along the axis; the arm lags a little while moving.
            assert 0.035 < sign * moving[axis] < 0.08, (axis, sign, moving)
            assert 0.06 < sign * moved[axis] < 0.08, (axis, sign, moved)
            others = [k for k in range(3) if k != axis]
            assert np.all(np.abs(moved[others]) < 0.005), (axis, sign, moved)


def test_yaw_action_turns_the_hand():
    env = make_env("reach_nut_m12")
    env.reset(seed=0)
    yaw0 = env.context()["ee_yaw"][0]
    for _ in range(2):
        env.step(np.array([0.0, 0.0, 0.0, 1.0, -1.0]))
    for _ in range(10):  # the wrist follows the command within about half a second
        env.step(FREE)
    assert env.context()["ee_yaw"][0] - yaw0 == pytest.approx(0.5, abs=0.03)
    env.close()


def test_gripper_closes_and_opens_on_command():
    env = make_env("reach_nut_m12")  # the hand starts high above the table, nothing in between
    env.reset(seed=0)
    ctx = env.context()
    assert ctx["gripper_width"][0] == pytest.approx(0.08, abs=0.003)
    assert ctx["grip_closed"][0] == 0.0
    close = np.array([0.0, 0.0, 0.0, 0.0, 1.0])
    for _ in range(5):
        env.step(close)
    ctx = env.context()
    assert ctx["gripper_width"][0] < 0.01
    assert ctx["grip_closed"][0] == 1.0
    for _ in range(5):
        env.step(FREE)
    ctx = env.context()
    assert ctx["gripper_width"][0] > 0.075
    assert ctx["grip_closed"][0] == 0.0
    env.close()


@pytest.mark.parametrize("name", ["lift_nut_m12", "lift_peg_round"])
def test_a_held_part_stays_in_the_grip_at_full_speed(name):
    # Lifting at full speed for 25 steps once shook 31 of 32 nuts out of the pads; the payload
    # speed limit (ControllerConfig.max_lead_closed) keeps every one.
    env = make_batch_env(name, num_envs=4, seed=3, n_threads=1)
    env.reset()
    up = np.tile([0.0, 0.0, 1.0, 0.0, 1.0], (4, 1))
    z0 = env.context()["ee_pos"][:, 2].copy()
    for _ in range(25):
        env.step(up)
    ctx = env.context()
    env.close()
    assert (ctx["grasped"][:, 0] > 0.5).all()
    assert (ctx["ee_pos"][:, 2] - z0 > 0.1).all()  # it did go up: 25 steps at ~5 mm each
    # With the fingers open the hand moves about twice as fast.
    free = make_batch_env("reach_nut_m12", num_envs=1, seed=3, n_threads=1)
    free.reset()
    start = free.context()["ee_pos"][0, 2]
    for _ in range(5):
        free.step(np.array([[0.0, 0.0, 1.0, 0.0, -1.0]]))
    held_speed = (ctx["ee_pos"][:, 2] - z0).mean() / 25
    assert (free.context()["ee_pos"][0, 2] - start) / 5 > 1.5 * held_speed
    free.close()


@pytest.mark.parametrize("end", ["low", "middle", "high"])
def test_a_part_started_in_the_gripper_sits_its_hold_above_the_grip_point_and_stays(end):
    # Place and Carry start from the holds a table pick leaves: the nut often hangs below the
    # grip point, held by its upper edge. From every hold in the task's range it is grasped
    # from the first step: a learner that reads `grasped` false opens its hand.
    spec = get_task("place_nut_m12")
    span = spec.init.objects[0].hold
    hold = {"low": span.low, "middle": 0.0, "high": span.high}[end]
    nut = replace(spec.init.objects[0], hold=Range(hold, hold))
    init = replace(spec.init, objects=(nut,))
    env = make_batch_env("place_nut_m12", num_envs=4, seed=2, n_threads=1)
    for i in range(4):
        env.sim.reset_env(i, np.random.default_rng(i), init)
    assert (env.context()["grasped"][:, 0] > 0.5).all()
    grip = np.tile([0.0, 0.0, 0.0, 0.0, 1.0], (4, 1))
    offsets = []
    for step in range(16):
        grip[:, 2] = 0.8 if step % 8 < 4 else -0.8
        env.step(grip)
        ctx = env.context()
        offsets.append(ctx["obj_pos"][:, 0, 2] - ctx["ee_pos"][:, 2])
    env.close()
    assert (ctx["grasped"][:, 0] > 0.5).all()
    np.testing.assert_allclose(offsets, hold, atol=0.002)


@pytest.mark.parametrize(
    ("task", "period"),
    [("place_nut_m12", np.pi / 3), ("insert_peg_rect", np.pi), ("insert_peg_round", 0.0)],
)
def test_a_part_started_in_the_hand_with_symmetric_yaw_is_turned_by_its_symmetries(task, period):
    # The pads meet the same faces as without symmetric_yaw, but the part's yaw varies as that of
    # a part picked from the table does: a nut by multiples of 60 degrees, a rectangular peg by
    # 180, a round peg by any angle.
    spec = get_task(task)
    part = spec.init.objects[0]
    turned = replace(spec.init, objects=(replace(part, symmetric_yaw=True),))
    plain = replace(spec.init, objects=(replace(part, symmetric_yaw=False),))
    offsets = {}
    for name, init in (("turned", turned), ("plain", plain)):
        env = make_batch_env(task, num_envs=24, seed=3, n_threads=1)
        for i in range(24):
            env.sim.reset_env(i, np.random.default_rng(i), init)
        ctx = env.context()
        assert (ctx["grasped"][:, 0] > 0.5).all()
        offsets[name] = ctx["obj_yaw"][:, 0] - ctx["ee_yaw"]
        env.close()
    face = offsets["plain"][0]
    np.testing.assert_allclose(offsets["plain"], face, atol=0.02)
    turns = np.angle(np.exp(1j * (offsets["turned"] - face)))  # wrapped to (-pi, pi]
    if period:
        steps = turns / period
        np.testing.assert_allclose(steps, np.round(steps), atol=0.02)
        assert len(set(np.round(steps).astype(int) % round(2 * np.pi / period))) == round(
            2 * np.pi / period
        )
    else:
        assert np.ptp(turns) > np.pi


@pytest.mark.parametrize("name", ["grasp_nut_m12", "grasp_peg_rect"])
def test_a_part_started_between_the_open_fingers_is_grasped_by_closing(name):
    env = make_batch_env(name, num_envs=4, seed=5, n_threads=1)
    env.reset()
    ctx = env.context()
    assert (ctx["gripper_width"] > 0.075).all() and not ctx["grasped"].any()
    assert (np.linalg.norm(ctx["obj_to_ee"][:, 0, :2], axis=-1) < 0.003).all()  # centred
    assert (np.abs(ctx["obj_bottom_z"][:, 0]) < 0.002).all()  # standing on the table
    for _ in range(6):
        env.step(np.tile([0.0, 0.0, 0.0, 0.0, 1.0], (4, 1)))
    held = env.context()["grasped"][:, 0]
    env.close()
    assert (held > 0.5).all()


@pytest.mark.parametrize("name", ["grasp_peg_round_hole", "grasp_peg_rect_hole"])
def test_a_peg_in_its_hole_is_held_by_closing_the_hand_around_it_and_comes_out_when_raised(name):
    env = make_batch_env(name, num_envs=4, seed=5, n_threads=1)
    env.reset()
    ctx = env.context()
    assert (ctx["gripper_width"] > 0.075).all() and not ctx["grasped"].any()
    assert (np.abs(ctx["obj_bottom_z"][:, 0]) < 0.002).all()  # resting on the hole's floor
    for _ in range(6):
        env.step(np.tile([0.0, 0.0, 0.0, 0.0, 1.0], (4, 1)))
    assert (env.context()["grasped"][:, 0] > 0.5).all()
    for _ in range(12):
        env.step(np.tile([0.0, 0.0, 1.0, 0.0, 1.0], (4, 1)))
    ctx = env.context()
    env.close()
    # Out of the 20 mm deep hole and still in the fingers.
    assert (ctx["obj_bottom_z"][:, 0] > 0.025).all() and (ctx["grasped"][:, 0] > 0.5).all()


@pytest.mark.parametrize("name", ["extract_peg_round", "extract_peg_rect"])
def test_a_peg_started_held_in_its_hole_sits_inside_it_upright_and_comes_out_when_raised(name):
    env = make_batch_env(name, num_envs=4, seed=5, n_threads=1)
    env.reset()
    ctx = env.context()
    assert (ctx["grasped"][:, 0] > 0.5).all()
    assert (ctx["insertion_depth"][:, 0] > 0.006).all() and (ctx["obj_tilt"][:, 0] < 0.02).all()
    for _ in range(12):
        env.step(np.tile([0.0, 0.0, 1.0, 0.0, 1.0], (4, 1)))
    ctx = env.context()
    env.close()
    assert (ctx["insertion_depth"][:, 0] <= 0.0).all() and (ctx["grasped"][:, 0] > 0.5).all()


def test_turning_the_wrist_against_the_yaw_error_lines_a_held_peg_up_with_its_hole():
    env = make_batch_env("align_peg_rect", num_envs=4, seed=5, n_threads=1)
    env.reset()
    assert (np.abs(env.context()["yaw_error"][:, 0]) > 0.05).any()
    for _ in range(15):
        ctx = env.context()
        turn = np.clip(-ctx["yaw_error"][:, 0] / ControllerConfig().yaw_step, -1.0, 1.0)
        actions = np.zeros((4, 5))
        actions[:, 3], actions[:, 4] = turn, 1.0
        env.step(actions)
    ctx = env.context()
    env.close()
    assert (np.abs(ctx["yaw_error"][:, 0]) < 0.05).all() and (ctx["grasped"][:, 0] > 0.5).all()


@pytest.mark.parametrize("name", ["grasp_nut_m12_bolt", "grasp_nut_m16_bolt"])
def test_a_nut_on_the_bolt_is_held_by_closing_the_hand_around_it_and_stays_on_the_thread(name):
    env = make_batch_env(name, num_envs=4, seed=5, n_threads=1)
    env.reset()
    ctx = env.context()
    assert (ctx["engaged"][:, 0] > 0.5).all() and not ctx["grasped"].any()
    for _ in range(6):
        env.step(np.tile([0.0, 0.0, 0.0, 0.0, 1.0], (4, 1)))
    ctx = env.context()
    env.close()
    assert (ctx["grasped"][:, 0] > 0.5).all() and (ctx["engaged"][:, 0] > 0.5).all()


def _starts(env, episodes: int) -> list[tuple[bool, bool]]:
    """For each of ``episodes`` episodes of the single environment of ``env``: whether it began
    on the table (not grasped right after reset), and the ``training_start`` flag of its end."""
    starts = []
    env.reset()
    for _ in range(episodes):
        on_table = bool(env.context()["grasped"][0, 0] < 0.5)
        for _ in range(env.task.max_steps):
            _, _, done, infos = env.step(np.array([[0.0, 0.0, 0.0, 0.0, 1.0]]))
        assert done[0]
        starts.append((on_table, infos[0].get("training_start", False)))
    return starts


def test_training_environments_draw_the_tasks_training_starts_and_say_so():
    spec = get_task("lift_nut_m12")
    # lift_nut_m12 starts with the nut in the fingers; a training start from the table (pick's
    # start) with share 0.5 must show up in about half the training episodes and in no other.
    table = get_task("pick_nut_m12").init
    task = replace(spec.to_sim_task(), max_steps=1, training_starts=(TrainingStart(table, 0.5),))
    training = BatchEnv(task, num_envs=1, seed=0, n_threads=1, training=True)
    starts = _starts(training, 40)
    training.close()
    assert 10 <= sum(on_table for on_table, _ in starts) <= 30
    # Episode by episode: a log leaving out flagged episodes must leave out exactly the table
    # starts, not as many episodes that began in the fingers.
    assert [flag for _, flag in starts] == [on_table for on_table, _ in starts]
    evaluation = BatchEnv(task, num_envs=1, seed=0, n_threads=1)
    starts = _starts(evaluation, 10)
    evaluation.close()
    assert starts == [(False, False)] * 10


# ---------------------------------------------------------------------- observation layout
@pytest.mark.parametrize("name, n_objects", [("pick_nut_m12", 1), ("pickplace2_nuts", 2)])
def test_observation_slices_hold_the_context(name, n_objects):
    env = make_batch_env(name, num_envs=2, seed=4)
    env.reset()
    for action in actions_sequence(3):
        obs = env.step(np.tile(action, (2, 1)))[0]
    ctx = env.context()
    env.close()

    def same(slice_name, value):
        np.testing.assert_allclose(obs[:, L[slice_name]], np.reshape(value, (2, -1)), atol=1e-6)

    same("ee_pos", ctx["ee_pos"])
    same("ee_vel", ctx["ee_vel"])
    same("ee_yaw_sincos", np.stack([np.sin(ctx["ee_yaw"]), np.cos(ctx["ee_yaw"])], -1))
    same("gripper_width", ctx["gripper_width"])
    same("grip_closed", ctx["grip_closed"])
    same("time_frac", ctx["time_frac"])
    for i in range(2):
        used = float(i < n_objects)
        same(f"obj{i}_mask", np.full(2, used))
        same(f"obj{i}_pos", ctx["obj_pos"][:, i])
        same(f"obj{i}_to_ee", ctx["obj_to_ee"][:, i])
        same(f"obj{i}_to_fix", ctx["obj_to_fix"][:, i])
        same(f"obj{i}_grasped", ctx["grasped"][:, i])
        same(f"obj{i}_size", np.stack([ctx["obj_width"][:, i], ctx["obj_height"][:, i]], -1))
        if used:
            assert np.all(obs[:, L[f"obj{i}_pos"]][:, 2] > 0)  # a real part, above the table
        else:
            assert not obs[:, L[f"obj{i}_pos"]].any()
    same("fix0_pos", ctx["fix_pos"][:, 0])
    same("fix0_mask", np.ones(2))
    same("fix1_mask", np.full(2, float(n_objects == 2)))
    onehot = obs[:, L["stage_onehot"]]
    np.testing.assert_array_equal(onehot.argmax(axis=1), ctx["stage"])
    np.testing.assert_array_equal(onehot.sum(axis=1), np.ones(2))


# ---------------------------------------------------------------------- rewards
def test_reward_fn_gets_the_context_and_its_total_is_the_reward():
    calls = []

    def reward_fn(ctx):
        calls.append(ctx)
        height = ctx["ee_pos"][:, 2]
        closeness = -np.linalg.norm(ctx["obj_to_ee"][:, 0], axis=-1)
        return 2.0 * height + closeness, {"height": height, "closeness": closeness}

    env = make_batch_env("pick_nut_m12", num_envs=3, seed=0, reward_fn=reward_fn)
    env.reset()
    for action in actions_sequence(3):
        obs, reward, _, _ = env.step(np.tile(action, (3, 1)))
    ctx = calls[-1]
    env.close()
    assert len(calls) == 3
    assert reward.shape == (3,)
    assert ctx["ee_pos"].shape == (3, 3) and "stage" in ctx
    np.testing.assert_allclose(ctx["ee_pos"], obs[:, L["ee_pos"]], atol=1e-6)
    expected = 2.0 * ctx["ee_pos"][:, 2] - np.linalg.norm(ctx["obj_to_ee"][:, 0], axis=-1)
    np.testing.assert_allclose(reward, expected, rtol=1e-6)

    # The single environment reports the same reward and its components.
    env = make_env("pick_nut_m12", reward_fn=reward_fn)
    env.reset(seed=0)
    _, reward, _, _, info = env.step(FREE)
    ctx = calls[-1]
    assert reward == pytest.approx(
        float(2.0 * ctx["ee_pos"][0, 2] + info["reward_components"]["closeness"])
    )
    assert set(info["reward_components"]) == {"height", "closeness"}
    env.close()


def test_diverged_physics_ends_the_episode_instead_of_continuing_from_a_reset_state():
    env = make_batch_env("pick_nut_m12", num_envs=2, seed=0, n_threads=1)
    env.reset()
    # A runaway velocity on env 1's nut: MuJoCo warns and silently resets that env's data.
    nut_dof = env.sim.scene.obj_dof[0]
    env.sim.datas[1].qvel[nut_dof[0]] = 1e20
    _, _, dones, infos = env.step(np.zeros((2, 5)))
    assert dones.tolist() == [False, True]
    # Its terminal observation is MuJoCo's reset pose: no value is bootstrapped from it.
    assert infos[1]["unstable"] and not infos[1]["TimeLimit.truncated"]
    assert "unstable" not in infos[0]
    # The diverged env was reset from the task's distribution, not left at qpos0.
    assert env.steps[1] == 0
    np.testing.assert_allclose(env.sim.ee_pos[1], env.sim.target_pos[1], atol=0.01)
    assert env.sim.ee_pos[1, 2] > 0.1
    env.close()


def test_a_rectangular_peg_held_across_its_longer_side_is_grasped_and_lifted():
    # The fingers may close on the peg's 16 mm faces as well as its 10 mm ones (a pick finds it
    # at any yaw). `grasped` read 0 there, though the peg was held and came up with the hand, so
    # a learner holding it so was paid nothing for lifting it.
    import mujoco

    env = make_batch_env("grasp_peg_rect", num_envs=2, seed=3, n_threads=1)
    env.reset()
    # Environment 1's peg, standing between the open fingers, turned a quarter about its axis.
    yaw = env.context()["obj_yaw"][1, 0] + np.pi / 2
    data, quat = env.sim.datas[1], env.sim.scene.obj_qpos[0][3:7]
    data.qpos[quat] = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
    mujoco.mj_forward(env.sim.model, data)
    for _ in range(6):
        env.step(np.tile([0.0, 0.0, 0.0, 0.0, 1.0], (2, 1)))
    for _ in range(8):
        env.step(np.tile([0.0, 0.0, 1.0, 0.0, 1.0], (2, 1)))
    ctx = env.context()
    env.close()
    width = ctx["gripper_width"]
    assert width[0] < 0.012 < 0.014 < width[1] < 0.017  # across 10 mm, and across 16 mm
    assert (ctx["obj_bottom_z"][:, 0] > 0.02).all()  # lifted, both
    assert (ctx["grasped"][:, 0] > 0.5).all()


def test_an_upside_down_part_on_the_table_reads_as_on_the_table():
    # The bottom was centre - height/2 * cos(tilt): turned over, its top face read as its bottom,
    # a part on the table as lifted by its own height.
    import mujoco

    env = make_batch_env("pick_peg_round", num_envs=1, seed=0, n_threads=1)
    env.reset()
    data, qpos = env.sim.datas[0], env.sim.scene.obj_qpos[0]
    data.qpos[qpos[3:7]] = [0.0, 1.0, 0.0, 0.0]  # half a turn about x
    mujoco.mj_forward(env.sim.model, data)
    for _ in range(3):
        env.step(np.zeros((1, 5)))
    ctx = env.context()
    env.close()
    assert ctx["obj_tilt"][0, 0] > 3.0
    assert abs(ctx["obj_bottom_z"][0, 0]) < 0.003


def test_vec_env_methods_on_some_environments_are_refused_not_applied_to_all():
    # set_attr(indices=[0]) changed every environment, env_method("reset") reset the whole
    # batch once per index: SB3's contract is per environment, the batch has one simulator.
    env = make_batch_env("reach_nut_m12", num_envs=3, seed=0, n_threads=1)
    env.reset()
    with pytest.raises(NotImplementedError, match="all 3 environments of a BatchEnv together"):
        env.set_attr("note", 1, indices=[0])
    with pytest.raises(NotImplementedError, match="env_method acts on all 3"):
        env.env_method("observe", indices=[1, 2])
    env.set_attr("note", 1)
    assert env.get_attr("note") == [1, 1, 1]
    calls = []
    env.note_call = lambda: calls.append(1) or "done"
    assert env.env_method("note_call") == ["done"] * 3 and calls == [1]
    env.close()
