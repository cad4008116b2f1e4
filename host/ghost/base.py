"""The :class:`Ghost` interface: an LLM client that streams text chunks."""

from __future__ import annotations

import abc
from collections.abc import AsyncIterator

#: An OpenAI-style chat message: ``{"role": "system"|"user"|"assistant", "content": "..."}``.
Message = dict[str, str]


class GhostError(RuntimeError):
    """An LLM backend failed; ``str(err)`` is a one-line human-readable reason.

    ``status`` is the HTTP status when there was one, ``provider_message`` the
    provider's own error text (or the underlying exception's), ``retryable``
    whether trying again later may help (rate limits, connection problems).
    """

    def __init__(
        self,
        message: str,
        *,
        status: int | None = None,
        provider_message: str | None = None,
        retryable: bool = False,
    ) -> None:
        super().__init__(message)
        self.status = status
        self.provider_message = provider_message
        self.retryable = retryable


class Ghost(abc.ABC):
    """An LLM client: ``stream(messages)`` yields the reply as text chunks.

    Concatenating the chunks gives the full reply. ``stream`` is an async
    generator: a consumer that stops early should close it (``aclose()``, or
    ``contextlib.aclosing``) so the backend releases its connection at once.
    """

    #: short description, e.g. ``"scripted"`` or ``"openai:gpt-4o-mini"``
    name: str = "ghost"

    @abc.abstractmethod
    def stream(self, messages: list[Message]) -> AsyncIterator[str]:
        """Yield the reply to ``messages`` chunk by chunk (non-empty strings)."""

    async def complete(self, messages: list[Message]) -> str:
        """Return the whole reply (the concatenated stream)."""
        parts: list[str] = []
        gen = self.stream(messages)
        try:
            async for chunk in gen:
                parts.append(chunk)
        finally:
            aclose = getattr(gen, "aclose", None)
            if aclose is not None:
                await aclose()
        return "".join(parts)
