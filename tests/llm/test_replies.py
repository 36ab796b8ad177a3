"""The JSON-reply parser: the fences and prose models put around an object, and clear refusals."""

from __future__ import annotations

import pytest

from itskill.llm import JSONReplyError, parse_json_reply

OBJECT = '{"matrix": [[1.0]], "note": "a } in a string"}'
EXPECTED = {"matrix": [[1.0]], "note": "a } in a string"}

ACCEPTED = {
    "json-fence": f"Here:\n```json\n{OBJECT}\n```\nDone.",
    "upper-case-fence": f"```JSON\n{OBJECT}\n```",
    "untagged-fence": f"```\n{OBJECT}\n```",
    "one-line-fence": f"```json {OBJECT}```",
    "bare": OBJECT,
    "prose-around": f"Here it is: {OBJECT} Hope this helps.",
    # The closing fence of the code block opened a block of the prose after it.
    "after-a-code-block": f"Some code:\n```python\nx = 1\n```\nThe plan:\n```json\n{OBJECT}\n```",
    # From the first brace to the last was not JSON.
    "brace-in-prose": f"I fill the {{task}} field: {OBJECT}",
    # A brace or a quote in the prose before it hid the object as "not closed".
    "lone-brace-in-prose": f"A dict opens with {{. Here: {OBJECT}",
    "quoted-brace-in-prose": f'I use the "{{" character. {OBJECT}',
    "brace-in-a-code-block": f'Code:\n```python\nx = "{{"\n```\n{OBJECT}',
}


@pytest.mark.parametrize("reply", ACCEPTED.values(), ids=ACCEPTED.keys())
def test_the_object_is_found_however_it_is_wrapped(reply: str) -> None:
    assert parse_json_reply(reply) == EXPECTED


REFUSED = {
    "no-json": ("Sure! Here is the plan.", "no valid JSON object"),
    "cut-off": ('Here: {"matrix": [[1.0], [', r"not closed \(cut off\?\)"),
    "invalid": ("{'matrix': [[1.0]]}", "no valid JSON object"),
    "not-an-object": ("```json\n[[1.0]]\n```", "expected a JSON object, got list"),
    # Its inner object was handed back as the reply's.
    "cut-off-after-an-inner-object": (
        '{"task": "t", "meta": {"a": 1}, "subtasks": ["Fi',
        r"not closed \(cut off\?\)",
    ),
    "invalid-with-an-inner-object": (
        '```json\n{"meta": {"a": 1}, "b": 2,}\n```',
        "no valid JSON object",
    ),
}


@pytest.mark.parametrize("reply,problem", REFUSED.values(), ids=REFUSED.keys())
def test_a_reply_without_an_object_says_why(reply: str, problem: str) -> None:
    with pytest.raises(JSONReplyError, match=problem):
        parse_json_reply(reply)
