"""The call context a running shell function can inspect: ``current_call()``.

Inside a function (or its reset hook) invoked by the scheduler,
``current_call()`` returns a :class:`CallContext`: whether the element is
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

from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import Any

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


_current: ContextVar[CallContext | None] = ContextVar("ghostshell_call", default=None)


def current_call() -> CallContext | None:
    """The context of the shell call running in this task, or None outside the shell."""
    return _current.get()


def _set_current(ctx: CallContext | None) -> None:
    _current.set(ctx)
