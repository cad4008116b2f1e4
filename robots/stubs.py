"""Stub marks: :func:`stub` marks a function as an interface stub (a leaf module).

What a robot's interface module declares its stubs with (see :mod:`robots.interface`, which re-exports
every name here, and where robot packages import them from). Its own module because
:mod:`robots.generic` marks the generic stubs with it while :func:`robots.interface.build_interface`
adds the generic module to every vocabulary.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

__all__ = ["StubInfo", "class_stubs", "stub", "stub_info"]


@dataclass(frozen=True)
class StubInfo:
    """How a stub maps onto a behaviour."""

    channel: str
    behaviour: str
    rename: dict[str, str] = field(default_factory=dict)  # stub param -> behaviour param
    fixed: dict[str, Any] = field(default_factory=dict)  # behaviour params the stub pins


_ATTR = "__stub_info__"


def stub(channel: str, behaviour: str | None = None, *, rename: dict[str, str] | None = None,
         fixed: dict[str, Any] | None = None) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Mark a function as an interface stub on ``channel`` implemented by ``behaviour`` (default: its name)."""

    def mark(fn: Callable[..., Any]) -> Callable[..., Any]:
        setattr(fn, _ATTR, StubInfo(channel, behaviour or fn.__name__, rename or {}, fixed or {}))
        return fn

    return mark


def stub_info(fn: Any) -> StubInfo | None:
    """The :class:`StubInfo` of a stub, None for anything else."""
    info = getattr(fn, _ATTR, None)
    return info if isinstance(info, StubInfo) else None


def class_stubs(cls: type) -> dict[str, Callable[..., Any]]:
    """The stubs a module class declares, by name (declaration order)."""
    return {n: f for n, f in vars(cls).items() if stub_info(f) is not None}
