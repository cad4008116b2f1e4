"""The ``on_sent`` listeners of a session (``BoardClient.on_sent``), told after every send or after a burst.

python-can's ``Listener`` model for the transmit side: a run's recorder, a live view or a test
registers ``callback(seq, message)``; a failing listener is logged and never fails the send. Inside
:meth:`SentFanout.burst` the sends go on the wire together when the block ends, and the listeners, like the transport's
frame log (:meth:`host.link.transports.base.Transport.burst`), hear of them when the block
ends, in send order.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Iterator

from host.link.transports import Transport
from protocol.messages import Message

__all__ = ["SentFanout", "SentListener"]

log = logging.getLogger("host.link")

#: called with (sequence number, message) after a message was handed to the transport
SentListener = Callable[[int, Message], None]


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
        sent is written, logged and told however the block ends)."""
        if self._held is not None:
            yield
            return
        self._held = []
        try:
            with transport.burst() if transport is not None else contextlib.nullcontext():
                yield
        finally:
            held, self._held = self._held, None
            for seq, msg in held:
                self._tell(seq, msg)
