"""Hyper-parameter files: packaged values load, bad values are named with file and field."""

from __future__ import annotations

from pathlib import Path

import pytest

from itskill.datafile import read_toml
from itskill.rl.config import A2CConfig, HyperparamError, PPOConfig, default_path, load_hyperparams
from itskill.tasks import get_task


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
        # Out of range, these trained into a NaN traceback, or into nothing, after the envs.
        ("[nutbolt.ppo]\ngamma = 90\n", "nutbolt.ppo.gamma", "expected a value in (0, 1]"),
        ("[nutbolt.ppo]\ngamma = nan\n", "nutbolt.ppo.gamma", "in (0, 1], got nan"),
        # The other algorithm's table too (the file is loaded for PPO): found on first use.
        ("[nutbolt.a2c]\ngamma = 90\n", "nutbolt.a2c.gamma", "expected a value in (0, 1]"),
        ("[nutbolt.ppo]\ngae_lambda = 1.5\n", "nutbolt.ppo.gae_lambda", "in [0, 1]"),
        ("[nutbolt.ppo]\nclip_range = -0.2\n", "nutbolt.ppo.clip_range", "in (0, 1]"),
        ("[nutbolt.ppo]\nclip_range = 2\n", "nutbolt.ppo.clip_range", "in (0, 1]"),
        ("[nutbolt.ppo]\nmax_grad_norm = 0\n", "nutbolt.ppo.max_grad_norm", "positive"),
        ("[nutbolt.ppo]\nent_coef = -0.01\n", "nutbolt.ppo.ent_coef", "0 or more"),
        ("[nutbolt.ppo]\nvf_coef = -1\n", "nutbolt.ppo.vf_coef", "0 or more"),
        ("[nutbolt.ppo]\nlearning_rate = -3e-4\n", "nutbolt.ppo.learning_rate", "in (0, 1]"),
        # 3e4 for 3e-4 trained a rollout, then failed on NaN actions with a tensor dump.
        ("[nutbolt.ppo]\nlearning_rate = 3e4\n", "nutbolt.ppo.learning_rate", "in (0, 1], got"),
        ("[nutbolt.ppo]\nbatch_size = 0\n", "nutbolt.ppo.batch_size", "positive"),
        # SB3's PPO asserted batch_size > 1 after the environments were built.
        ("[nutbolt.ppo]\nbatch_size = 1\n", "nutbolt.ppo.batch_size", "2 or more for PPO"),
        ("[nutbolt.tasks.pick_nut_m12]\nppo = 3\n", "nutbolt.tasks.pick_nut_m12.ppo", "a table"),
        # A task table's, whichever task or algorithm the file is loaded for.
        (
            "[nutbolt.tasks.pick_nut_m12.ppo]\nbatch_size = 1\n",
            "nutbolt.tasks.pick_nut_m12.ppo.batch_size",
            "2 or more for PPO",
        ),
        ("[nutbolt.demos]\nepochs = 0\n", "nutbolt.demos.epochs", "positive"),
        ("[nutbolt.policy]\nobs_clip = 0\n", "nutbolt.policy.obs_clip", "1 or more"),
        ("[nutbolt.policy]\nobs_clip = 1e-9\n", "nutbolt.policy.obs_clip", "1 or more"),
        ("[nutbolt.policy]\nstages = [1, 'x']\n", "nutbolt.policy.stages", "list of integers"),
        # A network of a hundred thousand layers was built (the widths alone were bounded).
        (
            "[nutbolt.policy]\nstages = [8, 8, 8, 8, 8, 8, 8, 8, 8, 8, 8, 8, 8, 8, 8, 8, 8]\n",
            "nutbolt.policy.stages",
            "1 to 16 positive widths",
        ),
        ("[peghole]\n", "nutbolt", "no table"),
        ("[nutbolt.ppo]\nlr_schedule = 'cosine'\n", "nutbolt.ppo", "lr_schedule must be one of"),
        ("[nutbolt\n", "TOML syntax", ""),
        # Above the first table the key is no family's: it was silently dropped.
        (
            "num_envs = 4\n[nutbolt]\ncheckpoint_every = 1000\n",
            "num_envs",
            "(known families: nutbolt, peghole)",
        ),
        ("normalize_reward = false\n", "normalize_reward", "a key above the first table"),
        # A mistyped family's table was never read.
        (
            "[nutbolt]\n[peghol]\nnum_envs = 4\n",
            "peghol",
            "did you mean 'peghole'? known families: nutbolt, peghole",
        ),
        (
            "[nutbolt]\n[screws.ppo]\nn_steps = 32\n",
            "screws",
            "unknown task family 'screws'; known families: nutbolt",
        ),
        # Not finite: "Invalid learning rate: nan" from PyTorch, or a traceback mid-training.
        *(
            (f"[nutbolt.ppo]\nlearning_rate = {v}\n", "nutbolt.ppo.learning_rate", f"got {got}")
            for v, got in (("inf", "inf"), ("nan", "nan"), ("-inf", "-inf"), ("1e999", "inf"))
        ),
        ("[nutbolt.a2c]\nrms_prop_eps = inf\n", "nutbolt.a2c.rms_prop_eps", "finite"),
        ("[nutbolt.policy]\nobs_clip = inf\n", "nutbolt.policy.obs_clip", "finite"),
        ("[nutbolt.policy]\nlog_std_init = nan\n", "nutbolt.policy.log_std_init", "got nan"),
        ("[nutbolt.init]\nlog_std_init = inf\n", "nutbolt.init.log_std_init", "got inf"),
        ("[nutbolt.init]\nlearning_rate = inf\n", "nutbolt.init.learning_rate", "(0, 1], got inf"),
        # log_std_init had no range at all: the action noise's log standard deviation.
        ("[nutbolt.policy]\nlog_std_init = 3\n", "nutbolt.policy.log_std_init", "[-5, 2]"),
        ("[nutbolt.policy]\nlog_std_init = -6\n", "nutbolt.policy.log_std_init", "[-5, 2]"),
        ("[nutbolt.init]\nlog_std_init = -50\n", "nutbolt.init.log_std_init", "[-5, 2]"),
        (
            "[nutbolt.tasks.pick_nut_m12.policy]\nlog_std_init = 10\n",
            "nutbolt.tasks.pick_nut_m12.policy.log_std_init",
            "[-5, 2]",
        ),
        # Counts with no upper bound crashed the run at allocation, or after its training.
        ("[nutbolt]\nnum_envs = 100000000000\n", "nutbolt.num_envs", "at most 1,024"),
        ("[nutbolt]\nnum_envs = 1025\n", "nutbolt.num_envs", "at most 1,024"),
        ("[nutbolt.demos]\nepisodes = 100000000000000\n", "nutbolt.demos.episodes", "1,000,000"),
        ("[nutbolt.demos]\nepisodes = -1\n", "nutbolt.demos.episodes", "0 or more"),
        ("[nutbolt.init]\ncritic_episodes = 10000000\n", "nutbolt.init.critic_episodes", "most"),
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


