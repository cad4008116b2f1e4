"""``AnthropicGhost``: Anthropic Messages streaming through the official ``anthropic`` SDK.

Events (https://docs.anthropic.com/en/api/messages-streaming): ``message_start``,
``content_block_start``, ``content_block_delta`` (``text_delta`` is yielded;
``thinking_delta``, ``signature_delta`` and ``input_json_delta`` are not text),
``content_block_stop``, ``message_delta`` (carries ``stop_reason``),
``message_stop``, ``ping``, and ``error`` (e.g. ``overloaded_error`` mid-stream).

Settings: ``api_key`` argument, else ``GHOSTSHELL_LLM_API_KEY``, else
``ANTHROPIC_API_KEY``; ``base_url`` argument, else ``GHOSTSHELL_LLM_BASE_URL``,
else ``ANTHROPIC_BASE_URL``, else the SDK's default. Request-level retries
(429/5xx/529 and connection errors, honouring ``retry-after``) are the SDK's
(``max_retries``); stream-level retries and the first-token / overall timeouts
are :mod:`host.ghost.retry`'s. Every SDK failure becomes a :class:`GhostError`.

With ``tools`` the request carries Anthropic tool definitions and
:meth:`AnthropicGhost.tool_reply` returns the text and the ``tool_use`` blocks
in the order given (the native function-calling ablation).
"""

from __future__ import annotations

import os
from collections.abc import AsyncIterator, Mapping
from typing import Any

import anyio
import anthropic

from host.ghost.base import Ghost, GhostError, Message
from host.ghost.retry import StreamLimits, retrying_stream

LOCAL_PLACEHOLDER_KEY = "not-needed"
#: Anthropic requires max_tokens; the paper's replies are short programs
DEFAULT_MAX_TOKENS = 2048
#: error types in an ``error`` event / error body that may succeed later
RETRYABLE_TYPES = {"overloaded_error", "rate_limit_error", "api_error", "timeout_error"}

_STATUS_HINTS = {
    400: "bad request",
    401: "authentication failed; check the API key (GHOSTSHELL_LLM_API_KEY, ANTHROPIC_API_KEY or --api-key)",
    403: "permission denied for this key or model",
    404: "model or endpoint not found; check the model name and the base URL",
    413: "request too large",
    429: "rate limited",
    529: "overloaded",
}


def _env(*names: str) -> str | None:
    return next((v for n in names if (v := os.environ.get(n))), None)


def split_system(messages: list[Message]) -> tuple[str | None, list[dict[str, Any]]]:
    """OpenAI-style messages -> (Anthropic ``system`` string, ``messages`` list).

    System messages are joined (Anthropic takes the system prompt as a top-level
    field); consecutive messages of one role are merged (the API requires
    alternation). Content may be a string or a list of content blocks.
    """
    system = "\n\n".join(str(m["content"]) for m in messages if m.get("role") == "system") or None
    out: list[dict[str, Any]] = []
    for m in messages:
        role = m.get("role")
        if role == "system":
            continue
        if role not in ("user", "assistant"):
            raise GhostError(f"anthropic: unsupported message role {role!r} (expected system, user, assistant)")
        content: Any = m.get("content", "")
        if out and out[-1]["role"] == role and isinstance(content, str) and isinstance(out[-1]["content"], str):
            out[-1]["content"] += "\n\n" + content
        else:
            out.append({"role": role, "content": content})
    return system, out


def _error_body(body: object) -> tuple[str | None, str | None]:
    """(error type, message) from an Anthropic error body ``{"type":"error","error":{...}}``."""
    if isinstance(body, Mapping):
        inner = body.get("error", body)
        if isinstance(inner, Mapping):
            etype, msg = inner.get("type"), inner.get("message")
            return (etype if isinstance(etype, str) else None, msg if isinstance(msg, str) else None)
    if isinstance(body, str) and body.strip():
        return None, body.strip()[:500]
    return None, None


