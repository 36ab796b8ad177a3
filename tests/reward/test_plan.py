"""The planner: Table I commands with the offline backend, validation of replies, clear errors."""

from __future__ import annotations

import json

import pytest
from fake_openai import FakeOpenAIServer
from typer.testing import CliRunner

from itskill.cli import app
from itskill.llm import make_client
from itskill.llm.openai_client import OpenAIClient
from itskill.reward.plan import PlanError, TaskPlan, plan_command, plan_for_task, task_catalogue
from itskill.tasks import all_tasks, get_task

TABLE_I = [t for t in all_tasks().values() if t.table_i]


@pytest.fixture(scope="module")
def offline():
    return make_client("offline")


@pytest.mark.parametrize("spec", TABLE_I, ids=[t.id for t in TABLE_I])
def test_table_i_commands_plan_to_their_task(offline, spec) -> None:
    plan = plan_command(spec.command, offline)
    assert plan.task == spec.id
    assert plan.actions == tuple(s.name for s in spec.stages)
    assert plan.objects == tuple(o.name for o in spec.objects)
    assert len(plan.subtasks) == len(spec.stages)
    assert plan.subtasks[0].startswith("First,")


@pytest.mark.parametrize(
    ("command", "task"),
    [
        ("Pick up the nut, place it on the bolt and screw it down", "pickplacescrew_nut_m12"),
        ("pick up the M16 nut and put it on the bolt", "pickplace_nut_m16"),
    ],
)
def test_paraphrases(offline, command: str, task: str) -> None:
    plan = plan_command(command, offline)
    assert plan.task == task
    if "M16" not in command:
        assert "M12" in plan.notes  # "the nut" alone is grounded, and the plan says how


def test_ungroundable_command_says_what_is_known_in_one_short_line(offline) -> None:
    with pytest.raises(PlanError) as info:
        plan_command("make me a sandwich", offline)
    message = str(info.value)
    assert "make me a sandwich" in message
    assert "nut_m12" in message and "itskill tasks list" in message
    # Nothing is like a sandwich: no task is offered, and the catalogue is not dumped.
    assert "Closest tasks" not in message and "pick_nut_m12" not in message
    assert len(message) < 500


@pytest.mark.parametrize("command", ["", "   ", "\t\n"])
def test_empty_command_gets_a_short_error(command: str) -> None:
    with pytest.raises(PlanError) as info:
        plan_command(command, make_client("offline"))
    message = str(info.value)
    assert message.startswith("the command is empty: say what the robot should do, e.g.")
    assert "itskill tasks list" in message
    assert "pick_nut_m12" not in message and len(message) < 200


def test_a_command_in_another_encoding_is_named_not_a_traceback(tmp_path, monkeypatch) -> None:
    # A Latin-1 terminal's "é" reaches Python as the lone surrogate U+DCE9, which the reply
    # cache's key could not encode.
    command = "Pick up the nut and place it \udce9 on the bolt"
    with pytest.raises(PlanError) as info:
        plan_command(command, make_client("offline"))
    assert str(info.value) == (
        "the command is not UTF-8 text (the byte 0xe9 after 'Pick up the nut and place it '): "
        "type it again in a UTF-8 terminal"
    )
    monkeypatch.chdir(tmp_path)
    for args in (["reward", "generate", command], ["plan", command]):
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 2, result.output
        assert "not UTF-8 text" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "runs").exists()


def test_plan_for_task_needs_no_model() -> None:
    plan = plan_for_task("pickplace2_nuts")
    assert plan.command == get_task("pickplace2_nuts").command
    # The second half of the task concerns the second nut, and the sentences say so.
    assert "M16 nut" in plan.subtasks[4] and "M12 nut" in plan.subtasks[0]
    assert plan.subtasks[2].startswith("Third, carry the M12 nut over the M12 bolt")


def test_describe_renders_stages_slots_and_notes() -> None:
    plan = TaskPlan(**{**plan_for_task("pick_nut_m12").to_dict(), "notes": "assumed M12"})
    text = plan.describe()
    assert "stage 2: lift | object 0 | done when lifted(0, 3) and grasped(0)" in text
    assert "object 0: nut_m12" in text
    assert "Success: lifted(0, 3) and grasped(0)" in text
    assert text.endswith("Notes: assumed M12")


