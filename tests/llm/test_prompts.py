"""Prompt templates: the parts each prompt must carry, and validation of edited templates."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from itskill.llm import prompts
from itskill.llm.prompts import (
    PromptError,
    analyzer_messages,
    check_template,
    execution_error_feedback,
    planner_messages,
    policy_feedback,
    reward_messages,
    task_description,
)
from itskill.sim.context import CONTEXT_DOC
from itskill.tasks import get_task

CATALOGUE = [
    {
        "task": "pick_nut_m12",
        "family": "nutbolt",
        "command": "Pick up the M12 nut",
        "actions": ["approach", "grasp", "lift"],
        "steps": ["approach", "grasp", "lift"],
        "objects": ["nut_m12"],
        "fixtures": ["bolt_m12"],
    }
]


def test_planner_prompt_carries_command_and_catalogue() -> None:
    system, user = planner_messages("  Pick up the nut ", CATALOGUE)
    assert system["role"] == "system" and "First," in system["content"]
    assert "<command>\nPick up the nut\n</command>" in user["content"]
    catalogue = user["content"].split("<catalogue>\n")[1].split("\n</catalogue>")[0]
    assert json.loads(catalogue) == CATALOGUE
    with pytest.raises(PromptError, match="empty"):
        planner_messages(" ", CATALOGUE)
    with pytest.raises(PromptError, match="catalogue entry 0 lacks fixtures"):
        planner_messages("x", [{k: v for k, v in CATALOGUE[0].items() if k != "fixtures"}])


def test_a_catalogue_without_steps_shows_its_actions_as_the_steps() -> None:
    # A catalogue built before tasks listed their steps apart from their stages was refused.
    entry = {k: v for k, v in CATALOGUE[0].items() if k != "steps"}
    _, user = planner_messages("lift it", [{**entry, "actions": ["approach", "lift"]}])
    catalogue = user["content"].split("<catalogue>\n")[1].split("\n</catalogue>")[0]
    assert json.loads(catalogue)[0]["steps"] == ["approach", "lift"]


def test_reward_prompt_has_its_four_parts() -> None:
    spec = get_task("pickplace_nut_m12")
    description = task_description(spec.command, ["First, a.", "Second, b."], spec)
    system, user = reward_messages(description)
    assert "compute_reward(ctx)" in system["content"] and "```python" in system["content"]
    body = user["content"]
    assert CONTEXT_DOC.strip() in body  # verbatim
    assert "| obj0_pos |" in body  # the observation layout table
    assert f"<task_description>\n{description}\n</task_description>" in body
    assert "temperature variable" in body and "import numpy as np" in body
    assert body.index("## Environment") < body.index("## Task description")
    assert body.index("## Task description") < body.index("## Constraints")


def test_task_description_lists_stages_objects_and_conditions() -> None:
    spec = get_task("pickplace2_nuts")
    text = task_description(spec.command, ["First, x."], spec)
    assert "stage 0: approach | object 0 | done when near(0, 0.02)" in text
    assert "stage 4: approach | object 1 |" in text
    assert "object 1: nut_m16" in text and "for fixture 1" in text
    assert "Success: engaged(0) and engaged(1)" in text
    assert "near(i, dist=0.02): The grip point is within dist metres" in text


def test_policy_feedback_reports_every_component() -> None:
    stats = {"0.approach/reach": {"max": 0.9, "mean": 0.5, "min": 0.01}}
    text = policy_feedback("def compute_reward(ctx):\n    pass", 0.25, stats)
    assert "Maximum success rate: 0.250" in text
    assert "0.approach/reach | 0.9 | 0.5 | 0.01" in text
    assert "```python\ndef compute_reward(ctx):" in text and "temperature" in text
    with pytest.raises(PromptError, match="lacks min"):
        policy_feedback("x", 0.1, {"a": {"max": 1, "mean": 0}})
    with pytest.raises(PromptError, match="success_rate"):
        policy_feedback("x", 1.5, {})
    with pytest.raises(PromptError, match="non-finite"):
        policy_feedback("x", 0.1, {"a": {"max": float("nan"), "mean": 0, "min": 0}})


def test_execution_error_feedback_has_code_and_error() -> None:
    text = execution_error_feedback("x = 1", "line 1: import 'os' is not allowed")
    assert "<execution_error>\nline 1: import 'os' is not allowed\n</execution_error>" in text
    assert "```python\nx = 1\n```" in text


def test_the_same_failure_in_two_iterations_makes_two_requests() -> None:
    # Without the iteration, a search that trained nothing twice on the same failure sent the
    # same request again, and the reply cache answered it with the replies it already held.
    first = execution_error_feedback("x = 1", "boom", iteration=2)
    second = execution_error_feedback("x = 1", "boom", iteration=3)
    assert first != second and "iteration 3 of the search" in second


def test_analyzer_prompt_and_its_checks() -> None:
    target = {"id": "t", "description": "pick and place", "actions": ["approach", "grasp"]}
    sources = [{"id": "s", "description": "pick", "actions": ["grasp"], "extra": 1}]
    system, user = analyzer_messages(target, sources)
    assert "matrix" in system["content"]
    assert json.loads(user["content"].split("<target>\n")[1].split("\n</target>")[0]) == target
    with pytest.raises(PromptError, match="sources\\[0\\] lacks actions"):
        analyzer_messages(target, [{"id": "s", "description": "d"}])
    with pytest.raises(PromptError, match="at least one source"):
        analyzer_messages(target, [])


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("Catalogue: {catalogue}", "missing field(s) {command}"),
        ("{catalogue} {command} {extra}", "unknown field {extra}"),
        ("{catalogue} {command} {{json}} {0.__class__}", "not a plain name"),
        ("{catalogue} {command} {", "literal braces"),
        # Accepted, then a ValueError with a traceback while the prompt was built.
        ("{catalogue} {command:d}", "cannot be filled with text: Unknown format code 'd'"),
        ("{catalogue} {command:{catalogue}}", "cannot be filled with text"),
    ],
)
def test_a_broken_template_is_named(text: str, problem: str) -> None:
    with pytest.raises(PromptError) as err:
        check_template("planner_user", text)
    assert "prompt template 'planner_user'" in str(err.value) and problem in str(err.value)


def test_templates_can_be_overridden_by_a_user_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "planner_user.txt").write_text(
        "MY PROMPT <command>\n{command}\n</command> {catalogue}"
    )
    monkeypatch.setenv(prompts.PROMPTS_DIR_ENV, str(tmp_path))
    _, user = planner_messages("lift it", CATALOGUE)
    assert user["content"].startswith("MY PROMPT")
    (tmp_path / "planner_system.txt").write_text("Reply in {format}")
    with pytest.raises(PromptError, match=r"'planner_system'.*unknown field \{format\}"):
        planner_messages("lift it", CATALOGUE)


def test_shipped_templates_are_all_valid() -> None:
    for name in prompts.TEMPLATE_FIELDS:
        path = Path(str(prompts._template_path(name)))
        check_template(name, path.read_text(encoding="utf-8"), path)


# ----------------------------------------------------------------------- user templates, checked
def _prompts_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, **files: bytes) -> Path:
    """``tmp_path/prompts`` holding ``files`` (name -> content) as ``$ITSKILL_PROMPTS_DIR``."""
    directory = tmp_path / "prompts"
    directory.mkdir()
    for name, content in files.items():
        (directory / name).write_bytes(content)
    monkeypatch.setenv(prompts.PROMPTS_DIR_ENV, str(directory))
    return directory


def test_a_template_that_is_not_utf8_is_named_not_a_traceback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # UnicodeDecodeError escaped: only OSError was caught.
    directory = _prompts_dir(tmp_path, monkeypatch, **{"planner_system.txt": b"\xff\xfe bad"})
    with pytest.raises(PromptError, match="not UTF-8 text") as err:
        planner_messages("lift it", CATALOGUE)
    assert str(directory / "planner_system.txt") in str(err.value)


@pytest.mark.parametrize("name", ["planner_system", "reward_system", "reward_constraints"])
@pytest.mark.parametrize("text", ["", "  \n\t\n"])
def test_a_blank_template_is_refused(name: str, text: str) -> None:
    # A template without fields passed the field check empty: an empty system prompt was sent.
    with pytest.raises(PromptError, match=rf"'{name}'.*is blank"):
        check_template(name, text, "x.txt")


def test_a_blank_user_template_is_refused_before_any_prompt_is_built(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _prompts_dir(tmp_path, monkeypatch, **{"reward_system.txt": b" \n"})
    with pytest.raises(PromptError, match=r"'reward_system'.*is blank"):
        reward_messages("a task")


def test_a_prompts_dir_that_is_not_a_directory_is_an_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Ignored without a word, while ITSKILL_TASKS_DIR refused a bad path.
    missing = tmp_path / "nonexistent"
    monkeypatch.setenv(prompts.PROMPTS_DIR_ENV, str(missing))
    with pytest.raises(
        PromptError, match=re.escape(f"{missing}: ITSKILL_PROMPTS_DIR: no such directory")
    ):
        planner_messages("lift it", CATALOGUE)
    a_file = tmp_path / "file"
    a_file.write_text("x")
    monkeypatch.setenv(prompts.PROMPTS_DIR_ENV, str(a_file))
    with pytest.raises(PromptError, match="ITSKILL_PROMPTS_DIR: not a directory"):
        planner_messages("lift it", CATALOGUE)


def test_a_file_in_the_prompts_dir_that_no_template_uses_is_an_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A misspelt name was ignored: the packaged prompt was sent instead of the user's.
    directory = _prompts_dir(tmp_path, monkeypatch, **{"planer_system.txt": b"Be brief."})
    with pytest.raises(PromptError) as err:
        planner_messages("lift it", CATALOGUE)
    message = str(err.value)
    assert message.startswith(f"{directory / 'planer_system.txt'}: ITSKILL_PROMPTS_DIR:")
    assert "not a prompt template's file" in message
    for name in prompts.TEMPLATE_FIELDS:
        assert f"{name}.txt" in message


def test_a_directory_named_as_a_template_is_an_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    directory = _prompts_dir(tmp_path, monkeypatch)
    (directory / "planner_user.txt").mkdir()
    with pytest.raises(PromptError, match=r"planner_user\.txt: ITSKILL_PROMPTS_DIR: not a file"):
        planner_messages("lift it", CATALOGUE)


def test_a_template_the_user_dir_lacks_is_the_packaged_one_and_hidden_files_are_ignored(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _prompts_dir(
        tmp_path,
        monkeypatch,
        **{"planner_system.txt": b"MY SYSTEM", ".planner_system.txt.swp": b"\x00\xff"},
    )
    system, user = planner_messages("lift it", CATALOGUE)
    assert system["content"] == "MY SYSTEM\n"
    assert "<command>\nlift it\n</command>" in user["content"]  # the packaged planner_user


def test_a_bad_prompts_dir_is_one_line_and_exit_2_from_the_cli(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from typer.testing import CliRunner

    from itskill.cli import app

    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    monkeypatch.delenv("ITSKILL_LLM_MODEL", raising=False)
    _prompts_dir(tmp_path, monkeypatch, **{"planner_system.txt": b"\xff\xfe"})
    result = CliRunner().invoke(app, ["plan", "Pick up the nut"])
    assert result.exit_code == 2, result.output
    assert "not UTF-8 text" in result.output and "Traceback" not in result.output


# ----------------------------------------------------------------------- the analyzer's retry
# The retry note as transfer/data/analyzer_retry.txt wrote it: the same text keeps the LLM reply
# cache's keys of runs made before it became a template.
RETRY = """Your reply cannot be used: no matrix.
Reply again with exactly one JSON object in a ```json fence, {"matrix": [...], "reasoning": "..."},
where "matrix" has 3 rows (one per target segment, in order) and each row has 2 non-negative
numbers (one per source skill, in the order given) that sum to 1.
"""


def test_the_analyzer_retry_is_a_template_like_the_others() -> None:
    assert prompts.TEMPLATE_FIELDS["analyzer_retry"] == {"error", "m", "n"}
    path = prompts._template_path("analyzer_retry")
    assert path.parent.name == "prompts" and path.parent.parent.name == "llm"
    assert prompts.analyzer_retry("no matrix", 3, 2) == RETRY
    with pytest.raises(PromptError, match=r"'analyzer_retry'.*missing field\(s\) \{n\}"):
        check_template("analyzer_retry", "{error} {m}")


def test_the_analyzer_retry_can_be_overridden(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _prompts_dir(tmp_path, monkeypatch, **{"analyzer_retry.txt": b"Fix: {error} ({m}x{n})"})
    assert prompts.analyzer_retry("bad", 3, 2) == "Fix: bad (3x2)\n"
