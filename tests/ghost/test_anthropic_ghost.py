"""AnthropicGhost against a real local HTTP server emitting Anthropic's documented SSE events."""

from __future__ import annotations

from typing import Any

import anyio
import pytest

from host.ghost import GhostError, make_ghost
from host.ghost.anthropic_client import AnthropicGhost, split_system
from host.ghost.retry import StreamLimits, backoff_s, retrying_stream
from support.fake_anthropic import (error_event, error_response, message_end, message_start, ping, sequence,
                                    stream, text_block, thinking_block, tool_block)
from support.fake_llm import FakeLLM, Handler, replay

MESSAGES = [{"role": "system", "content": "You are CoCo."}, {"role": "user", "content": "Nod, then wave."}]
PIECES = ["Sure", "! ", "<", "head", "_act", ' action="', "nod", '"/>', "好的，", "我来", "挥手。", "<wave/>"]


def ghost(fake: FakeLLM, **kw: Any) -> AnthropicGhost:
    kw.setdefault("api_key", "test-key")
    kw.setdefault("max_retries", 0)
    kw.setdefault("stream_retries", 0)
    kw.setdefault("timeout_s", 10.0)
    return AnthropicGhost("claude-test", base_url=f"http://127.0.0.1:{fake.port}", **kw)


async def collect_until_error(g: AnthropicGhost) -> tuple[list[str], GhostError | None]:
    got: list[str] = []
    try:
        async for c in g.stream(MESSAGES):
            got.append(c)
    except GhostError as err:
        return got, err
    return got, None


@pytest.mark.parametrize("backend", ["asyncio", "trio"])
def test_text_deltas_split_across_writes(fake_llm: FakeLLM, backend: str) -> None:
    body = b"".join([message_start(), ping(), *thinking_block(0, "The user wants a nod."),
                     *text_block(1, PIECES), ping(), *message_end()])
    fake_llm.responder = replay(body, split=5)  # cuts through event names, JSON and UTF-8 alike
    got, err = anyio.run(collect_until_error, ghost(fake_llm, temperature=0.2, max_tokens=300), backend=backend)
    assert err is None and got == PIECES  # thinking, signature and ping are not text
    (req,) = fake_llm.requests
    assert req["path"] == "/v1/messages"
    h = req["headers"]  # the key travels as x-api-key (SDK 0.x/1.x) or as a bearer token (SDK 2.x)
    assert (h.get("x-api-key") == "test-key" or h.get("authorization") == "Bearer test-key") and "anthropic-version" in h
    j = req["json"]
    assert (j["model"], j["stream"], j["max_tokens"], j["temperature"]) == ("claude-test", True, 300, 0.2)
    assert j["system"] == "You are CoCo." and j["messages"] == [{"role": "user", "content": "Nod, then wave."}]


def test_429_with_retry_after_is_retried_by_the_sdk(fake_llm: FakeLLM) -> None:
    fake_llm.responder = sequence(error_response(429, "rate_limit_error", "slow down", {"retry-after": "0.01"}),
                                  replay(stream(["<wave/>"])))
    got, err = anyio.run(collect_until_error, ghost(fake_llm, max_retries=2, stream_retries=2))
    assert err is None and got == ["<wave/>"]
    assert len(fake_llm.requests) == 2


def test_429_without_retries_left_reports_status_and_retry_after(fake_llm: FakeLLM) -> None:
    fake_llm.responder = error_response(429, "rate_limit_error", "slow down", {"retry-after": "7"})
    got, err = anyio.run(collect_until_error, ghost(fake_llm, stream_retries=3))
    assert got == [] and err is not None
    assert err.status == 429 and err.retryable and "rate limited" in str(err) and "slow down" in str(err)
    assert getattr(err, "retry_after_s") == 7.0
    assert len(fake_llm.requests) == 1  # the SDK's retries were the retries: no second layer on top


