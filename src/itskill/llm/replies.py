"""Reading the JSON object out of a language model's reply.

Models wrap JSON in a fence (```json, ```JSON or a bare ```) or put prose around it, whatever the
prompt asks; :func:`parse_json_reply` accepts all of these, so that a usable reply is not sent back
for a retry. Each caller words its own error from :class:`JSONReplyError`.
"""

from __future__ import annotations

import json
import re
from typing import Any

# A fence opens at the start of a line: the closing ``` of an earlier block (a ```python one)
# would otherwise open the next one, and the prose between them be read as the object.
_FENCE = re.compile(r"^[ \t]*```[ \t]*(\w*)[ \t]*\n(.*?)^[ \t]*```", re.DOTALL | re.MULTILINE)


class JSONReplyError(ValueError):
    """A reply that holds no JSON object; the message says why."""


def parse_json_reply(reply: str) -> dict[str, Any]:
    """The JSON object in ``reply``: the first ```json (or untagged) fenced block that holds one,
    else the first object that starts at an outermost brace (prose around it, a ``{`` in that
    prose, a fence on one line). A brace inside an object that does not decode is not tried:
    a reply cut off mid-object would otherwise hand back one of its inner objects.

    Raises :class:`JSONReplyError` when the object is cut off, is not valid JSON or is not an
    object.
    """
    not_object: str | None = None
    first_error: json.JSONDecodeError | None = None
    blocks = [m.group(2) for m in _FENCE.finditer(reply) if m.group(1).lower() in ("", "json")]
    for block in blocks:
        try:
            data = json.loads(block)
        except json.JSONDecodeError as err:
            first_error = first_error or err
            continue
        if isinstance(data, dict):
            return data
        not_object = not_object or type(data).__name__
    decoder = json.JSONDecoder()
    starts, unclosed = _outermost_braces(reply)
    for start in starts:
        try:
            data, _ = decoder.raw_decode(reply, start)
        except json.JSONDecodeError as err:
            first_error = first_error or err
            continue
        if isinstance(data, dict):
            return data
    if not_object is not None:
        raise JSONReplyError(f"expected a JSON object, got {not_object}")
    if unclosed:
        raise JSONReplyError("the reply's JSON object is not closed (cut off?)")
    why = f" ({first_error})" if first_error else ""
    raise JSONReplyError(f"the reply holds no valid JSON object{why}")


def _outermost_braces(text: str) -> tuple[list[int], bool]:
    """The positions of the braces in ``text`` that no earlier brace encloses (braces inside
    the double-quoted strings of an enclosing object not counted), and whether the last of them
    is still open where the text ends."""
    starts: list[int] = []
    depth, in_string, escaped = 0, False, False
    for i, char in enumerate(text):
        if in_string:
            if escaped:
                escaped = False
            elif char == "\\":
                escaped = True
            elif char == '"':
                in_string = False
        elif char == '"' and depth:
            in_string = True
        elif char == "{":
            if not depth:
                starts.append(i)
            depth += 1
        elif char == "}" and depth:
            depth -= 1
    return starts, depth > 0
