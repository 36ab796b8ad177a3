"""A client for any OpenAI-compatible chat endpoint: OpenAI, vLLM, Ollama, a llama.cpp server.

Built on the ``openai`` SDK with its own retries turned off, because the policy here is ours
(and both at once would multiply the waits): exponential back-off with jitter on rate limits
(429, honouring ``Retry-After``), timeouts (408 and the client's own), lock conflicts (409),
connection errors, 5xx replies and replies whose JSON is cut off, then an
:class:`LLMUnavailableError` that says what to do. A
refused connection is the exception: it is asked again once, shortly, then reported as a server
that is not running. ``n`` samples are asked for in one request; a
server that rejects ``n`` (its error names it) or returns fewer choices (Ollama ignores it) gets
the missing ones as repeated single-sample requests, and is remembered as such so later requests
go straight to repeated calls. Any other rejected request is an error as it stands.
"""

from __future__ import annotations

import ipaddress
import json
import random
import re
import time
from dataclasses import dataclass
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import openai

from itskill.datafile import DataFileError, check_nonnegative, check_table, read_toml
from itskill.llm.client import (
    BASE_URL_ENV,
    TIMEOUT_ENV,
    BaseClient,
    LLMError,
    LLMUnavailableError,
    Message,
)

OPENAI_URL = "https://api.openai.com/v1"
OFFLINE = 'the offline backend (--llm offline, or llm = "offline" in an experiment file)'
"""How every unavailable-model message ends: ``experiment run`` has no ``--llm``, its file does."""
LOCAL_DUMMY_KEY = "sk-no-key-needed"
"""Sent to a custom endpoint when no key is set: the SDK insists on one, Ollama ignores it."""
RETRY_STATUSES = frozenset({408, 409, 429})
"""Statuses below 500 asked again, as the SDK's own policy does: a request timeout, a lock
timeout, a rate limit."""
CUT_OFF = (json.JSONDecodeError, UnicodeDecodeError)
"""What the SDK lets through unwrapped for a 200 reply whose body is not whole JSON: a proxy
passing on an upstream that dropped mid-reply, with a Content-Length that fits what it sent (cut
inside a multi-byte character, the bytes do not even decode). A body shorter than its
Content-Length is an ``APIConnectionError``, retried already."""
_ABOUT_N = re.compile(
    r"""
    (?i:(?<!character\ )(?<!char\ )(?<!token\ )(?<!letter\ )(?<!symbol\ )(?<!literal\ )
        (?<!token:\ )(?<!character:\ )(?<!found\ )(?<!character\ \())
    [`'"]n[`'"](?!\s*:\s*\d)  # named: 'n' (OpenAI, Groq), `n`, a validation error's ('body', 'n');
    (?i:(?!\s*\(code)(?!\s+is\ an\ invalid\ start)(?!\s+is\ not\ valid\ JSON))
                              # not a JSON parser's unexpected token 'n' (V8, Jackson, .NET),
                              # nor the 'n': 2 of an echoed request body...
    | [`'"]n[`'"]\s*:\s*\d+\s+(?:is|are)\s+not\b  # ...unless refused there
    | (?i:parameters?|params?|arguments?)(?:[ \t]+supplied)?[ \t]*:[ \t]*
      (?:[{\[][^}\]\n]{0,200}?[`'"]n[`'"][ \t]*:|(?:[`'"]|(?<![\w-]))n\b(?!-))
                              # LiteLLM: does not support parameters: {'n': 2} (n anywhere
                              # in the braces); Unrecognized request argument supplied: n
    | (?i:\b(?:invalid|unsupported)[ \t]+(?:value[ \t]+for[ \t]+)?)n\b  # invalid n: 2
    | (?i:choices)[ \t]*\(n\)  # Number of choices (n) must be 1
    | (?<![\w\\-])n(?:      # the word n, not the n of an escaped newline (\nn samples)
        \s*(?:[<>!]=?|==?)\s*\d  # bounded: n > 1 is not supported, only n=1, got n=2
        | \s+(?:must|should|cannot|can\ only|is\ not|isn't)\b  # vLLM: n must be at least 1
        | \s+(?:parameter|field|argument)\b
      )
    | \b(?:parameter|field|argument):?\s+n\b
    | (?:^|\s-\s|->\s?|\.)n(?::\s|$)  # a validation error's field: n on its line (pydantic),
                                     # body -> n, body.n: ...
    | completion\ choice        # llama.cpp: Only one completion choice is allowed
    """,
    re.VERBOSE | re.MULTILINE,
)
"""A refusal that names the ``n`` parameter, or the choices it counts. Only as a parameter: a
prompt the error echoes ("n samples each", a line after an escaped newline) does not count."""


