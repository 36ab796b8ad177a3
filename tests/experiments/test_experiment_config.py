"""Experiment files: the shipped ones load; every mistake names the file and the field."""

from __future__ import annotations

from pathlib import Path

import pytest

from itskill.experiments.config import (
    ExperimentConfig,
    ExperimentConfigError,
    load_experiment,
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
    assert ExperimentConfig.from_dict(config.to_dict()) == config


def test_per_task_reward_files_resolve_relative_to_the_experiment_file(tmp_path):
    (tmp_path / "r.py").write_text("def compute_reward(ctx):\n    pass\n")
    text = MINIMAL.replace("steps = 1000", 'steps = 1000\nreward = {pick_nut_m12 = "r.py"}')
    config = load_experiment(write(tmp_path, text))
    assert config.reward["pick_nut_m12"] == str((tmp_path / "r.py").resolve())


@pytest.mark.parametrize(
    ("edit", "where", "problem"),
    [
        (('tasks = ["pick_nut_m12"]', 'tasks = ["pick_nut_m99"]'), "tasks[0]", "unknown task"),
        (('"itn"', '"itm"'), "methods[0]", "unknown method 'itm'"),
        (("steps = 1000", "steps = 0"), "steps", "must be positive"),
        (("steps = 1000", 'steps = "many"'), "steps", "expected int"),
        (("every = 500", "every = 5000"), "eval.every", "more than steps"),
        (("steps = 1000", 'steps = 1000\nalgo = "dqn"'), "algo", "expected one of"),
        (("steps = 1000", "steps = 1000\nseeds = [1, 1]"), "seeds", "distinct"),
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
        (
            ("every = 500", 'every = 500\n[report]\nbaseline = "pst"'),
            "report.baseline",
            "not one of the methods",
        ),
        (
            ("every = 500", "every = 500\n[report]\nfractions = [0.5, 0.2]"),
            "report.fractions",
            "increasing",
        ),
        (("every = 500", "every = 500\n[report]\nthreshold = 80"), "report.threshold", "(0, 1]"),
        (
            ("every = 500", 'every = 500\n[execution]\nexecutor = "slurm"'),
            "execution.executor",
            "expected one of",
        ),
    ],
)
def test_invalid_fields_are_named(tmp_path, edit, where, problem):
    path = write(tmp_path, MINIMAL.replace(*edit))
    with pytest.raises(ExperimentConfigError) as info:
        load_experiment(path)
    assert info.value.where == where
    assert problem in info.value.problem
    assert str(path) in str(info.value)


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
