"""OpenAIGhost against a real local HTTP server replaying OpenAI-style SSE streams."""

from __future__ import annotations

import json
import socket
import threading
from collections.abc import Callable, Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import pytest

DONE = b"data: [DONE]\n\n"


def chunk(
    content: str | None = None,
    *,
    role: str | None = None,
    finish: str | None = None,
    reasoning: str | None = None,
    no_choices: bool = False,
) -> dict[str, Any]:
    """One ``chat.completion.chunk`` object as the API documents it."""
    delta: dict[str, Any] = {}
    if role is not None:
        delta["role"] = role
    if content is not None:
        delta["content"] = content
    if reasoning is not None:
        delta["reasoning_content"] = reasoning
    body: dict[str, Any] = {
        "id": "chatcmpl-test",
        "object": "chat.completion.chunk",
        "created": 1700000000,
        "model": "test-model",
        "system_fingerprint": "fp_test",
        "choices": []
        if no_choices
        else [{"index": 0, "delta": delta, "logprobs": None, "finish_reason": finish}],
    }
    if no_choices:
        body["usage"] = {"prompt_tokens": 5, "completion_tokens": 7, "total_tokens": 12}
    return body


def sse(obj: dict[str, Any]) -> bytes:
    """One SSE event carrying ``obj`` as JSON."""
    return b"data: " + json.dumps(obj, ensure_ascii=False).encode() + b"\n\n"


def stream_body(contents: list[str], *, reasoning: list[str] = ()) -> bytes:  # type: ignore[assignment]
    """A complete, well-formed stream: role chunk, reasoning, contents, usage, finish, [DONE]."""
    events = [sse(chunk("", role="assistant"))]
    events += [sse(chunk(None, reasoning=r)) for r in reasoning]
    events += [sse(chunk(c)) for c in contents]
    events.append(sse(chunk(None, finish="stop")))
    events.append(sse(chunk(no_choices=True)))
    events.append(DONE)
    return b"".join(events)


Responder = Callable[["Handler", "FakeLLM"], None]


class Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    server: "_Server"

    def log_message(self, format: str, *args: Any) -> None:  # quiet
        pass

    def do_POST(self) -> None:
        length = int(self.headers.get("Content-Length", "0"))
        body = json.loads(self.rfile.read(length) or b"{}")
        fake = self.server.fake
        fake.requests.append({"path": self.path, "headers": {k.lower(): v for k, v in self.headers.items()}, "json": body})
        self.connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        fake.responder(self, fake)

    # -- helpers for responders -------------------------------------------
    def start_sse(self, *, chunked: bool = True) -> None:
        self.send_response(200)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-cache")
        if chunked:
            self.send_header("Transfer-Encoding", "chunked")
        else:
            self.send_header("Connection", "close")
            self.close_connection = True
        self.end_headers()
        self.wfile.flush()

    def write_piece(self, data: bytes, *, chunked: bool = True) -> bool:
        """Write ``data`` as its own TCP write; False once the client is gone."""
        try:
            if chunked:
                self.wfile.write(b"%x\r\n%s\r\n" % (len(data), data))
            else:
                self.wfile.write(data)
            self.wfile.flush()
            return True
        except (BrokenPipeError, ConnectionResetError):
            self.server.fake.disconnected.set()
            self.close_connection = True
            return False

    def end_chunked(self) -> None:
        self.write_piece(b"")  # the zero-length terminating chunk

    def send_json_error(self, status: int, body: bytes, content_type: str = "application/json") -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)
        self.wfile.flush()


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    fake: "FakeLLM"


class FakeLLM:
    """Handle to the running server: set ``responder``, read ``requests``."""

    def __init__(self) -> None:
        self.requests: list[dict[str, Any]] = []
        self.responder: Responder = lambda h, f: h.send_json_error(500, b"{}")
        self.gate = threading.Event()
        self.gate_timed_out = False
        self.disconnected = threading.Event()
        self.httpd = _Server(("127.0.0.1", 0), Handler)
        self.httpd.fake = self
        self.port = self.httpd.server_address[1]
        self.base_url = f"http://127.0.0.1:{self.port}/v1"
        self._thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.02}, daemon=True)

    def wait_gate(self, timeout: float = 5.0) -> None:
        """Block the responder until the test opens the gate (records a timeout)."""
        if not self.gate.wait(timeout):
            self.gate_timed_out = True


@pytest.fixture
def fake_llm() -> Iterator[FakeLLM]:
    fake = FakeLLM()
    fake._thread.start()
    try:
        yield fake
    finally:
        fake.gate.set()
        fake.httpd.shutdown()
        fake.httpd.server_close()


# ---------------------------------------------------------------------------
# tests

import anyio  # noqa: E402
import openai  # noqa: E402

from host.ghost import GhostError, make_ghost  # noqa: E402
from host.ghost.openai_client import OpenAIGhost  # noqa: E402