@dataclass(frozen=True)
class RetryConfig:
    """How hard to try before giving up on an endpoint.

    A request is attempted ``1 + max_retries`` times; the wait before retry ``k`` (0-based) is
    ``min(backoff_max_s, backoff_initial_s * 2**k)`` scaled by a random factor in [0.5, 1.5) so
    that parallel workers do not retry in lock-step.

    A refused connection gets at most ``refused_retries`` of those retries, each after the first,
    shortest wait: the host answered that nothing listens on the port, which a server that is not
    running (a local Ollama or vLLM not started, a wrong port) keeps answering for far longer than
    the back-off waits, while one restarting that instant is back within a second.
    """

    max_retries: int = 5
    refused_retries: int = 1
    timeout_retries: int = 1
    """A request that timed out is asked again once: each try starts its whole generation (K
    samples) again, which a slow server does not finish sooner and a provider bills."""
    backoff_initial_s: float = 1.0
    backoff_max_s: float = 30.0
    timeout_s: float = 180.0


class PriceFileError(DataFileError):
    """A ``prices.toml`` that does not validate: names the file, the model and the problem."""


def prices_path() -> Path:
    """The packaged ``prices.toml``: USD per 1M tokens of each OpenAI model."""
    return Path(str(resources.files("itskill.llm") / "prices.toml"))


@cache
def load_prices(path: Path | None = None) -> dict[str, tuple[float, float]]:
    """Model -> (USD per 1M input tokens, USD per 1M output tokens) from ``prices.toml``
    (default :func:`prices_path`); :class:`PriceFileError` names an entry that is not a pair of
    finite numbers >= 0, or a key that would be ignored."""
    source = path or prices_path()
    data = read_toml(source, PriceFileError)
    for key in data:
        if key != "models":
            raise PriceFileError(source, key, 'unknown key; prices go in [models."NAME"] tables')
    models = check_table(source, "models", data.get("models", {}), PriceFileError)
    prices: dict[str, tuple[float, float]] = {}
    for model, entry in models.items():
        where = f"models.{model}"
        check_table(source, where, entry, PriceFileError, ("input", "output"))
        # A cost is summed into every usage report: NaN or a negative price would make it
        # meaningless, and a string one would fail only once a model answered.
        input_price, output_price = (
            check_nonnegative(
                source, f"{where}.{key}", entry.get(key), PriceFileError, unit="USD per 1M tokens"
            )
            for key in ("input", "output")
        )
        prices[model] = (input_price, output_price)
    return prices


def model_price(model: str) -> tuple[float, float]:
    """The price of ``model`` (a dated snapshot falls back to its base name); (0, 0) if unknown."""
    prices = load_prices()
    if model in prices:
        return prices[model]
    base = re.sub(r"-\d{4}-\d{2}-\d{2}$", "", model)
    return prices.get(base, (0.0, 0.0))


_WHERE_URL = f"{BASE_URL_ENV} (or --base-url of plan and reward generate)"
"""Where a user sets the endpoint's address: learn, transfer and experiment have no flag for it."""


