"""Experiment files: the shipped ones load; every mistake names the file and the field."""

from __future__ import annotations

from pathlib import Path

import pytest

from itskill.experiments.config import (
    ExperimentConfigError,
    load_experiment,
    parse_experiment,
)

REPO = Path(__file__).resolve().parents[2]

MINIMAL = """
tasks = ["pick_nut_m12"]
methods = ["itn", "no_transfer"]
steps = 1000
[eval]
every = 500
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "exp.toml"
    path.write_text(text)
    return path


def test_shipped_experiment_files_load():
    validation = load_experiment(REPO / "experiments" / "validation.toml")
    assert validation.tasks == ("pickplace_nut_m12", "pickplaceinsert_peg_round")
    assert validation.methods == ("itn", "nia", "dfs", "pst", "no_transfer")
    assert validation.seeds == (0, 1, 2, 3, 4) and validation.algo == "ppo"
    assert validation.report.paper_gain["pickplace_nut_m12"] == pytest.approx(0.7222)
    smoke = load_experiment(REPO / "experiments" / "smoke.toml")
    assert smoke.steps <= 10_000
    reduced = load_experiment(REPO / "experiments" / "validation_2core.toml")
    assert reduced.tasks == validation.tasks and reduced.methods == validation.methods


def test_defaults_and_round_trip(tmp_path):
    config = load_experiment(write(tmp_path, MINIMAL))
    assert config.name == "exp" and config.seeds == (0, 1, 2, 3, 4)
    assert config.reward == {"pick_nut_m12": "expert"}
    assert config.sources == {"pick_nut_m12": "auto"}
    assert config.report.threshold == 0.8 and config.report.baseline == "no_transfer"
    # A run records its configuration as JSON and reads it back with the file's checks.
    assert parse_experiment(config.to_dict(), tmp_path / "config.json", recorded=True) == config


def test_hyperparams_a_file_names_are_kept_and_recorded(tmp_path):
    table = "[hyperparams.pick_nut_m12]\nlearning_rate = 1e-5\npolicy = {log_std_init = -3.0}\n"
    text = MINIMAL + table
    config = load_experiment(write(tmp_path, text))
    assert config.hyperparams == {
        "pick_nut_m12": {"learning_rate": 1e-5, "policy": {"log_std_init": -3.0}}
    }
    assert config.training_settings()["hyperparams"] == config.hyperparams
    assert parse_experiment(config.to_dict(), tmp_path / "config.json", recorded=True) == config
    # A run recorded before files could name them trained every task with the packaged ones.
    record = {k: v for k, v in config.to_dict().items() if k != "hyperparams"}
    old = parse_experiment(record, tmp_path / "config.json", recorded=True)
    assert old.training_settings()["hyperparams"] == {"pick_nut_m12": {}}


def test_a_transfer_setting_is_named_where_the_file_sets_it(tmp_path):
    config = load_experiment(write(tmp_path, MINIMAL + "[transfer.pst]\nkeep = 2\n"))
    assert config.transfer_key("pst_keep") == "transfer.pst.keep"
    assert config.transfer_key("prior_weight") is None  # the packaged transfer.toml's


def test_transfer_settings_a_file_names_are_on_top_of_the_packaged_ones(tmp_path):
    from itskill.transfer import load_transfer_config

    table = "[transfer.pst]\nkeep = 2\n[transfer.attention]\nprior_weight = 0.25\n"
    config = load_experiment(write(tmp_path, MINIMAL + table))
    assert config.transfer == {"pst": {"keep": 2}, "attention": {"prior_weight": 0.25}}
    packaged = load_transfer_config()
    settings = config.transfer_config()
    assert (settings.pst_keep, settings.prior_weight) == (2, 0.25)
    assert settings.residual == packaged.residual and settings.k == config.k
    # What a resume compares: the settings ITN's network uses (No_Transfer's none), resolved.
    assert config.training_settings()["transfer"] == {
        "attention_hidden": packaged.attention_hidden, "prior_weight": 0.25,
        "fusion_hidden": list(packaged.fusion_hidden), "residual": packaged.residual,
    }  # fmt: skip
    assert parse_experiment(config.to_dict(), tmp_path / "config.json", recorded=True) == config
    # A run recorded before files could name them trained with the packaged ones.
    record = {k: v for k, v in config.to_dict().items() if k != "transfer"}
    old = parse_experiment(record, tmp_path / "config.json", recorded=True)
    assert old.transfer == {} and old.transfer_config() == packaged


def test_a_baseline_trained_in_another_run_may_be_named_without_its_method(tmp_path):
    # Refused as "not one of the methods": an experiment of ITN alone, its baseline from a run
    # of it given to the report (--baseline-run), could not name it.
    text = MINIMAL.replace('["itn", "no_transfer"]', '["itn"]')
    config = load_experiment(write(tmp_path, text + '[report]\nbaseline = "no_transfer"\n'))
    assert config.methods == ("itn",) and config.report.baseline == "no_transfer"


GOOD_REWARD = """\
import numpy as np