BACKENDS = ["asyncio", "trio"]
MESSAGES = [{"role": "system", "content": "You are CoCo."}, {"role": "user", "content": "Nod, then wave."}]
CONTENTS = ["Sure", "! ", "<", "head", "_act", ' action="', "nod", '"/>', "好的，", "我来", "挥手。", "<wave/>"]


def ghost(fake: FakeLLM, **kw: Any) -> OpenAIGhost:
    kw.setdefault("api_key", "test-key")
    kw.setdefault("max_retries", 0)
    kw.setdefault("timeout_s", 10.0)
    return OpenAIGhost("test-model", base_url=fake.base_url, **kw)


async def collect(g: OpenAIGhost) -> list[str]:
    return [c async for c in g.stream(MESSAGES)]


async def collect_until_error(g: OpenAIGhost) -> tuple[list[str], GhostError | None]:
    got: list[str] = []
    try:
        async for c in g.stream(MESSAGES):
            got.append(c)
    except GhostError as err:
        return got, err
    return got, None


def replay(body: bytes, *, split: int | None = None, chunked: bool = True, end: bool = True) -> Responder:
    """A responder writing ``body`` in ``split``-byte TCP writes."""

    def respond(h: Handler, fake: FakeLLM) -> None:
        h.start_sse(chunked=chunked)
        step = split or len(body) or 1
        for i in range(0, len(body), step):
            if not h.write_piece(body[i : i + step], chunked=chunked):
                return
        if chunked and end:
            h.end_chunked()
        if not end:
            h.close_connection = True

    return respond


@pytest.mark.parametrize("backend", BACKENDS)
def test_stream_yields_content_split_across_writes(fake_llm: FakeLLM, backend: str) -> None:
    body = stream_body(CONTENTS, reasoning=["The user wants", " a nod."])
    # 7-byte writes cut through "data:" prefixes, JSON and UTF-8 characters alike
    fake_llm.responder = replay(body, split=7)
    g = ghost(fake_llm, temperature=0.3, extra_body={"enable_thinking": False}, max_tokens=256)
    got = anyio.run(collect, g, backend=backend)
    assert got == CONTENTS  # role-only, reasoning and usage chunks are skipped; no empty pieces
    (req,) = fake_llm.requests
    assert req["path"] == "/v1/chat/completions"
    assert req["headers"]["authorization"] == "Bearer test-key"
    j = req["json"]
    assert (j["model"], j["stream"], j["messages"]) == ("test-model", True, MESSAGES)
    assert (j["temperature"], j["max_tokens"], j["enable_thinking"]) == (0.3, 256, False)


def test_complete_joins_the_stream(fake_llm: FakeLLM) -> None:
    fake_llm.responder = replay(stream_body(CONTENTS))
    assert anyio.run(ghost(fake_llm).complete, MESSAGES) == "".join(CONTENTS)


@pytest.mark.parametrize("backend", BACKENDS)
def test_chunks_arrive_while_the_server_is_still_streaming(fake_llm: FakeLLM, backend: str) -> None:
    def respond(h: Handler, fake: FakeLLM) -> None:
        h.start_sse()
        h.write_piece(sse(chunk("", role="assistant")) + sse(chunk("first")))
        fake.wait_gate()  # held until the client has yielded "first"
        h.write_piece(sse(chunk(" second")) + sse(chunk(None, finish="stop")) + DONE)
        h.end_chunked()

    fake_llm.responder = respond

    async def main() -> list[str]:
        got = []
        async for c in ghost(fake_llm).stream(MESSAGES):
            got.append(c)
            fake_llm.gate.set()
        return got

    assert anyio.run(main, backend=backend) == ["first", " second"]
    assert not fake_llm.gate_timed_out, "the client buffered instead of streaming"


@pytest.mark.parametrize("backend", BACKENDS)
def test_closing_the_stream_early_closes_the_connection(fake_llm: FakeLLM, backend: str) -> None:
    def respond(h: Handler, fake: FakeLLM) -> None:
        h.start_sse()
        h.write_piece(sse(chunk("", role="assistant")) + sse(chunk("<wave/>")))
        fake.wait_gate()
        for i in range(5000):  # the client is gone: a write fails soon
            if not h.write_piece(sse(chunk(f" {i}"))):
                return

    fake_llm.responder = respond

    async def main() -> list[str]:
        got = []
        gen = ghost(fake_llm).stream(MESSAGES)
        async for c in gen:
            got.append(c)
            break
        await gen.aclose()
        fake_llm.gate.set()
        assert await anyio.to_thread.run_sync(fake_llm.disconnected.wait, 10.0)
        return got

    assert anyio.run(main, backend=backend) == ["<wave/>"]
    assert not fake_llm.gate_timed_out


def _err_body(message: str, type_: str, code: str | None) -> bytes:
    return json.dumps({"error": {"message": message, "type": type_, "param": None, "code": code}}).encode()


