"""The analyzer: valid replies become normalised matrices, bad ones are re-asked then refused."""

from __future__ import annotations

import json

import numpy as np
import pytest

from itskill.llm.client import make_client
from itskill.tasks import get_task
from itskill.transfer import AnalyzerError, analyze, target_entry

TARGET = {"id": "t", "description": "Pick up the nut and place it", "actions": ["grasp", "place"]}
SOURCES = [
    {"id": "pick", "description": "Pick up the nut", "actions": ["approach", "grasp", "lift"]},
    {"id": "place", "description": "Place the nut", "actions": ["approach", "place"]},
]


class ScriptedClient:
    """Replies from a list, recording every conversation it was sent."""

    name = "scripted"
    offline = True

    def __init__(self, replies: list[str]) -> None:
        self.replies, self.requests = list(replies), []

    def complete(self, messages, n=1, *, purpose, temperature=1.0):
        assert purpose == "analyze" and n == 1
        self.requests.append(messages)
        return [self.replies.pop(0)]


def fenced(matrix, reasoning="because") -> str:
    return f"Here:\n```json\n{json.dumps({'matrix': matrix, 'reasoning': reasoning})}\n```\n"


def test_a_valid_reply_is_normalised_per_row() -> None:
    client = ScriptedClient([fenced([[3, 1], [0, 2]])])
    result = analyze(TARGET, SOURCES, client)
    np.testing.assert_allclose(result.matrix, [[0.75, 0.25], [0.0, 1.0]])
    assert result.segments == ("grasp", "place") and result.sources == ("pick", "place")
    assert result.reasoning == "because" and result.client == "scripted"
    # As a transfer record stores it.
    stored = json.loads(json.dumps(result.to_dict()))
    assert stored["matrix"] == [[0.75, 0.25], [0.0, 1.0]] and stored["sources"] == ["pick", "place"]
    # A bare JSON object is accepted too.
    bare = analyze(TARGET, SOURCES, ScriptedClient([json.dumps({"matrix": [[1, 1], [1, 3]]})]))
    np.testing.assert_allclose(bare.matrix, [[0.5, 0.5], [0.25, 0.75]])


BAD_REPLIES = {
    "wrong-shape": (fenced([[1, 0, 0], [0, 1, 0]]), "expected 2 rows"),
    "missing-row": (fenced([[1, 0]]), "has 1 rows"),
    "negative": (fenced([[1, -0.5], [0, 1]]), r"entry \[0\]\[1\] is -0.5.*non-negative"),
    "nan": ('```json\n{"matrix": [[NaN, 1], [0, 1]]}\n```', "finite"),
    "zero-row": (fenced([[0, 0], [0, 1]]), "row 0 is all zeros"),
    "not-json": ("The pick skill matters most for grasping.", "no valid JSON object"),
    "no-matrix": (fenced([[1, 0], [0, 1]]).replace("matrix", "weights"), 'no "matrix"'),
    "text-entry": (fenced([["high", 0], [0, 1]]), "not a number"),
    "integer-beyond-float": (fenced([[10**400, 1], [0, 1]]), "not a rectangular table"),
}


@pytest.mark.parametrize("reply,problem", BAD_REPLIES.values(), ids=BAD_REPLIES.keys())
def test_bad_replies_are_reasked_then_refused(reply: str, problem: str) -> None:
    client = ScriptedClient([reply] * 3)
    with pytest.raises(AnalyzerError, match=problem) as info:
        analyze(TARGET, SOURCES, client, retries=2)
    assert "3 attempt(s)" in str(info.value)
    assert len(client.requests) == 3
    # Each retry carries the previous reply and what was wrong with it.
    follow_up = client.requests[1]
    assert follow_up[-2] == {"role": "assistant", "content": reply}
    assert follow_up[-1]["role"] == "user"
    assert "cannot be used" in follow_up[-1]["content"]
    assert "2 rows" in follow_up[-1]["content"] and "2 non-negative" in follow_up[-1]["content"]


