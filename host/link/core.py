"""The link session proper: sequence numbers, sending, request/ACK/NACK and the link's state.

A :class:`LinkSession` owns one :class:`host.link.transports.base.Transport` (built on first use by
the ``make_transport`` it is given, then kept across reconnects) and:

* numbers and sends (:meth:`LinkSession.transmit`; 16-bit sequence numbers that wrap: every map keyed
  by one, the :class:`host.link.requests.RequestTable` and the :class:`host.link.camera.CameraAssembler`
  it holds, forgets the number's old entry when it is sent again, so answers from one lap are never
  taken for the next);
* awaits a request's ACK with retries (:meth:`LinkSession.request`; a NACK raises :class:`NackError`);
* keeps the link state: up (after a handshake, :meth:`link_up`), lost (:meth:`on_lost`, with the
  reason), closing; calls made while it is down raise :class:`LinkDown`.

It does not know who answers: the receive path (:class:`host.link.receive.ReceivePath`) is handed
the transport's items through ``receive``; the supervisor (:class:`host.link.supervisor.Supervisor`)
decides when to connect, handshake and reconnect; the commands, telemetry waits, board clock and
camera capture hold it through the narrow Protocols of their own modules. Whoever else must hear of
a handshake or a loss appends to ``on_link_up`` / ``on_fail``.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Sequence

import anyio

from host.link.camera import CameraAssembler
from host.link.errors import LinkDown, LinkError, LinkTimeout
from host.link.receive import LinkStats
from host.link.requests import RequestTable, RetransmitTimeout
from host.link.sent import SentFanout, SentListener
from host.link.transports import Transport
from host.link.waiting import Flag
from protocol.framing import DecodeError, Frame
from protocol.linkspec import LinkSpec, parse_link_spec
from protocol.messages import Ack, Caps, Message, Nack, ServoFrame
from protocol.wiremodel import WireModel

__all__ = ["LinkSession", "LinkTarget"]

log = logging.getLogger("host.link")

#: what a client connects to: a link spec (text or parsed), or a callable giving one, re-resolved on
#: every reconnect attempt (serial links: a board that comes back on another pty)
LinkTarget = LinkSpec | str | Callable[[], LinkSpec | str]


class LinkSession:
    """One link's numbering, sends, requests and state (module docstring).

    ``target`` is the link spec (or a callable giving one); ``make_transport`` builds the transport
    from it when none was given (``transport``; raising :class:`OSError` makes :class:`LinkDown`).
    ``reply_timeout`` (s, > 0) bounds each wait for an ACK; ``reconnect`` says whether the supervisor
    reconnects after a loss (it only changes the messages here); ``wire_baud`` makes :attr:`tx_wire`.
    """

    #: sends of one request before :class:`LinkTimeout` (a frame lost either way costs a retry).
    #: Six, not three: over CAN a SPEAKER or SCREEN request travels as an ISO-TP transfer of ~5 frames
    #: plus its flow control and the ACK, and any one of those ~7 frames dropped, flipped, duplicated
    #: or reordered fails the attempt; at the paper's fault rates (drop 1 %, corrupt 1 %, dup and
    #: reorder 0.5 % per frame) an attempt fails ~19 % of the time (1 - 0.97**7), so three attempts
    #: lost ~1 request in 150 (seen in CI: a speech call failed, tests/e2e/test_faults_can_e2e.py
    #: task 8) and six lose ~1 in 20 000. A link that is really gone is found by the heartbeat.
    request_attempts = 6

    def __init__(self, target: LinkTarget, make_transport: Callable[[LinkTarget], Transport], *,
                 transport: Transport | None = None, reply_timeout: float = 1.0, reconnect: bool = True,
                 wire_baud: int | None = None) -> None:
        if not reply_timeout > 0:
            raise ValueError(f"reply_timeout must be > 0 s, got {reply_timeout}")
        self.target = target
        self.spec: LinkSpec | None = None if callable(target) else parse_link_spec(target)
        #: the link as messages name it (the transport's name once connected: over CAN with its node)
        self.port_name: str = str(self.spec) if self.spec is not None else ""
        #: the spec to give ``--link`` to reach this board again (no decoration; see Transport.link_spec)
        self.link_spec: str = self.port_name
        self.reply_timeout, self.reconnect = reply_timeout, reconnect
        self._make_transport = make_transport
        self._transport = transport
        #: the transport's items go here (the receive path's ``on_items``; set by whoever assembles the parts)
        self.receive: Callable[[Sequence[Frame | DecodeError]], None] = lambda items: None
        self.caps: Caps | None = None  # the board's CAPS of the latest handshake
        self.stats = LinkStats()
        #: pending requests, frame NACKs and their waiters by sequence number (host.link.requests)
        self.requests = RequestTable(self.count_retry)
        self.camera = CameraAssembler()  # camera captures in progress, by the CAMERA_CAPTURE's seq too
        #: the wait before a request is re-sent, from this connection's measured round trips (at most
        #: ``reply_timeout``; measured anew after every handshake)
        self.rto = RetransmitTimeout(min_s=min(0.1, reply_timeout), max_s=reply_timeout)
        self.sent = SentFanout()  # the on_sent listeners
        #: the host's model of its own line (a UART of known baud; the emulated board's ``--baud``), or
        #: None: every message sent occupies it for its wire bytes, so the streamer knows how long a
        #: message sent now waits behind earlier ones (host.motion.board_link); set by whoever knows the rate
        self.tx_wire: WireModel | None = WireModel(wire_baud) if wire_baud else None
        self.tx_seq = 0
        self.last_tx = 0.0  # time.monotonic() of the latest send
        self.ready = False  # between a completed handshake and the loss
        self.closing = False
        self.up = Flag()  # set when a connection completed
        self.lost = Flag()  # set when the port went away
        self.last_disconnect_reason = ""
        self.last_reconnect_error = ""  # why the latest reconnect attempt failed ("" once it succeeded)
        #: called with the CAPS of every completed handshake (the board clock, the telemetry waits)
        self.on_link_up: list[Callable[[Caps], None]] = []
        #: called when the exchanges in flight fail (a loss, a close): the supervisor's HELLO and TIME_SYNC
        self.on_fail: list[Callable[[LinkError], None]] = []
        #: called after every reconnect
        self.on_reconnected: list[Callable[[], None]] = []

    # --- transport and state (the supervisor's calls; host.link.supervisor.SupervisedSession) ---

    @property
    def transport(self) -> Transport | None:
        """The transport (None before the first connection attempt)."""
        return self._transport

    async def attach(self, servo_count: int | None) -> Transport:
        """Connect the transport (built on first use) to :attr:`receive` and :meth:`on_lost`; the port's
        names are the transport's from here on. Raises :class:`LinkDown` when it cannot be opened."""
        if self._transport is None:
            try:
                self._transport = self._make_transport(self.target)
            except OSError as e:
                raise LinkDown(f"cannot open {self.target}: {e}") from None
        transport = self._transport
        if servo_count is not None:
            transport.set_servo_count(servo_count)
        self.lost.clear()
        await transport.connect(self.receive, self.on_lost)
        self.port_name = transport.name  # a callable spec resolves on connect
        self.link_spec = transport.link_spec
        return transport

    def link_up(self, caps: Caps) -> None:
        """The handshake succeeded with ``caps``: round trips are measured anew (a board after a reconnect
        may be another, slower one: QEMU), the ``on_link_up`` listeners hear of it, the link is ready."""
        self.caps = caps
        self.rto = RetransmitTimeout(min_s=self.rto.min_s, max_s=self.rto.max_s)
        for cb in self.on_link_up:
            cb(caps)
        self.ready = True

    def count_retry(self) -> None:
        """A message was sent again for want of its answer (``stats.retries``)."""
        self.stats.retries += 1

    def reconnected(self) -> None:
        """A reconnect completed: counted, logged, the ``on_reconnected`` listeners called."""
        self.stats.reconnects += 1
        self.last_reconnect_error = ""
        log.warning("link to %s re-established (reconnect #%d)", self.port_name, self.stats.reconnects)
        for cb in list(self.on_reconnected):
            cb()

    def on_lost(self, reason: str) -> None:
        """The transport lost the port (``reason``): everything in flight fails with :class:`LinkDown`."""
        was_ready = self.ready
        self.ready = False
        self.up.clear()
        self.last_disconnect_reason = reason
        self.fail_pending(LinkDown(f"link to {self.port_name!r} lost: {reason}"))
        if was_ready and not self.closing:
            log.warning("link to %s lost: %s%s", self.port_name, reason, "; reconnecting" if self.reconnect else "")
        self.lost.set()

    def close(self) -> None:
        """Close the transport and its frame log; everything in flight fails (idempotent)."""
        self.closing = True
        if self._transport is not None:
            self._transport.close()
        self.ready = False
        self.fail_pending(LinkDown("client closed"))

    def fail_pending(self, exc: LinkError) -> None:
        """Fail every request, capture and ``on_fail`` exchange in flight with ``exc``."""
        self.requests.fail_all(exc)
        for cb in self.on_fail:
            cb(exc)
        self.camera.clear()

    def require_ready(self) -> None:
        """:class:`LinkDown` unless the link is up."""
        if not self.ready:
            raise LinkDown(f"link to {self.port_name!r} is not up" + self.down_detail())

    def down_detail(self) -> str:
        """Why the link is down: the loss's cause and, while reconnecting fails, why."""
        return ((f" (last error: {self.last_disconnect_reason})" if self.last_disconnect_reason else "")
                + (f"; reconnecting fails: {self.last_reconnect_error}" if self.last_reconnect_error else ""))

    async def wait_connected(self, timeout: float) -> None:
        """Wait until the link is up (e.g. after a reconnect); :class:`LinkTimeout` otherwise."""
        with anyio.move_on_after(timeout):
            await self.up.wait()
            return
        raise LinkTimeout(f"link to {self.port_name or self.target!r} not up within {timeout} s" + self.down_detail())

    async def wait_disconnected(self, timeout: float) -> str:
        """Wait until the port goes away; returns the reason. :class:`LinkTimeout` otherwise."""
        with anyio.move_on_after(timeout):
            await self.lost.wait()
            return self.last_disconnect_reason
        raise LinkTimeout(f"link to {self.port_name!r} still up after {timeout} s")

    # --- sending ---------------------------------------------------------------------------

    def transmit(self, msg: Message) -> int:
        """Number ``msg`` and hand it to the transport, also before the handshake completed (HELLO,
        TIME_SYNC, a lockstep nudge's ADVANCE); returns its sequence number. :class:`LinkDown` when
        the transport is not connected."""
        t = self._transport
        if t is None or not t.connected:
            raise LinkDown(f"link to {self.port_name!r} is down" + (" (reconnecting)" if self.reconnect else "")
                           + self.down_detail())
        seq = self.tx_seq
        self.requests.forget_seq(seq)  # 16-bit wrap: nothing keyed by seq's previous use survives
        self.camera.forget_seq(seq)
        nbytes = t.send(msg, seq)
        self.tx_seq = (seq + 1) & 0xFFFF
        self.last_tx = time.monotonic()
        if self.tx_wire is not None:
            self.tx_wire.occupy(self.last_tx, nbytes)
        self.stats.tx_frames += 1
        if type(msg) is ServoFrame:
            self.stats.servo_frames_sent += 1
        self.sent.sent(seq, msg)
        return seq

    def send(self, msg: Message) -> int:
        """Send any message without waiting for a reply; returns its sequence number. :class:`LinkDown`
        unless the link is up."""
        self.require_ready()
        return self.transmit(msg)

    @property
    def on_sent(self) -> list[SentListener]:
        """Called with (seq, message) after every message handed to the transport (inside :meth:`burst`,
        when the block ends): listeners, e.g. a run's recorder (python-can's Listener model). Append to
        it; the list itself is the fan-out's and cannot be replaced."""
        return self.sent.listeners

    def burst(self) -> contextlib.AbstractContextManager[None]:
        """Messages sent inside go on the wire together when the block ends (serial: one write, so the
        board reads them at once), then the frame log's records of them and the ``on_sent`` listeners,
        in send order. For sends that must follow each other closely: a start's FLUSH and first frame
        (otherwise the board handled the FLUSH alone, one read and ~0.2 ms before the frame).
        Nested blocks are one block. Nothing inside may await (:class:`host.link.sent.SentFanout`)."""
        return self.sent.burst(self._transport)

    async def request(self, msg: Message, timeout: float | None = None, attempts: int | None = None) -> Ack:
        """Send ``msg`` and await its ACK, re-sending it (new sequence number) after each
        ``timeout`` s without a reply, ``attempts`` times in all (default :attr:`request_attempts`);
        the first ACK/NACK to any copy answers. Without ``timeout`` the first re-send comes after the
        link's measured round-trip timeout (:attr:`rto`, 0.1 s to ``reply_timeout``), later ones
        after twice the wait before, up to ``reply_timeout``, for ``attempts × reply_timeout`` s in
        all (:meth:`host.link.requests.RequestTable.request`).

        Raises :class:`NackError` (the board's reason) on a NACK, :class:`LinkTimeout` without
        a reply, :class:`LinkDown` when the link is not up. For messages the board answers
        with ACK/NACK: FLUSH, ESTOP, ESTOP_CLEAR, ADVANCE, CONFIG, SCREEN, SPEAKER (all of
        which the board may apply twice with the same effect, so a lost ACK is harmless).
        """
        self.require_ready()
        return await self.requests.request(self.transmit, msg, timeout or self.reply_timeout,
                                           attempts or self.request_attempts,
                                           rto=self.rto if timeout is None else None)

    def frame_nack(self, seq: int) -> Nack | None:
        """The NACK the board sent for the latest frame sent with sequence ``seq``, if any (last 1024 kept)."""
        return self.requests.frame_nack(seq)

    async def wait_frame_nack(self, seq: int, timeout: float) -> Nack | None:
        """The NACK for frame ``seq``, waiting up to ``timeout`` s; None if none came (or ``seq`` was reused)."""
        return await self.requests.wait_frame_nack(seq, timeout)
