"""Search settings: packaged defaults, a user's file, overrides, clear errors."""

from __future__ import annotations

from pathlib import Path

import pytest

from itskill.reward.config import (
    RewardSearchConfig,
    SearchConfigError,
    default_path,
    load_search_config,
)
from itskill.reward.sandbox import SandboxConfig


def test_defaults_come_from_the_packaged_file() -> None:
    config = RewardSearchConfig()
    assert (config.iterations, config.samples) == (5, 10)  # the paper's loop
    assert config == load_search_config()
    assert isinstance(config.sandbox, SandboxConfig)
    assert "steps = " in default_path().read_text()


def test_overrides_apply_and_none_means_not_given() -> None:
    config = load_search_config(
        overrides={
            "iterations": 2,
            "samples": None,
            "seeds": [3, 4],
            "sandbox": {"call_timeout_s": 1},
        }
    )
    assert config.iterations == 2
    assert config.samples == RewardSearchConfig().samples
    assert config.seeds == (3, 4)
    assert config.sandbox.call_timeout_s == 1.0


def test_eval_every_spreads_the_evaluations() -> None:
    assert load_search_config(overrides={"steps": 1000, "evaluations": 4}).eval_every == 250
    assert load_search_config(overrides={"steps": 1001, "evaluations": 4}).eval_every == 251


def test_user_file(tmp_path: Path) -> None:
    path = tmp_path / "search.toml"
    path.write_text("[search]\nsamples = 3\n[sandbox]\nmemory_limit_mb = 2048\n")
    config = load_search_config(path)
    assert config.samples == 3
    assert config.sandbox.memory_limit_mb == 2048
    # What a user's file leaves out of [sandbox] keeps the packaged limits: it ran generated
    # code with no CPU or memory limit at all.
    packaged = load_search_config().sandbox
    assert config.sandbox.cpu_limit_s == packaged.cpu_limit_s is not None
    path.write_text("[search]\nsamples = 3\n")
    assert load_search_config(path).sandbox == packaged


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[search]\nsampels = 3\n", "search.sampels: unknown field"),
        ("[search]\nsamples = 'ten'\n", "search.samples: expected an integer"),
        ("[search]\nsamples = 0\n", "samples: expected a positive number"),
        ("[search]\nalgo = 'sac'\n", "algo: expected one of"),
        ("[search]\nseeds = [1, 1]\n", "seeds: expected distinct seeds"),
        # These planned and generated, then every candidate failed to train.
        ("[search]\nseeds = [0, -1]\n", r"seeds\[1\]: expected a seed between 0 and 4294967295"),
        ("[search]\nseeds = [99999999999]\n", r"seeds\[0\]: expected a seed between 0 and"),
        # The final retraining trains on the seeds after the largest: the search's last step.
        ("[search]\nseeds = [4294967295]\n", "seeds: the retraining after the search takes"),
        ("[search]\nselect_top = -1\n", "select_top: expected 0 or more"),
        ("[search]\nselect_seeds = 0\n", "select_seeds: expected a positive number"),
        ("[sandbox]\ntimeout = 1\n", "sandbox.timeout: unknown field"),
        # These ran the generated code with no timeout and no memory limit.
        (
            "[sandbox]\ncall_timeout_s = -1\n",
            "sandbox.call_timeout_s: expected a positive number, got -1.0",
        ),
        ("[sandbox]\ncpu_limit_s = 0\n", "sandbox.cpu_limit_s: expected a positive number"),
        (
            "[sandbox]\nmemory_limit_mb = -5\n",
            "sandbox.memory_limit_mb: expected a positive number",
        ),
        (
            "[sandbox]\nmax_source_chars = 0\n",
            "sandbox.max_source_chars: expected a positive number",
        ),
        ("search = 5\n", "search: expected a table, got int"),
        ("[serach]\n", "serach: unknown table"),
        ("[search\n", "TOML syntax"),
    ],
)
def test_file_errors_name_the_file_and_field(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SearchConfigError, match=message) as info:
        load_search_config(path)
    assert str(path) in str(info.value)


