"""The link client: the host's client for a robot's board, written once above every transport.

``BoardClient`` owns one :class:`host.link.transports.base.Transport` (serial, CAN; built from a link
spec by :func:`host.link.transports.open_transport`) and speaks protocol v1 over it: handshake
(HELLO -> CAPS; the robot's wire schema first, each other schema this build speaks after a
SCHEMA_MISMATCH, :class:`RobotMismatch` when the board drives another robot), NTP-style time sync
(realtime boards; a lockstep board's clock is virtual and moves on ``advance``), timed servo
frames (no reply when accepted; a NACK is recorded), control requests awaiting their ACK (a NACK
raises :class:`NackError`), telemetry, fault edges and camera images in, a heartbeat whenever nothing
else was sent for ``heartbeat_s``, and reconnection with exponential backoff when the wire goes away
(calls made meanwhile raise :class:`LinkDown`). Undecodable frames are counted, never raised.

It is a facade over parts, each an object of its own (as python-can splits Bus, Notifier and
Listener), each holding the others only through a narrow Protocol of its own module:

* ``session`` (:class:`host.link.core.LinkSession`): sequence numbers, sends, request/ACK/NACK
  (:class:`host.link.requests.RequestTable`), link state (up, lost, closing);
* ``supervisor`` (:class:`host.link.supervisor.Supervisor`): handshake, time sync, heartbeat,
  reconnect; its loops run in :mod:`host.link.background` (an anyio task group);
* ``receiver`` (:class:`host.link.receive.ReceivePath`, the Notifier): received messages to their
  handler through a table, then to the ``on_received`` listeners;
* ``board_clock`` (:class:`host.link.board_time.BoardClock`): board time, synced or reported;
* ``waits`` (:class:`host.link.telemetry_waits.TelemetryWaits`) over the TELEMETRY listener
  ``fanout`` (:class:`host.link.telemetry.TelemetryFanout`): ``wait_for`` with the lockstep nudge,
  ``next_telemetry``, ``telemetry()``;
* ``commands`` and ``capturer`` (:mod:`host.link.board_commands`): frames, FLUSH, ESTOP, ADVANCE,
  CONFIG, SCREEN, SPEAKER; camera capture over :class:`host.link.camera.CameraAssembler`.

The parts' public methods are the client's own (bound once when it is made: no extra call per use);
its state is read through properties. Waiting is anyio (:mod:`host.link.waiting`); the client runs on
anyio's asyncio backend or under ``asyncio.run`` (the transports sit on the asyncio loop). Open with
``await BoardClient.connect(...)`` or ``async with``; :meth:`BoardClient.close` is idempotent.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from host.link.background import BackgroundLoops
from host.link.board_commands import BoardCommands, CameraCapturer
from host.link.board_time import BoardClock
from host.link.camera import CameraAssembler
from host.link.core import LinkSession, LinkTarget
from host.link.errors import LinkError
from host.link.facade import PartAttr, WritablePartAttr
from host.link.receive import LinkStats, ReceivePath
from host.link.requests import RequestTable, RetransmitTimeout
from host.link.sent import SentListener
from host.link.supervisor import HEARTBEAT_S, RobotIdentity, Supervisor, host_now_us
from host.link.telemetry import FAULT_BITS, FaultEvent, TelemetryFanout
from host.link.telemetry_waits import TelemetryWaits
from host.link.timesync import ClockEstimate, ClockSync
from host.link.transports import Transport, open_transport
from protocol.codec import WIRE_SCHEMA_16, WireBoundError, WireSchema, schema_for
from protocol.linkspec import LinkSpec
from protocol.messages import PROTOCOL_VERSION, Caps, ConfigKey, FaultFlags, Message, Nack, SimState, Telemetry
from protocol.wiremodel import WireModel

__all__ = ["FAULT_BITS", "HEARTBEAT_S", "BoardClient", "FaultEvent", "LinkStats", "LinkTarget", "RobotIdentity", "host_now_us"]

log = logging.getLogger("host.link")


class BoardClient:
    """Client for one board; create with ``await BoardClient.connect(spec)`` or ``async with``.

    ``link`` is a link spec (``"/dev/pts/3"``, ``"can:socketcan:vcan0?node=2"``, a
    :class:`LinkSpec`) or a callable returning one; ``transport`` (optional) is an already
    built transport to use instead (e.g. one wrapped for fault injection). ``baud`` and
    ``force_thread`` are for serial links; ``log_path`` is the transport's frame log;
    ``transport_options`` go to :func:`host.link.transports.open_transport` (CAN settings).
    ``robot`` is the robot this host was started for (CAPS must report it; it also picks the wire
    schema); ``schema_hash`` pins the hash HELLO carries (tests), instead of the robot's schema's.
    ``wire_baud``: the line's rate when the host should model it (:attr:`tx_wire`; a UART whose wire
    time matters, such as the emulated board's ``--baud``), else None. ``link_config``: (key, value) CONFIGs
    the handshake sends after CAPS (a slow line's watchdog and report rate, :mod:`host.motion.line_cadence`).
    The rest are the supervisor's
    (:class:`host.link.supervisor.Supervisor`) and the session's (:class:`host.link.core.LinkSession`).
    """

    def __init__(
        self, link: LinkTarget, *, transport: Transport | None = None, baud: int = 115200,
        log_path: str | Path | None = None, reply_timeout: float = 1.0, handshake_timeout: float = 3.0,
        heartbeat_s: float = HEARTBEAT_S, sync_interval_s: float = 0.5, sync_burst: int = 8, reconnect: bool = True,
        reconnect_max_s: float = 1.0, telemetry_queue: int = 64, protocol_version: int = PROTOCOL_VERSION,
        schema_hash: int | None = None, force_thread: bool = False, transport_options: dict[str, Any] | None = None,
        robot: RobotIdentity | None = None, wire_baud: int | None = None,
        link_config: tuple[tuple[ConfigKey, int], ...] = (),
    ) -> None:
        self.robot = robot
        try:
            #: the wire schema of the robot this host was started for (the u16 one without a robot)
            self.schema: WireSchema = WIRE_SCHEMA_16 if robot is None else schema_for(robot.servo_count)
        except WireBoundError as e:
            raise LinkError(f"robot {robot}: {e}") from None
        options = dict(transport_options or {})
        if robot is not None:
            options.setdefault("servo_count", robot.servo_count)

        def make_transport(target: LinkTarget) -> Transport:
            return open_transport(target, baud=baud, log_path=log_path, force_thread=force_thread, **options)

        self.session = s = LinkSession(link, make_transport, transport=transport, reply_timeout=reply_timeout,
                                       reconnect=reconnect, wire_baud=wire_baud)
        self.board_clock = clock = BoardClock(s)
        self.supervisor = sup = Supervisor(
            s, clock, robot=robot, schema=self.schema, schema_hash=schema_hash, protocol_version=protocol_version,
            handshake_timeout=handshake_timeout, reconnect_max_s=reconnect_max_s, sync_burst=sync_burst,
            heartbeat_s=heartbeat_s, sync_interval_s=sync_interval_s, link_config=link_config)
        #: the TELEMETRY listener: latest report, fault edges, subscribers, waiters (host.link.telemetry)
        self.fanout = TelemetryFanout(telemetry_queue)
        self.receiver = rx = ReceivePath(s, self.fanout, clock, sup)
        s.receive = rx.on_items
        self.waits = waits = TelemetryWaits(s, self.fanout, clock, sup.sync_once)
        s.on_link_up += [clock.restart, waits.restart, self._wire_clock]
        s.on_fail.append(sup.fail_all)
        s.on_reconnected.append(self._reconnected)
        self.commands = cmd = BoardCommands(s)
        self.capturer = CameraCapturer(s)
        self.on_reconnect: list[Callable[[BoardClient], None]] = []
        #: the board stops when this command does (the command started it): a servo fault's line says to run
        #: again, not how to clear a board that will be gone (set by whoever started it)
        self.board_started_here = False
        self._background = BackgroundLoops()
        # the parts' API as the client's own (bound methods: no extra call per use)
        self.send, self.request, self.burst = s.send, s.request, s.burst
        self.frame_nack, self.wait_frame_nack = s.frame_nack, s.wait_frame_nack
        self.wait_connected, self.wait_disconnected = s.wait_connected, s.wait_disconnected
        self.send_frame, self.send_targets, self.all_mask = cmd.send_frame, cmd.send_targets, cmd.all_mask
        self.flush, self.estop, self.estop_clear, self.advance = cmd.flush, cmd.estop, cmd.estop_clear, cmd.advance
        self.configure, self.screen, self.speaker = cmd.configure, cmd.screen, cmd.speaker
        self.capture = self.capturer.capture
        self.sync_once = sup.sync_once
        self.host_to_board, self.board_now_estimate = clock.host_to_board, clock.board_now_estimate
        self.wait_for, self.next_telemetry, self.telemetry = waits.wait_for, waits.next_telemetry, waits.telemetry
        self.board_reached, self.link_lossy = waits.board_reached, waits.link_lossy
        self.report_period_us, self.nudge_raise_s = waits.report_period_us, waits.nudge_raise_s

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
        sup = self.supervisor
        await sup.connect_once()
        self._background.start({"link-supervisor": sup.supervise, "link-heartbeat": sup.heartbeat_loop,
                                "link-sync": sup.sync_loop})

    async def close(self) -> None:
        """Stop the background loops, close the transport and its frame log (idempotent)."""
        self.session.closing = True
        try:
            await self._background.stop()
        finally:  # also when the close itself is cancelled (a second Ctrl-C): the port and the frame log close
            self.session.close()

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

    def _wire_clock(self, caps: Caps) -> None:
        """A lockstep board: the wire's timers (CAN's ISO-TP) count the board time reported, not wall time."""
        transport, clock = self.session.transport, self.board_clock
        if transport is not None:
            transport.use_board_clock((lambda: clock.seen_us * 1000) if caps.lockstep else None)

    def _reconnected(self) -> None:
        for cb in list(self.on_reconnect):
            cb(self)

    # --- state, the parts' (read through; host.link.facade) --------------------------------

    #: True between a completed handshake and the port going away
    connected = PartAttr[bool]("session.ready")
    #: the transport (None before the first connection attempt)
    transport = PartAttr["Transport | None"]("session.transport")
    #: the link spec given (None when it was a callable, resolved on every connect)
    spec = PartAttr["LinkSpec | None"]("session.spec")
    #: the link as messages name it (the transport's name once connected: over CAN with its node)
    port_name = PartAttr[str]("session.port_name")
    #: the spec to give ``--link`` to reach this board again (the port name without decoration)
    link_spec = PartAttr[str]("session.link_spec")
    #: the board's CAPS of the latest handshake (None before the first)
    caps = PartAttr["Caps | None"]("session.caps")
    #: the schema hash HELLO carries (the one the board accepted, after a handshake)
    schema_hash = PartAttr[int]("supervisor.schema_hash")
    #: True when the board's clock is virtual (CAPS says so)
    lockstep = PartAttr[bool]("board_clock.lockstep")
    #: the time-sync estimator (offset, drift, uplink delays; realtime boards)
    clock = PartAttr[ClockSync]("board_clock.sync")
    #: current offset/drift estimate (None before the first sync or in lockstep)
    clock_estimate = PartAttr["ClockEstimate | None"]("board_clock.estimate")
    #: counters since the client was created
    stats = PartAttr[LinkStats]("session.stats")
    #: pending requests, frame NACKs and their waiters by sequence number
    requests = PartAttr[RequestTable]("session.requests")
    #: camera captures in progress
    camera = PartAttr[CameraAssembler]("session.camera")
    #: the wait before a request is re-sent, from this connection's measured round trips
    rto = PartAttr[RetransmitTimeout]("session.rto")
    #: the latest 16 lockstep report latencies (s) the nudge works from (``nudge_raise_s``)
    report_latencies = PartAttr["deque[float]"]("waits.report_latencies")
    #: heartbeat + periodic sync (default on); turn off to let the board's watchdog fire
    keepalive = WritablePartAttr[bool]("supervisor.keepalive")
    #: the host's model of its own line, or None (:attr:`host.link.core.LinkSession.tx_wire`)
    tx_wire = WritablePartAttr["WireModel | None"]("session.tx_wire")
    #: why the link was last lost ("" before)
    last_disconnect_reason = PartAttr[str]("session.last_disconnect_reason")
    #: why the latest reconnect attempt failed ("" once it succeeded)
    last_reconnect_error = PartAttr[str]("session.last_reconnect_error")
    #: called with (seq, message) after every message handed to the transport (append to it)
    on_sent = PartAttr["list[SentListener]"]("session.on_sent")
    #: called with every message received, after the client handled it (append to it)
    on_received = PartAttr["list[Callable[[Message], None]]"]("receiver.on_received")
    #: called with every NACK no request awaited (a servo frame's; append to it)
    on_nack = PartAttr["list[Callable[[Nack], None]]"]("receiver.on_nack")
    #: the latest SIM_STATE (None before the first)
    latest_sim_state = PartAttr["SimState | None"]("receiver.latest_sim_state")
    #: the board's latest NACK SERVO_FAULT (its detail names the servo that stopped answering)
    servo_fault = PartAttr["Nack | None"]("receiver.servo_fault")
    #: every NACK SERVO_FAULT so far, oldest first, the last 64
    servo_faults = PartAttr["list[Nack]"]("receiver.servo_faults")
    #: the latest TELEMETRY report (None before the first)
    latest_telemetry = PartAttr["Telemetry | None"]("fanout.latest")
    #: the fault bits of :data:`FAULT_BITS` in the latest report
    faults = PartAttr[FaultFlags]("fanout.faults")
    #: the latest 256 fault edges
    fault_events = PartAttr["deque[FaultEvent]"]("fanout.fault_events")
    #: callbacks called with every fault edge (append to it)
    on_fault = PartAttr["list[Callable[[FaultEvent], None]]"]("fanout.on_fault")
