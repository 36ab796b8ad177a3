"""The reward generator: K samples per iteration, each checked and, if broken, regenerated.

A sample is the code in a reply's ```python fence (or the whole reply if it has none). It is
accepted once it compiles in the sandbox and runs on a probe batch: real reward contexts from a
few random steps of the task, on which it must return finite ``(total, components)`` within the
sandbox's time limit. Otherwise the model gets the error back (``execution_error_feedback``) and
writes the sample again, up to ``max_regenerations`` times; a sample still broken then is recorded
as failed with every reply and the reason each was rejected. Nothing here raises for a bad reply.

The probe runs the code in a child process under the sandbox's limits
(:class:`itskill.reward.probe.Probe`), never in the search's own process.
"""

from __future__ import annotations

import ast
import re
import textwrap
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from itskill.llm.client import LLMClient, Message
from itskill.llm.prompts import execution_error_feedback
from itskill.reward.probe import Probe
from itskill.reward.sandbox import SandboxConfig
from itskill.sim.task import Context
from itskill.tasks import make_batch_env

_FENCE = re.compile(
    r"^[ \t]*(?P<fence>(?P<char>[`~])(?P=char){2,})[ \t]*(?P<lang>[A-Za-z0-9_+-]*)[^\n]*(?:\n|\Z)"
    r"(?P<code>.*?)(?:^[ \t]*(?P=fence)|(?P=fence)[ \t]*$|\Z)",
    re.DOTALL | re.MULTILINE,
)
"""A fenced block as Markdown writes it: opened at the start of a line (indented inside a list
item too) by three or more backticks or tildes, its language tag followed by anything
(```` ```python title=reward.py ````), closed by at least as many of the same on a line of its
own or at the end of the last code line (so a block opened by four backticks holds ```` ``` ````
blocks); unclosed (a reply cut off by the token limit), it runs to the end of the reply."""
_LOOSE_FENCE = re.compile(
    r"```[ \t]*(?P<lang>[A-Za-z0-9_+-]*)[ \t]*\n(?P<code>.*?)(?:```|\Z)", re.DOTALL
)
"""A fence anywhere on a line ("Here it is: ```python"), tried when no block of :data:`_FENCE`
defines the reward: read first, it would take ```` ```inline``` ```` prose for a block."""
_PYTHON = ("python", "py", "python3", "")


def extract_code(reply: str) -> str:
    """The reward code in a reply.

    The first fenced block that defines ``compute_reward``, a Python or untagged one before
    any other (a ```` ```diff ```` of the change, written first, is not the code); else the
    first ``python`` block; else the whole reply (a model that answers with bare code). A block
    nested in another that is not Python (the reward in a Markdown answer, fenced by four
    backticks) comes before the block around it; one indented inside a list item is dedented;
    Windows line endings are read as Unix ones.
    """
    reply = reply.replace("\r\n", "\n")
    found = []
    for fence in (_FENCE, _LOOSE_FENCE):
        blocks = _blocks(reply, fence)
        defining = sorted(
            (block for block in blocks if "def compute_reward" in block[1]),
            key=lambda block: block[0] not in _PYTHON,
        )
        if defining:
            return defining[0][1].strip()
        found += blocks
    for lang, code in found:
        if lang in _PYTHON[:3]:
            return code.strip()
    return reply.strip()


_MAX_NESTING = 16
"""Fenced blocks read inside one another: Markdown around the code nests two or three deep, and
a reply nested a thousand deep would exhaust Python's recursion (an error no resume gets past,
since the reply is cached)."""


def _blocks(text: str, fence: re.Pattern[str], depth: int = 0) -> list[tuple[str, str]]:
    """(language, dedented code) of each block of ``fence`` in ``text``; the blocks nested in one
    tagged other than Python, or untagged, fenced by four or more and not Python itself, come
    first: that one is the Markdown around the code, not the code. Blocks nested deeper than
    :data:`_MAX_NESTING` are read as their outer block's text."""
    blocks = []
    for match in fence.finditer(text):
        lang, code = match["lang"].lower(), textwrap.dedent(match["code"])
        wrapper = not lang and len(match.groupdict().get("fence") or "") > 3 and not _parses(code)
        if (lang not in _PYTHON or wrapper) and depth < _MAX_NESTING:
            # Code holds no block: a line of tildes in it underlines a docstring heading.
            blocks += _blocks(code, fence, depth + 1)
        blocks.append((lang, code))
    return blocks