class AnthropicGhost(Ghost):
    """Stream ``text_delta`` pieces from Anthropic's Messages API.

    ``first_token_s`` / ``total_s`` bound the wait for the first text and for the
    whole reply; ``max_retries`` is the SDK's request-level retry count;
    ``stream_retries`` the retries of a stream that fails before any text.
    A stream that ends without ``message_stop`` raises :class:`GhostError`.
    """

    def __init__(
        self,
        model: str,
        base_url: str | None = None,
        api_key: str | None = None,
        *,
        temperature: float | None = None,
        max_tokens: int = DEFAULT_MAX_TOKENS,
        timeout_s: float = 60.0,
        max_retries: int = 2,
        first_token_s: float | None = 60.0,
        total_s: float | None = 600.0,
        stream_retries: int = 2,
        tools: list[dict[str, Any]] | None = None,
        client: anthropic.AsyncAnthropic | None = None,
        **options: Any,
    ) -> None:
        if not model:
            raise GhostError("anthropic: no model given; use --llm anthropic:MODEL")
        self.model = model
        self.name = f"anthropic:{model}"
        self.base_url = base_url or _env("GHOSTSHELL_LLM_BASE_URL", "ANTHROPIC_BASE_URL")
        key = api_key or _env("GHOSTSHELL_LLM_API_KEY", "ANTHROPIC_API_KEY")
        if key is None and client is None:
            host = (self.base_url or "").split("//")[-1].split("/")[0].split(":")[0]
            if host not in {"127.0.0.1", "localhost", "::1", "[::1]"}:
                raise GhostError(
                    f"{self.name}: no API key; set GHOSTSHELL_LLM_API_KEY or ANTHROPIC_API_KEY, or pass --api-key"
                )
            key = LOCAL_PLACEHOLDER_KEY
        self._api_key = key
        self.temperature = temperature
        self.max_tokens = max_tokens
        self.timeout_s = timeout_s
        self.max_retries = max_retries
        self.limits = StreamLimits(first_token_s=first_token_s, total_s=total_s, stream_retries=stream_retries)
        self.tools = tools
        self.options = options
        self._client = client
        #: tool_use blocks of the last reply, in the order given: ``[{"id", "name", "input"}]``
        self.last_tool_calls: list[dict[str, Any]] = []
        self.last_stop_reason: str | None = None

    def __repr__(self) -> str:
        return f"AnthropicGhost(model={self.model!r}, base_url={self.base_url!r})"

    def _where(self) -> str:
        return f"{self.name} at {self.base_url or 'api.anthropic.com'}"

    def _wrap(self, err: anthropic.AnthropicError, *, in_stream: bool) -> GhostError:
        where = self._where()
        if isinstance(err, anthropic.APIStatusError):
            etype, msg = _error_body(err.body)
            msg = msg or err.message
            status = err.status_code if not in_stream else None
            if in_stream:  # an SSE `error` event inside a 200 stream: the SDK did not retry it
                g = GhostError(f"{where}: {etype or 'error'} in the stream: {msg}", status=status,
                               provider_message=msg, retryable=etype in RETRYABLE_TYPES)
            else:
                code = err.status_code
                hint = _STATUS_HINTS.get(code, "server error" if code >= 500 else "request failed")
                g = GhostError(f"{where}: {hint} (HTTP {code}, {etype or 'error'}): {msg}", status=code,
                               provider_message=msg, retryable=code in (408, 409, 429) or code >= 500)
                g.sdk_retried = True  # type: ignore[attr-defined]
                ra = err.response.headers.get("retry-after")
                try:
                    g.retry_after_s = float(ra) if ra is not None else None  # type: ignore[attr-defined]
                except ValueError:
                    g.retry_after_s = None  # type: ignore[attr-defined]
            return g
        if isinstance(err, anthropic.APITimeoutError):
            g = GhostError(f"{where}: request timed out after {self.timeout_s:g} s", retryable=True)
            g.sdk_retried = not in_stream  # type: ignore[attr-defined]
            return g
        if isinstance(err, anthropic.APIConnectionError):
            cause = err.__cause__ or err.__context__
            detail = f"{type(cause).__name__}: {cause}" if cause else err.message
            g = GhostError(f"{where}: cannot reach the server ({detail})", provider_message=detail, retryable=True)
            g.sdk_retried = not in_stream  # type: ignore[attr-defined]
            return g
        return GhostError(f"{where}: {type(err).__name__}: {err}", provider_message=str(err))

    def _request(self, messages: list[Message]) -> dict[str, Any]:
        system, msgs = split_system(messages)
        req: dict[str, Any] = {"model": self.model, "max_tokens": self.max_tokens, "messages": msgs,
                               "stream": True, **self.options}
        if system:
            req["system"] = system
        if self.temperature is not None:  # recent SDKs dropped the keyword; the API field stays for older models
            req["extra_body"] = {**req.get("extra_body", {}), "temperature": self.temperature}
        if self.tools:
            req["tools"] = self.tools
        return req

    async def _attempt(self, messages: list[Message]) -> AsyncIterator[str]:
        client = self._client or anthropic.AsyncAnthropic(
            api_key=self._api_key, base_url=self.base_url, timeout=self.timeout_s, max_retries=self.max_retries)
        self.last_tool_calls = []
        self.last_stop_reason = None
        tool_json: dict[int, list[str]] = {}
        tool_meta: dict[int, dict[str, Any]] = {}
        try:
            try:
                response = await client.messages.create(**self._request(messages))
            except anthropic.AnthropicError as err:
                raise self._wrap(err, in_stream=False) from err
            stopped = False
            try:
                async for event in response:
                    kind = event.type
                    if kind == "content_block_delta":
                        delta = event.delta
                        if delta.type == "text_delta" and delta.text:
                            yield delta.text
                        elif delta.type == "input_json_delta":
                            tool_json.setdefault(event.index, []).append(delta.partial_json)
                    elif kind == "content_block_start":
                        block = event.content_block
                        if block.type == "text" and block.text:
                            yield block.text
                        elif block.type == "tool_use":
                            tool_meta[event.index] = {"id": block.id, "name": block.name, "input": block.input}
                    elif kind == "message_delta":
                        self.last_stop_reason = event.delta.stop_reason
                    elif kind == "message_stop":
                        stopped = True
            except anthropic.AnthropicError as err:
                raise self._wrap(err, in_stream=True) from err
            except ValueError as err:
                raise GhostError(f"{self._where()}: malformed stream data: {err}") from err
            finally:
                with anyio.move_on_after(5, shield=True):
                    await response.close()
            if not stopped:
                raise GhostError(f"{self._where()}: the stream ended before message_stop; the reply is truncated",
                                 retryable=True)
            self.last_tool_calls = [_finish_tool(tool_meta[i], tool_json.get(i)) for i in sorted(tool_meta)]
        finally:
            if self._client is None:
                with anyio.move_on_after(5, shield=True):
                    await client.close()

    def stream(self, messages: list[Message]) -> AsyncIterator[str]:
        """Yield the reply's text as the server streams it (timeouts and retries applied)."""
        return retrying_stream(lambda: self._attempt(messages), self.limits, name=self._where())


def _finish_tool(meta: dict[str, Any], parts: list[str] | None) -> dict[str, Any]:
    import json

    if parts:
        try:
            meta = {**meta, "input": json.loads("".join(parts))}
        except json.JSONDecodeError as err:
            meta = {**meta, "input": {}, "error": f"malformed tool input JSON: {err}"}
    return meta
