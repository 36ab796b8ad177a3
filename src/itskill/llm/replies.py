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
_OPENING = re.compile(r'\{(?=\s*["}])')
"""A brace that opens an object: a key or the closing brace follows it (``{.`` in prose does
not)."""


class JSONReplyError(ValueError):
    """A reply that holds no JSON object; the message says why."""


def parse_json_reply(reply: str) -> dict[str, Any]:
    """The JSON object in ``reply``: the first ```json (or untagged) fenced block that holds one,
    else the first object decoded from a brace that opens one (``{`` then a key or ``}``) outside
    those blocks: prose around it, a brace in that prose, a fence on one line. A reply cut off
    inside an object is reported as such, not answered with one of that object's inner objects.

    Raises :class:`JSONReplyError` when the object is cut off, is not valid JSON or is not an
    object.
    """
    not_object: str | None = None
    first_error: json.JSONDecodeError | None = None
    tried: list[tuple[int, int]] = []
    for m in _FENCE.finditer(reply):
        if m.group(1).lower() not in ("", "json"):
            continue
        tried.append(m.span(2))
        try:
            data = json.loads(m.group(2))
        except json.JSONDecodeError as err:
            first_error = first_error or err
            continue
        if isinstance(data, dict):
            return data
        not_object = not_object or type(data).__name__
    decoder = json.JSONDecoder()
    for brace in _OPENING.finditer(reply):
        if any(start <= brace.start() < end for start, end in tried):
            continue  # a block that did not decode: its inner objects are not the reply's
        try:
            data, _ = decoder.raw_decode(reply, brace.start())
        except json.JSONDecodeError as err:
            first_error = first_error or err
            if err.pos >= len(reply.rstrip()) or err.msg.startswith("Unterminated string"):
                # Everything after this brace is inside its unfinished object.
                raise JSONReplyError("the reply's JSON object is not closed (cut off?)") from err
            continue
        if isinstance(data, dict):
            return data
    if not_object is not None:
        raise JSONReplyError(f"expected a JSON object, got {not_object}")
    why = f" ({first_error})" if first_error else ""
    raise JSONReplyError(f"the reply holds no valid JSON object{why}")