def test_plan_round_trips_through_json() -> None:
    plan = plan_for_task("insert_peg_round")
    assert TaskPlan.from_dict(json.loads(json.dumps(plan.to_dict()))) == plan
    with pytest.raises(ValueError, match=r"plan\.actions: expected a list of strings"):
        TaskPlan.from_dict({**plan.to_dict(), "actions": "insert"})


def test_catalogue_actions_are_stage_names() -> None:
    entry = next(e for e in task_catalogue() if e["task"] == "removenut_m12")
    assert entry["actions"] == ["unscrew", "lift"]
    assert entry["objects"] == ["nut_m12"] and entry["fixtures"] == ["bolt_m12"]


VALID = json.dumps(
    {
        "task": "pick_nut_m12",
        "subtasks": ["First, reach the nut.", "Second, grasp it.", "Third, lift it."],
        "actions": ["approach", "grasp", "lift"],
        "objects": ["nut_m12"],
        "notes": "",
    }
)


def _openai(server: FakeOpenAIServer) -> OpenAIClient:
    return OpenAIClient("fake-model", base_url=server.base_url)


def test_invalid_replies_are_sent_back_with_the_problem() -> None:
    wrong_actions = VALID.replace('"lift"]', '"raise"]')
    cut_off = VALID[: len(VALID) // 2]  # a reply stopped by the token limit
    with FakeOpenAIServer(
        ["Sure! Here is the plan.", cut_off, wrong_actions, f"```json\n{VALID}\n```"]
    ) as server:
        plan = plan_command("pick up the nut", _openai(server), attempts=4)
        requests = server.requests
    assert plan.task == "pick_nut_m12" and plan.command == "pick up the nut"
    assert len(requests) == 4
    second, third, fourth = (r["messages"] for r in requests[1:])
    assert second[-2] == {"role": "assistant", "content": "Sure! Here is the plan."}
    assert "no valid JSON object" in second[-1]["content"]
    assert "not closed" in third[-1]["content"]
    assert "action sequence ['approach', 'grasp', 'lift']" in fourth[-1]["content"]


def test_a_model_that_never_gives_a_valid_plan() -> None:
    wrong_task = VALID.replace("pick_nut_m12", "pick_the_nut")
    with FakeOpenAIServer([wrong_task]) as server:
        with pytest.raises(PlanError, match=r"no valid plan .* in 3 replies.*'pick_the_nut'"):
            plan_command("pick up the nut", _openai(server))
        assert len(server.requests) == 3


def test_a_model_that_says_it_cannot_ground_the_command() -> None:
    with FakeOpenAIServer(['{"error": "there is no sandwich here"}']) as server:
        with pytest.raises(PlanError, match=r"there is no sandwich here.*itskill tasks list"):
            plan_command("make me a sandwich", _openai(server))
        assert len(server.requests) == 1


@pytest.mark.parametrize("empty", ["null", '""'])
def test_a_plan_with_an_empty_error_key_is_a_plan(empty: str) -> None:
    # A model in JSON mode writes every key it was shown; this one was refused, not retried.
    reply = VALID.replace('"notes": ""', f'"notes": "", "error": {empty}')
    assert f'"error": {empty}' in reply
    with FakeOpenAIServer([reply]) as server:
        assert plan_command("pick up the nut", _openai(server)).task == "pick_nut_m12"


def test_a_plan_with_null_notes_is_a_plan_asked_once() -> None:
    # Refused as "notes must be a string", each refusal a paid request again.
    reply = VALID.replace('"notes": ""', '"notes": null')
    assert '"notes": null' in reply
    with FakeOpenAIServer([reply]) as server:
        plan = plan_command("pick up the nut", _openai(server))
        assert (plan.task, plan.notes, len(server.requests)) == ("pick_nut_m12", "", 1)


def test_a_refused_command_names_the_closest_tasks() -> None:
    with FakeOpenAIServer(['{"error": "which nut?"}']) as server, pytest.raises(PlanError) as info:
        plan_command("pick up the nut", _openai(server))
    message = str(info.value)
    closest = message[message.index("Closest tasks:") :]
    assert "pick_nut_m12 (Pick up the M12 nut)" in closest
    assert "pick_nut_m16" in closest
    assert "insert_peg_rect" not in message and len(message) < 500


# ----------------------------------------------------------------------- plan.toml, checked
def _damaged_plan(tmp_path, old: str, new: str):
    """A copy of the packaged plan.toml with ``old`` replaced by ``new``."""
    from itskill.reward.plan import plan_data_path

    text = plan_data_path().read_text(encoding="utf-8")
    assert old in text
    path = tmp_path / "plan.toml"
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    return path


APPROACH = 'approach = "move the gripper to {object}"'


@pytest.mark.parametrize(
    ("old", "new", "where", "problem"),
    [
        (APPROACH, "approach = [", "TOML syntax", ""),
        (APPROACH, "approach = 5", "phrases.approach", "expected a non-empty string, got 5"),
        (APPROACH, APPROACH.replace("{object}", "{objekt}"), "phrases.approach",
         "unknown placeholder {objekt}; known: {fixture}, {object}"),
        (APPROACH, APPROACH.replace("{object}", "{object:d}"), "phrases.approach",
         "cannot be filled"),
        (APPROACH, APPROACH.replace("{object}", "{object"), "phrases.approach", "literal braces"),
        ("Your plan cannot be used: {problem}", "Your plan cannot be used.", "correction",
         "missing placeholder {problem}"),
        ('"First", ', '"", ', "ordinals[0]", "expected a word"),
        ("[phrases]", "[phrase]", "phrase", "unknown field"),
    ],
)  # fmt: skip
def test_a_damaged_plan_toml_is_named_not_a_traceback(tmp_path, old, new, where, problem):
    # TOMLDecodeError, AttributeError ('int' has no 'format') and KeyError ('objekt') escaped.
    from itskill.datafile import DataFileError
    from itskill.reward.plan import PlanDataError, load_plan_data

    path = _damaged_plan(tmp_path, old, new)
    with pytest.raises(PlanDataError) as err:
        load_plan_data(path)
    assert isinstance(err.value, DataFileError)  # reported by the CLI as a user error
    assert str(err.value).startswith(f"{path}: {where}:") and problem in str(err.value)


def test_an_empty_plan_toml_says_what_is_missing(tmp_path) -> None:
    from itskill.reward.plan import PlanDataError, load_plan_data

    path = tmp_path / "plan.toml"
    path.write_text("")
    with pytest.raises(PlanDataError, match="ordinals: missing"):
        load_plan_data(path)


def test_a_damaged_plan_toml_is_one_line_and_exit_2_from_the_cli(tmp_path, monkeypatch) -> None:
    from typer.testing import CliRunner

    from itskill.cli import app
    from itskill.reward import plan as plan_module

    path = _damaged_plan(tmp_path, APPROACH, APPROACH.replace("{object}", "{objekt}"))
    monkeypatch.setattr(plan_module, "plan_data_path", lambda: path)
    plan_module._plan_data.cache_clear()
    try:
        result = CliRunner().invoke(app, ["plan", "pick_nut_m12"])
    finally:
        plan_module._plan_data.cache_clear()
    assert result.exit_code == 2, result.output
    assert "unknown placeholder {objekt}" in result.output and "Traceback" not in result.output


def _with_stages(task: str, names: list[str]):
    """Task ``task`` with its stages renamed (and repeated) as ``names``: a user's task."""
    from dataclasses import replace

    spec = get_task(task)
    stages = [replace(spec.stages[k % len(spec.stages)], name=n) for k, n in enumerate(names)]
    return replace(spec, stages=tuple(stages), source="/home/me/tasks/mine.toml")


def test_a_user_task_whose_action_has_no_phrase_is_a_plan_error() -> None:
    # ValueError traceback ("plan.toml: phrases: no entry ...") naming neither task nor file.
    from itskill.reward.plan import subtask_sentences

    spec = _with_stages("pick_nut_m12", ["approach", "wiggle", "lift"])
    with pytest.raises(PlanError) as err:
        subtask_sentences(spec)
    message = str(err.value)
    assert "task 'pick_nut_m12' (/home/me/tasks/mine.toml)" in message
    assert "stage 1 action 'wiggle' has no phrase" in message
    assert "known actions: align, approach," in message


def test_a_user_task_with_more_stages_than_ordinals_is_a_plan_error() -> None:
    from itskill.reward.plan import _plan_data, subtask_sentences

    many = len(_plan_data()["ordinals"]) + 1
    spec = _with_stages("reach_nut_m12", ["approach"] * many)
    with pytest.raises(PlanError, match=rf"'reach_nut_m12' \(/home/me.*\) has {many} stages"):
        subtask_sentences(spec)