def _check_base_url(url: str) -> None:
    """Raise :class:`LLMUnavailableError` for an endpoint that is no http(s) URL: the SDK finds
    out only when it sends, with a traceback (a bad address) or after every retry (no scheme)."""
    if not url.strip():
        # `--base-url ""` was typed, not inherited: using OpenAI's endpoint instead would send the
        # prompts somewhere the user did not ask for (and a local run's key-less requests fail).
        raise LLMUnavailableError(
            "the endpoint URL is empty: give one (--base-url http://HOST[:PORT]/v1), or leave "
            f"--base-url out to use {BASE_URL_ENV}, else OpenAI's endpoint"
        )
    problem = None
    try:
        parts = urlsplit(url)
        parts.port  # noqa: B018 - parsing it is the check: ValueError for a bad port
        host = parts.hostname or ""
        if re.fullmatch(r"[\d.]+", host):
            ipaddress.ip_address(host)
        if parts.scheme not in ("http", "https") or not host:
            problem = "expected http://HOST[:PORT]/... or https://..."
    except ValueError as err:
        problem = str(err)
    if problem:
        raise LLMUnavailableError(
            f"{url!r} is not a usable endpoint URL ({problem}); check {_WHERE_URL}"
        )


class OpenAIClient(BaseClient):
    """``complete()`` against an OpenAI-compatible ``/v1/chat/completions`` endpoint."""

    offline = False

    def __init__(
        self,
        model: str,
        *,
        base_url: str | None = None,
        api_key: str | None = None,
        cache_dir: Path | None = None,
        price: tuple[float, float] | None = None,
        retry: RetryConfig | None = None,
    ) -> None:
        super().__init__(cache_dir)
        if not model:
            raise ValueError("OpenAIClient needs a model name")
        if base_url is not None:
            # First: an empty URL is no reason to ask for a key (nor to fall back to OpenAI's).
            _check_base_url(base_url)
        if api_key is None and base_url is None:
            raise LLMUnavailableError(
                f"no API key for openai:{model}: set OPENAI_API_KEY, point OPENAI_BASE_URL at a "
                "local OpenAI-compatible server (vLLM, Ollama, llama.cpp), or use " + OFFLINE
            )
        self.model = model
        self.name = f"openai:{model}"
        self.base_url = OPENAI_URL if base_url is None else base_url
        self.price = price if price is not None else model_price(model)
        self.retry = retry or RetryConfig()
        self.n_supported: bool | None = None  # unknown until the server has answered once
        self._sdk = openai.OpenAI(
            base_url=self.base_url,
            api_key=api_key or LOCAL_DUMMY_KEY,
            max_retries=0,  # the retries are _request's: the SDK's on top would multiply them
            timeout=self.retry.timeout_s,
        )

    def _complete(
        self, messages: list[Message], n: int, purpose: str, temperature: float
    ) -> list[str]:
        replies: list[str] = []
        if n > 1 and self.n_supported is not False:
            try:
                replies = self._request(messages, n, temperature)
            except (openai.BadRequestError, openai.UnprocessableEntityError) as err:
                # Any other refusal (a prompt too long, a bad temperature) would be asked again
                # sample by sample, and every later request would lose `n` for good.
                if not _about_n(err):
                    raise self._rejected(err) from err
                self.n_supported = False
            else:
                self.n_supported = len(replies) >= n
        while len(replies) < n:
            try:
                reply = self._request(messages, 1, temperature)[:1]
            except (openai.BadRequestError, openai.UnprocessableEntityError) as err:
                raise self._rejected(err) from err
            if not reply:
                # Asking again would pay for the same empty answer forever.
                raise LLMError(f"{self.name} at {self.base_url} returned no choices")
            replies += reply
        return replies[:n]

    def _rejected(self, err: openai.APIStatusError) -> LLMError:
        """The error for a request the server refused as malformed (400, 422)."""
        return LLMError(f"{self.name} at {self.base_url} rejected the request: {_detail(err)}")

    def _request(self, messages: list[Message], n: int, temperature: float) -> list[str]:
        """One chat-completion request with retries; its choices' texts."""
        kwargs: dict[str, Any] = {
            "model": self.model,
            "messages": messages,
            "temperature": temperature,
        }
        if n > 1:
            kwargs["n"] = n
        attempts = self.retry.max_retries + 1
        # Refused connections and timeouts have retry limits of their own, counted apart from
        # the rate limits and server errors that may come before them.
        limits = {"refused": self.retry.refused_retries, "timeout": self.retry.timeout_retries}
        retried = dict.fromkeys(limits, 0)
        for attempt in range(attempts):
            try:
                response = self._sdk.chat.completions.create(**kwargs)
            except openai.AuthenticationError as err:
                raise LLMUnavailableError(
                    f"{self.base_url} refused the API key for {self.name}: {_detail(err)}; "
                    "set OPENAI_API_KEY or use " + OFFLINE
                ) from err
            except openai.PermissionDeniedError as err:
                raise LLMUnavailableError(
                    f"{self.base_url} denied access to {self.name}: {_detail(err)}; "
                    "check the key's permissions or use " + OFFLINE
                ) from err
            except openai.NotFoundError as err:
                raise LLMError(
                    f"{self.base_url} does not serve model {self.model!r} (404): {_detail(err)}; "
                    "check the model name in --llm openai:MODEL"
                ) from err
            except (openai.BadRequestError, openai.UnprocessableEntityError):
                raise
            except (openai.APIConnectionError, openai.APIStatusError, *CUT_OFF) as err:
                if getattr(err, "code", None) == "insufficient_quota":
                    # Sent as a 429, like a rate limit, but no wait mends it.
                    raise LLMUnavailableError(
                        f"{self.base_url}: the account's quota is used up for {self.name}: "
                        f"{_detail(err)}; check its plan and billing, or use " + OFFLINE
                    ) from err
                retryable = not isinstance(err, openai.APIStatusError) or (
                    err.status_code in RETRY_STATUSES or err.status_code >= 500
                )
                if not retryable:
                    raise LLMError(
                        f"{self.name} at {self.base_url} failed: {_detail(err)}"
                    ) from err
                refused = _refused(err)
                # A refused connection is not transient like a rate limit or a timeout: waiting
                # the whole back-off (half a minute) only delays the news that no server runs.
                kind = (
                    "refused"
                    if refused
                    else "timeout"
                    if isinstance(err, openai.APITimeoutError)
                    else None
                )
                if attempt == attempts - 1 or (kind and retried[kind] >= limits[kind]):
                    raise _unavailable(self, err, attempt + 1) from err
                if kind:
                    retried[kind] += 1
                time.sleep(self._backoff(0 if refused else attempt, err))
                continue
            self._account(response)
            return self._texts(response)
        raise AssertionError("unreachable")  # pragma: no cover

    def _texts(self, response: Any) -> list[str]:
        """The choices' texts; a clear error for a server that is not OpenAI-compatible (the
        SDK hands back whatever came: an HTML page as a string, ``{}`` without choices)."""
        choices = getattr(response, "choices", None)
        if not isinstance(choices, list):
            got = (
                f"a text reply starting {response[:60]!r}"
                if isinstance(response, str)
                else "a reply without 'choices'"
            )
            raise LLMError(
                f"{self.base_url} did not answer like an OpenAI-compatible endpoint ({got}); "
                f"check {_WHERE_URL}: it should end in /v1"
            )
        texts = []
        for choice in choices:
            message = getattr(choice, "message", None)
            if message is None:
                # A text-completions server's choices carry "text": read as an empty reply, it
                # was cached and cost a regeneration each time.
                raise LLMError(
                    f"{self.base_url} did not answer like an OpenAI-compatible chat endpoint (a "
                    f"choice without a message); check {_WHERE_URL}: it should serve "
                    "/v1/chat/completions"
                )
            content = getattr(message, "content", None)
            if content is not None and not isinstance(content, str):
                raise LLMError(
                    f"{self.base_url} did not answer like an OpenAI-compatible endpoint (a "
                    f"choice's message content is {type(content).__name__}, not text)"
                )
            # A lone UTF-16 surrogate cannot be written to the reply cache or sent back in the
            # next request: the run stopped after the reply was paid for.
            texts.append((content or "").encode("utf-8", "replace").decode("utf-8"))
        return texts

    def _backoff(self, attempt: int, err: Exception) -> float:
        wait = min(self.retry.backoff_max_s, self.retry.backoff_initial_s * 2**attempt)
        wait *= 0.5 + random.random()
        retry_after = _retry_after(err)
        if retry_after is not None:
            wait = max(wait, min(retry_after, self.retry.backoff_max_s))
        return wait

    def _account(self, response: Any) -> None:
        self.usage.requests += 1
        usage = getattr(response, "usage", None)
        prompt, completion = (
            _count(getattr(usage, k, 0)) for k in ("prompt_tokens", "completion_tokens")
        )
        self.usage.prompt_tokens += prompt
        self.usage.completion_tokens += completion
        self.usage.cost_usd += (prompt * self.price[0] + completion * self.price[1]) / 1e6