def test_529_overloaded_is_retried_max_retries_times_only(fake_llm: FakeLLM) -> None:
    fake_llm.responder = error_response(529, "overloaded_error", "Overloaded", {"retry-after": "0"})
    got, err = anyio.run(collect_until_error, ghost(fake_llm, max_retries=1, stream_retries=2))
    assert err is not None and err.status == 529 and "overloaded" in str(err).lower()
    assert len(fake_llm.requests) == 2  # 1 + max_retries, not multiplied by stream_retries


def test_overloaded_error_event_before_text_is_retried(fake_llm: FakeLLM) -> None:
    failing = replay(message_start() + ping() + error_event("overloaded_error", "Overloaded"))
    fake_llm.responder = sequence(failing, replay(stream(["<nod/>"])))
    got, err = anyio.run(collect_until_error, ghost(fake_llm, stream_retries=1))
    assert err is None and got == ["<nod/>"] and len(fake_llm.requests) == 2


def test_error_event_after_text_is_not_retried(fake_llm: FakeLLM) -> None:
    body = b"".join([message_start(), *text_block(0, ["Hello", " there"])[:3], error_event("overloaded_error", "Overloaded")])
    fake_llm.responder = replay(body)
    got, err = anyio.run(collect_until_error, ghost(fake_llm, stream_retries=3))
    assert got == ["Hello", " there"]  # text already spoken is never repeated by a retry
    assert err is not None and err.retryable and "overloaded_error in the stream: Overloaded" in str(err)
    assert len(fake_llm.requests) == 1


def test_invalid_request_error_event_is_not_retried(fake_llm: FakeLLM) -> None:
    fake_llm.responder = replay(message_start() + error_event("invalid_request_error", "bad"))
    got, err = anyio.run(collect_until_error, ghost(fake_llm, stream_retries=3))
    assert err is not None and not err.retryable and len(fake_llm.requests) == 1


def test_stream_without_message_stop_is_truncation(fake_llm: FakeLLM) -> None:
    body = b"".join([message_start(), *text_block(0, ["<wave"])])
    fake_llm.responder = replay(body, chunked=False)
    got, err = anyio.run(collect_until_error, ghost(fake_llm))
    assert got == ["<wave"] and err is not None and "message_stop" in str(err)


def test_http_400_is_a_clear_error(fake_llm: FakeLLM) -> None:
    fake_llm.responder = error_response(400, "invalid_request_error", "max_tokens: field required")
    _, err = anyio.run(collect_until_error, ghost(fake_llm, max_retries=2))
    assert err is not None and err.status == 400 and not err.retryable
    assert "max_tokens: field required" in str(err) and len(fake_llm.requests) == 1


def test_first_token_timeout(fake_llm: FakeLLM) -> None:
    def respond(h: Handler, fake: FakeLLM) -> None:
        h.start_sse()
        h.write_piece(message_start() + ping())
        fake.wait_gate()  # never any text until the test is over

    fake_llm.responder = respond
    got, err = anyio.run(collect_until_error, ghost(fake_llm, first_token_s=0.3, stream_retries=2))
    assert got == [] and err is not None and "first token" in str(err) and "timeout" in str(err)
    assert len(fake_llm.requests) == 1  # the budget is spent: no retry


@pytest.mark.parametrize("backend", ["asyncio", "trio"])
def test_closing_early_closes_the_http_stream(fake_llm: FakeLLM, backend: str) -> None:
    def respond(h: Handler, fake: FakeLLM) -> None:
        h.start_sse()
        h.write_piece(b"".join([message_start(), *text_block(0, ["<wave/>"])[:2]]))
        fake.wait_gate()
        for i in range(5000):
            if not h.write_piece(text_block(0, [f" {i}"])[1]):
                return

    fake_llm.responder = respond

    async def main() -> list[str]:
        got = []
        gen = ghost(fake_llm).stream(MESSAGES)
        async for c in gen:
            got.append(c)
            break
        await gen.aclose()  # type: ignore[attr-defined]
        fake_llm.gate.set()
        assert await anyio.to_thread.run_sync(fake_llm.disconnected.wait, 10.0)
        return got

    assert anyio.run(main, backend=backend) == ["<wave/>"]


