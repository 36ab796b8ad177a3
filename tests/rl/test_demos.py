"""Warm start from the scripted controller: demonstrations, returns, cloning, and resuming."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from stable_baselines3.common.policies import ActorCriticPolicy
from typer.testing import CliRunner

from itskill.cli import app
from itskill.rl import demos as demos_module
from itskill.rl.checkpoint import as_policy, load_policy
from itskill.rl.config import HyperparamError, load_hyperparams
from itskill.rl.demos import DemoConfig, Demonstrations, collect_demos, discounted_returns
from itskill.rl.logger import LoggerConfig
from itskill.rl.train import train
from itskill.tasks import get_task, make_batch_env
from itskill.tasks.evaluate import RandomPolicy, evaluate

QUIET = LoggerConfig(progress=False, tensorboard=False, min_steps_per_row=1)
TASK = "reach_nut_m12"


def test_demonstrations_are_the_scripts_successful_episodes(monkeypatch) -> None:
    spec = get_task(TASK)
    script = demos_module.ScriptedPolicy.__call__

    def idle_in_odd_envs(self, ctx):
        # The reach script succeeds from every start; standing still never reaches.
        actions = script(self, ctx).copy()
        actions[1::2] = 0.0
        return actions

    monkeypatch.setattr(demos_module.ScriptedPolicy, "__call__", idle_in_odd_envs)
    env = make_batch_env(spec, num_envs=4, seed=3, training=True)
    sent, successes = [], []
    step = env.step

    def step_and_record(actions):
        obs, rewards, dones, infos = step(actions)
        sent.append(np.clip(actions, -1.0, 1.0))
        successes.extend(infos[e]["is_success"] for e in np.flatnonzero(dones))
        return obs, rewards, dones, infos

    monkeypatch.setattr(env, "step", step_and_record)
    try:
        demos = collect_demos(spec, env, episodes=8)
    finally:
        env.close()
    assert demos.attempted == len(successes) == 8
    assert demos.episodes == sum(successes) == 4
    # Two rounds of episodes run to the time limit together; what is kept is, in order, the
    # successful environments' episodes and none of the idle ones'.
    rounds = np.stack(sent).reshape(2, spec.max_steps, 4, -1)
    kept = [rounds[r, :, e] for r in range(2) for e in range(4) if successes[4 * r + e]]
    np.testing.assert_array_equal(demos.actions, np.concatenate(kept))
    assert demos.episode_ends[-1] == len(demos.obs) == len(demos.actions) == len(demos.rewards)
    assert demos.episodes * spec.max_steps == len(demos.obs)  # reach runs to its time limit
    assert demos.obs.shape[1] == env.observation_space.shape[0]
    assert np.all(np.abs(demos.actions) <= 1.0)
    # Steps are counted over all environments, unfinished episodes included.
    assert demos.env_steps >= demos.attempted * spec.max_steps


def test_returns_bootstrap_the_last_reward_past_the_time_limit() -> None:
    demos = Demonstrations(
        obs=np.zeros((5, 1)),
        actions=np.zeros((5, 1)),
        rewards=np.array([0.0, 1.0, 2.0, 0.0, 4.0]),
        episode_ends=np.array([2, 5]),
        attempted=2,
        env_steps=5,
    )
    # gamma 0.5: the tail after a last reward r is r / (1 - 0.5) = 2r.
    np.testing.assert_allclose(
        discounted_returns(demos, gamma=0.5),
        [0.0 + 0.5 * 2.0, 1.0 + 0.5 * 2.0, 2.0 + 0.5 * 4.0, 0.0 + 0.5 * 8.0, 4.0 + 0.5 * 8.0],
    )
    # Undiscounted, the tail has no finite value: the returns stop at the episode's end.
    np.testing.assert_allclose(discounted_returns(demos, gamma=1.0), [1.0, 1.0, 6.0, 4.0, 4.0])


def test_cloning_the_script_makes_a_policy_that_reaches(tmp_path: Path) -> None:
    """Before any RL update (one PPO rollout at a negligible learning rate), the cloned policy
    reaches the nut where the random policy does not."""
    out = tmp_path / "run"
    train(
        TASK, "ppo", 64, seed=0, out=out, num_envs=8, logger=QUIET,
        overrides={"n_steps": 8, "batch_size": 64, "n_epochs": 1, "learning_rate": 1e-9,
                   "demos": {"episodes": 48, "epochs": 30}},
    )  # fmt: skip
    summary = json.loads((out / "demos.json").read_text())
    assert summary["episodes_run"] == 48 and summary["episodes_kept"] >= 40
    assert summary["actor_mse"] < 0.05
    spec = get_task(TASK)
    cloned = evaluate(spec, as_policy(out), episodes=32, seed=123)
    random = evaluate(spec, RandomPolicy(), episodes=32, seed=123)
    print(cloned.success_rate, random.success_rate)
    assert cloned.success_rate >= 0.8 > random.success_rate + 0.5


def test_the_normaliser_stays_as_the_demonstrations_fitted_it(tmp_path: Path) -> None:
    out = tmp_path / "run"
    overrides = {"n_steps": 16, "batch_size": 64, "n_epochs": 1, "demos": {"episodes": 8}}
    train(TASK, "ppo", 128, seed=0, out=out, num_envs=4, logger=QUIET, overrides=overrides)
    first = load_policy(out).obs_norm.count.item()
    assert first == json.loads((out / "demos.json").read_text())["transitions"]
    # RL rollouts and a resumed session leave it as it was; the warm start is not repeated.
    summary = (out / "demos.json").stat().st_mtime_ns
    result = train(TASK, "ppo", 256, seed=0, out=out, num_envs=4, logger=QUIET, overrides=overrides)
    assert result.resumed_from == 128 and result.num_timesteps == 256
    assert load_policy(out).obs_norm.count.item() == first
    assert (out / "demos.json").stat().st_mtime_ns == summary


def test_demo_settings_are_validated_where_they_are_read(tmp_path: Path) -> None:
    hp = tmp_path / "hp.toml"
    hp.write_text(f"[nutbolt.tasks.{TASK}.demos]\nepisodes = 50\n")
    assert load_hyperparams("nutbolt", "ppo", hp, task=TASK).demos == DemoConfig(episodes=50)
    assert load_hyperparams("nutbolt", "ppo", hp, task="pick_nut_m12").demos.episodes == 0
    hp.write_text("[nutbolt.demos]\nepisodes = -1\n")
    with pytest.raises(
        HyperparamError, match=r"nutbolt\.demos\.episodes: expected a value of 0 or more"
    ):
        load_hyperparams("nutbolt", "ppo", hp)
    hp.write_text("[nutbolt.demos]\nepsiodes = 5\n")
    with pytest.raises(HyperparamError, match=r"nutbolt\.demos\.epsiodes: unknown field"):
        load_hyperparams("nutbolt", "ppo", hp)


def test_cli_train_warm_starts_with_demos(tmp_path: Path) -> None:
    out = tmp_path / "run"
    args = ["train", TASK, "--algo", "a2c", "--steps", "32", "--num-envs", "4", "--out", str(out)]
    result = CliRunner().invoke(app, [*args, "--demos", "4", "--eval-every", "32"])
    assert result.exit_code == 0, result.output
    assert json.loads((out / "demos.json").read_text())["episodes_run"] == 4
    meta = json.loads((out / "checkpoint.json").read_text())
    assert meta["hyperparams"]["demos"]["episodes"] == 4
    # The clone is evaluated before the first update, then at the end.
    steps = [row.split(",")[0] for row in (out / "eval.csv").read_text().splitlines()[1:]]
    assert steps == ["0", "32"]


def test_a_warm_start_needs_the_staged_policy(tmp_path: Path) -> None:
    with pytest.raises(HyperparamError, match="needs a StagedActorCriticPolicy"):
        train(
            TASK, "ppo", 64, out=tmp_path / "run", num_envs=4, logger=QUIET,
            overrides={"demos": {"episodes": 4}}, policy_class=ActorCriticPolicy,
        )  # fmt: skip
    assert not (tmp_path / "run").exists()


def test_a_script_that_never_succeeds_stops_the_run_with_a_clear_error(
    tmp_path: Path, monkeypatch
) -> None:
    def stand_still(self, ctx):
        return np.zeros((self.num_envs, 5))

    monkeypatch.setattr(demos_module.ScriptedPolicy, "__call__", stand_still)
    out = tmp_path / "run"
    args = ["train", TASK, "--steps", "32", "--num-envs", "4", "--demos", "4", "--out", str(out)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2
    assert "succeeded in none of 4 episodes" in " ".join(result.output.split())
    assert not (out / "checkpoint.json").exists()