def test_num_envs_wins_over_the_overrides_and_takes_their_bounds() -> None:
    overrides = {"num_envs": 4, "learning_rate": 1e-5}
    hp = load_hyperparams("nutbolt", "ppo", overrides=overrides, num_envs=2)
    assert (hp.num_envs, hp.algo_config.learning_rate) == (2, 1e-5)
    assert overrides["num_envs"] == 4  # the caller's table is left as it was
    with pytest.raises(HyperparamError) as info:
        load_hyperparams("nutbolt", "ppo", num_envs=0)
    assert info.value.where == "overrides.num_envs"


def test_a_task_table_changes_its_task_only(tmp_path: Path) -> None:
    path = tmp_path / "hp.toml"
    path.write_text(
        "[peghole.policy]\nlog_std_init = -0.5\n[peghole.ppo]\nn_steps = 64\n"
        "[peghole.tasks.place_peg_rect.policy]\nlog_std_init = -1.5\n"
    )
    own = load_hyperparams("peghole", "ppo", path, task="place_peg_rect")
    other = load_hyperparams("peghole", "ppo", path, task="insert_peg_rect")
    assert own.policy.log_std_init == -1.5 and other.policy.log_std_init == -0.5
    # The rest of the family's values still apply to the task.
    assert own.algo_config.n_steps == other.algo_config.n_steps == 64
    overridden = load_hyperparams(
        "peghole", "ppo", path, {"policy": {"log_std_init": 0.0}}, task="place_peg_rect"
    )
    assert overridden.policy.log_std_init == 0.0


