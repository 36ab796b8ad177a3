"""OpenAIClient against a local OpenAI-compatible server: samples, fallbacks, retries, accounting,
errors and the reply cache; make_client's choice of backend."""

from __future__ import annotations

import json
import re
import socket
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import openai
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from fake_openai import FakeOpenAIServer, Status, Truncated, words

from itskill.llm import LLMError, LLMUnavailableError, OfflineClient, make_client, openai_client
from itskill.llm.openai_client import OpenAIClient, RetryConfig, model_price

FAST = RetryConfig(max_retries=2, backoff_initial_s=0.01, backoff_max_s=0.05, timeout_s=5.0)
MESSAGES = [
    {"role": "system", "content": "You write rewards."},
    {"role": "user", "content": "Write one for picking up the nut."},
]
PROMPT_WORDS = sum(words(m["content"]) for m in MESSAGES)


def client(server: FakeOpenAIServer, **kwargs) -> OpenAIClient:
    return OpenAIClient("fake-model", base_url=server.base_url, retry=FAST, **kwargs)


def test_n_samples_in_one_request_with_token_and_cost_accounting() -> None:
    with FakeOpenAIServer(["alpha one", "beta two three", "gamma"]) as server:
        c = client(server, price=(1.0, 2.0))
        replies = c.complete(MESSAGES, n=3, purpose="reward", temperature=0.7)
    assert replies == ["alpha one", "beta two three", "gamma"]
    assert len(server.requests) == 1
    body = server.requests[0]
    assert body["n"] == 3 and body["temperature"] == 0.7 and body["model"] == "fake-model"
    assert body["messages"] == MESSAGES
    assert c.usage.requests == 1
    assert c.usage.prompt_tokens == PROMPT_WORDS
    assert c.usage.completion_tokens == 6
    assert c.usage.cost_usd == pytest.approx((PROMPT_WORDS * 1.0 + 6 * 2.0) / 1e6)
    assert c.n_supported is True


@pytest.mark.parametrize("mode", ["reject", "ignore"])
def test_falls_back_to_repeated_calls_when_n_is_not_served(mode: str) -> None:
    with FakeOpenAIServer(["a", "b", "c", "d"], n_mode=mode) as server:
        c = client(server)
        assert c.complete(MESSAGES, n=3, purpose="plan") == ["a", "b", "c"]
        assert c.n_supported is False
        first = len(server.requests)
        # Remembered: the next request goes straight to single samples.
        assert c.complete(MESSAGES, n=1, purpose="plan") == ["d"]
    assert first == (4 if mode == "reject" else 3)
    assert all("n" not in body for body in server.requests[1:])


@pytest.mark.parametrize(
    "refusal",
    [
        Status(400, "Only one completion choice is allowed"),  # llama.cpp
        Status(400, "'n' must be 1 for this model"),
        Status(400, "Unsupported value", param="n"),
        Status(400, "'n' : number must be at most 1"),  # Groq
        Status(400, "n must be 1, got 2"),
        Status(
            400,
            "1 validation error for ChatCompletionRequest\nn\n  Input should be less than or "
            "equal to 1 [type=less_than_equal, input_value=2, input_type=int]",  # pydantic
        ),
        # LiteLLM's, and others the first review of the pattern left out.
        Status(
            400,
            "litellm.UnsupportedParamsError: anthropic does not support parameters: "
            "{'n': 2}, for model=claude-3",
        ),
        Status(400, "Unrecognized request argument supplied: n"),
        Status(400, "Invalid value for n: must be 1"),
        Status(400, "'n': 2 is not supported"),
        Status(400, "Unsupported Parameters: {'temperature': 0.2, 'n': 2}"),
        Status(400, "Number of choices (n) must be 1"),
    ],
)
def test_a_refusal_of_n_falls_back_to_single_samples(refusal: Status) -> None:
    with FakeOpenAIServer([refusal, "a", "b"]) as server:
        c = client(server)
        assert c.complete(MESSAGES, n=2, purpose="reward") == ["a", "b"]
    assert c.n_supported is False and len(server.requests) == 3


