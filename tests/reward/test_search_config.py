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
        ("[search]\nsamples = 'ten'\n", "search.samples: expected int"),
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