@pytest.mark.parametrize(
    ("status", "message", "hint", "retryable"),
    [
        (401, "Incorrect API key provided: sk-xx.", "authentication failed", False),
        (404, "The model `test-model` does not exist or you do not have access to it.", "model or endpoint not found", False),
        (429, "Rate limit reached for requests", "rate limited", True),
        (500, "The server had an error while processing your request.", "server error", True),
    ],
)
def test_http_error_status_becomes_ghost_error(
    fake_llm: FakeLLM, status: int, message: str, hint: str, retryable: bool
) -> None:
    body = _err_body(message, "invalid_request_error", "code_x")
    fake_llm.responder = lambda h, f: h.send_json_error(status, body)
    got, err = anyio.run(collect_until_error, ghost(fake_llm))
    assert got == []
    assert err is not None
    assert (err.status, err.provider_message, err.retryable) == (status, message, retryable)
    assert hint in str(err) and message in str(err) and f"HTTP {status}" in str(err)
    assert fake_llm.base_url in str(err)
    assert len(fake_llm.requests) == 1  # max_retries=0: no retry


def test_non_json_error_body_is_reported_verbatim(fake_llm: FakeLLM) -> None:
    fake_llm.responder = lambda h, f: h.send_json_error(502, b"upstream exploded", "text/plain")
    _, err = anyio.run(collect_until_error, ghost(fake_llm))
    assert err is not None and err.status == 502 and "upstream exploded" in str(err)


def test_connection_refused_is_a_clear_error() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    g = OpenAIGhost("m", base_url=f"http://127.0.0.1:{port}/v1", api_key="k", max_retries=0)
    _, err = anyio.run(collect_until_error, g)
    assert err is not None and err.retryable and err.status is None
    assert "cannot reach the server" in str(err) and str(port) in str(err)


def test_stream_cut_mid_chunk_yields_partial_text_then_error(fake_llm: FakeLLM) -> None:
    body = stream_body(["<head", "_act/>", "never"])
    cut = body.index(b"never") - 10
    fake_llm.responder = replay(body[:cut], end=False)  # chunked body without its terminator
    got, err = anyio.run(collect_until_error, ghost(fake_llm))
    assert got == ["<head", "_act/>"]
    assert err is not None and "cannot reach the server" in str(err)


def test_stream_closed_without_finish_reason_is_truncation(fake_llm: FakeLLM) -> None:
    body = sse(chunk("", role="assistant")) + sse(chunk("<wave")) + sse(chunk("/>"))
    fake_llm.responder = replay(body, chunked=False)  # EOF-delimited body, no finish, no [DONE]
    got, err = anyio.run(collect_until_error, ghost(fake_llm))
    assert got == ["<wave", "/>"]
    assert err is not None and "truncated" in str(err)


def test_error_event_inside_the_stream(fake_llm: FakeLLM) -> None:
    body = sse(chunk("", role="assistant")) + sse(chunk("<nod")) + sse({"error": {"message": "Overloaded", "type": "server_error"}})
    fake_llm.responder = replay(body)
    got, err = anyio.run(collect_until_error, ghost(fake_llm))
    assert got == ["<nod"]
    assert err is not None and "Overloaded" in str(err) and err.provider_message == "Overloaded"


def test_malformed_event_data_is_a_ghost_error(fake_llm: FakeLLM) -> None:
    fake_llm.responder = replay(sse(chunk("ok")) + b"data: {not json\n\n")
    got, err = anyio.run(collect_until_error, ghost(fake_llm))
    assert got == ["ok"]
    assert err is not None and "malformed" in str(err)


def test_settings_from_environment(fake_llm: FakeLLM, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OPENAI_BASE_URL", "http://127.0.0.1:1/unused")
    monkeypatch.setenv("OPENAI_API_KEY", "from-openai-env")
    monkeypatch.setenv("GHOSTSHELL_LLM_BASE_URL", fake_llm.base_url)
    monkeypatch.setenv("GHOSTSHELL_LLM_API_KEY", "from-ghostshell-env")
    monkeypatch.setenv("GHOSTSHELL_LLM_MODEL", "env-model")
    fake_llm.responder = replay(stream_body(["hi"]))
    g = make_ghost("openai", max_retries=0)
    assert isinstance(g, OpenAIGhost) and g.name == "openai:env-model"
    assert anyio.run(g.complete, MESSAGES) == "hi"
    req = fake_llm.requests[0]
    assert req["headers"]["authorization"] == "Bearer from-ghostshell-env"
    assert req["json"]["model"] == "env-model"


def test_missing_key_is_an_error_except_for_local_servers(monkeypatch: pytest.MonkeyPatch) -> None:
    for var in ("OPENAI_API_KEY", "GHOSTSHELL_LLM_API_KEY", "OPENAI_BASE_URL", "GHOSTSHELL_LLM_BASE_URL"):
        monkeypatch.delenv(var, raising=False)
    with pytest.raises(GhostError, match="no API key.*OPENAI_API_KEY"):
        OpenAIGhost("gpt-4o-mini")
    assert OpenAIGhost("llama", base_url="http://localhost:8080/v1").base_url == "http://localhost:8080/v1"


def test_sdk_version_supports_streaming() -> None:
    assert hasattr(openai, "AsyncOpenAI")
