"""The planner: Table I commands with the offline backend, validation of replies, clear errors."""

from __future__ import annotations

import json

import pytest
from fake_openai import FakeOpenAIServer

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


def test_a_refused_command_names_the_closest_tasks() -> None:
    with FakeOpenAIServer(['{"error": "which nut?"}']) as server, pytest.raises(PlanError) as info:
        plan_command("pick up the nut", _openai(server))
    message = str(info.value)
    closest = message[message.index("Closest tasks:") :]
    assert "pick_nut_m12 (Pick up the M12 nut)" in closest
    assert "pick_nut_m16" in closest
    assert "insert_peg_rect" not in message and len(message) < 500
