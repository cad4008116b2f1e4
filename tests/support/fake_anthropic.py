"""Anthropic Messages SSE events as the streaming docs list them, for the local test server.

https://docs.anthropic.com/en/api/messages-streaming: every event is
``event: NAME\\ndata: JSON\\n\\n``; a stream is message_start, per content block
content_block_start / content_block_delta* / content_block_stop, message_delta,
message_stop, with ``ping`` anywhere and ``error`` events on failure.
The server itself is :class:`support.fake_llm.FakeLLM` (any POST path).
"""

from __future__ import annotations

import json
from typing import Any

from support.fake_llm import FakeLLM, Handler, Responder


def event(name: str, data: dict[str, Any]) -> bytes:
    """One named SSE event."""
    return b"event: " + name.encode() + b"\ndata: " + json.dumps(data, ensure_ascii=False).encode() + b"\n\n"


def message_start(model: str = "claude-test") -> bytes:
    return event("message_start", {"type": "message_start", "message": {
        "id": "msg_test", "type": "message", "role": "assistant", "content": [], "model": model,
        "stop_reason": None, "stop_sequence": None, "usage": {"input_tokens": 25, "output_tokens": 1}}})


def ping() -> bytes:
    return event("ping", {"type": "ping"})


def text_block(index: int, pieces: list[str]) -> list[bytes]:
    out = [event("content_block_start", {"type": "content_block_start", "index": index,
                                         "content_block": {"type": "text", "text": ""}})]
    out += [event("content_block_delta", {"type": "content_block_delta", "index": index,
                                          "delta": {"type": "text_delta", "text": p}}) for p in pieces]
    out.append(event("content_block_stop", {"type": "content_block_stop", "index": index}))
    return out


def tool_block(index: int, tool_id: str, name: str, input_json_pieces: list[str]) -> list[bytes]:
    out = [event("content_block_start", {"type": "content_block_start", "index": index,
                                         "content_block": {"type": "tool_use", "id": tool_id, "name": name, "input": {}}})]
    out += [event("content_block_delta", {"type": "content_block_delta", "index": index,
                                          "delta": {"type": "input_json_delta", "partial_json": p}})
            for p in input_json_pieces]
    out.append(event("content_block_stop", {"type": "content_block_stop", "index": index}))
    return out


def thinking_block(index: int, thought: str) -> list[bytes]:
    return [event("content_block_start", {"type": "content_block_start", "index": index,
                                          "content_block": {"type": "thinking", "thinking": ""}}),
            event("content_block_delta", {"type": "content_block_delta", "index": index,
                                          "delta": {"type": "thinking_delta", "thinking": thought}}),
            event("content_block_delta", {"type": "content_block_delta", "index": index,
                                          "delta": {"type": "signature_delta", "signature": "sig"}}),
            event("content_block_stop", {"type": "content_block_stop", "index": index})]


def message_end(stop_reason: str = "end_turn") -> list[bytes]:
    return [event("message_delta", {"type": "message_delta", "delta": {"stop_reason": stop_reason,
                                                                      "stop_sequence": None},
                                    "usage": {"output_tokens": 15}}),
            event("message_stop", {"type": "message_stop"})]


def error_event(etype: str = "overloaded_error", message: str = "Overloaded") -> bytes:
    return event("error", {"type": "error", "error": {"type": etype, "message": message}})


def stream(pieces: list[str], *, with_ping: bool = True) -> bytes:
    """A complete well-formed text reply."""
    parts = [message_start()] + ([ping()] if with_ping else []) + text_block(0, pieces) + message_end()
    return b"".join(parts)


def error_response(status: int, etype: str, message: str, headers: dict[str, str] | None = None) -> Responder:
    """An HTTP error with Anthropic's error body (e.g. 529 overloaded_error, 429 with retry-after)."""

    def respond(h: Handler, fake: FakeLLM) -> None:
        body = json.dumps({"type": "error", "error": {"type": etype, "message": message}}).encode()
        h.send_response(status)
        h.send_header("Content-Type", "application/json")
        h.send_header("Content-Length", str(len(body)))
        for k, v in (headers or {}).items():
            h.send_header(k, v)
        h.end_headers()
        h.wfile.write(body)
        h.wfile.flush()

    return respond


def sequence(*responders: Responder) -> Responder:
    """Answer the n-th request with the n-th responder (the last one repeats)."""

    def respond(h: Handler, fake: FakeLLM) -> None:
        i = min(len(fake.requests) - 1, len(responders) - 1)
        responders[i](h, fake)

    return respond
