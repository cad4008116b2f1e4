"""The ``on_sent`` listeners of a session (``BoardClient.on_sent``), told after every send or after a burst.

python-can's ``Listener`` model for the transmit side: a run's recorder, a live view or a test
registers ``callback(seq, message)``; a failing listener is logged and never fails the send. Inside
:meth:`SentFanout.burst` the sends go on the wire together when the block ends, and the listeners, like the transport's
frame log (:meth:`host.link.transports.base.Transport.burst`), hear of them when the block
ends, in send order.

Nothing inside a burst may await: a task that yields there lets other tasks send between the burst's
messages (their bytes would go out first, the burst's after them), and a start's FLUSH and first frame
would no longer arrive together. :meth:`SentFanout.burst` checks it on asyncio (the host's backend; elsewhere nothing is checked): it queues a marker callback on
the running event loop when the block opens and raises :class:`AwaitInBurst` when the block ends if the
loop ran it meanwhile, which it does only when something in the block gave control back to the loop.
An ``await`` that completes without suspending is harmless and not caught.
"""


from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Iterator

from host.link.transports import Transport
from protocol.messages import Message

__all__ = ["AwaitInBurst", "SentFanout", "SentListener"]

log = logging.getLogger("host.link")

#: called with (sequence number, message) after a message was handed to the transport
SentListener = Callable[[int, Message], None]


class AwaitInBurst(RuntimeError):
    """The event loop ran other work while a :meth:`SentFanout.burst` block was open: the block
    awaited (a programming error; what the block sent was still written, logged and told)."""


def _loop_marker() -> tuple[asyncio.Handle, list[bool]] | None:
    """A callback queued on the running event loop and the list it appends to when it runs; None
    outside a running loop (a synchronous caller cannot interleave)."""
    try:
        loop = asyncio.get_running_loop()
    except RuntimeError:
        return None
    ran: list[bool] = []
    return loop.call_soon(ran.append, True), ran


class SentFanout:
    """``listeners`` hear of every message sent (:meth:`sent`); a :meth:`burst` holds them back."""

    def __init__(self) -> None:
        self.listeners: list[SentListener] = []
        self._held: list[tuple[int, Message]] | None = None

    def sent(self, seq: int, msg: Message) -> None:
        """``msg`` went to the transport with sequence number ``seq``."""
        if self._held is not None:
            self._held.append((seq, msg))
        else:
            self._tell(seq, msg)

    def _tell(self, seq: int, msg: Message) -> None:
        for cb in self.listeners:
            try:
                cb(seq, msg)
            except Exception:  # a bug in a listener must not fail the send
                log.exception("link: error in an on_sent listener")

    @contextlib.contextmanager
    def burst(self, transport: Transport | None) -> Iterator[None]:
        """Hold back the listeners and ``transport``'s writes and frame log until the block ends
        (:meth:`host.link.transports.base.Transport.burst`; nested blocks are one block; what was
        sent is written, logged and told however the block ends). Raises :class:`AwaitInBurst` when
        the block ends normally after awaiting inside (module docstring)."""
        if self._held is not None:
            yield
            return
        self._held = []
        marker = _loop_marker()
        try:
            with transport.burst() if transport is not None else contextlib.nullcontext():
                yield
        finally:
            held, self._held = self._held, None
            for seq, msg in held:
                self._tell(seq, msg)
            if marker is not None:
                marker[0].cancel()
        if marker is not None and marker[1]:
            raise AwaitInBurst(f"the event loop ran other tasks inside a burst of {len(held)} message(s): "
                               "something in the block awaited (host.link.sent)")
