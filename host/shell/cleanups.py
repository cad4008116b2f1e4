"""Shielded cleanups that a forced stop may cut short.

A cancelled call still runs its cleanup (a reset, a smooth stop, a peripheral's stop) inside a
shielded cancel scope with a timeout, so an interruption ends gracefully. A forced stop (a second
Ctrl-C) must not wait for them: :meth:`Cleanups.abort` cancels the shields running now, and
:attr:`Cleanups.aborted` tells later cleanups to skip. Used by :class:`host.shell.scheduler.ProgramRun`
(resets) and :class:`host.runtime.robot_runtime.RobotRuntime` (stops).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import anyio

__all__ = ["Cleanups"]


class Cleanups:
    """The shielded cleanups of one owner (a run, a runtime) that are running now."""

    def __init__(self) -> None:
        self._running: set[anyio.CancelScope] = set()
        #: :meth:`abort` was called: cleanups that have not started yet should be skipped
        self.aborted = False

    @contextmanager
    def shielded(self, timeout_s: float) -> Iterator[tuple[anyio.CancelScope, anyio.CancelScope]]:
        """A cleanup's scopes: ``(shield, timeout)``, a shielded scope (cancelled only by :meth:`abort`;
        ``shield.cancel_called`` then) inside which ``timeout`` moves on after ``timeout_s`` s
        (``timeout.cancelled_caught`` then). Enter and leave it in one task."""
        with anyio.CancelScope(shield=True) as shield, anyio.move_on_after(timeout_s) as timeout:
            self._running.add(shield)
            try:
                yield shield, timeout
            finally:
                self._running.discard(shield)

    def abort(self) -> None:
        """Stop at once: cut the running cleanups short; later ones see :attr:`aborted`."""
        self.aborted = True
        for shield in list(self._running):
            shield.cancel()
