"""Prompt templates: the parts each prompt must carry, and validation of edited templates."""

from __future__ import annotations

import json
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
