"""The language-model interface every caller uses, and the factory that picks a backend.

A client answers ``complete(messages, n, purpose=...)`` with exactly ``n`` reply texts. Two
backends implement it: :class:`~itskill.llm.openai_client.OpenAIClient` (any OpenAI-compatible
endpoint) and :class:`~itskill.llm.offline.OfflineClient` (the embedded rule-based backend, no
network). Both share :class:`BaseClient`, which validates requests, replays cached replies and keeps
the token and cost accounting, so every backend behaves the same to its caller.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from itskill.llm.cache import ReplyCache, request_key

Message = dict[str, str]
"""One chat message: ``{"role": "system" | "user" | "assistant", "content": ...}``."""

PURPOSES = ("plan", "reward", "analyze")
"""What a request is for: the offline backend dispatches on it, accounting and caching record it."""

ROLES = ("system", "user", "assistant")
MODEL_ENV = "ITSKILL_LLM_MODEL"
BASE_URL_ENV = "OPENAI_BASE_URL"
TIMEOUT_ENV = "ITSKILL_LLM_TIMEOUT"
"""Seconds an OpenAI-compatible endpoint has to answer a request (default 180): K samples of a
reasoning model, or of a local server on a small machine, can take longer."""
API_KEY_ENV = "OPENAI_API_KEY"


@dataclass
class Usage:
    """What a client has consumed so far: tokens from the responses, requests sent, cache replays
    (which cost nothing) and the cost in USD from the price table."""

    prompt_tokens: int = 0
    completion_tokens: int = 0
    requests: int = 0
    cache_hits: int = 0
    cost_usd: float = 0.0

    def to_dict(self) -> dict:
        """The counts by name, JSON-ready."""
        return asdict(self)

    def since(self, earlier: Usage) -> Usage:
        """What was consumed after ``earlier`` (a copy of this usage taken then)."""
        return Usage(**{k: v - getattr(earlier, k) for k, v in asdict(self).items()})


class LLMError(RuntimeError):
    """A language-model failure a user can see; the message says what to do about it."""


class LLMUnavailableError(LLMError):
    """The endpoint cannot be reached, refuses the key, or no key is configured."""


class UnknownModelError(LLMError, ValueError):
    """A model spec that is neither ``offline`` nor ``openai:MODEL``."""


@runtime_checkable
class LLMClient(Protocol):
    """What the planner, the reward generator and the transfer analyzer need from a model."""

    name: str
    offline: bool
    usage: Usage

    def complete(
        self, messages: list[Message], n: int = 1, *, purpose: str, temperature: float = 1.0
    ) -> list[str]:
        """Exactly ``n`` reply texts to ``messages``."""
        ...


def validate_request(messages: list[Message], n: int, purpose: str, temperature: float) -> None:
    """Reject a malformed request before it costs anything, naming what is wrong."""
    if purpose not in PURPOSES:
        raise ValueError(f"unknown purpose {purpose!r}; expected one of {', '.join(PURPOSES)}")
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    if not 0.0 <= temperature <= 2.0:
        raise ValueError(f"temperature must be in [0, 2], got {temperature!r}")
    if not isinstance(messages, list) or not messages:
        raise ValueError("messages must be a non-empty list of {'role', 'content'} dicts")
    for k, message in enumerate(messages):
        if not isinstance(message, Mapping) or set(message) != {"role", "content"}:
            raise ValueError(f"messages[{k}] must be a dict with exactly 'role' and 'content'")
        if message["role"] not in ROLES:
            raise ValueError(
                f"messages[{k}]['role'] is {message['role']!r}; expected one of {', '.join(ROLES)}"
            )
        if not isinstance(message["content"], str):
            raise ValueError(f"messages[{k}]['content'] must be a string")


class BaseClient:
    """Shared behaviour of every backend: validation, the reply cache and usage accounting.

    A subclass sets ``name``/``offline`` and implements :meth:`_complete`, which returns the ``n``
    replies and adds what it consumed to ``self.usage``.
    """

    name: str = ""
    offline: bool = False

    def __init__(self, cache_dir: Path | None = None) -> None:
        self.usage = Usage()
        self.cache = ReplyCache(cache_dir) if cache_dir is not None else None

    def complete(
        self, messages: list[Message], n: int = 1, *, purpose: str, temperature: float = 1.0
    ) -> list[str]:
        validate_request(messages, n, purpose, temperature)
        if self.cache is None:
            return self._ask(messages, n, purpose, temperature)
        key = self.cache.occurrence_key(request_key(self.name, messages, n, temperature, purpose))
        with self.cache.lock():
            cached = self.cache.get(key, n)
            if cached is not None:
                self.usage.cache_hits += 1
                return cached
            replies = self._ask(messages, n, purpose, temperature)
            self.cache.put(key, replies, {"model": self.name, "purpose": purpose, "n": n})
        return replies

    def _ask(self, messages: list[Message], n: int, purpose: str, temperature: float) -> list[str]:
        replies = self._complete(messages, n, purpose, temperature)
        if len(replies) != n:
            raise LLMError(f"{self.name} returned {len(replies)} replies where {n} were asked for")
        return replies

    def _complete(
        self, messages: list[Message], n: int, purpose: str, temperature: float
    ) -> list[str]:
        raise NotImplementedError


def model_spec(spec: str | None = None) -> tuple[str, str]:
    """``spec`` (``None``: ``$ITSKILL_LLM_MODEL``, else ``"offline"``) as ``(backend, model)``:
    ``("offline", "")`` or ``("openai", MODEL)``; :class:`UnknownModelError` for anything else.

    Commands that may not need a model (``itskill plan TASK_ID``) check the spec with it anyway, so
    a mistyped ``--llm`` is never silently ignored.
    """
    given = spec
    if spec is None:
        spec = os.environ.get(MODEL_ENV) or "offline"
    spec = spec.strip()
    if spec == "offline":
        return "offline", ""
    backend, _, model = spec.partition(":")
    if backend == "openai" and model.strip():
        return "openai", model.strip()
    # Named by where it came from: a user who typed no --llm would look for the flag's typo.
    where = f"{MODEL_ENV}={spec!r}" if given is None else repr(spec)
    raise UnknownModelError(
        f"unknown language model {where}: expected 'offline' or 'openai:MODEL' "
        "(e.g. openai:gpt-4o, or openai:llama3.1 with OPENAI_BASE_URL=http://localhost:11434/v1)"
    )


def make_client(
    spec: str | None = None,
    *,
    base_url: str | None = None,
    api_key: str | None = None,
    cache_dir: Path | None = None,
    price: tuple[float, float] | None = None,
) -> LLMClient:
    """The client named by ``spec`` (:func:`model_spec`).

    ``spec`` is ``"offline"``, ``"openai:MODEL"`` (any OpenAI-compatible endpoint: the model name is
    whatever the server calls it), or ``None`` for ``$ITSKILL_LLM_MODEL``, else ``"offline"``.
    ``base_url``/``api_key`` default to ``$OPENAI_BASE_URL``/``$OPENAI_API_KEY``; a variable set
    to the empty string counts as unset, but an empty ``base_url`` given here (``--base-url ""``)
    is refused as no URL. ``price`` is ``(USD per 1M input tokens, USD per 1M output tokens)`` and
    overrides the price table. ``cache_dir`` turns on the reply cache (a rerun replays instead of
    asking again). ``$ITSKILL_LLM_TIMEOUT`` sets the seconds a request may take (default 180).
    """
    backend, model = model_spec(spec)
    if backend == "offline" and base_url is not None:
        # Else ignored: a user who forgot --llm would think the server had answered.
        raise LLMError(
            f"a base URL ({base_url!r}) is for an openai:MODEL backend; the offline one asks no "
            "server: give --llm openai:MODEL or leave out --base-url"
        )
    if backend == "offline":
        from itskill.llm.offline import OfflineClient

        return OfflineClient(cache_dir=cache_dir)
    from itskill.llm.openai_client import OpenAIClient, RetryConfig

    retry = RetryConfig()
    timeout = os.environ.get(TIMEOUT_ENV) or None
    if timeout is not None:
        try:
            seconds = float(timeout)
        except ValueError:
            seconds = math.nan
        if not (math.isfinite(seconds) and seconds > 0):
            raise LLMError(f"{TIMEOUT_ENV}={timeout!r}: expected a number of seconds above 0")
        retry = RetryConfig(timeout_s=seconds)
    if base_url is None:
        # An empty variable is how deployment templates (`OPENAI_BASE_URL=${URL:-}`) leave it
        # unset, so it means the default; an empty flag was typed and is refused by the client.
        base_url = os.environ.get(BASE_URL_ENV) or None
    return OpenAIClient(
        model,
        base_url=base_url,
        api_key=api_key or os.environ.get(API_KEY_ENV) or None,
        cache_dir=cache_dir,
        price=price,
        retry=retry,
    )


class LazyClient:
    """The client :func:`make_client` gives for the same arguments, made at its first request.

    For a run that may not ask a model at all (a transfer method's analyzer is skipped over one
    source, or when the run's record already holds its matrix): such a run then needs no API key,
    and one that does ask fails as the client would have when made, before any training. The
    spec is checked at once, so a mistyped ``--llm`` is never silently ignored."""

    def __init__(self, spec: str | None = None, **kwargs: Any) -> None:
        model_spec(spec)
        self._spec, self._kwargs = spec, kwargs
        self._client: LLMClient | None = None

    def _made(self) -> LLMClient:
        if self._client is None:
            self._client = make_client(self._spec, **self._kwargs)
        return self._client

    @property
    def name(self) -> str:
        return self._made().name

    @property
    def offline(self) -> bool:
        return self._made().offline

    @property
    def usage(self) -> Usage:
        return Usage() if self._client is None else self._client.usage

    def complete(
        self, messages: list[Message], n: int = 1, *, purpose: str, temperature: float = 1.0
    ) -> list[str]:
        return self._made().complete(messages, n, purpose=purpose, temperature=temperature)
