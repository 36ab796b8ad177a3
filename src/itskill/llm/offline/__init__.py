"""The embedded offline backend: deterministic, rule-based, no network.

It is not a language model and never claims to be one: it reads the same prompts a model gets
(the tagged blocks of :mod:`itskill.llm.prompts`) and answers in the format a model must use, so the
planner, the reward loop (code extraction, sandbox, feedback) and the transfer analyzer run exactly
as they would with a model. Purposes:

- ``plan``: :mod:`~itskill.llm.offline.planner` matches the command to a catalogue task.
- ``reward``: :mod:`~itskill.llm.offline.synthesiser` composes staged reward code, and retunes it
  from policy feedback; after an execution error it writes valid code again.
- ``analyze``: :mod:`~itskill.llm.offline.analyzer` scores action-sequence overlap.
"""

from __future__ import annotations

from itskill.llm.client import BaseClient, Message
from itskill.llm.offline import analyzer, planner, synthesiser
from itskill.llm.offline.blocks import last_tagged, tagged


class OfflineClient(BaseClient):
    """``complete()`` by rule: the default when no language model is configured."""

    name = "offline"
    offline = True

    def _complete(
        self, messages: list[Message], n: int, purpose: str, temperature: float
    ) -> list[str]:
        self.usage.requests += 1
        if purpose == "plan":
            text = planner.reply(
                last_tagged(messages, "command"), last_tagged(messages, "catalogue")
            )
            return [text] * n
        if purpose == "analyze":
            text = analyzer.reply(last_tagged(messages, "target"), last_tagged(messages, "sources"))
            return [text] * n
        description = last_tagged(messages, "task_description")
        if description is None:
            return [f"The {synthesiser.BACKEND} found no <task_description> in the prompt."] * n
        feedback = None
        for message in reversed(messages):
            if message["role"] == "user" and tagged(message["content"], "policy_feedback"):
                feedback = message["content"]
                break
        return synthesiser.synthesise(description, n, feedback)


__all__ = ["OfflineClient"]