def test_a_bad_task_table_is_named_even_when_another_task_loads(tmp_path: Path) -> None:
    path = tmp_path / "hp.toml"
    path.write_text("[peghole.tasks.place_peg_rect.policy]\nlog_std = -1.5\n")
    with pytest.raises(HyperparamError) as info:
        load_hyperparams("peghole", "ppo", path, task="insert_peg_rect")
    assert info.value.where == "peghole.tasks.place_peg_rect.policy.log_std"


@pytest.mark.parametrize("family", ["nutbolt", "peghole"])
def test_packaged_task_tables_name_tasks_of_their_family(family: str) -> None:
    tables = read_toml(default_path(), HyperparamError)[family].get("tasks", {})
    for name in tables:
        assert get_task(name).family == family


@pytest.mark.parametrize(
    ("table", "problem"),
    [
        # A typo: the run trained with the family's n_steps, and nothing said so.
        ("nutbolt.tasks.pick_nut_m21", "unknown task 'pick_nut_m21'; did you mean"),
        # Under the other family, the task's own family never reads it.
        ("peghole.tasks.pick_nut_m12", "task 'pick_nut_m12' is of family 'nutbolt'"),
        ("nutbolt.tasks.pick_peg_round", "its table goes under [peghole.tasks.pick_peg_round]"),
    ],
)
def test_a_task_table_of_no_task_of_its_family_is_named(
    tmp_path: Path, table: str, problem: str
) -> None:
    path = tmp_path / "hp.toml"
    path.write_text(default_path().read_text() + f"\n[{table}.ppo]\nn_steps = 32\n")
    with pytest.raises(HyperparamError) as info:
        load_hyperparams("nutbolt", "ppo", path, task="pick_nut_m12")
    assert (info.value.path, info.value.where) == (str(path), table)
    assert problem in info.value.problem
    if "did you mean" in problem:
        assert "'pick_nut_m12'" in info.value.problem


MY_TASK = """\
[[task]]
id = "my_pick"
family = "nutbot"
command = "Pick up the M12 nut"
skills = ["Pick"]
actions = ["approach", "grasp"]
objects = ["nut_m12"]
max_steps = 60
success = "grasped(0)"
stages = [{ name = "grasp", done = "grasped(0)" }]
[task.init]
objects = [{ mode = "table", x = 0.5 }]
"""


def test_a_task_of_a_family_without_hyperparameters_is_named(monkeypatch, tmp_path: Path) -> None:
    # The packaged hyper-parameter file took the blame for a typo in the user's task file.
    from typer.testing import CliRunner

    import itskill.tasks.spec as spec_module
    from itskill.cli import app

    (tmp_path / "tasks").mkdir()
    task_file = tmp_path / "tasks" / "mine.toml"
    task_file.write_text(MY_TASK)
    monkeypatch.setenv(spec_module.TASKS_DIR_ENV, str(tmp_path / "tasks"))
    spec_module._registry.cache_clear()
    try:
        args = ["train", "my_pick", "--steps", "64", "--out", str(tmp_path / "run")]
        result = CliRunner().invoke(app, args)
    finally:
        spec_module._registry.cache_clear()
    assert result.exit_code == 2, result.output
    message = (
        f"nutbot: no table for task family 'nutbot' (of task 'my_pick', from {task_file}); "
        "this file has tables for nutbolt, peghole"
    )
    assert "".join(message.split()) in "".join(result.output.split())  # rich wraps long lines
    assert "Traceback" not in result.output and not (tmp_path / "run").exists()


def test_the_bounds_themselves_load(tmp_path: Path) -> None:
    path = tmp_path / "hp.toml"
    path.write_text(
        "[nutbolt]\nnum_envs = 1024\n[nutbolt.policy]\nlog_std_init = -5\n"
        "[nutbolt.init]\nlog_std_init = 2\n[nutbolt.demos]\nepisodes = 1_000_000\n"
    )
    hp = load_hyperparams("nutbolt", "ppo", path)
    assert (hp.num_envs, hp.policy.log_std_init, hp.init.log_std_init) == (1024, -5.0, 2.0)


