"""A real local HTTP server speaking OpenAI's chat-completions SSE stream format (for tests).

It listens on 127.0.0.1 on an ephemeral port; a test sets ``responder`` to
decide what each POST gets (``replay(stream_body([...]))`` for a normal stream).
"""

from __future__ import annotations

import json
import socket
import sys
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

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A client that hangs up (the tests cancel streams on purpose) is not an error worth a traceback
        on the suite's stderr; anything else is reported as socketserver does."""
        if isinstance(sys.exc_info()[1], ConnectionError):
            return
        super().handle_error(request, client_address)


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
