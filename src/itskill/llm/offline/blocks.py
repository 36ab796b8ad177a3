"""Reading the structured parts of a prompt: ``<tag>...</tag>`` blocks and Markdown code fences."""

from __future__ import annotations

import re

from itskill.llm.client import Message


def tagged(text: str, tag: str) -> str | None:
    """The content of the last ``<tag>...</tag>`` block in ``text``, stripped; None if absent."""
    found = re.findall(rf"<{tag}>\n?(.*?)\n?</{tag}>", text, flags=re.S)
    return found[-1].strip() if found else None


def last_tagged(messages: list[Message], tag: str, role: str = "user") -> str | None:
    """The ``tag`` block of the latest message of ``role`` that has one."""
    for message in reversed(messages):
        if message["role"] == role:
            block = tagged(message["content"], tag)
            if block is not None:
                return block
    return None


def fenced(text: str, language: str) -> str | None:
    """The body of the first ```language fence in ``text``; None if there is none."""
    match = re.search(rf"```{language}[ \t]*\n(.*?)```", text, flags=re.S)
    return match.group(1) if match else None
