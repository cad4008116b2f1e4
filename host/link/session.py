"""The link session: an asyncio client for a robot's board, written once above every transport.

``BoardClient`` owns one :class:`host.link.transports.base.Transport` (serial, CAN; built
from a link spec by :func:`host.link.transports.open_transport`), speaks protocol v1 over
it and keeps the session alive:

* handshake: HELLO -> CAPS; a protocol-version or schema-hash mismatch (either
  side noticing) raises :class:`HandshakeError` with both values and what to do.
  The wire schema (:class:`protocol.codec.WireSchema`: u16 servo mask up to 16 servos, u32
  above) is the robot's: a client started for a robot (``robot=RobotIdentity(...)``) speaks its
  schema from the first frame. HELLO, CAPS and NACK are the same in every schema, so when the
  board refuses the HELLO with SCHEMA_MISMATCH and the schema was not pinned (``schema_hash=``),
  the client says HELLO once more with each other schema this build speaks: a client without a
  robot (``ghostshell estop``) so reaches any board, and one started for another robot learns which
  robot the board drives and raises :class:`RobotMismatch` naming both. After CAPS the transport
  speaks the board's servo count (:meth:`Transport.set_servo_count`);
* time sync: NTP-style TIME_SYNC exchanges feed :class:`host.link.timesync.ClockSync`
  (offset + drift + uncertainty); :meth:`BoardClient.host_to_board` and
  :meth:`BoardClient.board_now_estimate` turn host time into board time. A
  lockstep board's clock is virtual: there the estimate is the latest board time
  reported, and the host moves it on with :meth:`BoardClient.advance`;
* sending: timed servo frames (no reply when accepted; a NACK is recorded and
  reported), and control messages that await their ACK (a NACK raises
  :class:`NackError` with the board's reason);
* receiving: telemetry (``latest_telemetry``, ``async for t in client.telemetry()``
  with a bounded drop-oldest queue, ``await client.wait_for(pred, timeout)``), fault
  edges (estop / watchdog bits -> ``on_fault`` callbacks and a log line), camera
  images reassembled from chunks. Undecodable frames are counted, never raised;
* keep-alive: a heartbeat whenever nothing else was sent for ``heartbeat_s``;
* reconnect: when the wire goes away the client retries with exponential backoff
  (a serial port may be a callable re-resolved on every attempt), then re-handshakes
  and re-syncs; calls made meanwhile raise :class:`LinkDown`.

The parts are objects of their own, as python-can splits Bus, Notifier and Listener: the session
(:class:`BoardClient`) numbers, sends and matches ACK/NACK to requests; the supervisor
(:class:`host.link.supervisor.Supervisor`) does the handshake, time sync, heartbeat and reconnect;
telemetry fan-out and fault edges are a listener (:class:`host.link.telemetry.TelemetryFanout`);
camera images are reassembled by :class:`host.link.camera.CameraAssembler`; the frame log is the
transport's (:mod:`protocol.logfile`); received messages go to their handler through a table.

Background tasks (supervisor, heartbeat, sync) run in an ``asyncio.TaskGroup`` the
session enters in :meth:`BoardClient.open` and leaves in :meth:`BoardClient.close`
(call both from the same task, e.g. ``async with``); they never raise.

Sequence numbers are 16-bit and wrap, one counter per direction. Every map keyed by
a sequence number (pending ACKs, frame NACKs, NACK waiters, camera captures) forgets
a sequence number's old entry when that number is sent again, so answers from one
lap are never taken for the next. With ``log_path`` the transport logs every frame
both ways in its own format (JSON Lines for serial, :mod:`protocol.framelog`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections import OrderedDict, deque
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from host.link.errors import (
    HandshakeError,
    LinkDown,
    LinkError,
    LinkTimeout,
    NackError,
    SchemaMismatch,
)
from host.link.camera import CameraAssembler
from host.link.supervisor import RobotIdentity, Supervisor, host_now_us
from host.link.telemetry import FAULT_BITS, FaultEvent, TelemetryFanout
from host.link.telemetry import flag_names as _flag_names
from host.link.timesync import ClockEstimate, ClockSync
from host.link.transports import Transport, open_transport
from protocol.codec import (
    WIRE_SCHEMA_16,
    WireBoundError,
    WireSchema,
    schema_for,
)
from protocol.faults import GapDetector
from protocol.framing import DecodeError, Frame
from protocol.linkspec import LinkSpec, parse_link_spec
from protocol.messages import (
    PROTOCOL_VERSION,
    Ack,
    Advance,
    CameraCapture,
    CameraChunk,
    CameraResend,
    Caps,
    Config,
    ConfigKey,
    Estop,
    EstopClear,
    FaultFlags,
    Flush,
    Message,
    MsgType,
    Nack,
    NackReason,
    ScreenCommand,
    ScreenTarget,
    ServoFrame,
    SimState,
    SoundKind,
    SpeakerAction,
    SpeakerCommand,
    Telemetry,
    TimeSyncReply,
)

__all__ = ["FAULT_BITS", "BoardClient", "FaultEvent", "LinkStats", "LinkTarget", "RobotIdentity", "host_now_us"]

log = logging.getLogger("host.link")

#: what a client connects to: a link spec (text or parsed), or a callable giving one, re-resolved on
#: every reconnect attempt (serial links: a board that comes back on another pty)
LinkTarget = LinkSpec | str | Callable[[], LinkSpec | str]
PortSpec = LinkTarget  # old name


@dataclass
class LinkStats:
    """Counters since the client was created."""

    tx_frames: int = 0
    rx_frames: int = 0
    decode_errors: int = 0
    frame_nacks: int = 0
    telemetry: int = 0
    reconnects: int = 0
    retries: int = 0  # requests re-sent because no ACK/NACK came in time (a lost frame either way)
    seq_gaps: int = 0  # board messages never received (gaps in the board's sequence numbers), since the handshake
    last_decode_error: str = ""  # kind and detail of the latest undecodable item, for reports


class BoardClient:
    """Asyncio client for one board; create with ``await BoardClient.connect(spec)`` or ``async with``.

    ``link`` is a link spec (``"/dev/pts/3"``, ``"can:socketcan:vcan0?node=2"``, a
    :class:`LinkSpec`) or a callable returning one; ``transport`` (optional) is an already
    built transport to use instead (e.g. one wrapped for fault injection). ``baud`` and
    ``force_thread`` are for serial links; ``log_path`` is the transport's frame log;
    ``transport_options`` go to :func:`host.link.transports.open_transport` (CAN settings).
    ``robot`` is the robot this host was started for (CAPS must report it; it also picks the wire
    schema); ``schema_hash`` pins the hash HELLO carries (tests), instead of the robot's schema's.
    """

    def __init__(
        self,
        link: LinkTarget,
        *,
        transport: Transport | None = None,
        baud: int = 115200,
        log_path: str | Path | None = None,
        reply_timeout: float = 1.0,
        handshake_timeout: float = 3.0,
        heartbeat_s: float = 0.05,
        sync_interval_s: float = 0.5,
        sync_burst: int = 8,
        reconnect: bool = True,
        reconnect_max_s: float = 1.0,
        telemetry_queue: int = 64,
        protocol_version: int = PROTOCOL_VERSION,
        schema_hash: int | None = None,
        force_thread: bool = False,
        transport_options: dict[str, Any] | None = None,
        robot: RobotIdentity | None = None,
    ) -> None:
        self._port = link
        self.robot = robot
        self.baud = baud
        self.reply_timeout = reply_timeout
        self.handshake_timeout = handshake_timeout
        self.heartbeat_s = heartbeat_s
        self.sync_interval_s = sync_interval_s
        self.sync_burst = sync_burst
        self.reconnect = reconnect
        self.reconnect_max_s = reconnect_max_s
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
        self.force_thread = force_thread
        self.log_path = log_path
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
        #: called with (seq, message) after every message handed to the transport, and with every message
        #: received, after the client handled it (listeners, e.g. a run's recorder; python-can's Listener model)
        self.on_sent: list[Callable[[int, Message], None]] = []
        self.on_received: list[Callable[[Message], None]] = []
        self.on_reconnect: list[Callable[[BoardClient], None]] = []
        self.keepalive = True  # heartbeat + periodic sync; turn off to let the watchdog fire

        self._transport: Transport | None = transport
        self._tx_seq = 0
        self._ready = False
        self._closing = False
        self._last_tx = 0.0
        self._board_time_seen = 0
        self._pending: dict[int, asyncio.Future[Any]] = {}  # wire seq -> ACK (or image) future
        self._frame_nacks: OrderedDict[int, Nack] = OrderedDict()
        self._nack_waiters: list[tuple[int, asyncio.Future[Nack | None]]] = []
        self.camera = CameraAssembler()  # camera captures in progress (host.link.camera)
        #: handshake, time sync, heartbeat, reconnect (host.link.supervisor)
        self.supervisor = Supervisor(self)
        self._next_request_id = 1
        self._connected = asyncio.Event()
        self._lost = asyncio.Event()
        self._tg: asyncio.TaskGroup | None = None
        self._tasks: list[asyncio.Task[None]] = []
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
        """First connection (no retries: a wrong port should fail fast), then the background tasks."""
        await self.supervisor.connect_once()
        tg = asyncio.TaskGroup()
        await tg.__aenter__()
        self._tg = tg
        self._tasks = [
            tg.create_task(self._guarded(self.supervisor.supervise), name="link-supervisor"),
            tg.create_task(self._guarded(self.supervisor.heartbeat_loop), name="link-heartbeat"),
            tg.create_task(self._guarded(self.supervisor.sync_loop), name="link-sync"),
        ]

    async def _guarded(self, loop: Callable[[], Any]) -> None:
        """Run a background loop; a bug in it is logged, never raised into the task group."""
        try:
            await loop()
        except Exception:
            log.exception("link: background task failed")

    async def close(self) -> None:
        """Stop the background tasks, close the transport and its frame log (idempotent)."""
        self._closing = True
        for t in self._tasks:
            t.cancel()
        tg, self._tg = self._tg, None
        try:
            if tg is not None:
                with contextlib.suppress(Exception):
                    await tg.__aexit__(None, None, None)
        finally:  # also when the close itself is cancelled (a second Ctrl-C): the port and the frame log close
            self._tasks = []
            if self._transport is not None:
                self._transport.close()
            self._ready = False
            self._fail_pending(LinkDown("client closed"))

    async def __aenter__(self) -> BoardClient:
        if self._tg is None:
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

    @property
    def lockstep(self) -> bool:
        return bool(self.caps and self.caps.lockstep)

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

    async def wait_connected(self, timeout: float) -> None:
        """Wait until the link is up (e.g. after a reconnect); :class:`LinkTimeout` otherwise."""
        try:
            await asyncio.wait_for(self._connected.wait(), timeout)
        except TimeoutError:
            raise LinkTimeout(
                f"link to {self.port_name or self._port!r} not up within {timeout} s"
                + (f" (last error: {self.last_disconnect_reason})" if self.last_disconnect_reason else "")
                + (f"; reconnecting fails: {self.last_reconnect_error}" if self.last_reconnect_error else "")
            ) from None

    async def wait_disconnected(self, timeout: float) -> str:
        """Wait until the port goes away; returns the reason. :class:`LinkTimeout` otherwise."""
        try:
            await asyncio.wait_for(self._lost.wait(), timeout)
        except TimeoutError:
            raise LinkTimeout(f"link to {self.port_name!r} still up after {timeout} s") from None
        return self.last_disconnect_reason

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
        futs = [*self._pending.values(), *self.supervisor.waiting(), *(f for _, f in self._nack_waiters)]
        for fut in futs:
            if not fut.done():
                fut.set_exception(exc)
                fut.exception()  # mark retrieved: nobody may be awaiting it
        self._pending.clear()
        self.supervisor.sync_pending.clear()
        self._nack_waiters.clear()
        self.camera.clear()

    # --- sending ---------------------------------------------------------------------------

    def _send(self, msg: Message) -> int:
        t = self._transport
        if t is None or not t.connected:
            raise LinkDown(f"link to {self.port_name!r} is down" + (" (reconnecting)" if self.reconnect else "")
                           + self._down_detail())
        seq = self._tx_seq
        self._forget_seq(seq)
        t.send(msg, seq)
        self._tx_seq = (seq + 1) & 0xFFFF
        self._last_tx = time.monotonic()
        self.stats.tx_frames += 1
        for cb in self.on_sent:
            try:
                cb(seq, msg)
            except Exception:  # a bug in a listener must not fail the send
                log.exception("link: error in an on_sent listener")
        return seq

    def _forget_seq(self, seq: int) -> None:
        """``seq`` is about to be reused (16-bit wrap): drop everything keyed by its previous use.

        An old NACK no longer describes the frame that will carry ``seq``; a waiter for the old
        frame's NACK gets None (no NACK came in a whole lap); a request still awaiting the old
        ACK fails, since an ACK from now on would be for the new message.
        """
        self._frame_nacks.pop(seq, None)
        if self._nack_waiters:
            for s, wfut in self._nack_waiters:
                if s == seq and not wfut.done():
                    wfut.set_result(None)
            self._nack_waiters = [(s, f) for s, f in self._nack_waiters if not f.done()]
        old = self._pending.pop(seq, None)
        if old is not None and not old.done():
            old.set_exception(LinkTimeout(f"no reply for seq {seq} before the sequence number came round again"))
            old.exception()
        self.camera.forget_seq(seq)

    def _require_ready(self) -> None:
        if not self._ready:
            raise LinkDown(f"link to {self.port_name!r} is not up" + self._down_detail())

    def _down_detail(self) -> str:
        """Why the link is down: the loss's cause and, while reconnecting fails, why."""
        return ((f" (last error: {self.last_disconnect_reason})" if self.last_disconnect_reason else "")
                + (f"; reconnecting fails: {self.last_reconnect_error}" if self.last_reconnect_error else ""))

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
        ``timeout`` s (default ``reply_timeout``) without a reply, ``attempts`` times in all
        (default :attr:`request_attempts`); the first ACK/NACK to any copy answers.

        Raises :class:`NackError` (the board's reason) on a NACK, :class:`LinkTimeout` without
        a reply, :class:`LinkDown` when the link is not up. For messages the board answers
        with ACK/NACK: FLUSH, ESTOP, ESTOP_CLEAR, ADVANCE, CONFIG, SCREEN, SPEAKER (all of
        which the board may apply twice with the same effect, so a lost ACK is harmless).
        """
        self._require_ready()
        fut: asyncio.Future[Ack] = asyncio.get_running_loop().create_future()
        per_try = timeout or self.reply_timeout
        n = max(1, attempts or self.request_attempts)
        seqs: list[int] = []
        try:
            for k in range(n):
                seq = self._send(msg)
                seqs.append(seq)
                self._pending[seq] = fut
                try:
                    return await asyncio.wait_for(asyncio.shield(fut), per_try)
                except TimeoutError:
                    if k + 1 < n:
                        self.stats.retries += 1
            raise LinkTimeout(
                f"no ACK for {type(msg).__name__} (seq {', '.join(map(str, seqs))}) after {n} attempt(s) "
                f"of {per_try} s"
            )
        finally:
            if not fut.done():
                fut.cancel()
            for seq in seqs:
                if self._pending.get(seq) is fut:
                    del self._pending[seq]

    _request = request

    def send(self, msg: Message) -> int:
        """Send any message without waiting for a reply; returns its sequence number."""
        self._require_ready()
        return self._send(msg)

    def send_frame(self, frame: ServoFrame) -> int:
        """Queue a timed servo frame; returns its sequence number (a NACK is recorded, see :meth:`frame_nack`)."""
        return self.send(frame)

    def all_mask(self) -> int:
        """The mask of every servo the board has (from CAPS; bits 0..N-1)."""
        if self.caps is None:
            raise LinkDown("not connected: no CAPS yet")
        return (1 << self.caps.servo_count) - 1

    def send_targets(self, apply_at_us: int, targets: Sequence[float], mask: int | None = None) -> int:
        """Convenience: a :class:`ServoFrame` for ``targets`` (one per mask bit) at ``apply_at_us``."""
        mask = self.all_mask() if mask is None else mask
        return self.send_frame(ServoFrame(int(apply_at_us), mask, tuple(float(v) for v in targets)))

    async def flush(self, from_us: int, mask: int | None = None) -> Ack:
        """Drop buffered frames due at or after ``from_us`` (board time) for the masked servos."""
        return await self.request(Flush(int(from_us), self.all_mask() if mask is None else mask))

    async def estop(self) -> Ack:
        """Emergency stop: the board holds where it is and refuses frames until :meth:`estop_clear`.

        Re-sent until acknowledged (up to 20 times, ``reply_timeout`` apart), also under loss.
        """
        return await self.request(Estop(), attempts=20)

    async def estop_clear(self) -> Ack:
        """Clear an estop or a latched watchdog fault."""
        return await self.request(EstopClear())

    async def advance(self, until_us: int) -> Ack:
        """Lockstep only: let the board clock run up to ``until_us``."""
        return await self.request(Advance(int(until_us)))

    async def configure(self, key: ConfigKey, value: int) -> Ack:
        """Change a board setting at run time (NACK BAD_VALUE when out of range)."""
        return await self.request(Config(ConfigKey(key), int(value)))

    async def screen(self, target: ScreenTarget, name: str, start_at_us: int = 0, duration_ms: int = 0) -> Ack:
        """Show an expression/animation on the face screen."""
        return await self.request(ScreenCommand(ScreenTarget(target), name, int(start_at_us), int(duration_ms)))

    async def speaker(
        self,
        action: SpeakerAction,
        kind: SoundKind = SoundKind.SPEECH,
        *,
        start_at_us: int = 0,
        duration_ms: int = 0,
        volume: int = 80,
        name: str = "",
        text: str = "",
    ) -> Ack:
        """Play or stop speech or a clip on the board clock."""
        return await self.request(
            SpeakerCommand(SpeakerAction(action), SoundKind(kind), int(start_at_us), int(duration_ms), int(volume), name, text)
        )

    async def capture(self, width: int, height: int, timeout: float = 10.0) -> bytes:
        """One head-camera image as PNG bytes (reassembled from CAMERA_CHUNKs).

        Selective repeat over a lossy link: when no new chunk came for :attr:`CAPTURE_STALL_S`
        s, the host asks again, with CAMERA_RESEND for the chunks still missing once it knows
        how many there are, else with the same CAMERA_CAPTURE (the board answers a request id it
        already rendered with the same image). Raises :class:`LinkTimeout` after ``timeout`` s
        without the whole image, :class:`NackError` when the board refuses the capture
        (NO_RENDERER, BAD_VALUE, BUSY).
        """
        self._require_ready()
        rid = self._next_request_id
        self._next_request_id = (rid + 1) & 0xFFFFFFFF or 1
        fut: asyncio.Future[bytes] = asyncio.get_running_loop().create_future()
        request = CameraCapture(rid, int(width), int(height))
        seqs = [self._send(request)]
        self._pending[seqs[0]] = fut
        parts = self.camera.start(rid, seqs[0])
        deadline = time.monotonic() + timeout
        try:
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError
                have = len(parts)
                try:
                    return await asyncio.wait_for(asyncio.shield(fut), min(left, self.CAPTURE_STALL_S))
                except TimeoutError:
                    if len(parts) != have:
                        continue  # chunks are still arriving
                gap = self.camera.missing(rid)
                if gap is None:  # nothing arrived: the request or every chunk was lost
                    seq = self._send(request)
                    seqs.append(seq)
                    self._pending[seq] = fut
                else:
                    self._send(CameraResend(rid, *gap))
                self.stats.retries += 1
        except TimeoutError:
            raise LinkTimeout(f"camera image {rid} incomplete after {timeout} s ({self.camera.describe(rid)})") from None
        finally:
            for seq in seqs:
                if self._pending.get(seq) is fut:
                    del self._pending[seq]
            if not fut.done():
                fut.cancel()
            self.camera.drop(rid)

    #: wall seconds without a new camera chunk before the host asks again (a render takes ~0.1 s)
    CAPTURE_STALL_S = 0.4

    # --- time ------------------------------------------------------------------------------

    # --- time (the supervisor's) -------------------------------------------------------------

    async def sync_once(self, timeout: float = 0.5) -> tuple[int, int, int, int]:
        """One TIME_SYNC exchange; returns ``(t1, t2, t3, t4)`` and feeds the estimator (realtime)."""
        return await self.supervisor.sync_once(timeout)

    async def _connect_once(self) -> None:
        """Connect, handshake and sync once (:meth:`host.link.supervisor.Supervisor.connect_once`)."""
        await self.supervisor.connect_once()

    @property
    def _sync_pending(self) -> dict[int, asyncio.Future[tuple[TimeSyncReply, int]]]:
        return self.supervisor.sync_pending

    @property
    def clock_estimate(self) -> ClockEstimate | None:
        """Current offset/drift estimate (None before the first sync or in lockstep)."""
        return self.clock.estimate

    def host_to_board(self, t_host_us: int) -> int:
        """Board time at host time ``t_host_us`` (realtime boards; see :meth:`board_now_estimate`)."""
        if self.lockstep:
            raise LinkError("the board runs in lockstep: its clock is virtual; use board_now_estimate() and advance()")
        est = self.clock.estimate
        if est is None:
            raise LinkError("no time sync yet")
        return est.host_to_board(t_host_us)

    def board_now_estimate(self) -> int:
        """Board time now: the synced estimate (realtime) or the latest board time reported (lockstep)."""
        if self.lockstep:
            return self._board_time_seen
        return self.host_to_board(host_now_us())

    # --- receiving -------------------------------------------------------------------------

    def _on_items(self, items: Sequence[Frame | DecodeError]) -> None:
        t4 = host_now_us()
        for item in items:
            if isinstance(item, DecodeError):
                self.stats.decode_errors += 1
                self.stats.last_decode_error = f"{item.kind.value}: {item.detail} ({len(item.raw)} bytes)"
                log.debug("link: discarded %d bytes (%s: %s)", len(item.raw), item.kind.value, item.detail)
                continue
            self.stats.rx_frames += 1
            self._rx_gaps.feed(item.seq)
            self.stats.seq_gaps = self._rx_gaps.lost
            try:
                self._dispatch(item.msg, t4)
                for cb in self.on_received:
                    cb(item.msg)
            except Exception:  # a bug in a callback must not kill the reader
                log.exception("link: error handling %s", item.msg_type.name)

    #: received message class -> the name of its handler, ``handler(msg, t4)`` (a table, not an isinstance
    #: chain; looked up by name so a handler replaced on the instance or the class is the one called)
    _HANDLERS: dict[type[Message], str] = {
        Telemetry: "_handle_telemetry",
        SimState: "_handle_sim_state",
        Ack: "_handle_ack",
        Nack: "_handle_nack",
        TimeSyncReply: "_handle_time_sync",
        Caps: "_handle_caps",
        CameraChunk: "_handle_chunk",
    }

    def _dispatch(self, msg: Message, t4: int) -> None:
        name = self._HANDLERS.get(type(msg))
        if name is not None:
            getattr(self, name)(msg, t4)

    def _handle_telemetry(self, msg: Telemetry, t4: int) -> None:
        self._on_telemetry(msg)

    def _handle_sim_state(self, msg: SimState, t4: int) -> None:
        self.latest_sim_state = msg

    def _handle_ack(self, msg: Ack, t4: int) -> None:
        fut = self._pending.get(msg.ack_seq)
        if fut is not None and not fut.done():
            fut.set_result(msg)

    def _handle_nack(self, msg: Nack, t4: int) -> None:
        self._on_nack(msg)

    def _handle_time_sync(self, msg: TimeSyncReply, t4: int) -> None:
        self.supervisor.on_sync_reply(msg, t4)

    def _handle_caps(self, msg: Caps, t4: int) -> None:
        self.supervisor.on_caps(msg)

    def _handle_chunk(self, msg: CameraChunk, t4: int) -> None:
        self._on_chunk(msg)

    def _on_nack(self, msg: Nack) -> None:
        if msg.reason == NackReason.SERVO_FAULT:
            self.servo_fault = msg
        if msg.msg_type == MsgType.HELLO:
            reason = msg.reason.name if hasattr(msg.reason, "name") else str(msg.reason)
            error = SchemaMismatch if msg.reason == NackReason.SCHEMA_MISMATCH else HandshakeError
            if self.supervisor.refuse_hello(error(
                f"board refused the handshake: {reason}: {msg.detail or 'no detail'}; "
                "host and board must run the same protocol version and message schema"
            )):
                return
        fut = self._pending.get(msg.ack_seq)
        if fut is not None and not fut.done():
            fut.set_exception(NackError(msg))
            return
        self.stats.frame_nacks += 1
        self._frame_nacks[msg.ack_seq] = msg
        while len(self._frame_nacks) > 1024:
            self._frame_nacks.popitem(last=False)
        log.debug("link: %s", NackError(msg))
        for seq, wfut in list(self._nack_waiters):
            if seq == msg.ack_seq and not wfut.done():
                wfut.set_result(msg)
        self._nack_waiters = [(s, f) for s, f in self._nack_waiters if not f.done()]
        for cb in list(self.on_nack):
            cb(msg)

    def frame_nack(self, seq: int) -> Nack | None:
        """The NACK the board sent for the latest frame sent with sequence ``seq``, if any (last 1024 kept)."""
        return self._frame_nacks.get(seq & 0xFFFF)

    async def wait_frame_nack(self, seq: int, timeout: float) -> Nack | None:
        """The NACK for frame ``seq``, waiting up to ``timeout`` s; None if none came (or ``seq`` was reused)."""
        seq &= 0xFFFF
        if seq in self._frame_nacks:
            return self._frame_nacks[seq]
        fut: asyncio.Future[Nack | None] = asyncio.get_running_loop().create_future()
        self._nack_waiters.append((seq, fut))
        try:
            return await asyncio.wait_for(fut, timeout)
        except TimeoutError:
            return None
        finally:
            self._nack_waiters = [(s, f) for s, f in self._nack_waiters if f is not fut]

    def _on_chunk(self, msg: CameraChunk) -> None:
        done = self.camera.on_chunk(msg)
        if done is not None:
            fut = self._pending.get(done[0])
            if fut is not None and not fut.done():
                fut.set_result(done[1])

    def _on_telemetry(self, t: Telemetry) -> None:
        self.stats.telemetry += 1
        self._board_time_seen = max(self._board_time_seen, t.board_time_us)
        self.fanout.on_telemetry(t)

    async def telemetry(self, maxsize: int | None = None) -> AsyncIterator[Telemetry]:
        """Every telemetry report from now on; a slow consumer loses the oldest (bounded queue)."""
        async for t in self.fanout.subscribe(maxsize):
            yield t

    async def wait_for(self, predicate: Callable[[Telemetry], bool], timeout: float, *, nudge: bool = False) -> Telemetry:
        """The first telemetry (latest included) satisfying ``predicate``; :class:`LinkTimeout` after ``timeout`` s.

        ``nudge`` (lockstep boards; ignored in realtime): a lockstep board only reports while its
        clock runs, so ADVANCE it one report period past the latest board time known at once and
        again every :attr:`NUDGE_S` s while no report satisfies ``predicate``: a lost ADVANCE or
        a lost report (likely on a lossy CAN link, where a report is 17 frames) cannot stall the
        wait. The target repeats until a report reaches it or :attr:`NUDGE_RAISE_S` passes, so a
        slow board is not pushed ahead. The ADVANCEs are not awaited: the report is the
        acknowledgement that matters.
        """
        t = self.latest_telemetry
        if t is not None and predicate(t):
            return t
        fut = self.fanout.waiter(predicate)
        deadline = time.monotonic() + timeout
        nudging = nudge and self.lockstep
        until = 0
        raised_at = 0.0
        try:
            while True:
                if nudging:
                    now = time.monotonic()
                    seen = self.board_now_estimate()
                    if until == 0 or seen >= until or now - raised_at >= self.NUDGE_RAISE_S:
                        # first nudge; a report reached the target without satisfying the predicate; or
                        # none for NUDGE_RAISE_S (lost): move the target one report period on. Otherwise the same
                        # target again (a lost ADVANCE): a slow board (QEMU on a loaded machine) must
                        # not be pushed ahead of the frames the host is about to time from its report
                        until = max(until, seen) + self.report_period_us()
                        raised_at = now
                    with contextlib.suppress(LinkError):
                        self._send(Advance(until))
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError
                try:
                    return await asyncio.wait_for(asyncio.shield(fut), min(left, self.NUDGE_S) if nudging else left)
                except TimeoutError:
                    if not nudging:
                        raise
        except TimeoutError:
            last = self.latest_telemetry
            where = f"; last telemetry at board time {last.board_time_us / 1e6:.3f} s, faults {_flag_names(last.faults)}" if last else "; no telemetry received"
            raise LinkTimeout(f"telemetry condition not met within {timeout} s{where}") from None
        finally:
            if not fut.done():
                fut.cancel()
            self.fanout.forget(fut)

    #: wall seconds between the ADVANCEs of :meth:`wait_for` with ``nudge`` (a lockstep board answers in ~1 ms)
    NUDGE_S = 0.1
    #: wall seconds without a satisfying report before a nudge moves its ADVANCE target further (a
    #: report lost on a lossy link); until then it repeats the target (it was pushed 5 periods ahead of
    #: a slow QEMU board in 0.5 s, whose next frames then arrived LATE)
    NUDGE_RAISE_S = 1.0

    def report_period_us(self) -> int:
        """One telemetry period plus one control tick (us): an ADVANCE this far always yields a report."""
        caps = self.caps
        rate = caps.telemetry_rate_hz if caps is not None and caps.telemetry_rate_hz > 0 else 50
        tick = caps.control_rate_hz if caps is not None and caps.control_rate_hz > 0 else 500
        return 1_000_000 // rate + 1_000_000 // tick

    async def next_telemetry(self, timeout: float) -> Telemetry:
        """The next telemetry report received after this call."""
        fut = self.fanout.waiter(lambda _t: True)
        try:
            return await asyncio.wait_for(fut, timeout)
        except TimeoutError:
            raise LinkTimeout(f"no telemetry within {timeout} s") from None
        finally:
            self.fanout.forget(fut)
