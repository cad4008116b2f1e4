"""``OpenAIGhost``: any OpenAI-compatible chat-completions stream, via the official SDK.

Covers OpenAI, DeepSeek, Qwen (DashScope), Kimi (Moonshot), Doubao (Ark), Grok
(xAI), Gemini's OpenAI-compatible endpoint and local servers (llama.cpp, vLLM,
Ollama, LM Studio) through ``base_url``. Settings come from the arguments, else
``GHOSTSHELL_LLM_BASE_URL`` / ``GHOSTSHELL_LLM_API_KEY``, else ``OPENAI_BASE_URL``
/ ``OPENAI_API_KEY``. Every SDK failure is re-raised as :class:`GhostError`.
"""

from __future__ import annotations

import json
import os
from collections.abc import AsyncIterator, Mapping
from typing import Any
from urllib.parse import urlsplit

import anyio
import openai

from host.ghost.base import Ghost, GhostError, Message
from host.ghost.retry import StreamLimits, retrying_stream

#: default endpoint when neither an argument nor the environment names one
DEFAULT_BASE_URL = "https://api.openai.com/v1"
#: key sent to local servers (127.0.0.1, localhost) when none is configured
LOCAL_PLACEHOLDER_KEY = "not-needed"

_STATUS_HINTS = {
    400: "bad request",
    401: "authentication failed; check the API key (GHOSTSHELL_LLM_API_KEY, OPENAI_API_KEY or --api-key)",
    403: "permission denied for this key or model",
    404: "model or endpoint not found; check the model name and that the base URL ends in the API root (often /v1)",
    429: "rate limited or out of quota",
}


def _env(*names: str) -> str | None:
    for name in names:
        value = os.environ.get(name)
        if value:
            return value
    return None


def _is_local(url: str) -> bool:
    host = urlsplit(url).hostname or ""
    return host in {"localhost", "127.0.0.1", "::1", "0.0.0.0"}


def provider_message(body: object, fallback: str) -> str:
    """The provider's error text from an error body (OpenAI-style or not)."""
    if isinstance(body, Mapping):
        for key in ("message", "detail", "error", "msg"):
            value = body.get(key)
            if isinstance(value, str) and value:
                return value
            if isinstance(value, Mapping):
                return provider_message(value, fallback)
        return json.dumps(body, ensure_ascii=False)[:500]
    if isinstance(body, str) and body.strip():
        return body.strip()[:500]
    return fallback


