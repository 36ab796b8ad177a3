"""Hyper-parameter files: packaged values load, bad values are named with file and field."""

from __future__ import annotations

from pathlib import Path

import pytest

from itskill.rl.config import A2CConfig, HyperparamError, PPOConfig, load_hyperparams


@pytest.mark.parametrize("family", ["nutbolt", "peghole"])
def test_packaged_file_loads(family: str) -> None:
    a2c = load_hyperparams(family, "a2c")
    ppo = load_hyperparams(family, "ppo")
    assert isinstance(a2c.algo_config, A2CConfig) and isinstance(ppo.algo_config, PPOConfig)
    assert a2c.policy.stages == (256, 256, 128)


@pytest.mark.parametrize(
    ("text", "where", "expected"),
    [
        ("[nutbolt.ppo]\nn_steps = 'many'\n", "nutbolt.ppo.n_steps", "expected an integer"),
        ("[nutbolt.ppo]\nlearning_rat = 1e-3\n", "nutbolt.ppo.learning_rat", "unknown field"),
        ("[nutbolt]\nnum_envs = 0\n", "nutbolt.num_envs", "positive"),
        ("[nutbolt.policy]\nstages = [1, 'x']\n", "nutbolt.policy.stages", "list of integers"),
        ("[peghole]\n", "nutbolt", "no table"),
        ("[nutbolt.ppo]\nlr_schedule = 'cosine'\n", "nutbolt.ppo", "lr_schedule must be one of"),
        ("[nutbolt\n", "TOML syntax", ""),
    ],
)
def test_invalid_file_names_file_field_expected(
    tmp_path: Path, text: str, where: str, expected: str
) -> None:
    path = tmp_path / "hp.toml"
    path.write_text(text)
    with pytest.raises(HyperparamError) as info:
        load_hyperparams("nutbolt", "ppo", path)
    assert info.value.path == str(path)
    assert info.value.where == where
    assert expected in info.value.problem


def test_overrides_checked() -> None:
    hp = load_hyperparams("nutbolt", "ppo", overrides={"n_steps": 8, "batch_size": 32})
    assert hp.algo_config.n_steps == 8
    with pytest.raises(HyperparamError, match="positive"):
        load_hyperparams("nutbolt", "ppo", overrides={"n_steps": 0})
    with pytest.raises(HyperparamError, match="unknown field"):
        load_hyperparams("nutbolt", "a2c", overrides={"clip_range": 0.1})


@pytest.mark.parametrize("algo", ["a2c", "ppo"])
def test_linear_schedule_anneals_the_learning_rate_to_zero(algo: str) -> None:
    hp = load_hyperparams("nutbolt", algo, overrides={"lr_schedule": "linear"})
    lr = hp.algo_config.sb3_kwargs()["learning_rate"]
    start = hp.algo_config.learning_rate
    # SB3 passes the fraction of the env-step budget still to go.
    assert lr(1.0) == pytest.approx(start)
    assert lr(0.5) == pytest.approx(start / 2)
    assert lr(0.0) == pytest.approx(0.0)
    constant = load_hyperparams("nutbolt", algo, overrides={"lr_schedule": "constant"})
    assert constant.algo_config.sb3_kwargs()["learning_rate"] == start


def test_fewer_environments_shrink_the_minibatch_to_the_rollout() -> None:
    family = load_hyperparams("nutbolt", "ppo")
    small = load_hyperparams("nutbolt", "ppo", overrides={"num_envs": 2})
    assert family.algo_config.batch_size == 256
    assert small.algo_config.batch_size == 2 * small.algo_config.n_steps