def _count(value: Any) -> int:
    """A token count as the server sent it; 0 for one that is not a whole number."""
    return value if isinstance(value, int) and not isinstance(value, bool) and value > 0 else 0


def _about_n(err: openai.APIStatusError) -> bool:
    """Whether a refused multi-sample request was refused for its ``n``: the error's ``param``
    (OpenAI's error body names the field), else its whole message, lines and all."""
    return err.param == "n" or _ABOUT_N.search(err.message) is not None


def _detail(err: Exception) -> str:
    message = getattr(err, "message", None) or str(err)
    return " ".join(str(message).split())[:300]


def _causes(err: BaseException) -> list[BaseException]:
    """``err`` and the exceptions it was raised from, outermost first: the SDK's
    ``APIConnectionError`` says only "Connection error.", the socket error is at the end."""
    chain: list[BaseException] = []
    current: BaseException | None = err
    while current is not None and all(current is not seen for seen in chain):
        chain.append(current)
        current = current.__cause__ or current.__context__
    return chain


def _refused(err: Exception) -> bool:
    """Whether the request failed because the host refused the connection (nothing listens on
    the port). Only that: a name that does not resolve, a reset or a timeout can be a passing
    network or resolver hiccup, and they keep the full back-off."""
    return isinstance(err, openai.APIConnectionError) and any(
        isinstance(cause, ConnectionRefusedError) for cause in _causes(err)
    )