@pytest.mark.parametrize(
    ("overrides", "where"),
    [
        ({"learning_rate": float("inf")}, "overrides.ppo.learning_rate"),
        ({"num_envs": 10**11}, "overrides.num_envs"),
        ({"policy": {"log_std_init": float("nan")}}, "overrides.policy.log_std_init"),
    ],
)
def test_overrides_take_the_same_bounds(overrides: dict, where: str) -> None:
    with pytest.raises(HyperparamError) as info:
        load_hyperparams("nutbolt", "ppo", overrides=overrides)
    assert info.value.where == where


def test_cli_reports_a_non_finite_hyperparameter_in_one_line(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from itskill.cli import app

    path = tmp_path / "hp.toml"
    path.write_text("[nutbolt.ppo]\nmax_grad_norm = inf\n")
    args = ["train", "pick_nut_m12", "--steps", "64", "--hyperparams", str(path)]
    result = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "run")])
    assert result.exit_code == 2, result.output
    message = f"error: {path}: nutbolt.ppo.max_grad_norm: expected a finite number, got inf"
    assert "".join(message.split()) in "".join(result.output.split())
    assert "Traceback" not in result.output and not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    ("table", "key", "most"),
    [
        # No upper bound: a mistyped huge width or count allocated until the machine gave out, or
        # trained on for days, before failing.
        ("nutbolt.policy", "stages", "[256, {}, 128]"),
        ("nutbolt.ppo", "n_steps", "{}"),
        ("nutbolt.a2c", "n_steps", "{}"),
        ("nutbolt.ppo", "batch_size", "{}"),
        ("nutbolt.ppo", "n_epochs", "{}"),
        ("nutbolt.demos", "epochs", "{}"),
        ("nutbolt.demos", "batch_size", "{}"),
    ],
)
def test_widths_and_counts_have_an_upper_bound(
    tmp_path: Path, table: str, key: str, most: str
) -> None:
    from itskill.limits import WIDTH_MAX
    from itskill.rl.config import BATCH_SIZE_MAX, EPOCHS_MAX, N_STEPS_MAX

    bound = {"stages": WIDTH_MAX, "n_steps": N_STEPS_MAX, "batch_size": BATCH_SIZE_MAX}.get(
        key, EPOCHS_MAX
    )
    path = tmp_path / "hp.toml"
    path.write_text(f"[{table}]\n{key} = {most.format(bound)}\n")
    load_hyperparams("nutbolt", "ppo", path)  # the bound itself loads
    path.write_text(f"[{table}]\n{key} = {most.format(bound + 1)}\n")
    with pytest.raises(HyperparamError) as info:
        load_hyperparams("nutbolt", "ppo", path)
    assert (info.value.path, info.value.where) == (str(path), f"{table}.{key}")
    assert f"at most {bound:,}" in info.value.problem


def test_overrides_take_the_upper_bounds() -> None:
    with pytest.raises(HyperparamError) as info:
        load_hyperparams("nutbolt", "ppo", overrides={"policy": {"stages": [256, 10**9]}})
    assert info.value.where == "overrides.policy.stages" and "at most 4,096" in info.value.problem
    with pytest.raises(HyperparamError) as info:
        load_hyperparams("nutbolt", "ppo", overrides={"n_epochs": 5000})
    assert info.value.where == "overrides.ppo.n_epochs" and "at most 1,000" in info.value.problem


def test_a_ppo_rollout_of_one_sample_is_refused() -> None:
    # The batch is cut to the rollout: 1 x 1 made a minibatch of one, an AssertionError in SB3.
    with pytest.raises(HyperparamError, match=r"n_steps 1 x num_envs 1 \(the overrides") as info:
        load_hyperparams("nutbolt", "ppo", overrides={"n_steps": 1, "num_envs": 1})
    assert info.value.where == "n_steps x num_envs"
    # The warm start's behaviour cloning takes minibatches of one.
    demos = load_hyperparams("nutbolt", "ppo", overrides={"demos": {"batch_size": 1}})
    assert demos.demos.batch_size == 1
    assert load_hyperparams("nutbolt", "a2c", overrides={"n_steps": 1, "num_envs": 1}).num_envs == 1
    # A2C normalising its advantages over one sample: NaN actions after the first update.
    one = {"n_steps": 1, "num_envs": 1, "normalize_advantage": True}
    with pytest.raises(HyperparamError, match="A2C needs 2 or more samples a rollout to normal"):
        load_hyperparams("nutbolt", "a2c", overrides=one)
