"""The link session: the host's client for a robot's board, written once above every transport.

``BoardClient`` owns one :class:`host.link.transports.base.Transport` (serial, CAN; built from a link
spec by :func:`host.link.transports.open_transport`) and speaks protocol v1 over it: handshake
(HELLO -> CAPS; the robot's wire schema first, each other schema this build speaks after a
SCHEMA_MISMATCH, :class:`RobotMismatch` when the board drives another robot), NTP-style time sync
(realtime boards; a lockstep board's clock is virtual and moves on :meth:`advance`), timed servo
frames (no reply when accepted; a NACK is recorded), control requests awaiting their ACK (a NACK
raises :class:`NackError`), telemetry, fault edges and camera images in, a heartbeat whenever nothing
else was sent for ``heartbeat_s``, and reconnection with exponential backoff when the wire goes away
(calls made meanwhile raise :class:`LinkDown`). Undecodable frames are counted, never raised.

The parts are objects of their own, as python-can splits Bus, Notifier and Listener. This module is
the session: it numbers and sends (16-bit sequence numbers that wrap; every map keyed by one forgets
the number's old entry when it is sent again, so answers from one lap are never taken for the next),
and keeps the link state (up, lost, closing). The rest:

* :mod:`host.link.requests` (:class:`RequestTable`): pending requests by sequence number, ACK/NACK
  matching, retries, frame NACKs and their waiters;
* :mod:`host.link.supervisor` (:class:`Supervisor`): handshake, time sync, heartbeat, reconnect; it
  knows the session as the Protocol ``SupervisedSession``; its loops run in
  :mod:`host.link.background` (an anyio task group);
* :mod:`host.link.receive` (:class:`ReceivePath`, the Notifier): received messages to their handler
  through a table, then to the ``on_received`` listeners;
* listeners: telemetry fan-out and fault edges (:class:`host.link.telemetry.TelemetryFanout`),
  camera reassembly (:class:`host.link.camera.CameraAssembler`), ``on_sent`` (:class:`host.link.sent.SentFanout`,
  held back with the writes and the frame log inside :meth:`BoardClient.burst`) / ``on_received`` /
  ``on_nack`` / ``on_fault`` callbacks (a run's recorder and live view), the frame log (the
  transport's, :mod:`protocol.logfile`, with ``log_path``);
* mixins giving ``BoardClient`` its convenience API: :class:`host.link.board_commands.BoardCommands`
  (frames, FLUSH, ESTOP, ADVANCE, CONFIG, SCREEN, SPEAKER, capture),
  :class:`host.link.telemetry_waits.TelemetryWaits` (``wait_for`` with the lockstep nudge,
  ``next_telemetry``, ``telemetry()``) and :class:`host.link.board_time.BoardTime` (board clock).

Waiting is anyio (:mod:`host.link.waiting`); the session runs on anyio's asyncio backend or under
``asyncio.run`` (the transports sit on the asyncio loop). Open with ``await BoardClient.connect(...)``
or ``async with``; :meth:`BoardClient.close` is idempotent.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import anyio

from host.link.background import BackgroundLoops
from host.link.board_commands import BoardCommands
from host.link.camera import CameraAssembler
from host.link.errors import LinkDown, LinkError, LinkTimeout
from host.link.receive import LinkStats, ReceivePath
from host.link.requests import RequestTable, RetransmitTimeout
from host.link.sent import SentFanout, SentListener
from host.link.supervisor import RobotIdentity, Supervisor, host_now_us
from host.link.telemetry import FAULT_BITS, FaultEvent, TelemetryFanout
from host.link.telemetry_waits import TelemetryWaits
from host.link.timesync import ClockSync
from host.link.transports import Transport, open_transport
from host.link.waiting import Flag
from protocol.codec import WIRE_SCHEMA_16, WireBoundError, WireSchema, schema_for
from protocol.faults import GapDetector
from protocol.linkspec import LinkSpec, parse_link_spec
from protocol.messages import PROTOCOL_VERSION, Ack, Caps, Message, Nack, ServoFrame, SimState
from protocol.wiremodel import WireModel

__all__ = ["FAULT_BITS", "HEARTBEAT_S", "BoardClient", "FaultEvent", "LinkStats", "LinkTarget", "RobotIdentity", "host_now_us"]

log = logging.getLogger("host.link")
#: a HEARTBEAT whenever nothing else was sent for this long (s): four per 200 ms of the board's default watchdog
HEARTBEAT_S = 0.05

#: what a client connects to: a link spec (text or parsed), or a callable giving one, re-resolved on
#: every reconnect attempt (serial links: a board that comes back on another pty)
LinkTarget = LinkSpec | str | Callable[[], LinkSpec | str]
PortSpec = LinkTarget  # old name


class BoardClient(ReceivePath, TelemetryWaits, BoardCommands):
    """Client for one board; create with ``await BoardClient.connect(spec)`` or ``async with``.

    ``link`` is a link spec (``"/dev/pts/3"``, ``"can:socketcan:vcan0?node=2"``, a
    :class:`LinkSpec`) or a callable returning one; ``transport`` (optional) is an already
    built transport to use instead (e.g. one wrapped for fault injection). ``baud`` and
    ``force_thread`` are for serial links; ``log_path`` is the transport's frame log;
    ``transport_options`` go to :func:`host.link.transports.open_transport` (CAN settings).
    ``robot`` is the robot this host was started for (CAPS must report it; it also picks the wire
    schema); ``schema_hash`` pins the hash HELLO carries (tests), instead of the robot's schema's.
    ``wire_baud``: the line's rate when the host should model it (:attr:`tx_wire`; a UART whose wire
    time matters, such as the emulated board's ``--baud``), else None.
    """

    def __init__(
        self, link: LinkTarget, *, transport: Transport | None = None, baud: int = 115200,
        log_path: str | Path | None = None, reply_timeout: float = 1.0, handshake_timeout: float = 3.0,
        heartbeat_s: float = HEARTBEAT_S, sync_interval_s: float = 0.5, sync_burst: int = 8, reconnect: bool = True,
        reconnect_max_s: float = 1.0, telemetry_queue: int = 64, protocol_version: int = PROTOCOL_VERSION,
        schema_hash: int | None = None, force_thread: bool = False, transport_options: dict[str, Any] | None = None,
        robot: RobotIdentity | None = None, wire_baud: int | None = None,
    ) -> None:
        self._port = link
        self.robot = robot
        self.baud, self.force_thread, self.log_path = baud, force_thread, log_path
        self.reply_timeout, self.handshake_timeout = reply_timeout, handshake_timeout
        self.heartbeat_s, self.sync_interval_s, self.sync_burst = heartbeat_s, sync_interval_s, sync_burst
        self.reconnect, self.reconnect_max_s = reconnect, reconnect_max_s
        self.telemetry_queue = telemetry_queue
        self.protocol_version = protocol_version
        try:
            #: the wire schema of the robot this host was started for (the u16 one without a robot)
            self.schema: WireSchema = WIRE_SCHEMA_16 if robot is None else schema_for(robot.servo_count)
        except WireBoundError as e:
            raise LinkError(f"robot {robot}: {e}") from None
        self._schema_pinned = schema_hash is not None
        #: the schema hash HELLO carries (the one the board accepted, after a handshake)
        self.schema_hash = self.schema.hash if schema_hash is None else schema_hash
        self.transport_options = dict(transport_options or {})
        self.spec: LinkSpec | None = None if callable(link) else parse_link_spec(link)
        self.port_name: str = str(self.spec) if self.spec is not None else ""
        #: the spec to give ``--link`` to reach this board again (no decoration; see Transport.link_spec)
        self.link_spec: str = str(self.spec) if self.spec is not None else ""
        self.caps: Caps | None = None
        self._rx_gaps = GapDetector()
        self.clock = ClockSync()
        self.stats = LinkStats()
        #: the TELEMETRY listener: latest report, fault edges, subscribers, waiters (host.link.telemetry)
        self.fanout = TelemetryFanout(telemetry_queue)
        self.latest_sim_state: SimState | None = None
        self.on_nack: list[Callable[[Nack], None]] = []
        #: the board's latest NACK SERVO_FAULT (its detail names the servo that stopped answering on its bus)
        self.servo_fault: Nack | None = None
        #: every NACK SERVO_FAULT so far, oldest first, the last 64 (the board reports each failed servo in
        #: its own: several silent at once; host.link.faultcheck.servo_fault_message reads them)
        self.servo_faults: list[Nack] = []
        #: the board stops when this command does (the command started it): a servo fault's line says to run
        #: again, not how to clear a board that will be gone (set by whoever started it)
        self.board_started_here = False
        self._sent = SentFanout()  # the on_sent listeners
        #: called with every message received, after the client handled it (listeners, e.g. a run's
        #: recorder; python-can's Listener model)
        self.on_received: list[Callable[[Message], None]] = []
        self.on_reconnect: list[Callable[[BoardClient], None]] = []
        self.keepalive = True  # heartbeat + periodic sync; turn off to let the watchdog fire
        #: the host's model of its own line (a UART of known baud; the emulated board's ``--baud``), or
        #: None: every message sent occupies it for its wire bytes, so the streamer knows how long a
        #: message sent now waits behind earlier ones (host.motion.board_link); set by whoever knows the rate
        self.tx_wire: WireModel | None = WireModel(wire_baud) if wire_baud else None

        self._transport: Transport | None = transport
        self._tx_seq = 0
        self._ready = False
        self._closing = False
        self._last_tx = 0.0
        self._board_time_seen = 0
        #: pending requests, frame NACKs and their waiters by sequence number (host.link.requests)
        self.requests = RequestTable(self._count_retry)
        if not reply_timeout > 0:
            raise ValueError(f"reply_timeout must be > 0 s, got {reply_timeout}")
        #: the wait before a request is re-sent, from this connection's measured round trips (at most
        #: ``reply_timeout``; measured anew after every handshake)
        self.rto = RetransmitTimeout(min_s=min(0.1, reply_timeout), max_s=reply_timeout)
        self.report_latencies = deque(maxlen=16)  # what the lockstep nudge waits (TelemetryWaits.nudge_raise_s)
        self.camera = CameraAssembler()  # camera captures in progress (host.link.camera)
        #: handshake, time sync, heartbeat, reconnect (host.link.supervisor)
        self.supervisor = Supervisor(self)
        self._background = BackgroundLoops()
        self._next_request_id = 1
        self._connected = Flag()
        self._lost = Flag()
        self.last_disconnect_reason = ""
        self.last_reconnect_error = ""  # why the latest reconnect attempt failed ("" once it succeeded)

    # --- lifecycle -------------------------------------------------------------------------

    @classmethod
    async def connect(cls, link: LinkTarget, **kw: Any) -> BoardClient:
        """Open ``link``, handshake and sync; raises :class:`LinkError` (with the reason) on failure
        and :class:`protocol.linkspec.LinkSpecError` (a ``ValueError``) for a malformed spec."""
        client = cls(link, **kw)
        try:
            await client.open()
        except BaseException:
            await client.close()
            raise
        return client

    async def open(self) -> None:
        """First connection (no retries: a wrong port should fail fast), then the background loops."""
        await self.supervisor.connect_once()
        sup = self.supervisor
        self._background.start({"link-supervisor": sup.supervise, "link-heartbeat": sup.heartbeat_loop,
                                "link-sync": sup.sync_loop})

    async def close(self) -> None:
        """Stop the background loops, close the transport and its frame log (idempotent)."""
        self._closing = True
        try:
            await self._background.stop()
        finally:  # also when the close itself is cancelled (a second Ctrl-C): the port and the frame log close
            if self._transport is not None:
                self._transport.close()
            self._ready = False
            self._fail_pending(LinkDown("client closed"))

    async def __aenter__(self) -> BoardClient:
        if not self._background.running:
            try:
                await self.open()
            except BaseException:
                await self.close()
                raise
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    @property
    def connected(self) -> bool:
        """True between a completed handshake and the port going away."""
        return self._ready

    async def wait_connected(self, timeout: float) -> None:
        """Wait until the link is up (e.g. after a reconnect); :class:`LinkTimeout` otherwise."""
        with anyio.move_on_after(timeout):
            await self._connected.wait()
            return
        raise LinkTimeout(f"link to {self.port_name or self._port!r} not up within {timeout} s" + self._down_detail())

    async def wait_disconnected(self, timeout: float) -> str:
        """Wait until the port goes away; returns the reason. :class:`LinkTimeout` otherwise."""
        with anyio.move_on_after(timeout):
            await self._lost.wait()
            return self.last_disconnect_reason
        raise LinkTimeout(f"link to {self.port_name!r} still up after {timeout} s")

    @property
    def transport(self) -> Transport | None:
        """The transport (None before the first connection attempt)."""
        return self._transport

    def _get_transport(self) -> Transport:
        """The transport, built from the spec on first use (it then lives across reconnects)."""
        if self._transport is None:
            options = dict(self.transport_options)
            if self.robot is not None:
                options.setdefault("servo_count", self.robot.servo_count)
            try:
                self._transport = open_transport(self._port, baud=self.baud, log_path=self.log_path,
                                                 force_thread=self.force_thread, **options)
            except OSError as e:
                raise LinkDown(f"cannot open {self._port}: {e}") from None
        return self._transport

    # --- link state (the supervisor's calls; host.link.supervisor.SupervisedSession) --------

    def _link_up(self, caps: Caps) -> None:
        """The handshake succeeded with ``caps``: the board's clock starts afresh (its numbering did when
        the CAPS arrived: :meth:`host.link.receive.ReceivePath._on_items`)."""
        self.caps = caps
        self._board_time_seen = caps.board_time_us
        self.clock.clear()
        # a board after a reconnect may be another (a slower one, QEMU): its round trips are measured anew
        self.rto = RetransmitTimeout(min_s=self.rto.min_s, max_s=self.rto.max_s)
        self.report_latencies.clear()
        self._ready = True

    def _count_retry(self) -> None:
        self.stats.retries += 1

    def _reconnected(self) -> None:
        self.stats.reconnects += 1
        self.last_reconnect_error = ""
        log.warning("link to %s re-established (reconnect #%d)", self.port_name, self.stats.reconnects)
        for cb in list(self.on_reconnect):
            cb(self)

    def _on_lost(self, reason: str) -> None:
        was_ready = self._ready
        self._ready = False
        self._connected.clear()
        self.last_disconnect_reason = reason
        self._fail_pending(LinkDown(f"link to {self.port_name!r} lost: {reason}"))
        if was_ready and not self._closing:
            log.warning("link to %s lost: %s%s", self.port_name, reason, "; reconnecting" if self.reconnect else "")
        self._lost.set()

    def _fail_pending(self, exc: LinkError) -> None:
        self.requests.fail_all(exc)
        self.supervisor.fail_all(exc)
        self.camera.clear()

    def _require_ready(self) -> None:
        if not self._ready:
            raise LinkDown(f"link to {self.port_name!r} is not up" + self._down_detail())

    def _down_detail(self) -> str:
        """Why the link is down: the loss's cause and, while reconnecting fails, why."""
        return ((f" (last error: {self.last_disconnect_reason})" if self.last_disconnect_reason else "")
                + (f"; reconnecting fails: {self.last_reconnect_error}" if self.last_reconnect_error else ""))

    # --- sending ---------------------------------------------------------------------------

    def _send(self, msg: Message) -> int:
        t = self._transport
        if t is None or not t.connected:
            raise LinkDown(f"link to {self.port_name!r} is down" + (" (reconnecting)" if self.reconnect else "")
                           + self._down_detail())
        seq = self._tx_seq
        self.requests.forget_seq(seq)  # 16-bit wrap: nothing keyed by seq's previous use survives
        self.camera.forget_seq(seq)
        nbytes = t.send(msg, seq)
        self._tx_seq = (seq + 1) & 0xFFFF
        self._last_tx = time.monotonic()
        if self.tx_wire is not None:
            self.tx_wire.occupy(self._last_tx, nbytes)
        self.stats.tx_frames += 1
        if type(msg) is ServoFrame:
            self.stats.servo_frames_sent += 1
        self._sent.sent(seq, msg)
        return seq

    @property
    def on_sent(self) -> list[SentListener]:
        """Called with (seq, message) after every message handed to the transport (inside :meth:`burst`,
        when the block ends): listeners, e.g. a run's recorder (python-can's Listener model). Append to
        it; the list itself is the fan-out's and cannot be replaced."""
        return self._sent.listeners

    def burst(self) -> contextlib.AbstractContextManager[None]:
        """Messages sent inside go on the wire together when the block ends (serial: one write, so the
        board reads them at once), then the frame log's records of them and the ``on_sent`` listeners,
        in send order. For sends that must follow each other closely: a start's FLUSH and first frame
        (otherwise the board handled the FLUSH alone, one read and ~0.2 ms before the frame).
        Nested blocks are one block. Nothing inside may await (:class:`host.link.sent.SentFanout`)."""
        return self._sent.burst(self._transport)

    #: sends of one request before :class:`LinkTimeout` (a frame lost either way costs a retry).
    #: Six, not three: over CAN a SPEAKER or SCREEN request travels as an ISO-TP transfer of ~5 frames
    #: plus its flow control and the ACK, and any one of those ~7 frames dropped, flipped, duplicated
    #: or reordered fails the attempt; at the paper's fault rates (drop 1 %, corrupt 1 %, dup and
    #: reorder 0.5 % per frame) an attempt fails ~19 % of the time (1 - 0.97**7), so three attempts
    #: lost ~1 request in 150 (seen in CI: a speech call failed, tests/e2e/test_faults_can_e2e.py
    #: task 8) and six lose ~1 in 20 000. A link that is really gone is found by the heartbeat.
    request_attempts = 6

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
        self._require_ready()
        return await self.requests.request(self._send, msg, timeout or self.reply_timeout,
                                           attempts or self.request_attempts,
                                           rto=self.rto if timeout is None else None)

    _request = request

    def send(self, msg: Message) -> int:
        """Send any message without waiting for a reply; returns its sequence number."""
        self._require_ready()
        return self._send(msg)

    def frame_nack(self, seq: int) -> Nack | None:
        """The NACK the board sent for the latest frame sent with sequence ``seq``, if any (last 1024 kept)."""
        return self.requests.frame_nack(seq)

    async def wait_frame_nack(self, seq: int, timeout: float) -> Nack | None:
        """The NACK for frame ``seq``, waiting up to ``timeout`` s; None if none came (or ``seq`` was reused)."""
        return await self.requests.wait_frame_nack(seq, timeout)

    async def _connect_once(self) -> None:
        """Connect, handshake and sync once (:meth:`host.link.supervisor.Supervisor.connect_once`)."""
        await self.supervisor.connect_once()

    # --- internals kept by name for tests and the fuzz harness (host.fuzz.session) ----------

    @property
    def _pending(self) -> dict[int, Any]:
        return self.requests.pending  # type: ignore[return-value]

    @property
    def _frame_nacks(self) -> dict[int, Nack]:
        return self.requests.frame_nacks

    @property
    def _sync_pending(self) -> dict[int, Any]:
        return self.supervisor.sync_pending