class OpenAIGhost(Ghost):
    """Stream ``choices[0].delta.content`` from an OpenAI-compatible chat endpoint.

    Role-only and empty deltas, ``reasoning_content`` and usage-only chunks are
    skipped. A stream that ends without a ``finish_reason`` (dropped connection)
    raises :class:`GhostError` after the text received so far. Closing the
    generator early closes the HTTP response. ``options`` are passed through to
    ``chat.completions.create`` (``max_tokens``, ``top_p``, ``seed``, ``stop``...);
    ``extra_body`` carries provider-specific fields (e.g. ``{"enable_thinking": False}``).
    """

    def __init__(
        self,
        model: str,
        base_url: str | None = None,
        api_key: str | None = None,
        *,
        temperature: float | None = None,
        timeout_s: float = 60.0,
        max_retries: int = 2,
        first_token_s: float | None = 60.0,
        total_s: float | None = 600.0,
        stream_retries: int = 2,
        extra_body: Mapping[str, Any] | None = None,
        extra_headers: Mapping[str, str] | None = None,
        client: openai.AsyncOpenAI | None = None,
        **options: Any,
    ) -> None:
        if not model:
            raise GhostError("openai: no model given; use --llm openai:MODEL or set GHOSTSHELL_LLM_MODEL")
        self.model = model
        self.name = f"openai:{model}"
        self.base_url = (
            base_url or _env("GHOSTSHELL_LLM_BASE_URL", "OPENAI_BASE_URL") or DEFAULT_BASE_URL
        ).rstrip("/")
        key = api_key or _env("GHOSTSHELL_LLM_API_KEY", "OPENAI_API_KEY")
        if key is None and client is None:
            if not _is_local(self.base_url):
                raise GhostError(
                    f"{self.name}: no API key for {self.base_url}; set GHOSTSHELL_LLM_API_KEY or "
                    "OPENAI_API_KEY, or pass --api-key"
                )
            key = LOCAL_PLACEHOLDER_KEY
        self._api_key = key
        self.temperature = temperature
        self.timeout_s = timeout_s
        self.max_retries = max_retries
        self.limits = StreamLimits(first_token_s=first_token_s, total_s=total_s, stream_retries=stream_retries)
        self.extra_body = dict(extra_body or {})
        self.extra_headers = dict(extra_headers or {})
        self.options = options
        self._client = client
        #: tool calls of the last reply (``tools=`` in ``options``), in the order given:
        #: ``[{"id", "name", "arguments"}]`` with ``arguments`` the raw JSON text
        self.last_tool_calls: list[dict[str, Any]] = []

    def __repr__(self) -> str:
        return f"OpenAIGhost(model={self.model!r}, base_url={self.base_url!r})"

    def _request(self, messages: list[Message]) -> dict[str, Any]:
        req: dict[str, Any] = {"model": self.model, "messages": list(messages), "stream": True, **self.options}
        if self.temperature is not None:
            req["temperature"] = self.temperature
        if self.extra_body:
            req["extra_body"] = self.extra_body
        if self.extra_headers:
            req["extra_headers"] = self.extra_headers
        return req

    def _wrap(self, err: openai.OpenAIError) -> GhostError:
        where = f"{self.name} at {self.base_url}"
        if isinstance(err, openai.APIStatusError):
            status = err.status_code
            msg = provider_message(err.body, err.message)
            hint = _STATUS_HINTS.get(status, "server error" if status >= 500 else "request failed")
            return GhostError(
                f"{where}: {hint} (HTTP {status}): {msg}",
                status=status,
                provider_message=msg,
                retryable=status in (408, 409, 429) or status >= 500,
            )
        if isinstance(err, openai.APITimeoutError):
            return GhostError(f"{where}: request timed out after {self.timeout_s:g} s", retryable=True)
        if isinstance(err, openai.APIConnectionError):
            cause = err.__cause__ or err.__context__
            detail = f"{type(cause).__name__}: {cause}" if cause else err.message
            return GhostError(f"{where}: cannot reach the server ({detail})", provider_message=detail, retryable=True)
        if isinstance(err, openai.APIError):
            msg = provider_message(err.body, err.message)
            return GhostError(f"{where}: error in the stream: {msg}", provider_message=msg)
        return GhostError(f"{where}: {type(err).__name__}: {err}", provider_message=str(err))

    def stream(self, messages: list[Message]) -> AsyncIterator[str]:
        """Yield the reply's content pieces as the server streams them (the first-token and
        overall timeouts and the stream-level retries of :mod:`host.ghost.retry` applied)."""
        return retrying_stream(lambda: self._attempt(messages), self.limits, name=f"{self.name} at {self.base_url}")

    async def _attempt(self, messages: list[Message]) -> AsyncIterator[str]:
        self.last_tool_calls = []
        client = self._client
        if client is None:
            client = openai.AsyncOpenAI(
                api_key=self._api_key,
                base_url=self.base_url,
                timeout=self.timeout_s,
                max_retries=self.max_retries,
            )
        try:
            try:
                response = await client.chat.completions.create(**self._request(messages))
            except openai.OpenAIError as err:
                wrapped = self._wrap(err)
                wrapped.sdk_retried = True  # type: ignore[attr-defined]  # the SDK's max_retries were the retries
                raise wrapped from err
            finish_reason: str | None = None
            tools: dict[int, dict[str, Any]] = {}
            try:
                async for chunk in response:
                    for choice in chunk.choices or ():
                        if choice.index != 0:
                            continue
                        content = choice.delta.content if choice.delta is not None else None
                        if content:
                            yield content
                        for tc in (choice.delta.tool_calls or ()) if choice.delta is not None else ():
                            slot = tools.setdefault(tc.index, {"id": None, "name": "", "arguments": ""})
                            slot["id"] = tc.id or slot["id"]
                            if tc.function is not None:
                                slot["name"] += tc.function.name or ""
                                slot["arguments"] += tc.function.arguments or ""
                        if choice.finish_reason:
                            finish_reason = choice.finish_reason
            except openai.OpenAIError as err:
                raise self._wrap(err) from err
            except (json.JSONDecodeError, ValueError) as err:
                raise GhostError(f"{self.name} at {self.base_url}: malformed stream data: {err}") from err
            finally:
                with anyio.move_on_after(5, shield=True):
                    await response.close()
            self.last_tool_calls = [tools[i] for i in sorted(tools)]
            if finish_reason is None:
                raise GhostError(
                    f"{self.name} at {self.base_url}: the stream ended before the model finished "
                    "(no finish_reason); the reply is truncated"
                )
        finally:
            if self._client is None:
                with anyio.move_on_after(5, shield=True):
                    await client.close()