def test_override_errors() -> None:
    with pytest.raises(SearchConfigError, match="overrides: executor: expected one of"):
        load_search_config(overrides={"executor": "slurm"})
    with pytest.raises(SearchConfigError, match=r"overrides: seeds\[0\]: expected a seed between"):
        load_search_config(overrides={"seeds": [-1]})
    with pytest.raises(SearchConfigError, match="overrides: iteratoins: unknown field"):
        load_search_config(overrides={"iteratoins": 2})
    with pytest.raises(SearchConfigError, match=r"overrides: sandbox\.call_timeout_s: expected a"):
        load_search_config(overrides={"sandbox": {"call_timeout_s": 0}})


def test_a_run_made_on_a_cluster_resumes_here_without_its_address(tmp_path) -> None:
    # The stored address went with `--executor local` and was refused, so a paid search could
    # not be finished on this machine once the cluster was gone.
    import json

    from itskill.reward.search import CONFIG_FILE, RUN_KIND, config_from_run

    cluster = load_search_config(overrides={"executor": "ray", "ray_address": "10.0.0.5:6379"})
    run = tmp_path / "run"
    run.mkdir()
    stored = {"kind": RUN_KIND, "target": "pick_nut_m12", "llm": "offline", "compare_expert": True}
    (run / CONFIG_FILE).write_text(json.dumps({**stored, "config": cluster.to_dict()}))
    here = config_from_run(run, {"executor": "local"})
    assert (here.executor, here.ray_address) == ("local", None)
    again = config_from_run(run, {})
    assert (again.executor, again.ray_address) == ("ray", "10.0.0.5:6379")


def test_a_stored_setting_that_no_longer_validates_names_the_run_not_a_flag(tmp_path) -> None:
    # It was reported as a bad value of --iterations, a flag the user had not typed.
    import json

    from typer.testing import CliRunner

    from itskill.cli import app
    from itskill.reward.search import CONFIG_FILE, RUN_KIND, config_from_run

    config = load_search_config().to_dict() | {"iterations": 500}
    run = tmp_path / "run"
    run.mkdir()
    stored = {"kind": RUN_KIND, "target": "pick_nut_m12", "llm": "offline", "compare_expert": True}
    (run / CONFIG_FILE).write_text(json.dumps({**stored, "config": config}))
    result = CliRunner().invoke(app, ["reward", "generate", "--resume", str(run)])
    assert result.exit_code == 2
    message = " ".join(result.output.split())
    assert f"{run / CONFIG_FILE}: iterations: expected at most 100, got 500" in message
    assert "--iterations" not in message
    # A setting a resume may change is mended by its flag.
    config = load_search_config().to_dict() | {"workers": 1025}
    (run / CONFIG_FILE).write_text(json.dumps({**stored, "config": config}))
    with pytest.raises(SearchConfigError, match=r"config\.json: workers"):
        config_from_run(run, {})
    assert config_from_run(run, {"workers": 2}).workers == 2


@pytest.mark.parametrize(
    ("text", "where", "problem"),
    [
        # Not finite: an OverflowError traceback from the timer, in the probe's process.
        ("[sandbox]\ncall_timeout_s = inf\n", "sandbox.call_timeout_s", "expected a finite"),
        ("[sandbox]\ncall_timeout_s = nan\n", "sandbox.call_timeout_s", "expected a finite"),
        ("[sandbox]\ncall_timeout_s = 1e999\n", "sandbox.call_timeout_s", "expected a finite"),
        ("[search]\ncandidate_timeout_s = inf\n", "search.candidate_timeout_s", "finite"),
        ("[search]\ntemperature = nan\n", "search.temperature", "expected a finite number"),
        # Finite, but no limit, and past what the timers and rlimits take.
        ("[sandbox]\ncall_timeout_s = 3601\n", "sandbox.call_timeout_s", "at most 3,600 s"),
        ("[sandbox]\ncpu_limit_s = 100000000000000\n", "sandbox.cpu_limit_s", "at most 259,200"),
        (
            "[sandbox]\nmemory_limit_mb = 100000000000000\n",
            "sandbox.memory_limit_mb",
            "at most 1,048,576 MB",
        ),
        ("[search]\ncandidate_timeout_s = 1e12\n", "search.candidate_timeout_s", "at most"),
        # Counts: MemoryError after every candidate's training, or a crash at allocation.
        ("[search]\neval_episodes = 100000000000000\n", "search.eval_episodes", "1,000,000"),
        ("[search]\nnum_envs = 100000000000\n", "search.num_envs", "at most 1,024"),
        ("[search]\ncorrelation_envs = 1025\n", "search.correlation_envs", "at most 1,024"),
        ("[search]\nprobe_envs = 5000\n", "search.probe_envs", "at most 1,024"),
        # Range errors named the field without its table ("iterations:").
        ("[search]\niterations = 0\n", "search.iterations", "expected a positive number"),
        ("[search]\nseeds = [0, -1]\n", "search.seeds[1]", "expected a seed between"),
        ("[search]\nselect_top = -1\n", "search.select_top", "expected 0 or more"),
    ],
)
def test_file_errors_name_the_field_as_the_file_has_it(
    tmp_path: Path, text: str, where: str, problem: str
) -> None:
    path = tmp_path / "search.toml"
    path.write_text(text)
    with pytest.raises(SearchConfigError) as info:
        load_search_config(path)
    assert (info.value.path, info.value.where) == (str(path), where)
    assert problem in info.value.problem