def _parses(code: str) -> bool:
    """Whether ``code`` is Python (a module docstring underlined with ``~~~`` is, Markdown around
    a fenced block is not)."""
    try:
        ast.parse(code)
    except (SyntaxError, ValueError, RecursionError, MemoryError):  # a reply nested past the parser
        return False
    return True


def probe_contexts(task: str, num_envs: int, steps: int, seed: int = 0) -> list[Context]:
    """Reward contexts of ``task`` at reset and after each of ``steps`` uniformly random actions.

    Deterministic for a seed, so a resumed run probes exactly as the original one did.
    """
    env = make_batch_env(task, num_envs, seed=seed)
    rng = np.random.default_rng(seed)
    try:
        env.reset()
        contexts = [env.context()]
        for _ in range(steps):
            contexts.append(env.advance(rng.uniform(-1.0, 1.0, (num_envs, 5))).context)
    finally:
        env.close()
    return contexts


@dataclass
class Attempt:
    """One reply for a sample: the code taken from it and why it was rejected (None: accepted)."""

    reply: str
    code: str
    error: str | None

    def to_dict(self) -> dict[str, Any]:
        return {"reply": self.reply, "code": self.code, "error": self.error}


@dataclass
class Sample:
    """Sample ``index`` of an iteration: its replies in order; the last one decides."""

    index: int
    attempts: list[Attempt] = field(default_factory=list)

    @property
    def accepted(self) -> bool:
        return bool(self.attempts) and self.attempts[-1].error is None

    @property
    def code(self) -> str:
        return self.attempts[-1].code

    @property
    def reply(self) -> str:
        return self.attempts[-1].reply

    @property
    def error(self) -> str | None:
        return self.attempts[-1].error

    def to_status(self) -> dict[str, Any]:
        return {
            "sample": self.index,
            "accepted": self.accepted,
            "regenerations": len(self.attempts) - 1,
            "error": self.error,
            "attempts": [a.to_dict() for a in self.attempts],
        }


def fenced(code: str) -> str:
    """``code`` as an assistant reply: one python fence."""
    return f"```python\n{code.strip()}\n```"


def generate_samples(
    messages: list[Message],
    client: LLMClient,
    k: int,
    contexts: list[Context],
    sandbox: SandboxConfig,
    max_regenerations: int,
    temperature: float = 1.0,
    after_request: Callable[[], object] | None = None,
    iteration: int = 1,
) -> list[Sample]:
    """``k`` samples for ``messages``, each regenerated with its error up to ``max_regenerations``
    times. The requests are made in a fixed order, so a rerun replays them from the reply cache.
    ``after_request`` is called after each request (a run records its usage there: killed
    mid-generation, the requests paid for would be replayed from the cache as free ones);
    ``iteration`` is the search iteration the error feedback names."""

    def ask(request: list[Message], n: int) -> list[str]:
        replies = client.complete(request, n=n, purpose="reward", temperature=temperature)
        if after_request is not None:
            after_request()
        return replies

    samples = []
    with Probe(contexts, sandbox) as probe:
        for index, reply in enumerate(ask(messages, k)):
            sample = Sample(index)
            while True:
                code = extract_code(reply)
                error = probe.check(code)
                sample.attempts.append(Attempt(reply, code, error))
                if error is None or len(sample.attempts) > max_regenerations:
                    break
                retry = [
                    *messages,
                    {"role": "assistant", "content": reply},
                    {"role": "user", "content": execution_error_feedback(code, error, iteration)},
                ]
                reply = ask(retry, 1)[0]
            samples.append(sample)
    return samples
