"""A run started from a trained policy (``init``): where it starts, what it keeps, its errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from itskill.cli import app
from itskill.rl.checkpoint import as_policy, load_policy
from itskill.rl.config import HyperparamError, default_path, load_hyperparams
from itskill.rl.logger import LoggerConfig
from itskill.rl.train import ResumeMismatchError, train
from itskill.skills.store import SHIPPED_LIBRARY
from itskill.tasks import get_task
from itskill.tasks.evaluate import CheckpointError, evaluate

QUIET = LoggerConfig(progress=False, tensorboard=False, min_steps_per_row=1)
TASK = "reach_nut_m12"
SKILL = SHIPPED_LIBRARY / TASK
STILL = {"n_steps": 8, "batch_size": 32, "n_epochs": 1}
"""One PPO rollout and an update too small to move a weight: what the run starts from."""


def _train(
    out: Path, steps: int = 32, init: Path | None = SKILL, init_table: dict | None = None, **ov
) -> object:
    table = {"learning_rate": 1e-9, "critic_episodes": 16, **(init_table or {})}
    return train(
        TASK, "ppo", steps, seed=0, out=out, num_envs=4, logger=QUIET, eval_every=32,
        eval_episodes=8, init=init, overrides={**STILL, "init": table, **ov},
    )  # fmt: skip


def test_a_run_starts_from_the_skill_it_is_given(tmp_path: Path) -> None:
    out = tmp_path / "run"
    _train(out, init_table={"log_std_init": -2.0})
    skill, run = load_policy(SKILL).state_dict(), load_policy(out).state_dict()
    critic = ("mlp_extractor.critic.", "value_net.")
    for name, value in skill.items():
        if name == "log_std":
            # The exploration is the run's own, not what the skill's training left.
            assert torch.all(run[name] == -2.0)
        elif not name.startswith(critic):
            # The actor and the observation statistics alike: RL rollouts do not move the
            # normaliser the skill was trained with.
            torch.testing.assert_close(run[name], value, msg=name)
    # The critic was fitted to the skill's own returns in this run's reward scale.
    assert not torch.equal(run["value_net.weight"], skill["value_net.weight"])
    warm_up = json.loads((out / "critic_warm_up.json").read_text())
    assert warm_up["critic_mse"] < warm_up["critic_mse_before"] / 2
    assert warm_up["episodes_run"] == 16 and warm_up["transitions"] == 16 * get_task(TASK).max_steps
    spec = get_task(TASK)
    started = evaluate(spec, as_policy(out), 16, seed=5)
    assert started.success_rate == evaluate(spec, as_policy(SKILL), 16, seed=5).success_rate
    meta = json.loads((out / "checkpoint.json").read_text())
    assert meta["init"]["task"] == TASK and meta["init"]["path"] == str(SKILL.resolve())
    # Evaluated before its first update, so the kept policy is never worse than the start.
    steps = [row.split(",")[0] for row in (out / "eval.csv").read_text().splitlines()[1:]]
    assert steps == ["0", "32"]


def test_a_start_interrupted_before_its_first_update_is_evaluated_at_0_once(
    tmp_path: Path, monkeypatch
) -> None:
    # The resumed session evaluated the starting policy again: two rows at 0, and a wasted
    # evaluation.
    from stable_baselines3 import PPO

    def interrupted(self):
        raise KeyboardInterrupt

    out = tmp_path / "run"
    monkeypatch.setattr(PPO, "train", interrupted)
    with pytest.raises(KeyboardInterrupt):
        _train(out)
    monkeypatch.undo()
    assert json.loads((out / "checkpoint.json").read_text())["num_timesteps"] == 0
    _train(out)
    steps = [row.split(",")[0] for row in (out / "eval.csv").read_text().splitlines()[1:]]
    assert steps == ["0", "32"]


def test_a_resume_needs_the_same_starting_policy(tmp_path: Path) -> None:
    out = tmp_path / "run"
    _train(out)
    with pytest.raises(ResumeMismatchError, match="random weights"):
        _train(out, 64, init=None)
    other = SHIPPED_LIBRARY / "reach_nut_m16"
    with pytest.raises(ResumeMismatchError, match="reach_nut_m16"):
        _train(out, 64, init=other)
    assert _train(out, 64).resumed_from == 32


def test_a_resume_from_a_skill_retrained_in_place_says_its_weights_changed(tmp_path: Path) -> None:
    # The message named the same directory twice: "started from X, this call starts from X".
    skill = tmp_path / "skill"
    shutil.copytree(SKILL, skill)
    out = tmp_path / "run"
    _train(out, init=skill)
    other = (SHIPPED_LIBRARY / "reach_nut_m16" / "policy.safetensors").read_bytes()
    (skill / "policy.safetensors").write_bytes(other)
    with pytest.raises(ResumeMismatchError, match="its weights have changed since") as err:
        _train(out, 64, init=skill)
    assert str(err.value).count(str(skill.resolve())) == 1


def test_a_policy_of_another_shape_is_refused_by_name(tmp_path: Path) -> None:
    with pytest.raises(CheckpointError, match=r"stages \[256, 256, 128\] \(run: \[64, 64, 64\]\)"):
        _train(tmp_path / "run", policy={"stages": [64, 64, 64]})


def test_a_run_starts_from_demonstrations_or_a_policy_not_both(tmp_path: Path) -> None:
    with pytest.raises(HyperparamError, match="not both"):
        _train(tmp_path / "run", demos={"episodes": 4})
    assert not (tmp_path / "run").exists()


def test_demonstrations_a_packaged_task_table_asks_for_are_named_with_the_way_out(
    tmp_path: Path,
) -> None:
    # The user asked for neither a hyper-parameter file nor demonstrations: the packaged
    # pick_peg_round table did, and the error named neither it nor --demos 0.
    with pytest.raises(HyperparamError) as info:
        train("pick_peg_round", "ppo", 32, out=tmp_path / "run", init=SKILL, logger=QUIET)
    assert info.value.path == str(default_path())
    assert info.value.where == "peghole.tasks.pick_peg_round.demos.episodes"
    assert "200 demonstrations" in info.value.problem and "--demos 0" in info.value.problem
    assert not (tmp_path / "run").exists()


def test_the_init_table_is_validated_and_used_only_when_starting_from_a_policy(
    tmp_path: Path,
) -> None:
    hp_file = tmp_path / "hp.toml"
    hp_file.write_text("[nutbolt.init]\nlog_std_init = -2.5\nlearning_rate = 5e-5\n")
    hp = load_hyperparams("nutbolt", "ppo", hp_file)
    assert hp.policy.log_std_init == -0.5 and hp.algo_config.learning_rate == 3e-4
    started = hp.starting_from_policy()
    assert started.policy.log_std_init == -2.5 and started.algo_config.learning_rate == 5e-5
    hp_file.write_text("[nutbolt.init]\ncritic_episodes = 0\n")
    with pytest.raises(HyperparamError, match=r"nutbolt\.init\.critic_episodes"):
        load_hyperparams("nutbolt", "ppo", hp_file)


def test_cli_init_from_a_missing_directory_is_a_clear_error(tmp_path: Path) -> None:
    missing = tmp_path / "no_such_run"
    args = ["train", TASK, "--steps", "32", "--out", str(tmp_path / "run"), "--init", str(missing)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2
    assert "no such checkpoint directory" in result.output and "Traceback" not in result.output


def test_cli_init_takes_a_skill_by_name_and_its_weights_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # `eval` and `render` took skill:NAME and the checkpoint `skills show` prints; --init took
    # only the skill's directory ("skill:...: no such checkpoint directory").
    import hashlib

    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    # The packaged settings but a critic fitted on 2 episodes, not 64: five runs start below.
    hyperparams = tmp_path / "hyperparams.toml"
    packaged = default_path().read_text()
    assert packaged.count("critic_episodes = 64") == 2
    hyperparams.write_text(packaged.replace("critic_episodes = 64", "critic_episodes = 2"))
    quick = ["--steps", "8", "--num-envs", "2", "--demos", "0", "--hyperparams", str(hyperparams)]
    weights = SKILL / "policy.safetensors"
    digest = hashlib.sha256(weights.read_bytes()).hexdigest()
    for n, ref in enumerate((f"skill:{TASK}", str(weights))):
        out = tmp_path / f"run{n}"
        args = ["train", TASK, *quick, "--out", str(out), "--init", ref]
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 0, result.output
        assert json.loads((out / "checkpoint.json").read_text())["init"]["sha256"] == digest
    # A run's weights file named itself is that policy, not the run's best one beside it.
    run = tmp_path / "source_run"
    shutil.copytree(SKILL, run)
    shutil.copytree(SHIPPED_LIBRARY / "lift_nut_m12", run / "best")
    from itskill.skills import Skill, open_skill_space

    with open_skill_space() as space:  # a skill added from the run's own weights file
        space.add(Skill("mine", TASK, "reach", ("approach",), str(run / "policy.safetensors")))
    cases = ((run / "policy.safetensors", run), ("skill:mine", run), (run, run / "best"))
    for ref, used in cases:
        out = tmp_path / f"from_{str(ref).replace('/', '_').replace(':', '_')}"
        args = ["train", TASK, *quick, "--out", str(out), "--init", str(ref)]
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 0, result.output
        recorded = json.loads((out / "checkpoint.json").read_text())["init"]
        assert recorded["path"] == str(used.resolve())
    unknown = ["train", TASK, "--out", str(tmp_path / "other"), "--init", "skill:no_such_skill"]
    result = CliRunner().invoke(app, unknown)
    assert result.exit_code == 2 and "no_such_skill" in result.output