def _retry_after(err: Exception) -> float | None:
    response = getattr(err, "response", None)
    headers = getattr(response, "headers", None)
    if headers is None:
        return None
    try:
        return float(headers.get("retry-after"))
    except (TypeError, ValueError):
        return None


def _unavailable(client: OpenAIClient, err: Exception, attempts: int) -> LLMUnavailableError:
    gave_up = f"gave up after {attempts} attempt{'s' if attempts > 1 else ''}"
    if isinstance(err, openai.RateLimitError):
        what = f"rate-limited by {client.base_url}"
        advice = "try again later"
    elif isinstance(err, openai.APIStatusError):
        kind = "server error" if err.status_code >= 500 else "HTTP"
        what = f"{kind} {err.status_code} from {client.base_url}"
        advice = "try again later"
    elif isinstance(err, CUT_OFF):
        what = f"a cut-off or invalid JSON reply from {client.base_url}"
        advice = "try again later or check any proxy in between"
    elif isinstance(err, openai.APITimeoutError):
        # The server may well be up: it did not finish K samples within the limit.
        what = (
            f"no answer from {client.name} at {client.base_url} within {client.retry.timeout_s:g} s"
        )
        advice = f"the server may be slow: raise {TIMEOUT_ENV} (seconds)"
    elif _refused(err):
        return LLMUnavailableError(
            f"cannot reach {client.name} at {client.base_url}: connection refused ({gave_up}); "
            "is the server running? Start it (ollama serve, vllm serve MODEL, llama-server) or "
            f"correct the address in {_WHERE_URL}, or use " + OFFLINE
        )
    else:
        what = f"cannot reach {client.name} at {client.base_url}"
        # The address is often already set (OPENAI_BASE_URL), just to a server that is down.
        advice = "check that a server answers there (OPENAI_BASE_URL sets the address)"
    return LLMUnavailableError(f"{what}: {_reason(err)} ({gave_up}); {advice}, or use " + OFFLINE)


def _reason(err: Exception) -> str:
    """What went wrong: the SDK's message, with the socket-level cause of a connection error
    ("Name or service not known") that its "Connection error." leaves out."""
    detail = _detail(err)
    root = _causes(err)[-1]
    if isinstance(err, openai.APIConnectionError) and root is not err and str(root):
        detail += f" ({_detail(root)})"
    return detail