def test_entries_near_the_float_limit_normalise_to_their_shares() -> None:
    # Their row sum overflows to inf: divided by it, the row read as all zeros and crashed.
    result = analyze(TARGET, SOURCES, ScriptedClient([fenced([[1e308, 1e308], [1, 3]])]))
    np.testing.assert_allclose(result.matrix, [[0.5, 0.5], [0.25, 0.75]])


def test_a_corrected_reply_is_accepted() -> None:
    client = ScriptedClient(["no idea", fenced([[1, 0], [0, 1]])])
    result = analyze(TARGET, SOURCES, client, retries=1)
    np.testing.assert_array_equal(result.matrix, np.eye(2))
    assert "no valid JSON object" in client.requests[1][-1]["content"]
    with pytest.raises(AnalyzerError):
        analyze(TARGET, SOURCES, ScriptedClient(["no idea"]), retries=0)


def test_offline_analyzer_for_pick_and_place() -> None:
    spec = get_task("pickplace_nut_m12")
    sources = [
        {"id": "pick_nut_m12", "description": "Pick up the M12 nut",
         "actions": ["approach", "grasp", "lift"]},
        {"id": "place_nut_m12", "description": "Place the M12 nut on the bolt",
         "actions": ["approach", "place"]},
    ]  # fmt: skip
    result = analyze(target_entry(spec), sources, make_client("offline"))
    assert result.segments == tuple(st.name for st in spec.stages)
    assert result.matrix.shape == (len(spec.stages), 2)
    np.testing.assert_allclose(result.matrix.sum(1), 1.0)
    pick, place = result.matrix[:, 0], result.matrix[:, 1]
    assert pick[1] > place[1] and pick[2] > place[2]  # grasp, lift: the pick skill
    assert place[4] > pick[4]  # place: the place skill


ACCEPTED_FORMS = {
    "upper-case-fence": '```JSON\n{"matrix": [[1, 3], [1, 1]], "reasoning": "because"}\n```',
    "prose-around": 'Here it is: {"matrix": [[1, 3], [1, 1]], "reasoning": "because"} Thanks.',
}


@pytest.mark.parametrize("reply", ACCEPTED_FORMS.values(), ids=ACCEPTED_FORMS.keys())
def test_a_reply_the_planner_accepts_needs_no_retry(reply: str) -> None:
    client = ScriptedClient([reply])
    result = analyze(TARGET, SOURCES, client, retries=0)
    np.testing.assert_allclose(result.matrix, [[0.25, 0.75], [0.5, 0.5]])
    assert result.reasoning == "because" and len(client.requests) == 1


def test_a_cut_off_reply_is_reasked_as_cut_off() -> None:
    client = ScriptedClient(['{"matrix": [[1, 0], [0,', fenced([[1, 0], [0, 1]])])
    result = analyze(TARGET, SOURCES, client, retries=1)
    np.testing.assert_array_equal(result.matrix, np.eye(2))
    assert "not closed (cut off?)" in client.requests[1][-1]["content"]


def test_the_retry_note_is_a_prompt_template_the_user_can_override(tmp_path, monkeypatch) -> None:
    # It was read from transfer/data, out of reach of ITSKILL_PROMPTS_DIR and of the checks.
    from itskill.llm.prompts import PROMPTS_DIR_ENV, PromptError

    prompts_dir = tmp_path / "prompts"
    prompts_dir.mkdir()
    (prompts_dir / "analyzer_retry.txt").write_text("Wrong ({error}); want {m} x {n}.")
    monkeypatch.setenv(PROMPTS_DIR_ENV, str(prompts_dir))
    client = ScriptedClient(["no idea", fenced([[1, 0], [0, 1]])])
    analyze(TARGET, SOURCES, client, retries=1)
    assert client.requests[1][-1]["content"].startswith("Wrong (the reply holds no valid JSON")
    assert client.requests[1][-1]["content"].endswith("want 2 x 2.\n")
    # An override missing a field is named, not sent half-filled.
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "analyzer_retry.txt").write_text("Wrong ({error})")
    monkeypatch.setenv(PROMPTS_DIR_ENV, str(broken))
    with pytest.raises(PromptError, match=r"'analyzer_retry'.*missing field\(s\) \{m\}, \{n\}"):
        analyze(TARGET, SOURCES, ScriptedClient(["no idea"]), retries=1)
