"""Received CAN frames from python-can to the asyncio loop, for the host's CAN transport.

Part of :class:`host.link.transports.can.CanLinkTransport` (python-can's ``Notifier`` / ``Listener``
side of its Bus / Notifier / Listener split; opening the bus is :mod:`host.link.transports.can_bus`).
:class:`CanReceiver` hands every python-can message the bus receives to ``on_message(msg,
generation)`` on the loop thread, in order, and a receive failure to ``on_error(reason, generation)``:

* a bus with a file descriptor (SocketCAN, SLCAN): ``loop.add_reader`` on it, and every frame that is
  ready is drained with ``bus.recv(0)`` per wake-up (python-can's Notifier would take one frame per
  readiness callback, too slow for a lockstep board's bursts; at most 1024 per wake-up, and lines a
  :class:`~host.link.transports.slcan_rx.BufferedSlcanBus` has read but not parsed, which the fd no
  longer shows, are drained on the next loop turn);
* a bus without one (the virtual bus): python-can's :class:`can.Notifier` reads in its thread and its
  listener (:class:`_Listener`) appends to :attr:`CanReceiver.inbox` and wakes the loop with
  ``call_soon_threadsafe``. The Notifier gets no ``loop=``: python-can would then queue each message
  on the loop itself, out of reach of the transport's ``close()``, which must log what the loop has
  not taken yet (:meth:`CanReceiver.leftovers`).

Every hand-over carries the transport's connection generation (incremented on every connect and
disconnect); the transport drops what belongs to an earlier connection, and the drain stops as soon
as ``is_current(generation)`` is false. asyncio stays here (``add_reader``, ``call_soon``,
``call_soon_threadsafe`` from the Notifier thread), as in every transport adapter: see
:mod:`host.link.transports` for why.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable, Iterator

import can

__all__ = ["CanReceiver"]

#: (a received message, the connection generation it belongs to) -> None
MessageHandler = Callable[[can.Message, int], None]
#: (a reason, the connection generation) -> None
ErrorHandler = Callable[[str, int], None]


class _Listener(can.Listener):
    """Hands every received message (or the bus error) from the Notifier's thread to the loop thread."""

    def __init__(self, loop: asyncio.AbstractEventLoop, owner: CanReceiver, generation: int) -> None:
        self.loop, self.owner, self.generation = loop, owner, generation

    def on_message_received(self, msg: can.Message) -> None:
        # through the owner's inbox, in order: what the loop has not taken when the transport closes
        # still reaches the frame log
        self.owner.inbox.append((msg, self.generation))
        try:
            self.loop.call_soon_threadsafe(self.owner._from_inbox)
        except RuntimeError:  # loop closed
            pass

    def on_error(self, exc: Exception) -> None:
        try:
            self.loop.call_soon_threadsafe(self.owner._on_error, f"CAN receive failed: {exc}", self.generation)
        except RuntimeError:
            pass


class CanReceiver:
    """The receive side of one CAN transport, across its connections (see the module docstring).

    ``on_message`` and ``on_error`` run on the loop thread; ``is_current(generation)`` says whether a
    generation is still the transport's connection.
    """

    def __init__(self, on_message: MessageHandler, on_error: ErrorHandler,
                 is_current: Callable[[int], bool]) -> None:
        self._on_message = on_message
        self._on_error = on_error
        self._is_current = is_current
        self._bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._reader_fd: int | None = None
        self.inbox: deque[tuple[can.Message, int]] = deque()  # from python-can's Notifier thread

    def start(self, loop: asyncio.AbstractEventLoop, bus: can.BusABC, fd: int, generation: int) -> None:
        """Deliver ``bus``'s messages as ``generation``: through ``loop.add_reader(fd)`` when ``fd >= 0``,
        else through a python-can Notifier thread."""
        self._bus = bus
        self._reader_fd = None
        if fd >= 0:
            loop.add_reader(fd, self._drain, generation)
            self._reader_fd = fd
        else:  # no fd (e.g. the virtual bus): python-can's Notifier reads in its thread
            # no loop= here: python-can would queue each message on the loop itself, out of close()'s reach;
            # the listener runs in the Notifier's thread and hands over through the inbox
            self._notifier = can.Notifier(bus, [_Listener(loop, self, generation)], timeout=0.05)

    def stop(self) -> None:
        """No more frames to the loop (the bus stays open; idempotent). Messages already in the inbox stay."""
        self._bus = None
        if self._reader_fd is not None:
            try:
                asyncio.get_running_loop().remove_reader(self._reader_fd)
            except (RuntimeError, ValueError, OSError):
                pass
            self._reader_fd = None
        if self._notifier is not None:
            try:
                self._notifier.stop(timeout=0.2)
            except Exception:
                pass
            self._notifier = None

    def clear(self) -> None:
        """Forget what the Notifier handed over and the loop has not taken."""
        self.inbox.clear()

    def leftovers(self, generation: int) -> Iterator[can.Message]:
        """Take the inbox's messages of ``generation``, oldest first, one at a time (for the frame log on close)."""
        while self.inbox:
            msg, gen = self.inbox.popleft()
            if gen == generation:
                yield msg

    def _drain(self, generation: int) -> None:
        bus = self._bus
        buffered = getattr(bus, "has_buffered_line", None)  # BufferedSlcanBus: lines read, not yet parsed
        for _ in range(1024):
            if bus is None or not self._is_current(generation):
                return
            try:
                msg = bus.recv(timeout=0)
            except (can.CanError, OSError, ValueError) as e:
                self._on_error(f"CAN receive failed: {e}", generation)
                return
            if msg is None:
                if buffered is not None and buffered():
                    continue  # an adapter response or a filtered frame: more lines wait behind it
                return
            self._on_message(msg, generation)
        if buffered is not None and buffered():  # the fd will not wake us for lines already read
            asyncio.get_running_loop().call_soon(self._drain, generation)

    def _from_inbox(self) -> None:
        try:
            msg, generation = self.inbox.popleft()
        except IndexError:  # taken by close()
            return
        self._on_message(msg, generation)
