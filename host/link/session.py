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
from protocol.messages import PROTOCOL_VERSION, Caps, FaultFlags, Message, Nack, SimState, Telemetry
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
    time matters, such as the emulated board's ``--baud``), else None. The rest are the supervisor's
    (:class:`host.link.supervisor.Supervisor`) and the session's (:class:`host.link.core.LinkSession`).
    """

    def __init__(
        self, link: LinkTarget, *, transport: Transport | None = None, baud: int = 115200,
        log_path: str | Path | None = None, reply_timeout: float = 1.0, handshake_timeout: float = 3.0,
        heartbeat_s: float = HEARTBEAT_S, sync_interval_s: float = 0.5, sync_burst: int = 8, reconnect: bool = True,
        reconnect_max_s: float = 1.0, telemetry_queue: int = 64, protocol_version: int = PROTOCOL_VERSION,
        schema_hash: int | None = None, force_thread: bool = False, transport_options: dict[str, Any] | None = None,
        robot: RobotIdentity | None = None, wire_baud: int | None = None,
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
            heartbeat_s=heartbeat_s, sync_interval_s=sync_interval_s)
        #: the TELEMETRY listener: latest report, fault edges, subscribers, waiters (host.link.telemetry)
        self.fanout = TelemetryFanout(telemetry_queue)
        self.receiver = rx = ReceivePath(s, self.fanout, clock, sup)
        s.receive = rx.on_items
        self.waits = waits = TelemetryWaits(s, self.fanout, clock, sup.sync_once)
        s.on_link_up += [clock.restart, waits.restart]
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

    def _reconnected(self) -> None:
        for cb in list(self.on_reconnect):
            cb(self)

    # --- state, read from the parts ---------------------------------------------------------

    @property
    def connected(self) -> bool:
        """True between a completed handshake and the port going away."""
        return self.session.ready

    @property
    def transport(self) -> Transport | None:
        """The transport (None before the first connection attempt)."""
        return self.session.transport

    @property
    def spec(self) -> LinkSpec | None:
        """The link spec given (None when it was a callable, resolved on every connect)."""
        return self.session.spec

    @property
    def port_name(self) -> str:
        """The link as messages name it (the transport's name once connected: over CAN with its node)."""
        return self.session.port_name

    @property
    def link_spec(self) -> str:
        """The spec to give ``--link`` to reach this board again (the port name without decoration)."""
        return self.session.link_spec

    @property
    def caps(self) -> Caps | None:
        """The board's CAPS of the latest handshake (None before the first)."""
        return self.session.caps

    @property
    def schema_hash(self) -> int:
        """The schema hash HELLO carries (the one the board accepted, after a handshake)."""
        return self.supervisor.schema_hash

    @property
    def lockstep(self) -> bool:
        """True when the board's clock is virtual (CAPS says so)."""
        return self.board_clock.lockstep

    @property
    def clock(self) -> ClockSync:
        """The time-sync estimator (offset, drift, uplink delays; realtime boards)."""
        return self.board_clock.sync

    @property
    def clock_estimate(self) -> ClockEstimate | None:
        """Current offset/drift estimate (None before the first sync or in lockstep)."""
        return self.board_clock.estimate

    @property
    def stats(self) -> LinkStats:
        """Counters since the client was created."""
        return self.session.stats

    @property
    def requests(self) -> RequestTable:
        """Pending requests, frame NACKs and their waiters by sequence number."""
        return self.session.requests

    @property
    def camera(self) -> CameraAssembler:
        """Camera captures in progress."""
        return self.session.camera

    @property
    def rto(self) -> RetransmitTimeout:
        """The wait before a request is re-sent, from this connection's measured round trips."""
        return self.session.rto

    @property
    def report_latencies(self) -> deque[float]:
        """The latest 16 lockstep report latencies (s) the nudge works from (:meth:`nudge_raise_s`)."""
        return self.waits.report_latencies

    @property
    def keepalive(self) -> bool:
        """Heartbeat + periodic sync (default on); turn off to let the board's watchdog fire."""
        return self.supervisor.keepalive

    @keepalive.setter
    def keepalive(self, on: bool) -> None:
        self.supervisor.keepalive = on

    @property
    def tx_wire(self) -> WireModel | None:
        """The host's model of its own line, or None (:attr:`host.link.core.LinkSession.tx_wire`); settable."""
        return self.session.tx_wire

    @tx_wire.setter
    def tx_wire(self, line: WireModel | None) -> None:
        self.session.tx_wire = line

    @property
    def last_disconnect_reason(self) -> str:
        """Why the link was last lost ("" before)."""
        return self.session.last_disconnect_reason

    @property
    def last_reconnect_error(self) -> str:
        """Why the latest reconnect attempt failed ("" once it succeeded)."""
        return self.session.last_reconnect_error

    @property
    def on_sent(self) -> list[SentListener]:
        """Called with (seq, message) after every message handed to the transport (append to it)."""
        return self.session.on_sent

    @property
    def on_received(self) -> list[Callable[[Message], None]]:
        """Called with every message received, after the client handled it (append to it)."""
        return self.receiver.on_received

    @property
    def on_nack(self) -> list[Callable[[Nack], None]]:
        """Called with every NACK no request awaited (a servo frame's; append to it)."""
        return self.receiver.on_nack

    @property
    def latest_sim_state(self) -> SimState | None:
        """The latest SIM_STATE (None before the first)."""
        return self.receiver.latest_sim_state

    @property
    def servo_fault(self) -> Nack | None:
        """The board's latest NACK SERVO_FAULT (its detail names the servo that stopped answering)."""
        return self.receiver.servo_fault

    @property
    def servo_faults(self) -> list[Nack]:
        """Every NACK SERVO_FAULT so far, oldest first, the last 64."""
        return self.receiver.servo_faults

    @property
    def latest_telemetry(self) -> Telemetry | None:
        """The latest TELEMETRY report (None before the first)."""
        return self.fanout.latest

    @property
    def faults(self) -> FaultFlags:
        """The fault bits of :data:`FAULT_BITS` in the latest report."""
        return self.fanout.faults

    @property
    def fault_events(self) -> deque[FaultEvent]:
        """The latest 256 fault edges."""
        return self.fanout.fault_events

    @property
    def on_fault(self) -> list[Callable[[FaultEvent], None]]:
        """Callbacks called with every fault edge (append to it)."""
        return self.fanout.on_fault
