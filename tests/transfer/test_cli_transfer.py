"""`itskill transfer`: analyze prints the matrix, train runs a method, errors exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from itskill.cli import app

runner = CliRunner()


def analyze_json(sources: str, llm: str) -> dict:
    """``transfer analyze pickplace_nut_m12 --sources SOURCES --llm LLM --json``, read."""
    args = ["transfer", "analyze", "pickplace_nut_m12", "--sources", sources, "--llm", llm]
    res = runner.invoke(app, [*args, "--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.output)


def test_analyze_json_and_table(home: Path) -> None:
    data = analyze_json("pick_nut_m12,place_nut_m12", "offline")
    assert data["sources"] == ["pick_nut_m12", "place_nut_m12"]
    np.testing.assert_allclose(np.sum(data["matrix"], axis=1), 1.0)
    table = runner.invoke(app, ["transfer", "analyze", "pickplace_nut_m12", "-k", "2"])
    assert table.exit_code == 0, table.output
    assert (
        "3 approach" in table.output
        and "4 place" in table.output
        and "place_nut_m12" in table.output
    )


def test_analyze_of_one_source_shows_the_prior_training_uses(home: Path, monkeypatch) -> None:
    # It asked the model, whose fair 0 for stages a pick cannot do was refused after its retries
    # (and needed a key), while training used an all-ones matrix without asking.
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    monkeypatch.delenv("OPENAI_BASE_URL", raising=False)
    data = analyze_json("pick_nut_m12", "openai:gpt-4o")
    assert data["matrix"] == [[1.0]] * 5 and data["client"] == "none (one source)"


def test_train_then_trace(home: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    args = ["transfer", "train", "pickplace_nut_m12", "--method", "pst",
            "--sources", "place_nut_m12,pick_nut_m12", "--algo", "a2c",
            "--steps", "16", "--num-envs", "2", "--out", str(out)]  # fmt: skip
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    assert "16 env-steps" in res.output
    assert [s["name"] for s in json.loads((out / "transfer.json").read_text())["sources"]] == [
        "place_nut_m12"
    ]
    trace = runner.invoke(app, ["transfer", "trace", str(out)])
    assert trace.exit_code == 0 and "W place_nut_m12" in trace.output


def test_errors_are_one_line_and_exit_2(home: Path, tmp_path: Path) -> None:
    bad_source = runner.invoke(
        app, ["transfer", "analyze", "pickplace_nut_m12", "--sources", "pick_nut_m99"]
    )
    assert bad_source.exit_code == 2 and "unknown skill 'pick_nut_m99'" in bad_source.output
    bad_method = runner.invoke(app, ["transfer", "train", "pickplace_nut_m12", "--method", "xyz"])
    assert bad_method.exit_code == 2 and "itn, nia, dfs, pst, no_transfer" in bad_method.output
    bad_task = runner.invoke(app, ["transfer", "analyze", "nothing"])
    assert bad_task.exit_code == 2 and "unknown task" in bad_task.output
    not_transfer = tmp_path / "plain"
    runner.invoke(app, ["train", "reach_nut_m12", "--steps", "16", "--num-envs", "2", "--algo",
                        "a2c", "--out", str(not_transfer)])  # fmt: skip
    trace = runner.invoke(app, ["transfer", "trace", str(not_transfer)])
    assert trace.exit_code == 2 and "no contribution weights" in trace.output


def test_analyze_refuses_a_bad_llm_before_it_creates_a_skill_space(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "fresh"))
    result = runner.invoke(app, ["transfer", "analyze", "pickplace_nut_m12", "--llm", "x"])
    assert result.exit_code == 2 and "unknown language model 'x'" in result.output
    assert not (tmp_path / "fresh").exists()


def test_settings_that_cannot_train_are_one_line_errors(home: Path, tmp_path: Path) -> None:
    train = ["transfer", "train", "pickplace_nut_m12", "--steps", "16", "--num-envs", "2"]
    bad_llm = runner.invoke(app, [*train, "--llm", "gpt-4o", "--out", str(tmp_path / "a")])
    assert bad_llm.exit_code == 2
    assert "unknown language model 'gpt-4o'" in " ".join(bad_llm.output.split())
    # PST over every source it was given would be ITN under another name.
    pst = runner.invoke(app, [*train, "--method", "pst", "--sources", "pick_nut_m12",
                              "--out", str(tmp_path / "b")])  # fmt: skip
    assert pst.exit_code == 2 and "that is ITN itself" in " ".join(pst.output.split())
    assert "smaller" not in pst.output  # it keeps 1, the least there is
    for result in (bad_llm, pst):
        assert "Traceback" not in result.output


def test_a_broken_reward_file_is_one_line_and_writes_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The same check as `itskill train`: the reward file is probed before the run is recorded.
    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    reward = tmp_path / "my_reward.py"
    reward.write_text("def compute_reward(ctx):\n    return 'high'\n")
    out = tmp_path / "run"
    res = runner.invoke(app, ["transfer", "train", "pick_nut_m12", "--method", "no_transfer",
                              "--reward", str(reward), "--out", str(out)])  # fmt: skip
    assert res.exit_code == 2, res.output
    problem = f"{reward}: compute_reward must return (total, components); got str"
    assert "".join(problem.split()) in "".join(res.output.split())  # rich wraps long lines
    assert "Traceback" not in res.output and not out.exists()


def test_skill_names_with_brackets_are_printed_as_typed(home: Path, tmp_path: Path) -> None:
    # Rich read the name as markup: a MarkupError traceback from each command, the training's
    # after its transfer.json was written.
    from dataclasses import replace

    from itskill.skills import open_skill_space

    name = "pick[/v2]"
    with open_skill_space() as space:
        space.add(replace(space.get("pick_nut_m12"), name=name, id=None, created=None))
    try:
        sources = f"{name},reach_nut_m12"
        analyze = runner.invoke(app, ["transfer", "analyze", "pick_nut_m12", "--sources", sources])
        assert analyze.exit_code == 0, analyze.output
        assert name in analyze.output
        out = tmp_path / "run"
        train = runner.invoke(app, ["transfer", "train", "pick_nut_m12", "--sources", sources,
                                    "--algo", "a2c", "--steps", "16", "--num-envs", "2",
                                    "--out", str(out)])  # fmt: skip
        assert train.exit_code == 0, train.output
        assert f"itn on pick_nut_m12: sources {name}, reach_nut_m12" in train.output
        trace = runner.invoke(app, ["transfer", "trace", str(out)])
        assert trace.exit_code == 0, trace.output
        assert f"W {name}" in trace.output
    finally:
        with open_skill_space() as space:
            space.remove(name)


def test_a_damaged_transfer_record_is_one_line_naming_the_file(home: Path, tmp_path: Path) -> None:
    # Each ended in a traceback: a list has no .get, a null config no keys, and bytes that are not
    # UTF-8 a UnicodeDecodeError.
    out = tmp_path / "run"
    train = ["transfer", "train", "pick_nut_m12", "--sources", "pick_nut_m12,reach_nut_m12",
             "--algo", "a2c", "--steps", "16", "--num-envs", "2", "--out", str(out)]  # fmt: skip
    assert runner.invoke(app, train).exit_code == 0
    record = out / "transfer.json"
    null_config = json.dumps({**json.loads(record.read_text()), "config": None}).encode()
    damages = [
        (b"[]", "expected a JSON object, got []"),
        (null_config, "config: expected an object, got null"),
        (b"\xff\xfe{", "not UTF-8 text"),
    ]
    for damage, problem in damages:
        record.write_bytes(damage)
        for args in (train, ["transfer", "trace", str(out)]):
            result = runner.invoke(app, args)
            assert result.exit_code == 2, result.output
            assert f"error: {record}: {problem}" in result.output
            assert "Traceback" not in result.output


@pytest.fixture
def no_api_key(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in ("OPENAI_API_KEY", "OPENAI_BASE_URL", "ITSKILL_LLM_MODEL"):
        monkeypatch.delenv(name, raising=False)


@pytest.mark.parametrize(
    ("method", "sources"),
    [("no_transfer", "auto"), ("dfs", "auto"), ("itn", "pick_nut_m12"), ("pst", "auto")],
)
def test_a_run_that_asks_no_model_needs_no_api_key(
    home: Path, tmp_path: Path, no_api_key: None, method: str, sources: str
) -> None:
    # The analyzer's client was built for every method: "no API key" though none was needed.
    # Over one source (ITN given one, PST keeping one) the analyzer is not asked either.
    res = runner.invoke(app, ["transfer", "train", "pick_nut_m12", "--method", method,
                              "--sources", sources, "--llm", "openai:gpt-4o", "--algo", "a2c",
                              "--steps", "16", "--num-envs", "2",
                              "--out", str(tmp_path / "run")])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "16 env-steps" in res.output


def test_a_resumed_run_asks_no_model_and_a_new_one_does(
    home: Path, tmp_path: Path, no_api_key: None
) -> None:
    out = tmp_path / "run"
    train = ["transfer", "train", "pick_nut_m12", "--sources", "pick_nut_m12,reach_nut_m12",
             "--algo", "a2c", "--num-envs", "2", "--out", str(out)]  # fmt: skip
    assert runner.invoke(app, [*train, "--steps", "16", "--llm", "offline"]).exit_code == 0
    # Its transfer.json holds the matrix: the model is not asked again.
    resumed = runner.invoke(app, [*train, "--steps", "32", "--llm", "openai:gpt-4o"])
    assert resumed.exit_code == 0, resumed.output
    assert "resumed from 16" in " ".join(resumed.output.split())
    new = runner.invoke(app, [*train[:-1], str(tmp_path / "new"), "--steps", "16",
                              "--llm", "openai:gpt-4o"])  # fmt: skip
    assert new.exit_code == 2 and "no API key for openai:gpt-4o" in " ".join(new.output.split())


@pytest.mark.parametrize("command", ["train", "analyze"])
def test_k_with_named_sources_is_refused(home: Path, tmp_path: Path, command: str) -> None:
    # -k was silently ignored: the named skills were the sources, however many -k asked for.
    args = ["transfer", command, "pick_nut_m12", "--sources", "pick_nut_m12,reach_nut_m12",
            "-k", "1"]  # fmt: skip
    if command == "train":
        args += ["--out", str(tmp_path / "run")]
    res = runner.invoke(app, args)
    assert res.exit_code == 2, res.output
    assert "-k sets how many skills --sources auto retrieves" in " ".join(res.output.split())
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("extra", [["--sources", "pick_nut_m12"], ["-k", "2"]])
def test_sources_for_a_method_that_uses_none_are_refused(
    home: Path, tmp_path: Path, extra: list[str]
) -> None:
    # Silently ignored: the run trained from scratch, whatever skills were named.
    out = tmp_path / "run"
    res = runner.invoke(app, ["transfer", "train", "pick_nut_m12", "--method", "no_transfer",
                              *extra, "--out", str(out)])  # fmt: skip
    assert res.exit_code == 2, res.output
    assert "no_transfer uses no source skills" in " ".join(res.output.split())
    assert not out.exists()
