"""``make_ghost(spec)``: build a :class:`Ghost` from a command-line spec."""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from typing import Any

from host.ghost.base import Ghost, GhostError


@dataclass(frozen=True)
class Provider:
    """One LLM provider a spec names as ``KIND:MODEL``: builds ``<module>.<cls>(model, **kw)``.

    ``example`` is a model name for the error line; ``ignores`` are keywords of the other answerers
    that this one drops (a command passes its flags through unconditionally). Add a provider with
    one entry in :data:`PROVIDERS` (its client module holds a :class:`Ghost` subclass)."""

    module: str
    cls: str
    example: str
    ignores: tuple[str, ...] = ()


_SCRIPTED_ONLY = ("model", "program", "tokens_per_s", "jitter", "sleep")

#: the LLM providers by spec kind (``scripted`` is built apart: it takes a program, not a model)
PROVIDERS: dict[str, Provider] = {
    "openai": Provider("host.ghost.openai_client", "OpenAIGhost", "gpt-4o-mini", _SCRIPTED_ONLY),
    "anthropic": Provider("host.ghost.anthropic_client", "AnthropicGhost", "claude-sonnet-4-0",
                          _SCRIPTED_ONLY + ("extra_body",)),
}

#: the accepted spec forms, for help texts and error messages
SPECS = ("scripted", *(f"{kind}:MODEL" for kind in PROVIDERS))
#: the providers' spec forms for ``--llm`` help texts (``openai`` is any OpenAI-compatible endpoint)
LLM_SPECS_HELP = " or ".join(f"{kind}:MODEL" for kind in PROVIDERS) + " (openai: any OpenAI-compatible endpoint)"


class UnknownSpecError(GhostError):
    """The spec names no LLM backend (its kind is none of :data:`SPECS`): a command that takes other
    answerers too (``eval``'s offline ones) adds them to the message."""


def make_ghost(spec: str, **kw: Any) -> Ghost:
    """Build a ghost from ``spec``.

    * ``"scripted"``: :class:`ScriptedGhost`; needs ``program=``, accepts
      ``tokens_per_s``, ``jitter``, ``seed``, ``sleep``.
    * ``"KIND:MODEL"`` (or ``"KIND"`` with ``GHOSTSHELL_LLM_MODEL`` set) for a kind of :data:`PROVIDERS`
      (``openai``: :class:`OpenAIGhost`, any OpenAI-compatible endpoint; ``anthropic``:
      :class:`AnthropicGhost`): ``cls(model, **kw)`` with every keyword given except those the provider
      ignores; the commands pass ``base_url``, ``api_key``, ``temperature`` and their timeouts through,
      so a provider's class takes ``**kw`` (or names each). Keyword arguments that are ``None``
      are dropped, so CLI flags can be passed through unconditionally.
    """
    kw = {k: v for k, v in kw.items() if v is not None}
    kind, _, rest = spec.strip().partition(":")
    kind = kind.lower()
    check_spec(spec, model=kw.get("model"))
    if kind == "scripted":
        from host.ghost.scripted import ScriptedGhost

        if "program" not in kw:
            raise GhostError("the scripted ghost needs a program (e.g. --task N, --xml TEXT or --xml-file F)")
        allowed = {"program", "tokens_per_s", "jitter", "seed", "sleep"}
        return ScriptedGhost(**{k: v for k, v in kw.items() if k in allowed})
    provider = PROVIDERS[kind]  # check_spec refused every other kind
    model = rest.strip() or kw.pop("model", None) or os.environ.get("GHOSTSHELL_LLM_MODEL")
    for other in provider.ignores:
        kw.pop(other, None)
    ghost: Ghost = getattr(importlib.import_module(provider.module), provider.cls)(model, **kw)
    return ghost


def check_spec(spec: str, *, model: str | None = None) -> str:
    """Raise the :class:`GhostError` :func:`make_ghost` would raise for the form of ``spec`` (an unknown kind:
    :class:`UnknownSpecError`; ``scripted:ARG``; a provider's spec without a model, when neither ``model``
    nor ``GHOSTSHELL_LLM_MODEL`` gives one), without building a client: no SDK import, no key, no network.
    Returns the spec as the commands read it (``" Scripted "`` -> ``"scripted"``; any other unchanged).
    A command checks its ``--llm`` with it before it starts a board or touches its ``--out`` folder."""
    kind, _, rest = spec.strip().partition(":")
    kind = kind.lower()
    if kind == "scripted":
        if rest:
            raise GhostError(f"LLM spec {spec!r}: 'scripted' takes no argument")
        return "scripted"
    provider = PROVIDERS.get(kind)
    if provider is None:
        raise UnknownSpecError(f"unknown LLM spec {spec!r}; expected one of: {', '.join(SPECS)}")
    if not (rest.strip() or model or os.environ.get("GHOSTSHELL_LLM_MODEL")):
        raise GhostError(f"LLM spec {spec!r}: no model; use {kind}:MODEL (e.g. {kind}:{provider.example})")
    return spec