def test_tool_use_blocks_are_collected_in_order(fake_llm: FakeLLM) -> None:
    body = b"".join([message_start(), *text_block(0, ["Hello!"]),
                     *tool_block(1, "toolu_1", "run_distance", ['{"dist', 'ance": 10}']),
                     *tool_block(2, "toolu_2", "head_act", ['{"action": "shake"}']), *message_end("tool_use")])
    fake_llm.responder = replay(body, split=9)
    tools = [{"name": "run_distance", "description": "walk", "input_schema": {"type": "object", "properties": {}}}]
    g = ghost(fake_llm, tools=tools)
    got, err = anyio.run(collect_until_error, g)
    assert err is None and got == ["Hello!"] and g.last_stop_reason == "tool_use"
    assert [(c["name"], c["input"]) for c in g.last_tool_calls] == [("run_distance", {"distance": 10}),
                                                                     ("head_act", {"action": "shake"})]
    assert fake_llm.requests[0]["json"]["tools"] == tools


def test_factory_and_environment(fake_llm: FakeLLM, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ANTHROPIC_API_KEY", "from-env")
    monkeypatch.setenv("ANTHROPIC_BASE_URL", f"http://127.0.0.1:{fake_llm.port}")
    monkeypatch.delenv("GHOSTSHELL_LLM_API_KEY", raising=False)
    monkeypatch.delenv("GHOSTSHELL_LLM_BASE_URL", raising=False)
    fake_llm.responder = replay(stream(["ok"]))
    g = make_ghost("anthropic:claude-x", max_retries=0)
    assert isinstance(g, AnthropicGhost) and g.name == "anthropic:claude-x"
    assert anyio.run(g.complete, MESSAGES) == "ok"
    h = fake_llm.requests[0]["headers"]
    assert h.get("x-api-key") == "from-env" or h.get("authorization") == "Bearer from-env"
    monkeypatch.delenv("ANTHROPIC_API_KEY")
    monkeypatch.setenv("ANTHROPIC_BASE_URL", "https://api.example.com")
    with pytest.raises(GhostError, match="no API key.*ANTHROPIC_API_KEY"):
        make_ghost("anthropic:claude-x")
    with pytest.raises(GhostError, match="no model"):
        make_ghost("anthropic:")


def test_split_system_merges_roles() -> None:
    system, msgs = split_system([{"role": "system", "content": "a"}, {"role": "user", "content": "u1"},
                                 {"role": "user", "content": "u2"}, {"role": "assistant", "content": "x"}])
    assert system == "a" and msgs == [{"role": "user", "content": "u1\n\nu2"}, {"role": "assistant", "content": "x"}]
    with pytest.raises(GhostError, match="role"):
        split_system([{"role": "tool", "content": "?"}])


def test_backoff_honours_retry_after_and_grows() -> None:
    assert backoff_s(0, 3.0) == 3.0
    import random

    rng = random.Random(1)
    d = [backoff_s(n, None, rng) for n in range(6)]
    assert 0.375 <= d[0] <= 0.5 and 0.75 <= d[1] <= 1.0 and all(6.0 <= x <= 8.0 for x in d[4:])


def test_retrying_stream_on_a_virtual_clock() -> None:
    """Stream-level retry sleeps the backoff (virtual clock): two failures, then text."""
    calls: list[float] = []
    slept: list[float] = []

    def attempt() -> Any:
        async def gen() -> Any:
            calls.append(anyio.current_time())
            if len(calls) < 3:
                e = GhostError("overloaded", retryable=True)
                raise e
            yield "ok"
        return gen()

    async def fake_sleep(s: float) -> None:
        slept.append(s)

    async def main() -> list[str]:
        return [c async for c in retrying_stream(attempt, StreamLimits(stream_retries=2), name="t", sleep=fake_sleep)]

    assert anyio.run(main) == ["ok"] and len(calls) == 3 and len(slept) == 2 and slept[1] > slept[0] * 1.2 - 0.2