def compute_reward(ctx):
    return np.zeros(len(ctx["ee_pos"])), {}
"""


def test_per_task_reward_files_resolve_relative_to_the_experiment_file(tmp_path):
    # With the byte-order mark an editor may write: not code, so not refused by the sandbox.
    (tmp_path / "r.py").write_bytes(b"\xef\xbb\xbf" + GOOD_REWARD.encode())
    text = MINIMAL.replace("steps = 1000", 'steps = 1000\nreward = {pick_nut_m12 = "r.py"}')
    config = load_experiment(write(tmp_path, text))
    assert config.reward["pick_nut_m12"] == str((tmp_path / "r.py").resolve())


@pytest.mark.parametrize(
    ("edit", "where", "problem"),
    [
        (('tasks = ["pick_nut_m12"]', 'tasks = ["pick_nut_m99"]'), "tasks[0]", "unknown task"),
        (('"itn"', '"itm"'), "methods[0]", "unknown method 'itm'"),
        (("steps = 1000", "steps = 0"), "steps", "must be positive"),
        (("steps = 1000", 'steps = "many"'), "steps", "expected an integer"),
        (("every = 500", "every = 5000"), "eval.every", "more than steps"),
        (("steps = 1000", 'steps = 1000\nalgo = "dqn"'), "algo", "expected one of"),
        (("steps = 1000", "steps = 1000\nseeds = [1, 1]"), "seeds", "distinct"),
        (("steps = 1000", "steps = 1000\nseeds = 10000000000"), "seeds", "at most 1000"),
        # These failed every cell only once the run had started (and needed --resume once fixed).
        *(
            (("steps = 1000", f"steps = 1000\nseeds = [0, {seed}]"), "seeds[1]", "between 0 and")
            for seed in (-1, 2**32, 99999999999)
        ),
        (("steps = 1000", 'steps = 1000\nllm = "bogus"'), "llm", "unknown language model"),
        (("steps = 1000", 'steps = 1000\nllm = "openai:"'), "llm", "unknown language model"),
        (("steps = 1000", 'steps = 1000\nreward = "nope.py"'), "reward", "existing .py"),
        (
            ("steps = 1000", 'steps = 1000\nsources = {pick_nut_m16 = "auto"}'),
            "sources.pick_nut_m16",
            "not one of the experiment's tasks",
        ),
        (("steps = 1000", "steps = 1000\nsources = 3"), "sources", "expected 'auto'"),
        (("steps = 1000", "steps = 1000\nbudget = 3"), "budget", "unknown field"),
        # The name is the run directory's: "../.." ran the experiment in the current directory.
        *(
            (("steps = 1000", f"steps = 1000\nname = {name!r}"), "name", "expected a plain")
            for name in ("../..", "..", ".", "", "  ", "a/b", "runs\\x")
        ),
        # These passed, and training ended at mkdir with an OSError or a ValueError.
        *(
            (("steps = 1000", f'steps = 1000\nname = "{name}"'), "name", "printable characters")
            for name in ("a\\u0000b", "a\\nb")
        ),
        (("steps = 1000", f"steps = 1000\nname = '{'x' * 300}'"), "name", "300 bytes (UTF-8)"),
        (("steps = 1000", f"steps = 1000\nname = '{'é' * 60}'"), "name", "120 bytes (UTF-8)"),
        (
            ("every = 500", 'every = 500\n[report]\nbaseline = "no_tranfer"'),
            "report.baseline",
            "unknown method 'no_tranfer'",
        ),
        (
            ("every = 500", "every = 500\n[report]\nfractions = [0.5, 0.2]"),
            "report.fractions",
            "increasing",
        ),
        (("every = 500", "every = 500\n[report]\nthreshold = 80"), "report.threshold", "(0, 1]"),
        # The report died of MemoryError after all the training.
        (
            ("every = 500", "every = 500\n[report]\ngrid_points = 100000000000"),
            "report.grid_points",
            "expected 2 to 100,000 points",
        ),
        # A percent was reported as "7222.00%"; nan was dropped.
        *(
            (
                ("every = 500", f"every = 500\n[report]\npaper_gain = {{pick_nut_m12 = {gain}}}"),
                "report.paper_gain.pick_nut_m12",
                problem,
            )
            for gain, problem in (
                ("72.22", "expected a fraction below 1 (0.7222 for 72.22%)"),
                ("1", "expected a fraction below 1 (0.7222 for 72.22%)"),
                ("nan", "expected a finite number"),
                ("-inf", "expected a finite number"),
            )
        ),
        (
            ("every = 500", 'every = 500\n[execution]\nexecutor = "slurm"'),
            "execution.executor",
            "expected one of",
        ),
        # Ray refused it only once the first cells started, after the run was recorded.
        (
            ("every = 500", 'every = 500\n[execution]\nexecutor = "ray"\nray_address = ""'),
            "execution.ray_address",
            "empty: leave it out",
        ),
        # As the algorithm (A2C by default) and the policy tables check them, named as written.
        *(
            (("every = 500", f"every = 500\n[hyperparams.pick_nut_m12]\n{line}"), where, problem)
            for line, where, problem in (
                ("learning_rate = 'fast'", "hyperparams.pick_nut_m12.learning_rate", "a number"),
                ("n_epochs = 4", "hyperparams.pick_nut_m12.n_epochs", "unknown field"),
                ("policy = {log_std = -3}", "hyperparams.pick_nut_m12.policy.log_std", "unknown"),
                ("gamma = 2", "hyperparams.pick_nut_m12.gamma", "(0, 1]"),
                ("num_envs = 8", "hyperparams.pick_nut_m12.num_envs", "at the top of the file"),
            )
        ),
        # A rollout of one sample: every cell failed once the run had started.
        (
            (
                "steps = 1000",
                'steps = 1000\nalgo = "ppo"\nnum_envs = 1\n[hyperparams.pick_nut_m12]\nn_steps = 1',
            ),
            "hyperparams.pick_nut_m12",
            "PPO needs 2 or more samples a rollout",
        ),
        (
            ("every = 500", "every = 500\n[hyperparams.pick_nut_m16]\ngamma = 0.9"),
            "hyperparams.pick_nut_m16",
            "not one of the experiment's tasks",
        ),
        (
            ("every = 500", "every = 500\n[hyperparams]\npick_nut_m12 = 3"),
            "hyperparams.pick_nut_m12",
            "expected a table",
        ),
        # As transfer.toml's are checked, named as this file has them.
        *(
            (("every = 500", f"every = 500\n{text}"), where, problem)
            for text, where, problem in (
                ("[transfer.pst]\nkeep = 0", "transfer.pst.keep", "expected at least 1"),
                ("[transfer.head]\nresidual = 1", "transfer.head.residual", "a boolean"),
                ("[transfer.fusion]\nwidth = [8]", "transfer.fusion.width", "unknown field"),
                ("[transfer.pts]\nkeep = 2", "transfer.pts", "unknown table"),
                ("[transfer]\npst = 2", "transfer.pst", "expected a table"),
                # The file's own k says how many auto retrieves: two places to say it.
                ("[transfer.sources]\nk = 2", "transfer.sources.k", "set k at the top"),
                # A TypeError and a misleading "set k" before the table's type was checked.
                ("[transfer]\nsources = 3", "transfer.sources", "expected a table"),
                ("[transfer]\nsources = 'kk'", "transfer.sources", "expected a table"),
            )
        ),
        (("steps = 1000", "steps = 1000\ntransfer = 2"), "transfer", "expected a table"),
    ],
)
def test_invalid_fields_are_named(tmp_path, edit, where, problem):
    path = write(tmp_path, MINIMAL.replace(*edit))
    with pytest.raises(ExperimentConfigError) as info:
        load_experiment(path)
    assert info.value.where == where
    assert problem in info.value.problem
    assert str(path) in str(info.value)


@pytest.mark.parametrize(
    ("body", "problem"),
    [
        ("def compute_reward(ctx)\n    return 0\n", "rejected by the sandbox: line 1: syntax"),
        ("def reward(ctx):\n    return 0\n", "defines no function compute_reward"),
        # Runs, but its result is caught only when called on the task's states.
        ("def compute_reward(ctx):\n    return 0\n", "must return (total, components)"),
        # Usually generated code: it is checked, and trains, only in the reward sandbox. It ran
        # as plain Python when the file was loaded, and in every cell.
        ("import os\nos.system('touch pwned')\n" + GOOD_REWARD, "import 'os' is not allowed"),
        (GOOD_REWARD.replace("np.zeros", "np.load('x.npy') + np.zeros"), "np.load"),
        ("\n", "the file is empty"),
        (b"\xff\xfe", "not UTF-8 text (byte 0)"),
    ],
)
def test_a_reward_file_training_would_refuse_is_refused_at_load(
    tmp_path, monkeypatch, body, problem
):
    (tmp_path / "r.py").write_bytes(body if isinstance(body, bytes) else body.encode())
    monkeypatch.chdir(tmp_path)  # where a file the code wrote would land
    text = MINIMAL.replace("steps = 1000", 'steps = 1000\nreward = {pick_nut_m12 = "r.py"}')
    path = write(tmp_path, text)
    with pytest.raises(ExperimentConfigError) as info:
        load_experiment(path)
    assert info.value.where == "reward.pick_nut_m12"
    assert str(tmp_path / "r.py") in info.value.problem and problem in info.value.problem
    assert str(path) in str(info.value)
    assert not (tmp_path / "pwned").exists()


def test_missing_required_field_and_bad_syntax(tmp_path):
    with pytest.raises(ExperimentConfigError, match="methods: missing"):
        load_experiment(write(tmp_path, MINIMAL.replace('methods = ["itn", "no_transfer"]', "")))
    with pytest.raises(ExperimentConfigError, match="TOML syntax"):
        load_experiment(write(tmp_path, "tasks = ["))
    with pytest.raises(ExperimentConfigError, match="no such experiment file"):
        load_experiment(tmp_path / "absent.toml")
    with pytest.raises(ExperimentConfigError, match="a directory, not a file"):
        load_experiment(tmp_path)


def test_cli_reports_a_bad_experiment_file_in_one_line(tmp_path):
    from typer.testing import CliRunner

    from itskill.cli import app

    path = write(tmp_path, MINIMAL.replace("steps = 1000", "steps = -5"))
    result = CliRunner().invoke(app, ["experiment", "run", str(path), "--out", str(tmp_path / "r")])
    assert result.exit_code == 2
    assert "steps: must be positive" in " ".join(result.output.split())
    assert "Traceback" not in result.output and not (tmp_path / "r").exists()
    report = CliRunner().invoke(app, ["report", str(tmp_path)])
    assert report.exit_code == 2 and "not an experiment run directory" in report.output


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        ("seeds = [-1]", "seeds[0]: expected a seed between 0 and 4294967295, got -1"),
        ('llm = "bogus"', "llm: unknown language model 'bogus'"),
        ('reward = "r.py"', "reward: " + "{r}: rejected by the sandbox: line 1: syntax error"),
    ],
)
def test_cli_refuses_what_every_cell_would_fail_on_before_making_the_run(tmp_path, edit, message):
    from typer.testing import CliRunner

    from itskill.cli import app

    (tmp_path / "r.py").write_text("def compute_reward(ctx)\n")
    # no_transfer uses no model: a mistyped llm was still fatal to every cell.
    text = MINIMAL.replace('["itn", "no_transfer"]', '["no_transfer"]')
    path = write(tmp_path, text.replace("steps = 1000", f"steps = 1000\n{edit}"))
    out = tmp_path / "r"
    result = CliRunner().invoke(app, ["experiment", "run", str(path), "--out", str(out)])
    assert result.exit_code == 2, result.output
    output = "".join(result.output.split())
    assert "error:" in output and str(path) in output
    assert "".join(message.format(r=tmp_path / "r.py").split()) in output
    assert "Traceback" not in result.output and not out.exists()


def test_cli_reports_an_unreadable_skill_space_and_records_no_run(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from itskill.cli import app

    home = tmp_path / "home"
    home.mkdir()
    (home / "skills.sqlite").write_bytes(b"garbage" * 1000)
    monkeypatch.setenv("ITSKILL_HOME", str(home))
    out = tmp_path / "r"
    args = ["experiment", "run", str(write(tmp_path, MINIMAL)), "--out", str(out)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    assert "skills.sqlite" in "".join(result.output.split()) and "Traceback" not in result.output
    # Nothing recorded: the same command runs once the skill space is fixed, without --resume.
    assert not (out / "config.json").exists()


@pytest.mark.parametrize(
    ("edit", "where", "problem"),
    [
        # Every cell trained, then failed with MemoryError evaluating.
        (("every = 500", "every = 500\nepisodes = 100000000000000"), "eval.episodes", "1,000,000"),
        (("every = 500", "every = 500\nepisodes = 1000001"), "eval.episodes", "at most"),
        # Every cell crashed allocating its environments.
        (("steps = 1000", "steps = 1000\nnum_envs = 100000000000"), "num_envs", "at most 1,024"),
        (("steps = 1000", "steps = 1000\nnum_envs = 1025"), "num_envs", "at most 1,024"),
        # Every cell trained on at an undecayed learning rate for ever (itskill.limits).
        (("steps = 1000", "steps = 1000000000000"), "steps", "at most 1,000,000,000"),
        # A repeated fraction passed the sorted check: the same column twice in the report.
        (
            ("every = 500", "every = 500\n[report]\nfractions = [0.5, 0.5]"),
            "report.fractions",
            "strictly increasing",
        ),
        (
            ("every = 500", "every = 500\n[report]\nfractions = [0.2, 1, 1]"),
            "report.fractions",
            "strictly increasing",
        ),
        # An integer past a float's range was an OverflowError traceback.
        (
            ("every = 500", f"every = 500\n[report]\nthreshold = {'9' * 400}"),
            "report.threshold",
            "expected a finite number",
        ),
    ],
)
def test_counts_past_their_bounds_and_repeated_fractions_are_named(tmp_path, edit, where, problem):
    path = write(tmp_path, MINIMAL.replace(*edit))
    with pytest.raises(ExperimentConfigError) as info:
        load_experiment(path)
    assert (info.value.path, info.value.where) == (str(path), where)
    assert problem in info.value.problem


def test_the_bounds_themselves_load(tmp_path):
    text = MINIMAL.replace("steps = 1000", "steps = 1000\nnum_envs = 1024").replace(
        "every = 500", "every = 500\nepisodes = 1_000_000"
    )
    config = load_experiment(write(tmp_path, text))
    assert (config.num_envs, config.eval.episodes) == (1024, 1_000_000)


@pytest.mark.parametrize(
    ("edit", "where", "bound"),
    [
        # No upper bound: thousands of frozen sources in every cell, processes until the machine
        # gave out.
        (("steps = 1000", "steps = 1000\nk = {}"), "k", 32),
        (("every = 500", "every = 500\n[execution]\nworkers = {}"), "execution.workers", 1024),
    ],
)
def test_source_and_worker_counts_have_an_upper_bound(tmp_path, edit, where, bound):
    old, new = edit
    load_experiment(write(tmp_path, MINIMAL.replace(old, new.format(bound))))  # the bound loads
    path = write(tmp_path, MINIMAL.replace(old, new.format(bound + 1)))
    with pytest.raises(ExperimentConfigError) as info:
        load_experiment(path)
    assert (info.value.path, info.value.where) == (str(path), where)
    assert info.value.problem == f"must be at most {bound:,}, got {bound + 1:,}"
