"""A local OpenAI-compatible chat server for tests: scripted replies, errors and usage.

    with FakeOpenAIServer(["first reply", Status(429), "second"]) as server:
        client = OpenAIClient("fake-model", base_url=server.base_url)

Each choice of a request takes the next scripted item: a string is a reply text; a
:class:`Status` makes the whole request fail with that HTTP status; a :class:`Truncated` reply
cuts the whole response body short; a callable gets the request body (a dict) and returns one of
those. When the script runs out, the last string is repeated.
``n_mode`` says what the server does with ``n``: ``"support"`` (n choices), ``"reject"`` (400 for
n > 1, like some local servers), ``"ignore"`` (one choice, like Ollama and llama.cpp) or
``"empty"`` (no choices at all, as some proxies answer a filtered request). ``answer`` other than
``"chat"`` makes it a server that is not OpenAI-compatible: ``"html"`` (a web page) or
``"empty-object"`` (``{}``), both with status 200.
Usage is counted as words: prompt tokens = words in the messages, completion tokens = words in
the replies. ``requests`` records every request body, failed ones included.

Other test packages reuse it: ``sys.path.insert(0, str(Path(__file__).parents[1] / "llm"))``,
then ``from fake_openai import FakeOpenAIServer, Status``.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, Literal


@dataclass(frozen=True)
class Status:
    """A scripted HTTP error; ``param`` is the request field it blames, as OpenAI names it, and
    ``error_code`` OpenAI's code for the error (``insufficient_quota``, ...)."""

    code: int
    message: str = "scripted error"
    param: str | None = None
    error_code: str | None = None


@dataclass(frozen=True)
class Truncated:
    """A reply ``text`` whose response body is cut off, sent with status 200 and a Content-Length
    that fits the part sent, as a proxy passes on an upstream that dropped mid-reply: just after
    the first byte of the first non-ASCII character of ``text``, else halfway."""

    text: str = "a reply cut off"


Reply = str | Status | Truncated
Item = Reply | Callable[[dict], Reply]


def words(text: str) -> int:
    return len(text.split())


def cut_off(payload: dict) -> bytes:
    """``payload`` as UTF-8 JSON (non-ASCII text unescaped, as vLLM sends it), cut as
    :class:`Truncated` says."""
    data = json.dumps(payload, ensure_ascii=False).encode()
    wide = next((i for i, byte in enumerate(data) if byte >= 0x80), None)
    return data[: len(data) // 2 if wide is None else wide + 1]


class FakeOpenAIServer:
    """``/v1/chat/completions`` on 127.0.0.1 with a free port, in a background thread."""

    def __init__(
        self,
        replies: list[Item],
        *,
        n_mode: Literal["support", "reject", "ignore", "empty"] = "support",
        model: str = "fake-model",
        answer: Literal["chat", "html", "empty-object"] = "chat",
    ) -> None:
        self.script = list(replies)
        self.n_mode = n_mode
        self.answer = answer
        self.model = model
        self.requests: list[dict[str, Any]] = []
        self._last = "ok"
        self._lock = threading.Lock()
        self._server = ThreadingHTTPServer(("127.0.0.1", 0), self._handler())
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self._server.server_address[1]}/v1"

    def __enter__(self) -> FakeOpenAIServer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._server.shutdown()
        self._server.server_close()
        self._thread.join()

    def _next(self, body: dict) -> Reply:
        item: Item = self.script.pop(0) if self.script else self._last
        if callable(item) and not isinstance(item, Status):
            item = item(body)
        if isinstance(item, str):
            self._last = item
        return item

    def respond(self, body: dict) -> tuple[int, dict | bytes, dict[str, str]]:
        """(status, JSON body, headers) for one request body; a body already in bytes is sent as
        it is (a cut-off one)."""
        with self._lock:
            self.requests.append(body)
            n = int(body.get("n", 1) or 1)
            if n > 1 and self.n_mode == "reject":
                error = {"message": "n > 1 is not supported", "type": "invalid_request_error"}
                return 400, {"error": error}, {}
            count = {"ignore": 1, "empty": 0}.get(self.n_mode, n)
            texts = []
            cut = False
            for _ in range(count):
                item = self._next(body)
                if isinstance(item, Status):
                    headers = {"retry-after": "0"} if item.code == 429 else {}
                    error = {"message": item.message, "param": item.param, "code": item.error_code}
                    return item.code, {"error": error}, headers
                if isinstance(item, Truncated):
                    cut, item = True, item.text
                texts.append(item)
        prompt = sum(words(m.get("content", "")) for m in body.get("messages", []))
        completion = sum(words(t) for t in texts)
        payload = {
            "id": f"chatcmpl-{len(self.requests)}",
            "object": "chat.completion",
            "created": 0,
            "model": body.get("model", self.model),
            "choices": [
                {
                    "index": k,
                    "message": {"role": "assistant", "content": text},
                    "finish_reason": "stop",
                }
                for k, text in enumerate(texts)
            ],
            "usage": {
                "prompt_tokens": prompt,
                "completion_tokens": completion,
                "total_tokens": prompt + completion,
            },
        }
        return 200, cut_off(payload) if cut else payload, {}

    def _handler(self) -> type[BaseHTTPRequestHandler]:
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                length = int(self.headers.get("content-length", 0))
                body = json.loads(self.rfile.read(length) or b"{}")
                if self.path.rstrip("/") != "/v1/chat/completions":
                    status, payload, headers = 404, {"error": {"message": "not found"}}, {}
                else:
                    status, payload, headers = server.respond(body)
                content_type = "application/json"
                if server.answer == "html":
                    data, content_type = b"<html><body>It works!</body></html>", "text/html"
                elif server.answer == "empty-object":
                    data = b"{}"
                elif isinstance(payload, bytes):
                    data = payload
                else:
                    data = json.dumps(payload).encode()
                self.send_response(status)
                self.send_header("content-type", content_type)
                self.send_header("content-length", str(len(data)))
                for key, value in headers.items():
                    self.send_header(key, value)
                self.end_headers()
                self.wfile.write(data)

            def log_message(self, *args: object) -> None:  # keep test output clean
                pass

        return Handler
