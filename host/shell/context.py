"""The call context the scheduler hands a running shell function: :class:`CallContext`.

A function (or its reset hook) that declares a parameter annotated :class:`CallContext` (any name,
e.g. ``call: CallContext``) receives its call's context in it; that parameter is not an attribute
the LLM sees (:func:`context_param`, :func:`host.shell.types.params_of`). The context says whether the element is
persistent (a start-tag, running until its children finish and it is reset) or
finite (self-closing), its element path and id, and whether a descendant on the
same channel currently overrides it (e.g. ``<stand posture="forward"><stand
posture="backward"/></stand>``: the inner call runs at once; a persistent
function that drives the same actuator should yield while ``overridden``).

A finite call may :meth:`CallContext.hand_over` its channel before it completes:
the next call queued on the same channel then starts (so a motion runtime can
plan it to begin exactly where this one is planned to end), while this call's
own completion still comes when it really ends.
"""

from __future__ import annotations

import inspect
import typing
from dataclasses import dataclass, field
from typing import Any, Protocol

import anyio


@dataclass
class CallContext:
    """What a running function knows about its own call."""

    function: str
    channel: str
    home_channel: str
    args: dict[str, Any]
    path: str
    element_id: int
    persistent: bool
    phase: str = "run"  # "run" or "reset"
    _overrides: int = 0
    _resumed: anyio.Event | None = field(default=None, repr=False)
    _hand_over: anyio.Event | None = field(default=None, repr=False)

    def hand_over(self) -> None:
        """Let the next call queued on this channel start now (this call keeps running)."""
        if self._hand_over is not None:
            self._hand_over.set()

    @property
    def overridden(self) -> bool:
        """True while a descendant call on the same channel is running."""
        return self._overrides > 0

    async def wait_not_overridden(self) -> None:
        """Return once no descendant on this channel is running."""
        while self._overrides > 0 and self._resumed is not None:
            await self._resumed.wait()

    def _enter_override(self) -> None:
        if self._overrides == 0:
            self._resumed = anyio.Event()
        self._overrides += 1

    def _exit_override(self) -> None:
        self._overrides -= 1
        if self._overrides == 0 and self._resumed is not None:
            self._resumed.set()


class RunningCall(Protocol):
    """What an executor (a robot runtime) needs of a call: its element path and id, whether it is
    persistent, and a way to hand its channel over. :class:`CallContext` is one; tests pass their own."""

    @property
    def path(self) -> str: ...
    @property
    def element_id(self) -> int: ...
    @property
    def persistent(self) -> bool: ...
    def hand_over(self) -> None: ...


def context_param(fn: Any) -> str | None:
    """The name of ``fn``'s parameter annotated :class:`CallContext` (the scheduler fills it), or None."""
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return None
    try:
        hints = typing.get_type_hints(fn)
    except Exception:  # noqa: BLE001 - an unresolvable hint elsewhere: fall back to the written annotation
        hints = {}
    for p in params.values():
        hint = hints.get(p.name, p.annotation)
        if hint is CallContext or hint == "CallContext":
            return p.name
    return None
