"""The host's link transport interface: what the session (:mod:`host.link.core`) needs from a wire.

Modelled on python-can's split of ``BusABC`` from ``can/interfaces/*``: a transport
moves whole protocol-v1 messages (with their 16-bit sequence number) to and from one
board and owns everything about its wire: the framing (COBS + CRC on serial, CAN
frames / ISO-TP on CAN) and the frame log (JSON Lines on serial, python-can writers
on CAN). The session above it (handshake, ACK/NACK, time sync, heartbeat, reconnect,
telemetry, faults, camera) is written once for every transport.

Life cycle: the session builds one transport per client (``open_transport``) and calls
:meth:`Transport.connect` for the first connection and again after every loss; a
transport object therefore outlives reconnects and keeps one frame log. All callbacks
run on the event loop thread.
"""

from __future__ import annotations

import contextlib
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence

from protocol.framing import DecodeError, Frame
from protocol.messages import Message

__all__ = ["LossHandler", "ReceiveHandler", "Transport"]

#: called with every batch of received items, in wire order: decoded frames and decode errors
ReceiveHandler = Callable[[Sequence[Frame | DecodeError]], None]
#: called once per connection when the wire goes away, with a human-readable reason
LossHandler = Callable[[str], None]


class Transport(ABC):
    """One wire to one board. Subclasses: :class:`host.link.transports.serial.SerialLinkTransport`, CAN."""

    @property
    @abstractmethod
    def name(self) -> str:
        """Where the link goes, for messages (``"/dev/pts/3"``, ``"can:socketcan:vcan0 (node 1)"``)."""

    @property
    def link_spec(self) -> str:
        """The link spec that reaches this board again, as ``--link`` takes it (``"/dev/pts/3"``,
        ``"can:slcan:/dev/pts/4?node=2"``): :attr:`name` without decoration. Valid after :meth:`connect`."""
        return self.name

    def use_board_clock(self, board_clock: Callable[[], int] | None) -> None:
        """A lockstep board's time as the host knows it (ns) for the wire's own timers (CAN's ISO-TP:
        :mod:`protocol.can.isotp_link`); None: wall time. A wire without timers ignores it."""

    @property
    @abstractmethod
    def connected(self) -> bool:
        """True between a successful :meth:`connect` and the loss / :meth:`disconnect`."""

    @abstractmethod
    async def connect(self, on_receive: ReceiveHandler, on_lost: LossHandler) -> None:
        """Open the wire (again) and start delivering received items to ``on_receive``.

        Raises :class:`host.link.errors.LinkDown` with the reason and a hint when the wire
        cannot be opened. After a loss ``on_lost(reason)`` is called exactly once and the
        wire is closed; the session may call :meth:`connect` again.
        """

    @abstractmethod
    def send(self, msg: Message, seq: int) -> int:
        """Encode ``msg`` with sequence number ``seq`` (0..65535), queue it for the wire and log it;
        returns the wire bytes it takes on a serial line (the encoded frame, for the session's model of
        the line, ``BoardClient.tx_wire``), 0 on a CAN bus (whose timing the host does not model).

        Never blocks. Raises :class:`host.link.errors.LinkDown` when not connected (or the write
        found the wire gone) and :class:`host.link.errors.LinkError` when the transmit backlog
        is full (the board stopped reading); nothing is logged then.
        """

    def burst(self) -> contextlib.AbstractContextManager[None]:
        """A block of sends that go out together when it ends, then are logged (``BoardClient.burst``: a
        start's FLUSH and first frame). Serial: one write where the port has a file descriptor (a pty,
        a tty; the board reads both at once and handles the frame right after the FLUSH, not a loop
        turn later; a port written from a thread writes each at once), then the frame log's records,
        stamped with the time of that write. This default sends and logs each at once (the CAN
        transports: their frames go out from a transmit queue, logged as they leave it). Errors are
        raised as :meth:`send` raises them; a write failing when the block ends is a lost link.
        """
        return contextlib.nullcontext()

    def set_servo_count(self, servo_count: int) -> None:
        """Speak the wire form of a robot of ``servo_count`` servos from now on: serial, its wire
        schema (:func:`protocol.codec.schema_for`); CAN, its layout table
        (:func:`protocol.can.layouts.can_layouts`). The session calls it before connecting when it
        knows its robot, and again with the servo count CAPS reports. Raises
        :class:`protocol.codec.WireBoundError` for a count the wire cannot carry. A transport whose
        framing does not depend on the robot keeps this default (nothing to change)."""

    @property
    def backlog(self) -> int:
        """Bytes (or encoded frame bytes) accepted by :meth:`send` but not yet handed to the OS."""
        return 0

    @abstractmethod
    def disconnect(self) -> None:
        """Close the wire without reporting a loss; the frame log stays open (idempotent)."""

    @abstractmethod
    def close(self) -> None:
        """:meth:`disconnect` and close the frame log (idempotent)."""
