"""Reading the JSON object out of a language model's reply.

Models wrap JSON in a fence (```json, ```JSON or a bare ```) or put prose around it, whatever the
prompt asks; :func:`parse_json_reply` accepts all of these, so that a usable reply is not sent back
for a retry. Each caller words its own error from :class:`JSONReplyError`.
"""

from __future__ import annotations

import json
import re
from typing import Any

_FENCE = re.compile(r"```[ \t]*(?:json)?[ \t]*\n(.*?)```", re.DOTALL | re.IGNORECASE)


class JSONReplyError(ValueError):
    """A reply that holds no JSON object; the message says why."""


def parse_json_reply(reply: str) -> dict[str, Any]:
    """The JSON object in ``reply``: inside its first ```json fence, or its outermost braces.

    Raises :class:`JSONReplyError` when the object is cut off, is not valid JSON or is not an
    object.
    """
    match = _FENCE.search(reply)
    text = match.group(1) if match else reply
    if not match and "{" in text:
        start, end = text.index("{"), text.rfind("}")
        if end < start:
            raise JSONReplyError("the reply's JSON object is not closed (cut off?)")
        text = text[start : end + 1]
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise JSONReplyError(f"the reply holds no valid JSON object ({err})") from err
    if not isinstance(data, dict):
        raise JSONReplyError(f"expected a JSON object, got {type(data).__name__}")
    return data
