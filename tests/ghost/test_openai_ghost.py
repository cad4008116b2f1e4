"""OpenAIGhost against a real local HTTP server replaying OpenAI-style SSE streams."""

from __future__ import annotations

import json
import socket
from typing import Any

import pytest

from support.fake_llm import DONE, FakeLLM, Handler, chunk, replay, sse, stream_body


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


def test_first_token_timeout_is_shared_with_anthropic(fake_llm: FakeLLM) -> None:
    def respond(h: Handler, fake: FakeLLM) -> None:
        h.start_sse()
        h.write_piece(sse(chunk("", role="assistant")))  # headers and a role chunk, then nothing
        fake.wait_gate()

    fake_llm.responder = respond
    got, err = anyio.run(collect_until_error, ghost(fake_llm, first_token_s=0.3, stream_retries=2))
    assert got == [] and err is not None and "no first token within 0.3 s" in str(err)
    assert len(fake_llm.requests) == 1  # a spent budget is not retried


def test_request_errors_are_not_retried_twice(fake_llm: FakeLLM) -> None:
    fake_llm.responder = lambda h, f: h.send_json_error(503, b'{"error": {"message": "busy"}}')
    _, err = anyio.run(collect_until_error, ghost(fake_llm, max_retries=1, stream_retries=3))
    assert err is not None and err.status == 503 and err.retryable
    assert len(fake_llm.requests) == 2  # 1 + the SDK's max_retries; stream_retries add nothing