def test_a_bad_request_about_something_else_is_an_error_and_n_stays_in_use() -> None:
    # Any refusal of a multi-sample request stopped asking for n for good, and the same request
    # was sent again sample by sample only to be refused again.
    refusal = Status(400, "This model's maximum context length is 8192 tokens", param="messages")
    with FakeOpenAIServer([refusal, "a", "b"]) as server:
        c = client(server)
        with pytest.raises(LLMError, match=r"rejected the request: .*maximum context length"):
            c.complete(MESSAGES, n=2, purpose="reward")
        assert len(server.requests) == 1 and c.n_supported is not False
        assert c.complete(MESSAGES, n=2, purpose="reward") == ["a", "b"]
    assert server.requests[-1]["n"] == 2


def test_a_reply_without_choices_is_an_error_not_a_paid_loop() -> None:
    # Some proxies answer 200 with no choices (a content filter): asking again pays for nothing.
    with FakeOpenAIServer(["never sent"], n_mode="empty") as server:
        c = client(server)
        with pytest.raises(LLMError, match="returned no choices"):
            c.complete(MESSAGES, purpose="reward")
    assert len(server.requests) == 1


@pytest.mark.parametrize(
    ("answer", "got"), [("html", "a text reply starting '<html>"), ("empty-object", "without")]
)
def test_a_server_that_is_not_openai_compatible_is_a_clear_error(answer: str, got: str) -> None:
    # A --base-url pointing at a web server: it ended in AttributeError or TypeError.
    with (
        FakeOpenAIServer(["never sent"], answer=answer) as server,  # type: ignore[arg-type]
        pytest.raises(LLMError, match=f"not answer like an OpenAI-compatible.*{got}"),
    ):
        client(server).complete(MESSAGES, purpose="plan")
    assert len(server.requests) == 1  # not asked again


@pytest.mark.parametrize("status", [408, 409, 429, 500, 503])
def test_retries_rate_limits_and_server_errors_then_succeeds(status: int) -> None:
    with FakeOpenAIServer([Status(status), Status(status), "finally"]) as server:
        c = client(server)
        assert c.complete(MESSAGES, purpose="reward") == ["finally"]
    assert len(server.requests) == 3
    assert c.usage.requests == 1  # only the answered request is accounted


@pytest.mark.parametrize(
    "cut", [Truncated(), Truncated("déjà vu")], ids=["halfway", "inside-a-character"]
)
def test_a_reply_cut_off_is_asked_again(cut: Truncated) -> None:
    # A proxy's 200 reply whose JSON body ended early stopped the run with a JSONDecodeError (or
    # a UnicodeDecodeError) traceback, asked only once.
    with FakeOpenAIServer([cut, "whole"]) as server:
        c = client(server)
        assert c.complete(MESSAGES, purpose="reward") == ["whole"]
    assert len(server.requests) == 2 and c.usage.requests == 1


def test_a_reply_always_cut_off_gives_up_saying_so() -> None:
    with (
        FakeOpenAIServer([Truncated()] * 10) as server,
        pytest.raises(LLMUnavailableError) as err,
    ):
        client(server).complete(MESSAGES, purpose="reward")
    assert len(server.requests) == FAST.max_retries + 1
    message = str(err.value)
    assert f"a cut-off or invalid JSON reply from {server.base_url}: Unterminated" in message
    assert f"gave up after {FAST.max_retries + 1} attempts" in message
    assert "--llm offline" in message


def test_gives_up_after_the_last_retry_with_advice() -> None:
    with FakeOpenAIServer([Status(429)] * 10) as server:
        c = client(server)
        with pytest.raises(LLMUnavailableError) as err:
            c.complete(MESSAGES, purpose="reward")
    assert len(server.requests) == FAST.max_retries + 1
    assert "rate-limited" in str(err.value) and "--llm offline" in str(err.value)
    assert "try again later" in str(err.value) and "OPENAI_BASE_URL" not in str(err.value)