def test_the_limits_themselves_load(tmp_path: Path) -> None:
    path = tmp_path / "search.toml"
    path.write_text(
        "[search]\nnum_envs = 1024\neval_episodes = 1_000_000\ncandidate_timeout_s = 259_200\n"
        "[sandbox]\ncall_timeout_s = 3600\ncpu_limit_s = 259_200\nmemory_limit_mb = 1_048_576\n"
    )
    config = load_search_config(path)
    assert (config.num_envs, config.sandbox.memory_limit_mb) == (1024, 1_048_576)


@pytest.mark.parametrize(
    ("overrides", "where"),
    [
        ({"eval_episodes": 10**14}, "eval_episodes"),
        ({"sandbox": {"memory_limit_mb": 10**14}}, "sandbox.memory_limit_mb"),
        # A SandboxConfig given whole skips the file's type checks, not the dataclass's.
        ({"sandbox": SandboxConfig(call_timeout_s=float("inf"))}, "sandbox.call_timeout_s"),
        ({"sandbox": SandboxConfig(call_timeout_s=float("nan"))}, "sandbox.call_timeout_s"),
    ],
)
def test_overrides_take_the_same_bounds(overrides: dict, where: str) -> None:
    with pytest.raises(SearchConfigError) as info:
        load_search_config(overrides=overrides)
    assert (info.value.path, info.value.where) == ("overrides", where)


def test_cli_reports_an_infinite_timeout_in_one_line(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from itskill.cli import app

    path = tmp_path / "search.toml"
    path.write_text("[sandbox]\ncall_timeout_s = inf\n")
    out = tmp_path / "run"
    args = ["reward", "generate", "pick_nut_m12", "--config", str(path), "--out", str(out)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    message = f"error: {path}: sandbox.call_timeout_s: expected a finite number, got inf"
    assert "".join(message.split()) in "".join(result.output.split())
    assert "Traceback" not in result.output and not out.exists()


@pytest.mark.parametrize(
    ("key", "bound"),
    [
        # No upper bound: thousands of paid model calls, trainings or processes, or days of one.
        ("iterations", 100),
        ("samples", 100),
        ("select_top", 100),
        ("steps", 1_000_000_000),
        ("evaluations", 1000),
        ("probe_steps", 1000),
        ("select_seeds", 1000),
        ("final_seeds", 1000),
        ("workers", 1024),
        ("max_regenerations", 10),
    ],
)
def test_counts_have_an_upper_bound(tmp_path: Path, key: str, bound: int) -> None:
    path = tmp_path / "search.toml"
    path.write_text(f"[search]\n{key} = {bound}\n")
    assert getattr(load_search_config(path), key) == bound  # the bound itself loads
    path.write_text(f"[search]\n{key} = {bound + 1}\n")
    with pytest.raises(SearchConfigError) as info:
        load_search_config(path)
    assert (info.value.path, info.value.where) == (str(path), f"search.{key}")
    assert info.value.problem == f"expected at most {bound:,}, got {bound + 1:,}"
    with pytest.raises(SearchConfigError) as info:
        load_search_config(overrides={key: bound + 1})
    assert (info.value.path, info.value.where) == ("overrides", key)
