"""``make_ghost(spec)``: build a :class:`Ghost` from a command-line spec."""

from __future__ import annotations

import os
from typing import Any

from host.ghost.base import Ghost, GhostError

#: the accepted spec forms, for help texts and error messages
SPECS = ("scripted", "openai:MODEL", "anthropic:MODEL")


class UnknownSpecError(GhostError):
    """The spec names no LLM backend (its kind is none of :data:`SPECS`): a command that takes other
    answerers too (``eval``'s offline ones) adds them to the message."""


def make_ghost(spec: str, **kw: Any) -> Ghost:
    """Build a ghost from ``spec``.

    * ``"scripted"``: :class:`ScriptedGhost`; needs ``program=``, accepts
      ``tokens_per_s``, ``jitter``, ``seed``, ``sleep``.
    * ``"openai:MODEL"`` (or ``"openai"`` with ``GHOSTSHELL_LLM_MODEL`` set):
      :class:`OpenAIGhost`; accepts ``base_url``, ``api_key``, ``temperature`` and
      the other :class:`OpenAIGhost` options.
    * ``"anthropic:MODEL"``: :class:`AnthropicGhost` (same keywords, plus
      ``max_tokens``, ``first_token_s``, ``total_s``, ``stream_retries``). Keyword arguments that are ``None``
      are dropped, so CLI flags can be passed through unconditionally.
    """
    kw = {k: v for k, v in kw.items() if v is not None}
    kind, _, rest = spec.strip().partition(":")
    kind = kind.lower()
    if kind == "scripted":
        from host.ghost.scripted import ScriptedGhost

        if rest:
            raise GhostError(f"ghost spec {spec!r}: 'scripted' takes no argument")
        if "program" not in kw:
            raise GhostError("the scripted ghost needs a program (e.g. --task N, --xml TEXT or --xml-file F)")
        allowed = {"program", "tokens_per_s", "jitter", "seed", "sleep"}
        return ScriptedGhost(**{k: v for k, v in kw.items() if k in allowed})
    if kind == "openai":
        from host.ghost.openai_client import OpenAIGhost

        model = rest.strip() or kw.pop("model", None) or os.environ.get("GHOSTSHELL_LLM_MODEL")
        for scripted_only in ("model", "program", "tokens_per_s", "jitter", "sleep"):
            kw.pop(scripted_only, None)
        if not model:
            raise GhostError(f"ghost spec {spec!r}: no model; use openai:MODEL (e.g. openai:gpt-4o-mini)")
        return OpenAIGhost(model, **kw)
    if kind == "anthropic":
        from host.ghost.anthropic_client import AnthropicGhost

        model = rest.strip() or kw.pop("model", None) or os.environ.get("GHOSTSHELL_LLM_MODEL")
        for scripted_only in ("model", "program", "tokens_per_s", "jitter", "sleep", "extra_body"):
            kw.pop(scripted_only, None)
        if not model:
            raise GhostError(f"ghost spec {spec!r}: no model; use anthropic:MODEL (e.g. anthropic:claude-sonnet-4-0)")
        return AnthropicGhost(model, **kw)
    raise UnknownSpecError(f"unknown LLM spec {spec!r}; expected one of: {', '.join(SPECS)}")
