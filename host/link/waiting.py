"""One-shot replies and a resettable flag on anyio events: what the link's waits are made of.

:class:`Reply` is a one-shot answer slot (an ACK, a CAPS, a TIME_SYNC reply, an image, a telemetry
report) with the subset of :class:`asyncio.Future`'s interface the receive path uses
(``done()``, ``set_result()``, ``set_exception()``, ``cancel()``, ``exception()``, ``result()``), so
the receive handlers also accept a plain future (the fuzz harness ``host.tools.fuzz.link_receive`` puts some in
the request table and the supervisor's maps). Waiting is anyio: :meth:`Reply.wait` is an :class:`anyio.Event` wait under
:func:`anyio.move_on_after`. The event is made on the first wait, inside the event loop: a reply may
be created and answered from synchronous code (the transport's receive callbacks, the fuzz harness)
where anyio cannot tell which async library runs.

:class:`Flag` is the set/clear/wait event anyio does not have (an :class:`anyio.Event` cannot be
cleared): the session's "link up" and "link lost" states (:class:`host.link.core.LinkSession`).
"""

from __future__ import annotations

from typing import Generic, TypeVar

import anyio

__all__ = ["Flag", "Reply"]

T = TypeVar("T")


class Reply(Generic[T]):
    """A one-shot answer: set once with a result or an exception (later sets are ignored by callers
    that check :meth:`done` first, as the receive path does; a second set raises ``RuntimeError``)."""

    __slots__ = ("_done", "_event", "_exc", "_value", "_cancelled")

    def __init__(self) -> None:
        self._done = False
        self._cancelled = False
        self._value: T | None = None
        self._exc: BaseException | None = None
        self._event: anyio.Event | None = None

    def done(self) -> bool:
        return self._done

    def cancelled(self) -> bool:
        return self._cancelled

    def _finish(self) -> None:
        if self._done:
            raise RuntimeError("reply already set")
        self._done = True
        if self._event is not None:
            self._event.set()

    def set_result(self, value: T) -> None:
        self._finish()
        self._value = value

    def set_exception(self, exc: BaseException) -> None:
        self._finish()
        self._exc = exc

    def cancel(self) -> bool:
        """Nobody waits any more: later answers are dropped (False when it was answered already)."""
        if self._done:
            return False
        self._cancelled = True
        self._finish()
        return True

    def exception(self) -> BaseException | None:
        return self._exc

    def result(self) -> T:
        """The answer; raises the exception it was set with (``RuntimeError`` when not answered)."""
        if self._exc is not None:
            raise self._exc
        if not self._done or self._cancelled:
            raise RuntimeError("reply not answered")
        return self._value  # type: ignore[return-value]

    async def wait(self, timeout: float | None) -> bool:
        """Wait up to ``timeout`` s (None: no limit) for the answer; True when it came (then call
        :meth:`result`), False on timeout. Waiting again after a timeout is allowed (retries)."""
        if not self._done:
            if self._event is None:
                self._event = anyio.Event()
            with anyio.move_on_after(timeout):
                await self._event.wait()
        return self._done

    async def get(self, timeout: float | None) -> T:
        """The answer within ``timeout`` s; ``TimeoutError`` otherwise (the exception it was set with raises)."""
        if not await self.wait(timeout):
            raise TimeoutError
        return self.result()


class Flag:
    """A settable, clearable condition with an anyio wait (:meth:`wait` returns at once while set)."""

    def __init__(self) -> None:
        self._set = False
        self._events: list[anyio.Event] = []

    def is_set(self) -> bool:
        return self._set

    def set(self) -> None:
        self._set = True
        events, self._events = self._events, []
        for ev in events:
            ev.set()

    def clear(self) -> None:
        self._set = False

    async def wait(self) -> None:
        if self._set:
            return
        ev = anyio.Event()
        self._events.append(ev)
        try:
            await ev.wait()
        finally:
            if ev in self._events:
                self._events.remove(ev)
