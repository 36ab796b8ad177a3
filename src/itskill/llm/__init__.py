"""Language models for planning, reward generation and transfer analysis.

``make_client(spec)`` gives an :class:`LLMClient`: ``"offline"`` (the embedded rule-based backend,
the default) or ``"openai:MODEL"`` (any OpenAI-compatible endpoint). Prompts are text templates in
``itskill/llm/prompts/``, filled by the builders of :mod:`itskill.llm.prompts`;
:func:`parse_json_reply` reads the JSON object out of a reply.
"""

from itskill.llm.client import (
    PURPOSES,
    LLMClient,
    LLMError,
    LLMUnavailableError,
    Message,
    Usage,
    make_client,
)
from itskill.llm.offline import OfflineClient
from itskill.llm.prompts import (
    PromptError,
    analyzer_messages,
    execution_error_feedback,
    planner_messages,
    policy_feedback,
    reward_messages,
    task_description,
)
from itskill.llm.replies import JSONReplyError, parse_json_reply

__all__ = [
    "PURPOSES",
    "JSONReplyError",
    "LLMClient",
    "LLMError",
    "LLMUnavailableError",
    "Message",
    "OfflineClient",
    "PromptError",
    "Usage",
    "analyzer_messages",
    "execution_error_feedback",
    "make_client",
    "parse_json_reply",
    "planner_messages",
    "policy_feedback",
    "reward_messages",
    "task_description",
]