def _closed_port_url() -> str:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    return f"http://127.0.0.1:{port}/v1"


def _count_requests(c: OpenAIClient) -> list[int]:
    """A list that grows by one for each request ``c`` sends through its SDK client."""
    sent: list[int] = []
    create = c._sdk.chat.completions.create

    def counted(**kwargs):
        sent.append(1)
        return create(**kwargs)

    c._sdk.chat.completions.create = counted  # type: ignore[method-assign]
    return sent


def test_a_refused_connection_fails_fast_saying_no_server_runs_there(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # It was retried with the whole back-off (6 attempts, about 30 s at the default settings)
    # before the user heard "Connection error.". The default policy, with its waits recorded.
    waits: list[float] = []
    # Only this module's clock: the SDK and pytest keep theirs.
    monkeypatch.setattr(openai_client, "time", SimpleNamespace(sleep=waits.append))
    url = _closed_port_url()
    c = OpenAIClient("llama3", base_url=url)
    assert c._sdk.max_retries == 0  # the SDK's own retries would multiply ours
    sent = _count_requests(c)
    with pytest.raises(LLMUnavailableError) as err:
        c.complete(MESSAGES, purpose="plan")
    assert len(sent) == 2 and len(waits) == 1 and waits[0] <= 1.5
    message = str(err.value)
    assert f"cannot reach openai:llama3 at {url}: connection refused" in message
    assert "gave up after 2 attempts" in message and "is the server running?" in message
    assert "OPENAI_BASE_URL" in message and "--llm offline" in message


def test_a_refused_connection_with_no_retries_is_one_attempt() -> None:
    c = OpenAIClient("llama3", base_url=_closed_port_url(), retry=RetryConfig(max_retries=0))
    sent = _count_requests(c)
    with pytest.raises(LLMUnavailableError, match=r"gave up after 1 attempt\)"):
        c.complete(MESSAGES, purpose="plan")
    assert len(sent) == 1


def _connection_error(c: OpenAIClient, cause: BaseException | None) -> openai.APIConnectionError:
    """What the SDK of ``c`` raises when a request got no answer: a timeout, else a connection
    error (the request is built by the SDK's own HTTP client, whichever httpx it uses)."""
    request = c._sdk._client.build_request("POST", f"{c.base_url}/chat/completions")
    if cause is None:
        return openai.APITimeoutError(request=request)
    return openai.APIConnectionError(request=request)


@pytest.mark.parametrize(
    ("cause", "attempts", "said"),
    [
        (ConnectionRefusedError(111, "Connection refused"), 2, "connection refused"),
        # A name that does not resolve and a reset can pass within the back-off (a resolver or
        # network hiccup): they are asked again as before.
        (socket.gaierror(-3, "Temporary failure in name resolution"), 6, "name resolution"),
        (ConnectionResetError(104, "Connection reset by peer"), 6, "reset by peer"),
        # A timeout is asked again once: each try started the whole generation again, and six
        # paid ones ended in "cannot reach", though the server answered, slowly.
        (
            None,
            2,
            "the server may be slow: raise ITSKILL_LLM_TIMEOUT",
        ),
    ],
)
def test_only_a_refused_connection_skips_the_back_off(
    monkeypatch: pytest.MonkeyPatch, cause: BaseException | None, attempts: int, said: str
) -> None:
    monkeypatch.setattr(openai_client, "time", SimpleNamespace(sleep=lambda s: None))
    c = OpenAIClient("m", base_url="http://example.invalid/v1", api_key="x")
    sent: list[int] = []

    def create(**kwargs):
        sent.append(1)
        # As httpx chains it: the SDK's error from the transport's, from the socket's.
        try:
            try:
                raise cause or TimeoutError("timed out")
            except OSError as inner:
                raise RuntimeError(str(inner)) from inner
        except RuntimeError as transport:
            raise _connection_error(c, cause) from transport

    c._sdk.chat.completions.create = create  # type: ignore[method-assign]
    with pytest.raises(LLMUnavailableError, match=f"gave up after {attempts} attempts") as err:
        c.complete(MESSAGES, purpose="plan")
    assert len(sent) == attempts and said in str(err.value)


def test_a_used_up_quota_is_not_retried_and_says_so() -> None:
    # OpenAI sends it as a 429, like a rate limit: six attempts and half a minute of back-off
    # ended in "try again later", which no wait mends.
    used_up = Status(429, "You exceeded your current quota", error_code="insufficient_quota")
    with FakeOpenAIServer([used_up] * 3) as server:
        with pytest.raises(LLMUnavailableError) as err:
            client(server).complete(MESSAGES, purpose="plan")
        assert len(server.requests) == 1
    text = str(err.value)
    assert "quota is used up" in text and "You exceeded your current quota" in text
    assert "billing" in text and "--llm offline" in text and "try again later" not in text


def test_auth_failure_and_unknown_model_are_not_retried() -> None:
    with FakeOpenAIServer([Status(401, "bad key")]) as server:
        with pytest.raises(LLMUnavailableError, match="refused the API key"):
            client(server).complete(MESSAGES, purpose="plan")
        assert len(server.requests) == 1
    with FakeOpenAIServer([Status(404, "no such model")]) as server:
        with pytest.raises(LLMError, match="does not serve model 'fake-model'"):
            client(server).complete(MESSAGES, purpose="plan")
        assert len(server.requests) == 1


def test_cache_replays_without_a_second_request(tmp_path: Path) -> None:
    with FakeOpenAIServer(["one", "two", "three", "four"]) as server:
        first = client(server, cache_dir=tmp_path)
        a = first.complete(MESSAGES, n=2, purpose="reward")
        b = first.complete(MESSAGES, n=2, purpose="reward")  # same request again: new samples
        assert (a, b) == (["one", "two"], ["three", "four"])
        assert len(server.requests) == 2 and first.usage.cache_hits == 0
        # A rerun (a new client on the same cache) replays both, in order, for free.
        rerun = client(server, cache_dir=tmp_path)
        assert rerun.complete(MESSAGES, n=2, purpose="reward") == a
        assert rerun.complete(MESSAGES, n=2, purpose="reward") == b
        assert len(server.requests) == 2
        assert rerun.usage.cache_hits == 2 and rerun.usage.requests == 0
        assert rerun.usage.cost_usd == 0.0
    files = sorted(tmp_path.glob("*.json"))
    assert len(files) == 2
    assert all(json.loads(f.read_text())["model"] == "openai:fake-model" for f in files)


def test_clients_sharing_a_cache_ask_a_question_once_and_get_one_answer(tmp_path: Path) -> None:
    # Two experiment cells asking the analyzer the same question at once: the second waits for
    # the first's reply and replays it, so both train on one prior whatever the worker count.
    in_flight = threading.Event()

    def slow(body: dict) -> str:
        in_flight.set()
        time.sleep(0.5)
        return "first"

    with FakeOpenAIServer([slow, "second"]) as server:
        got: dict[str, list[str]] = {}

        def ask(name: str) -> None:
            got[name] = client(server, cache_dir=tmp_path).complete(MESSAGES, purpose="analyze")

        early = threading.Thread(target=ask, args=("early",))
        early.start()
        assert in_flight.wait(5.0)
        late = threading.Thread(target=ask, args=("late",))
        late.start()
        early.join(10.0)
        late.join(10.0)
        assert got == {"early": ["first"], "late": ["first"]}
        assert len(server.requests) == 1


OTHER_MESSAGES = [MESSAGES[0], {"role": "user", "content": "Write one for placing the nut."}]


@pytest.mark.parametrize(
    ("change", "fresh"),
    [
        ({"purpose": "plan"}, ["three", "four"]),
        ({"temperature": 0.5}, ["three", "four"]),
        ({"n": 1}, ["three"]),
        # An experiment's cells share one cache: another task's prompt must not get this reply.
        ({"messages": OTHER_MESSAGES}, ["three", "four"]),
        ({"model": "other-model"}, ["three", "four"]),
    ],
)
def test_cache_does_not_replay_a_request_that_differs(
    tmp_path: Path, change: dict, fresh: list[str]
) -> None:
    asked = {"n": 2, "purpose": "reward", "temperature": 1.0, "messages": MESSAGES}
    asked["model"] = "fake-model"
    other = {**asked, **change}

    def ask(server: FakeOpenAIServer, request: dict) -> list[str]:
        # A new client each time, so each request is its first occurrence: a cache key that left
        # the difference out would replay the cached replies.
        settings = {k: v for k, v in request.items() if k not in ("model", "messages")}
        c = OpenAIClient(request["model"], base_url=server.base_url, retry=FAST, cache_dir=tmp_path)
        return c.complete(request["messages"], **settings)

    with FakeOpenAIServer(["one", "two", "three", "four"]) as server:
        cached = ask(server, asked)
        assert ask(server, other) == fresh
        assert len(server.requests) == 2
        # Neither overwrote the other: a rerun replays both.
        assert ask(server, asked) == cached
        assert ask(server, other) == fresh
        assert len(server.requests) == 2
    assert len(list(tmp_path.glob("*.json"))) == 2


def test_cache_is_shared_across_endpoints_of_the_same_model(tmp_path: Path) -> None:
    with FakeOpenAIServer(["from the first server"]) as server:
        client(server, cache_dir=tmp_path).complete(MESSAGES, purpose="plan")
    with FakeOpenAIServer(["from the second server"]) as server:
        replay = client(server, cache_dir=tmp_path).complete(MESSAGES, purpose="plan")
        assert not server.requests
    assert replay == ["from the first server"]


def test_a_corrupt_cache_entry_is_asked_again(tmp_path: Path) -> None:
    with FakeOpenAIServer(["fresh", "fresh again"]) as server:
        client(server, cache_dir=tmp_path).complete(MESSAGES, purpose="plan")
        (entry,) = tmp_path.glob("*.json")
        entry.write_text("{truncated")
        assert client(server, cache_dir=tmp_path).complete(MESSAGES, purpose="plan") == [
            "fresh again"
        ]


GPT_4O = '[models."gpt-4o"]\ninput = 2.50\noutput = 10.00'


@pytest.mark.parametrize(
    ("new", "where", "problem"),
    [
        ('[models."gpt-4o"\ninput = 2.50', "TOML syntax", ""),
        ('[models."gpt-4o"]\ninput = "cheap"\noutput = 10.00', 'models.gpt-4o.input',
         "expected a finite number >= 0 (USD per 1M tokens), got 'cheap'"),
        ('[models."gpt-4o"]\ninput = -5\noutput = 10.00', "models.gpt-4o.input", "got -5"),
        ('[models."gpt-4o"]\ninput = 2.50\noutput = nan', "models.gpt-4o.output", "got nan"),
        ('[models."gpt-4o"]\ninput = 2.50', "models.gpt-4o.output", "got None"),
        ('[models."gpt-4o"]\ninput = 2.50\noutput = 10.00\ncached = 1.25',
         "models.gpt-4o.cached", "unknown field"),
        ('[model."gpt-4o"]\ninput = 2.50\noutput = 10.00', "model", "unknown key"),
    ],
)  # fmt: skip
def test_a_damaged_price_file_is_named_not_a_traceback(
    tmp_path: Path, new: str, where: str, problem: str
) -> None:
    # A syntax error and input = "cheap" were tracebacks; input = -5 and output = nan accepted.
    from itskill.datafile import DataFileError

    text = openai_client.prices_path().read_text(encoding="utf-8")
    assert GPT_4O in text
    path = tmp_path / "prices.toml"
    path.write_text(text.replace(GPT_4O, new, 1), encoding="utf-8")
    with pytest.raises(openai_client.PriceFileError) as err:
        openai_client.load_prices(path)
    assert isinstance(err.value, DataFileError)  # reported by the CLI as a user error
    assert str(err.value).startswith(f"{path}: {where}:") and problem in str(err.value)


def test_a_damaged_price_file_stops_a_client_before_it_is_used(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "prices.toml"
    path.write_text('[models."gpt-4o"]\ninput = 2.50\noutput = nan\n')
    monkeypatch.setattr(openai_client, "prices_path", lambda: path)
    openai_client.load_prices.cache_clear()
    try:
        with pytest.raises(openai_client.PriceFileError, match=r"models\.gpt-4o\.output"):
            model_price("gpt-4o")
    finally:
        openai_client.load_prices.cache_clear()


def test_price_table_and_unknown_models() -> None:
    assert model_price("gpt-4o") == (2.5, 10.0)
    assert model_price("gpt-4o-2024-08-06") == (2.5, 10.0)
    assert model_price("llama3.1:8b") == (0.0, 0.0)
    with FakeOpenAIServer(["a b c"]) as server:
        c = OpenAIClient("llama3.1:8b", base_url=server.base_url, retry=FAST)
        c.complete(MESSAGES, purpose="plan")
    assert c.usage.completion_tokens == 3 and c.usage.cost_usd == 0.0


def test_make_client_picks_the_backend(monkeypatch: pytest.MonkeyPatch) -> None:
    for var in ("ITSKILL_LLM_MODEL", "OPENAI_BASE_URL", "OPENAI_API_KEY"):
        monkeypatch.delenv(var, raising=False)
    default = make_client()
    assert isinstance(default, OfflineClient) and default.offline and default.name == "offline"
    with pytest.raises(LLMUnavailableError, match="OPENAI_API_KEY"):
        make_client("openai:gpt-4o")  # no key and no local endpoint
    with pytest.raises(ValueError, match="expected 'offline' or 'openai:MODEL'"):
        make_client("anthropic:claude")
    with FakeOpenAIServer(["hello"]) as server:
        # A local key-less server (Ollama) works: a dummy key is sent.
        monkeypatch.setenv("ITSKILL_LLM_MODEL", "openai:llama3")
        monkeypatch.setenv("OPENAI_BASE_URL", server.base_url)
        c = make_client()
        assert c.name == "openai:llama3" and not c.offline
        assert c.complete(MESSAGES, purpose="plan") == ["hello"]


def test_a_bad_model_variable_is_named_and_a_base_url_needs_an_openai_backend(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The variable's typo was reported as the flag's, which the user had not typed.
    monkeypatch.setenv("ITSKILL_LLM_MODEL", "gpt-4o")
    with pytest.raises(ValueError, match="unknown language model ITSKILL_LLM_MODEL='gpt-4o'"):
        make_client()
    with pytest.raises(ValueError, match="unknown language model 'gpt-4o'"):
        make_client("gpt-4o")
    # A --base-url beside the offline backend was ignored: the plan came from the rules.
    monkeypatch.delenv("ITSKILL_LLM_MODEL")
    with pytest.raises(LLMError, match="offline one asks no server"):
        make_client(base_url="http://localhost:9/v1")
    monkeypatch.setenv("OPENAI_BASE_URL", "http://localhost:9/v1")  # set for other tools: fine
    assert make_client().offline


@pytest.mark.parametrize(
    ("kwargs", "problem"),
    [
        ({"purpose": "chat"}, "unknown purpose"),
        ({"purpose": "plan", "n": 0}, "n must be a positive integer"),
        ({"purpose": "plan", "temperature": 3.0}, "temperature"),
    ],
)
def test_bad_requests_are_refused_before_sending(kwargs: dict, problem: str) -> None:
    with FakeOpenAIServer(["x"]) as server:
        with pytest.raises(ValueError, match=problem):
            client(server).complete(MESSAGES, **kwargs)
        with pytest.raises(ValueError, match="role"):
            client(server).complete([{"role": "robot", "content": "x"}], purpose="plan")
        assert not server.requests


@pytest.mark.parametrize(
    ("url", "problem"),
    [
        ("http://256.1.1.1/v1", "does not appear to be an IPv4 or IPv6 address"),
        ("http://[::1/v1", "Invalid IPv6 URL"),
        ("http://localhost:99999/v1", "Port out of range"),
        ("localhost:8000/v1", "expected http://HOST"),
    ],
)
def test_an_endpoint_that_is_no_url_is_refused_before_any_request(url: str, problem: str) -> None:
    # The SDK found these out only when sending: a traceback (a bad address), or after every
    # retry, half a minute later (no scheme).
    with pytest.raises(LLMUnavailableError, match=re.escape(problem)):
        OpenAIClient("m", base_url=url, api_key="x")


def test_an_empty_base_url_is_refused_not_replaced_by_another(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # `--base-url ""` fell back to $OPENAI_BASE_URL, else to OpenAI's endpoint (with a key, the
    # prompts went there; without one, the error asked for a key): never the URL typed.
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    empty = "the endpoint URL is empty: give one (--base-url http://HOST[:PORT]/v1)"
    for key in (None, "sk-x"):
        with pytest.raises(LLMUnavailableError, match=re.escape(empty)):
            OpenAIClient("m", base_url="", api_key=key)
        with pytest.raises(LLMUnavailableError, match=re.escape(empty)):
            OpenAIClient("m", base_url="  ", api_key=key)
    with FakeOpenAIServer(["never sent"]) as server:
        monkeypatch.setenv("OPENAI_BASE_URL", server.base_url)
        with pytest.raises(LLMUnavailableError, match=re.escape(empty)):
            make_client("openai:m", base_url="")
        assert not server.requests


def test_an_empty_base_url_variable_counts_as_unset(monkeypatch: pytest.MonkeyPatch) -> None:
    # `OPENAI_BASE_URL=${URL:-}` in a compose file or CI template: the default, as if unset.
    monkeypatch.setenv("OPENAI_BASE_URL", "")
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    with pytest.raises(LLMUnavailableError, match="no API key for openai:m"):
        make_client("openai:m")
    monkeypatch.setenv("OPENAI_API_KEY", "sk-x")
    assert make_client("openai:m").base_url == "https://api.openai.com/v1"  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    "args",
    [
        ["plan", "Pick up the nut and lift it"],
        ["reward", "generate", "Pick up the nut and lift it"],
    ],
)
def test_the_commands_refuse_an_empty_base_url(
    args: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from typer.testing import CliRunner

    from itskill.cli import app

    monkeypatch.chdir(tmp_path)  # where `reward generate` would put its run
    monkeypatch.setenv("OPENAI_API_KEY", "sk-x")  # with a key it went to OpenAI's endpoint
    result = CliRunner().invoke(app, [*args, "--llm", "openai:m", "--base-url", ""])
    assert result.exit_code == 2, result.output
    assert "error: the endpoint URL is empty" in " ".join(result.output.split())
    assert not list(tmp_path.iterdir())  # no run left behind to be refused or resumed


def test_a_reply_with_a_lone_surrogate_is_cached_and_replayed(tmp_path: Path) -> None:
    # It could not be written to the cache (UTF-8) or sent back in the next request, and the
    # run stopped with a traceback after the reply had been paid for.
    with FakeOpenAIServer(["code \ud800 here"]) as server:
        first = client(server, cache_dir=tmp_path).complete(MESSAGES, n=1, purpose="reward")
    assert first == ["code ? here"]
    assert client(server, cache_dir=tmp_path).complete(MESSAGES, n=1, purpose="reward") == first


@pytest.mark.parametrize(
    "message",
    [
        "Input should be a valid string [input_value='write three rewards\\n']",
        "Input should be a valid string [input_value='write three rewards\\nn samples each']",
        'Invalid prompt "n samples of the reward, one per line"',
        # A check of the whole request (a pydantic model validator) echoes it, "n" among its keys.
        "Value error, tools need tool_choice [input_value={'model': 'm', 'n': 2, 'messages': []}]",
        "Input is invalid\nn samples each were asked",  # a real newline after "invalid"
        "Unknown parameters: {'temperature': 2, 'top_n': 3}",
        "Invalid params: n-gram penalty must be positive",
        "Bad request: see the prompt's figure (n)",
        "Unexpected token 'n' at line 1 column 2 of the JSON body",
        "Invalid character 'n' in the request at position 14",
        "Unexpected token: 'n' at position 2",
        "Expected a value but found 'n'",
        "Unexpected character ('n' (code 110)): expected a valid value",
        "'n' is an invalid start of a value. Path: $ | LineNumber: 0",
        "Unexpected token 'n', \"n\" is not valid JSON",
    ],
    ids=[
        "escaped-newline",
        "prompt-line-after-it",
        "quoted-prompt",
        "echoed-request",
        "newline-after-invalid",
        "another-parameter-ending-in-n",
        "n-gram",
        "figure-n",
        "json-token",
        "json-character",
        "json-token-colon",
        "json-found",
        "jackson",
        "dotnet",
        "v8",
    ],
)
def test_a_refusal_echoing_the_prompt_or_request_is_not_about_n(message: str) -> None:
    # The echoed prompt's "\n", or a prompt line "n samples ...", read as the parameter n: n was
    # dropped for good, every later request of K samples cost K prompts, and this one was asked
    # again sample by sample only to be refused again.
    with FakeOpenAIServer([Status(400, message)]) as server:
        c = client(server)
        with pytest.raises(LLMError, match="rejected the request"):
            c.complete(MESSAGES, n=2, purpose="reward")
    assert c.n_supported is not False and len(server.requests) == 1


def test_choices_and_usage_that_are_not_openais_shape_are_named_or_not_counted() -> None:
    c = OpenAIClient("fake-model", base_url="http://127.0.0.1:9/v1", retry=FAST)
    reply = SimpleNamespace(choices=[SimpleNamespace(message=SimpleNamespace(content=["x"]))])
    with pytest.raises(LLMError, match="content is list, not text"):
        c._texts(reply)
    with pytest.raises(LLMError, match="a choice without a message"):
        c._texts(SimpleNamespace(choices=[SimpleNamespace(text="hello")]))
    c._account(SimpleNamespace(usage=SimpleNamespace(prompt_tokens="n/a", completion_tokens=7)))
    assert c.usage.prompt_tokens == 0 and c.usage.completion_tokens == 7


def test_the_request_timeout_is_set_by_its_environment_variable(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from itskill.llm.client import TIMEOUT_ENV, make_client

    monkeypatch.setenv(TIMEOUT_ENV, "600")
    slow = make_client("openai:m", base_url="http://example.invalid/v1", api_key="x")
    assert slow.retry.timeout_s == 600.0
    for bad in ("0", "-5", "inf", "soon"):
        monkeypatch.setenv(TIMEOUT_ENV, bad)
        with pytest.raises(LLMError, match=f"{TIMEOUT_ENV}='{bad}': expected a number of seconds"):
            make_client("openai:m", base_url="http://example.invalid/v1", api_key="x")


def test_a_timeout_after_another_failure_still_gets_its_retry(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The timeout's limit was compared with the attempt count: after a reset, the first timeout
    # ended the request at once, though a timed-out request is asked once more.
    monkeypatch.setattr(openai_client, "time", SimpleNamespace(sleep=lambda s: None))
    c = OpenAIClient("m", base_url="http://example.invalid/v1", api_key="x")
    causes = [ConnectionResetError(104, "Connection reset by peer"), None, None]
    sent: list[int] = []

    def create(**kwargs):
        cause = causes[len(sent)]
        sent.append(1)
        raise _connection_error(c, cause)

    c._sdk.chat.completions.create = create  # type: ignore[method-assign]
    with pytest.raises(LLMUnavailableError, match="gave up after 3 attempts") as err:
        c.complete(MESSAGES, purpose="plan")
    assert len(sent) == 3 and "the server may be slow" in str(err.value)
