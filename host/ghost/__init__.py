"""LLM clients ("ghosts") that stream a reply as text chunks.

``make_ghost("scripted", program=...)`` replays a program as an LLM would;
``make_ghost("openai:MODEL")`` streams from any OpenAI-compatible endpoint, ``make_ghost("anthropic:MODEL")``
from Anthropic's Messages API (the providers: :data:`host.ghost.factory.PROVIDERS`).
The clients are imported lazily so the scripted ghost needs no SDK.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from host.ghost.base import Ghost, GhostError, Message
from host.ghost.factory import SPECS, UnknownSpecError, make_ghost
from host.ghost.scripted import ScriptedGhost
from host.ghost.tokenize import tokenize

if TYPE_CHECKING:
    from host.ghost.openai_client import OpenAIGhost

__all__ = ["SPECS", "Ghost", "GhostError", "Message", "OpenAIGhost", "ScriptedGhost", "UnknownSpecError", "make_ghost", "tokenize"]


def __getattr__(name: str) -> Any:
    if name == "OpenAIGhost":
        from host.ghost.openai_client import OpenAIGhost

        return OpenAIGhost
    raise AttributeError(name)
